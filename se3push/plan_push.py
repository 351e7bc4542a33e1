"""``plan-push``: one closed-loop push in simulation, a line per step and a result line; exit
code 0 when the object ends within ``--tolerance`` (2 cm, 10 deg by default), 1 when not, 2 on
bad input."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from collections.abc import Sequence

from se3push.options import (
    plan_settings,
    planning_options,
    run_command,
    tolerance,
    tolerance_option,
)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="plan-push",
        description="push an object to a goal pose with MPC over a learned SE3-Net",
    )
    p.add_argument("--goal", nargs=3, type=float, required=True, metavar=("X", "Y", "YAW_DEG"),
                   help="goal pose in the world frame: metres, metres, degrees")  # fmt: skip
    p.add_argument("--scenario", default="single_box", help="scenario name or TOML path")
    p.add_argument("--object", type=int, default=0, help="index of the object to push")
    p.add_argument(
        "--model",
        default="default",
        help="default (the shipped SE3-Net), pose (the shipped pose model), single_box or "
        "single_box_64 (earlier shipped models), a checkpoint path, checkpoints joined by + (an "
        "ensemble whose disagreement the cost penalises), oracle or no-motion",
    )
    planning_options(p)
    tolerance_option(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the world and the planner")
    p.add_argument("--max-steps", type=int, default=60, help="control steps before giving up")
    p.add_argument("--device", default="cpu", help="device of a learned model")
    p.add_argument("--threads", type=int, default=None,
                   help="torch threads (default: torch's own, one per core)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the result line as JSON")
    p.add_argument(
        "--viz", action="store_true", help="show the push live in meshcat (prints the URL)"
    )
    p.add_argument(
        "--record", metavar="HTML", help="write the push as a self-contained meshcat HTML animation"
    )
    return p


def _terminated(signum: int, _frame: object) -> None:
    raise SystemExit(128 + signum)


def _push(args: argparse.Namespace) -> int:
    import json
    import math

    from planner.loop import PushConfig, run_push, within

    x, y, yaw_deg = args.goal
    cfg = PushConfig(
        goal=(x, y, math.radians(yaw_deg)), scenario=args.scenario, object_index=args.object,
        model=args.model, seed=args.seed, max_steps=args.max_steps, device=args.device,
        plan=plan_settings(args), tolerance=tolerance(args),
    )  # fmt: skip

    def show(rec) -> None:
        if not args.json:
            print(
                f"step {rec.step:3d}  pos err {rec.pos_err_m * 100:5.1f} cm  "
                f"yaw err {rec.yaw_err_deg:5.1f} deg  replan {rec.replan_ms:6.0f} ms",
                flush=True,
            )

    viz = None
    if args.viz or args.record:
        from integrations.viz import MeshcatVisualiser

        viz = MeshcatVisualiser(live=args.viz, record=args.record)
        # SIGTERM ends the push as an exception would, so that meshcat's server is stopped
        # (its own cleanup runs only at a normal exit)
        signal.signal(signal.SIGTERM, _terminated)
    # with --json, stdout is the JSON line alone: the rest (meshcat's URL, the file written)
    # goes to stderr
    with contextlib.redirect_stdout(sys.stderr if args.json else sys.stdout):
        if args.threads is None:
            result = run_push(cfg, on_step=show, viz=viz)
        else:
            from evaluation.trials import worker_threads
            from sim.jobs import torch_threads

            with torch_threads(worker_threads(args.threads)):
                result = run_push(cfg, on_step=show, viz=viz)
        if args.record:
            print(f"wrote {args.record} ({viz.frames} frames)")
    reached = within((result.final_pos_err_m, result.final_yaw_err_deg), cfg.tolerance)
    if args.json:
        print(json.dumps(result.summary()))
    else:
        verdict = "SUCCESS" if reached else "FAILURE"
        print(
            f"{verdict}: final error {result.final_pos_err_m * 100:.1f} cm, "
            f"{result.final_yaw_err_deg:.1f} deg ({result.reason}); {result.steps} steps, "
            f"{result.sim_time_s:.2f} s simulated; median replan {result.replan_ms_median:.0f} ms; "
            f"within {cfg.tolerance[0] * 100:g} cm & {cfg.tolerance[1]:g} deg: {reached}"
        )
        if result.others_moved_m is not None:
            print(f"the other objects moved at most {result.others_moved_m * 100:.1f} cm")
    return 0 if reached else 1


def main(argv: Sequence[str] | None = None) -> int:
    """``plan-push`` entry point: 0 if the object reached the goal, 1 if not, 2 on bad input."""
    return run_command(_push, _parser().parse_args(argv))
