"""Text reports for people (tables, summaries); the figures come from library functions."""

from __future__ import annotations

from pathlib import Path

from sim.datastore import read_manifest, summarize
from sim.render import dataset_examples_png


def inspect_data(root: str | Path) -> str:
    """A dataset's manifest and statistics as text; also writes ``ROOT/inspect.png``."""
    root = Path(root)
    manifest = read_manifest(root)
    ident, st = manifest["identity"], summarize(manifest)
    png = root / "inspect.png"
    shown = dataset_examples_png(root, png)
    mix = ", ".join(
        f"{m} {f:.0%}" for m, f in sorted(st["mode_fractions"].items(), key=lambda x: -x[1])
    )
    exp, cam = ident["exploration"], ident["scenario"]["camera"]
    if "joints_moved" in exp:  # joint-velocity exploration (sim.joint_explore)
        (j0, j1), (f0, f1) = exp["joints_moved"], exp["speed_fraction"]
        s0, s1 = exp["scene_steps"]
        policy = (
            f"scenes of {j0}-{j1} joints at {f0}-{f1} of the speed bound for {s0}-{s1} steps, "
            f"rest {exp['p_rest']} (per scene)"
        )
    else:
        policy = (
            f"aimed {exp['p_aimed']}, glance {exp['p_glance']}, free {exp['p_free']}, "
            f"rest {exp['p_rest']} (per segment)"
        )
    lines = [
        f"dataset {root}",
        f"  scenario            {ident['scenario']['name']} "
        f"({cam['width']}x{cam['height']} camera)",
        f"  seed                {ident['seed']}",
        f"  episodes            {st['episodes']} x {ident['steps_per_episode']} steps "
        f"in {len(manifest['shards'])} shards",
        f"  code version        {manifest['code_version']} (data format {ident['format']})",
        f"  control layout      {', '.join(ident['control_layout'])}",
        f"  policy mixture      {policy}",
        f"  steps by mode       {mix}",
        f"  examples (h = 1)    {st['examples']}",
        f"  object moves        {st['object_motion_fraction']:.1%} of examples (> 1 mm; none "
        "without objects)",
        f"  moving points       {st['moving_points_per_example']:.0f} per example "
        f"(true flow > {st['moving_threshold_m'] * 1e3:.1f} mm)",
        f"  flow of moving pts  mean {st['mean_flow_m'] * 1e3:.2f} mm, "
        f"95th percentile {st['p95_flow_m'] * 1e3:.2f} mm",
        f"  no-motion MSE       {st['no_motion_mse_cm2']:.3f} cm^2 (h = 1; every moving point, "
        "seen or not: eval's counts the seen ones)",
        f"  QP failures         {st['qp_failures']}",
        f"  picture             {png} (episode, t: {shown})",
    ]
    return "\n".join(lines)
