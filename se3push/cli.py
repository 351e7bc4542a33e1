"""Command line: ``se3push <command>`` and ``plan-push``.

Each command parses its arguments, builds its config and calls one library function. Errors
the user can fix (a bad scenario, a bad argument) are printed as one line and give exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from scenarios import ScenarioError
from sim import ActionError

USER_ERRORS = (ScenarioError, ActionError, FileNotFoundError, PermissionError, ValueError)


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from scenarios import list_scenarios

    scenarios = list_scenarios()
    width = max(map(len, scenarios))
    for name, description in scenarios.items():
        print(f"{name:<{width}}  {description}")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from sim.render import render_scene

    summary = render_scene(args.scenario, args.seed, args.out)
    pixels = ", ".join(f"{k} {v}" for k, v in summary["pixels"].items())
    print(
        f"wrote {args.out}: step {summary['steps']}, max flow {summary['max_flow_m'] * 1e3:.1f} mm"
    )
    print(f"pixels per part: {pixels}")
    return 0


def _cmd_data(args: argparse.Namespace) -> int:
    if args.inspect:
        from se3push.report import inspect_data

        print(inspect_data(args.inspect))
        return 0
    from sim.dataset import DataConfig, generate
    from sim.datastore import summarize

    if args.episodes is None:
        raise ValueError("--episodes is required to generate data (or give --inspect DIR)")
    cfg = DataConfig(
        scenario=args.scenario,
        episodes=args.episodes,
        steps_per_episode=args.steps_per_episode,
        seed=args.seed,
    )
    manifest = generate(cfg, args.out, workers=args.workers)
    st = summarize(manifest)
    print(
        f"wrote {args.out}: {st['episodes']} episodes, {st['examples']} examples, "
        f"object moves in {st['object_motion_fraction']:.1%}; inspect with "
        f"`se3push data --inspect {args.out}`"
    )
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from se3push.bench import run_bench

    run_bench(args.what, repeats=args.repeats, json_path=args.json)
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="se3push", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("scenarios", help="list the packaged scenarios")
    s.set_defaults(run=_cmd_scenarios)

    s = sub.add_parser("render", help="write a PNG of depth, segmentation and one step's flow")
    s.add_argument("--scenario", default="single_box", help="scenario name or TOML path")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", default="scene.png", help="PNG path")
    s.set_defaults(run=_cmd_render)

    s = sub.add_parser("data", help="generate training episodes, or --inspect a dataset")
    s.add_argument("--scenario", default="single_box", help="scenario name or TOML path")
    s.add_argument("--episodes", type=int, help="number of episodes to generate")
    s.add_argument("--out", default="data/single_box", help="dataset folder")
    s.add_argument("--workers", type=int, default=1, help="processes (same bytes for any number)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--steps-per-episode", type=int, default=20, help="actions per episode")
    s.add_argument("--inspect", metavar="DIR", help="print a dataset's manifest and statistics")
    s.set_defaults(run=_cmd_data)

    s = sub.add_parser("bench", help="time the hot paths (medians over repeats)")
    s.add_argument("what", choices=["world", "data"], help="which benchmark")
    s.add_argument("--repeats", type=int, default=20, help="timed repeats per figure")
    s.add_argument("--json", default=None, metavar="PATH", help="also write the figures as JSON")
    s.set_defaults(run=_cmd_bench)
    return p


def _run(run: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    try:
        return run(args)
    except USER_ERRORS as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


def main(argv: Sequence[str] | None = None) -> int:
    """``se3push`` entry point; returns the exit code."""
    args = _parser().parse_args(argv)
    return _run(args.run, args)


if __name__ == "__main__":
    sys.exit(main())
