"""Diagnostics pooled over trials: the exploitation rates of many pushes, how directly they
carried the object, how often the pusher was out of sight, and the pauses between pushes.

The per-step figures they pool are the closed loop's (``planner.diagnostics``). The *pauses*,
runs of still steps between two steps that moved the object, are the steps a planner took to
get back behind the object and push again (a planner shunning the short way round makes them
long).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from planner.diagnostics import COUNT_KEYS, MIN_PROGRESS_M, STILL_M, SUM_KEYS, rates


def path_efficiency(trials: Iterable[Sequence[dict[str, float]]]) -> float | None:
    """How directly the pushes carried the object: of the distance it travelled, the share that
    brought it closer to the goal position, pooled over trials (the summed actual progress
    over the summed actual displacement of their :func:`step_figures`). 1 is a straight line
    to the goal; a planner whose model turns the pushes wrong moves the object as far per
    step but wanders. None where the object never moved."""
    progress = path = 0.0
    for steps in trials:
        progress += sum(s["actual_progress_m"] for s in steps)
        path += sum(s["actual_disp_m"] for s in steps)
    return progress / path if path > MIN_PROGRESS_M else None


def unseen_share(trials: Iterable[Sequence[dict[str, Any]]]) -> float | None:
    """Of the steps planned, pooled over trials, the share planned while the camera did not
    see the pusher (``pusher_seen`` of the per-step records): a learned model that cannot see
    the pusher predicts little from it. None where no step records it (older records)."""
    seen = [s["pusher_seen"] for steps in trials for s in steps if "pusher_seen" in s]
    return 1.0 - sum(seen) / len(seen) if seen else None


def pauses(actual_disp_m: Sequence[float]) -> list[int]:
    """The lengths of the runs of still steps (below ``STILL_M``) between two steps that moved
    the object, over one trial's actual displacements."""
    moved = [i for i, d in enumerate(actual_disp_m) if d >= STILL_M]
    return [b - a - 1 for a, b in zip(moved, moved[1:], strict=False) if b - a > 1]


def pooled(per_trial: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """Pool :func:`exploitation` results of several trials (sums of counts, then the rates)."""
    per_trial = list(per_trial)
    return rates(
        {
            **{k: int(sum(t[k] for t in per_trial)) for k in COUNT_KEYS},
            **{k: float(sum(t[k] for t in per_trial)) for k in SUM_KEYS},
        }
    )
