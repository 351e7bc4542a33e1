"""Command line: ``se3push <command>`` (``plan-push`` is ``se3push.plan_push``).

Each command parses its arguments, builds its config and calls one library function; the
exit codes are ``se3push.options.run_command``'s.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from scenarios import InputError
from se3push.cli_train import add_train_parser
from se3push.options import (
    backend,
    backend_options,
    closed_loop_options,
    feedback_option,
    noise_option,
    plan_settings,
    planning_options,
    run_command,
    split_option,
    tolerance,
    tolerance_option,
)


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
        raise InputError("--episodes is required to generate data (or give --inspect DIR)")
    cfg = DataConfig(
        scenario=args.scenario,
        episodes=args.episodes,
        steps_per_episode=args.steps_per_episode,
        seed=args.seed,
    )
    manifest = generate(cfg, args.out, workers=args.workers, **backend(args))
    st = summarize(manifest)
    motion = (
        f"object moves in {st['object_motion_fraction']:.1%}"
        if manifest["identity"]["scenario"]["objects"]["count"][1] > 0
        else f"{st['moving_points_per_example']:.0f} moving points per example"
    )
    print(
        f"wrote {args.out}: {st['episodes']} episodes, {st['examples']} examples, {motion}; "
        f"inspect with `se3push data --inspect {args.out}`"
    )
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    from se3net.evaluate import evaluate, table_markdown

    results = evaluate(
        args.checkpoints, args.data, args.out, max_examples=args.max_examples, split=args.split,
        noise=args.noise, device=args.device, feedback=args.feedback,
    )  # fmt: skip
    print(table_markdown(results, args.data))
    print(f"wrote {args.out}/table.md, eval.json and example PNGs")
    return 0


def _cmd_trials(args: argparse.Namespace) -> int:
    from evaluation.report import format_summary
    from evaluation.trials import TrialsConfig, run_trials

    cfg = TrialsConfig(scenario=args.scenario, n=args.n, model=args.model, seed=args.seed,
                       max_steps=args.max_steps, plan=plan_settings(args),
                       tolerance=tolerance(args))  # fmt: skip
    s = run_trials(cfg, args.out, workers=args.workers, threads=args.threads, **backend(args))
    print(format_summary(s, f"{args.model} / {cfg.plan.planner} on {args.scenario}, "
                            f"{s['trials']} trials (seed {args.seed})"))  # fmt: skip
    held = json.loads(Path(args.out, "config.json").read_text())["n"]
    if held > cfg.n:  # a prefix of the folder's set: run_trials wrote nothing
        print(f"summarised the first {cfg.n} of the {held} trials in {args.out}; its files "
              "are unchanged")  # fmt: skip
    else:
        print(f"wrote {args.out}/trials.jsonl, summary.json, paths.png")
    return 0


def _cmd_study(args: argparse.Namespace) -> int:
    from evaluation.study import StudyConfig, run_study

    cfg = StudyConfig(scenario=args.scenario, data=args.data, models=tuple(args.models),
                      trials=args.trials, seed=args.seed, max_steps=args.max_steps,
                      max_examples=args.max_examples, plan=plan_settings(args))  # fmt: skip
    result = run_study(cfg, args.out, workers=args.workers)
    print((Path(args.out) / "study.md").read_text())
    print(f"wrote {args.out}/study.md, study.json, study.png and trials/")
    return 0 if result["rows"] else 1


def _cmd_deflection(args: argparse.Namespace) -> int:
    from evaluation.deflection import push_deflection
    from evaluation.study import BACKEND_MODELS, parse_models, study_dynamics
    from planner.dynamics import CONTACT_MARGIN_M, PLAN_FEEDBACK
    from se3net.checkpoint import refuse_trained_on
    from sim.datastore import read_manifest, scenario_of
    from sim.shards import atomic_write_json

    if args.max_windows < 1:
        raise InputError(f"--max-windows must be positive, got {args.max_windows}")
    models = parse_models(args.models)
    for _, model in models:
        if model in BACKEND_MODELS:
            raise InputError(f"--models: {model} has no deflection to measure; name checkpoints")
    manifest = read_manifest(args.data)
    if args.split == "all":
        refuse_trained_on([model for _, model in models], manifest, args.data)
    scenario = scenario_of(manifest)
    dynamics = [study_dynamics(m, scenario, PLAN_FEEDBACK, CONTACT_MARGIN_M) for _, m in models]
    tables = push_deflection(dynamics, args.data, max_windows=args.max_windows, split=args.split)
    lines = [
        "| model | shape | off centre | windows (predicted still) | true deflection | predicted | "
        "direction error | length pred/true | left behind |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (label, _), rows in zip(models, tables, strict=True):
        for r in rows:
            lo, hi = r["off_centre_deg"]
            pred, err = (
                "–" if x is None else f"{x:.1f} deg"
                for x in (r["predicted_deflection_deg"], r["direction_error_deg"])
            )
            behind = "–" if r["left_behind"] is None else f"{r['left_behind']:.0%}"
            lines.append(
                f"| {label} | {r['shape']} | {lo}-{hi} deg | {r['windows']} "
                f"({r['predicted_still']}) | {r['true_deflection_deg']:.1f} deg | {pred} | "
                f"{err} | {r['length_ratio']:.2f} | {behind} |"
            )
    print("\n".join(lines))
    if args.json:
        out = {label: rows for (label, _), rows in zip(models, tables, strict=True)}
        atomic_write_json(Path(args.json), {"data": args.data, "models": out})
        print(f"wrote {args.json}")
    return 0


def _cmd_improve(args: argparse.Namespace) -> int:
    from evaluation.improve import ImproveConfig, run_improve

    cfg = ImproveConfig(
        scenarios=tuple(args.scenario), model=args.model, data=tuple(args.data),
        measure_only=tuple(args.measure_only), rounds=args.rounds,
        trials_per_round=args.trials_per_round, heldout=args.heldout, seed=args.seed,
        action_noise=args.action_noise, finetune_iters=args.finetune_iters,
        lr=args.lr, max_steps=args.max_steps,
        visited_fraction=args.visited_fraction, plan=plan_settings(args),
    )  # fmt: skip
    run_improve(cfg, args.out, workers=args.workers, **backend(args))
    print((Path(args.out) / "improve.md").read_text())
    print(f"wrote {args.out}/improve.md, improve.json, improve.png and round_*/")
    return 0


def _cmd_config(args: argparse.Namespace) -> int:
    from planner.settings import settings_toml

    print(settings_toml(plan_settings(args)), end="")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from se3push.bench import run_bench

    options = (
        {"model": args.model, "flow_model": args.flow_model, "device": args.device}
        if args.what == "planner"
        else {"model": args.model, "device": args.device}
        if args.what == "horizon"
        else {"device": args.device}
        if args.what == "ddp"
        else {}
    )
    run_bench(args.what, repeats=args.repeats, json_path=args.json, **options)
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    import json

    from evaluation.compare import (
        compare_trials,
        format_comparison,
        format_pooled,
        pool_comparisons,
    )

    pairs = [(args.a, args.b), *(args.pair or [])]
    results = [
        compare_trials(a, b, tolerance=args.tolerance, n=args.n, by=args.by or ()) for a, b in pairs
    ]
    if len(results) == 1:
        print(json.dumps(results[0]) if args.json else format_comparison(results[0]))
        return 0
    pooled = pool_comparisons(results)
    if args.json:
        print(json.dumps({"comparisons": results, "pooled": pooled}))
    else:
        print("\n".join(map(format_comparison, results)) + "\n" + format_pooled(pooled))
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
    backend_options(s)
    s.set_defaults(run=_cmd_data)

    add_train_parser(sub)

    s = sub.add_parser("eval", help="the paper's Table 1 on a dataset's test split")
    s.add_argument("--data", required=True, help="dataset folder")
    split_option(s)
    s.add_argument(
        "--checkpoints", nargs="+", required=True, help="checkpoint files ('default': shipped)"
    )
    s.add_argument("--out", required=True, help="folder for table.md, eval.json and PNGs")
    s.add_argument("--max-examples", type=int, default=2000, help="test examples to use")
    noise_option(s, "test under the paper's robustness noise (Table 2)")
    s.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or mps")
    feedback_option(s, "the predictions of the fed-back rows")
    s.set_defaults(run=_cmd_eval)

    s = sub.add_parser("trials", help="closed-loop trials with success rates")
    closed_loop_options(s, seed_help="seed of the trial set")
    tolerance_option(s)
    s.add_argument("--n", type=int, default=50, help="number of trials")
    s.add_argument(
        "--model",
        default="default",
        help="default (the shipped SE3-Net), pose (the shipped pose model), single_box or "
        "single_box_64 (earlier shipped models), a checkpoint path, checkpoints joined by + "
        "(ensemble), oracle or no-motion",
    )
    planning_options(s)
    s.add_argument("--threads", type=int, default=None,
                   help="torch threads per worker (default 1: the same records for any "
                   "--workers)")  # fmt: skip
    s.add_argument("--out", required=True, help="folder for trials.jsonl, summary.json, paths.png")
    backend_options(s)
    s.set_defaults(run=_cmd_trials)

    s = sub.add_parser("study", help="how model accuracy relates to closed-loop success")
    closed_loop_options(s, seed_help="seed of the trial set")
    s.add_argument("--data", required=True, help="dataset whose test split gives the accuracy")
    s.add_argument(
        "--models",
        nargs="+",
        required=True,
        help="oracle, no-motion, default or checkpoint paths (LABEL=PATH names one)",
    )
    s.add_argument("--trials", type=int, default=30, help="closed-loop trials per model")
    s.add_argument("--max-examples", type=int, default=1000, help="held-out examples per model")
    planning_options(s)
    s.add_argument("--out", required=True, help="folder for study.md/.json/.png and trials/")
    s.set_defaults(run=_cmd_study)

    s = sub.add_parser(
        "deflection", help="how far off-centre pushes turn the object, and how far a model says"
    )
    s.add_argument("--data", required=True, help="dataset whose pushes are measured")
    split_option(s)
    s.add_argument("--models", nargs="+", required=True,
                   help="default or checkpoint paths (LABEL=PATH names one)")  # fmt: skip
    s.add_argument("--max-windows", type=int, default=2000,
                   help="held-out one-step windows where the object moves, per model")  # fmt: skip
    s.add_argument("--json", default=None, help="also write the rows to this JSON file")
    s.set_defaults(run=_cmd_deflection)

    s = sub.add_parser("improve", help="rounds of planner-visited data and fine-tuning")
    closed_loop_options(
        s, seed_help="seed of the held-out trial sets", several=True,
        scenario_help="scenario names or TOML paths: pushes are collected in each and every "
        "round is measured on each",
    )  # fmt: skip
    s.add_argument("--model", required=True, help="starting checkpoint ('default': shipped)")
    s.add_argument("--data", required=True, nargs="+",
                   help="the exploration data folder(s) the model was trained on")  # fmt: skip
    s.add_argument(
        "--measure-only", nargs="*", default=[],
        help="scenarios measured every round but never collected in (held-out objects)",
    )  # fmt: skip
    s.add_argument("--rounds", type=int, default=3)
    s.add_argument("--trials-per-round", type=int, default=20,
                   help="pushes recorded per round in each --scenario")  # fmt: skip
    s.add_argument("--heldout", type=int, default=50,
                   help="held-out trials per scenario measuring each round")  # fmt: skip
    s.add_argument(
        "--action-noise",
        type=float,
        default=0.1,
        help="SD of the noise on executed actions while collecting (x bound)",
    )
    s.add_argument("--finetune-iters", type=int, default=1000)
    s.add_argument("--lr", type=float, default=3e-4)
    s.add_argument(
        "--visited-fraction",
        type=float,
        default=0.5,
        help="share of each fine-tuning batch drawn from the planner-visited data",
    )
    planning_options(s)
    s.add_argument("--out", required=True, help="folder of the rounds (resumable)")
    backend_options(s)
    s.set_defaults(run=_cmd_improve)

    s = sub.add_parser(
        "config", help="print the planning settings as TOML (the defaults, or a preset's)"
    )
    planning_options(s)
    s.set_defaults(run=_cmd_config)

    s = sub.add_parser("bench", help="time the hot paths (medians over repeats)")
    s.add_argument("what", choices=["world", "data", "model", "planner", "sampling", "ddp",
                                    "horizon"],
                   help="which benchmark")  # fmt: skip
    s.add_argument("--repeats", type=int, default=20, help="timed repeats per figure")
    s.add_argument("--json", default=None, metavar="PATH", help="also write the figures as JSON")
    s.add_argument(
        "--model",
        default=None,
        help="planner: the SE3-Net checkpoint to time (default: the shipped one)",
    )
    s.add_argument("--flow-model", default=None, help="planner: also time a flow-net checkpoint")
    s.add_argument("--device", default="cpu",
                   help="planner: device of the learned backends; ddp: of training")  # fmt: skip
    s.set_defaults(run=_cmd_bench)

    s = sub.add_parser(
        "compare", help="pair two trial folders' outcomes: wins, losses, exact McNemar test"
    )
    s.add_argument("a", metavar="A", help="trial folder (from `se3push trials --out`)")
    s.add_argument("b", metavar="B", help="trial folder of the same --scenario and --seed")
    s.add_argument(
        "--tolerance", choices=["precise", "tight", "loose"], default="tight",
        help="pair success within 1 cm & 5 deg (precise: folders whose trials ran on to it), "
        "2 cm & 10 deg (tight) or 5 cm & 20 deg (loose); every tolerance both measured is "
        "reported",
    )  # fmt: skip
    s.add_argument("--n", type=int, default=None,
                   help="compare the first N trials (default: every trial both hold)")  # fmt: skip
    s.add_argument("--pair", nargs=2, action="append", metavar=("A", "B"),
                   help="another pair of folders (another scenario, say); with one or more, "
                        "each pair is compared and then all their trials pooled in one "
                        "test")  # fmt: skip
    s.add_argument("--by", nargs="+", metavar="KEY",
                   help="also compare group by group of the pushed object: shape, size (its "
                        "footprint's longer extent, 2 cm bins), mass (0.1 kg bins), or several "
                        "of them for their combinations")  # fmt: skip
    s.add_argument("--json", action="store_true", help="print the figures as JSON")
    s.set_defaults(run=_cmd_compare)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """``se3push`` entry point; returns the exit code."""
    args = _parser().parse_args(argv)
    return run_command(args.run, args)


if __name__ == "__main__":
    sys.exit(main())
