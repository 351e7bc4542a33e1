"""What the commands share: the options of closed-loop, planning and scaling commands, and
how a command's errors become exit codes.

Input that was checked and refused (``scenarios.InputError``: a bad scenario, argument, file or
folder) is printed as one line and gives exit code 2; a full or read-only output folder too;
Ctrl-C gives one line and exit code 130; a reader that stops early (``| head``) ends the
command quietly with exit code 141, as a shell's SIGPIPE would; any other exception is a bug
and shows its traceback (exit code 1).
"""

from __future__ import annotations

import argparse
import gc
import os
import signal
import sys
from collections.abc import Callable

from scenarios import InputError

USER_ERRORS = (InputError, FileNotFoundError, FileExistsError, PermissionError)
"""refused input (ScenarioError, ActionError, DataError, CheckpointError are InputErrors) and
the OS's word on the user's paths"""


def closed_loop_options(
    s: argparse.ArgumentParser,
    *,
    seed_help: str,
    scenario_help: str = "scenario name or TOML path",
    several: bool = False,
) -> None:
    """The options every command that runs closed-loop trials shares (``several``: the
    command takes one or more scenarios)."""
    s.add_argument("--scenario", default=["single_box"] if several else "single_box",
                   nargs="+" if several else None, help=scenario_help)  # fmt: skip
    s.add_argument("--seed", type=int, default=0, help=seed_help)
    s.add_argument("--max-steps", type=int, default=60, help="control steps per trial")
    s.add_argument("--workers", type=int, default=1, help="processes for the trials")


def tolerance_option(s: argparse.ArgumentParser) -> None:
    """``--tolerance``: a name or two numbers; :func:`tolerance` reads it."""
    s.add_argument(
        "--tolerance", nargs="+", default=["tight"], metavar="NAME|M DEG",
        help="the push goes on until the object is within this of its goal: precise (1 cm, "
        "5 deg), tight (2 cm, 10 deg; the default), loose (5 cm, 20 deg), or metres and degrees",
    )  # fmt: skip


def tolerance(args: argparse.Namespace) -> tuple[float, float]:
    """The tolerance of :func:`tolerance_option`'s flag."""
    from planner.loop import check_tolerance

    given = args.tolerance
    if len(given) == 1:
        return check_tolerance(given[0])
    try:
        pos, yaw = (float(x) for x in given)
    except ValueError:
        raise InputError(
            f"--tolerance is a name or two numbers (metres, degrees), got {' '.join(given)}"
        ) from None
    return check_tolerance((pos, yaw))


def backend_options(s: argparse.ArgumentParser) -> None:
    """Where the independent jobs of a command run (``sim.jobs``)."""
    s.add_argument(
        "--backend", choices=["local", "ray"], default="local",
        help="local: a process pool on this machine; ray: Ray workers (pip install -e "
        "\".[scale]\"); the same records and bytes either way",
    )  # fmt: skip
    s.add_argument(
        "--address", default=None,
        help="ray: the address of an existing Ray cluster (default: start one here with "
        "--workers CPUs); its nodes must see the same files",
    )  # fmt: skip


def backend(args: argparse.Namespace) -> dict:
    """``backend`` and ``address`` from :func:`backend_options`' flags."""
    return {"backend": args.backend, "address": args.address}


def noise_option(s: argparse.ArgumentParser, what: str) -> None:
    s.add_argument(
        "--noise", default="none",
        help=f"{what}: none, or a noise of the paper's Table 2 by name (depth-scaled, depth, "
        "assoc-9, ...; a wrong name lists them)",
    )  # fmt: skip


def feedback_option(s: argparse.ArgumentParser, what: str, default: str = "grid") -> None:
    """``--feedback``: how ``what`` is fed back (``se3net.rollout.FEEDBACK``)."""
    s.add_argument(
        "--feedback", default=default, metavar="grid|rendered",
        help=f"how {what} are fed back as the next input: on the observed pixel grid (the "
        f"paper's way) or rendered again by the camera (default {default})",
    )  # fmt: skip


def split_option(s: argparse.ArgumentParser) -> None:
    """``--split``: the episodes of a dataset that a measurement reads."""
    s.add_argument(
        "--split", choices=["test", "all"], default="test",
        help="the dataset's episodes to use: its test split, or all (a held-out dataset)",
    )  # fmt: skip


def planning_options(s: argparse.ArgumentParser) -> None:
    """The planning settings of a command that pushes (``planner.settings.PlanSettings``): a
    preset, a TOML file, single settings, and the optimiser by name."""
    from planner.presets import PRESETS

    s.add_argument("--planner", default=None, help="optimiser: cem, mppi, grad or sqp")
    s.add_argument("--preset", default=None, choices=list(PRESETS),
                   help="a named planner: an earlier one, or long (1.2 s ahead); "
                   "default: today's")  # fmt: skip
    s.add_argument("--config", default=None, metavar="FILE.toml",
                   help="planning settings from a TOML file (`se3push config`)")  # fmt: skip
    s.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="assign",
                   help="one planning setting, e.g. --set optimiser.horizon_s=0.6 --set "
                   "cost.w_keepout=0 (after --preset and --config; repeatable)")  # fmt: skip


def plan_settings(args: argparse.Namespace):
    """The ``PlanSettings`` of :func:`planning_options`' flags."""
    from planner.settings import resolve_settings

    return resolve_settings(preset=args.preset, config=args.config, assignments=args.assign,
                            flags={"planner": args.planner})  # fmt: skip


def run_command(run: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    from sim.folders import unwritable

    try:
        return run(args)
    except BrokenPipeError:  # a reader that stopped early (`| head`): not an error of ours
        # what is still buffered would raise again at exit; send it nowhere
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + int(signal.SIGPIPE)
    except USER_ERRORS as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # a full, read-only or forbidden folder is the user's to fix
        if (refused := unwritable(err)) is None:
            raise
        print(f"error: {refused}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass
    # after the except block, so that the interrupted frames are gone and their progress bars
    # have drawn their last line: the message is the last line
    gc.collect()
    print(
        "interrupted: run the same command again to continue where it stopped "
        "(train: with --resume)",
        file=sys.stderr,
    )
    return 130
