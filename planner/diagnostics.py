"""Exploitation diagnostics: where the planner's model was wrong along the planner's own path.

For every executed step the closed loop records the pushed object's displacement that the
chosen plan predicted for the executed action and the displacement that happened, and the
progress toward the goal each implies. Over a trial (or pooled over many) that gives:

- phantom-motion rate: of the steps where the object moved less than ``STILL_M``, the
  fraction where the model predicted more than ``PHANTOM_M`` (the planner "saw" a push
  that did not happen);
- missed-motion rate: of the steps where the object moved more than ``PUSHED_M``, the
  fraction where the model predicted less than ``MISSED_M``;
- progress ratio: predicted over actual progress toward the goal position, summed over the
  steps (1 is an honest model; above 1 the planner is being flattered).

Pooled over trials in ``evaluation.diagnostics``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

STILL_M = 1e-3
"""the object counts as still below this displacement"""
PHANTOM_M = 3e-3
"""a prediction above this over a still object is phantom motion"""
PUSHED_M = 3e-3
"""the object counts as pushed above this displacement"""
MISSED_M = 1e-3
"""a prediction below this over a pushed object is missed motion"""
MIN_PROGRESS_M = 1e-3
"""below this much actual progress the ratio is undefined (None)"""

STEP_FIGURES = ("predicted_disp_m", "actual_disp_m", "predicted_progress_m", "actual_progress_m")
"""what :func:`step_figures` gives for each executed step"""
COUNT_KEYS = ("still_steps", "phantom_steps", "moved_steps", "missed_steps")
SUM_KEYS = ("predicted_progress_m", "actual_progress_m")


def step_figures(
    before: np.ndarray, predicted: np.ndarray, after: np.ndarray, goal: np.ndarray
) -> dict[str, float]:
    """One executed step: predicted and actual displacement and progress toward the goal (m).

    Args:
        before: (3,) the object's pose when the plan was made.
        predicted: (3,) the pose the plan predicted after its first (executed) action.
        after: (3,) the pose observed after the action.
        goal: (3,) the goal pose.
    """
    xy = [np.asarray(a, dtype=float)[:2] for a in (before, predicted, after, goal)]
    before, predicted, after, goal = xy
    d0 = np.hypot(*(before - goal))
    return {
        "predicted_disp_m": float(np.hypot(*(predicted - before))),
        "actual_disp_m": float(np.hypot(*(after - before))),
        "predicted_progress_m": float(d0 - np.hypot(*(predicted - goal))),
        "actual_progress_m": float(d0 - np.hypot(*(after - goal))),
    }


def rates(counts: dict[str, Any]) -> dict[str, Any]:
    """Add the three ratios to summed counts (None where the denominator is empty)."""
    still, moved, actual = counts["still_steps"], counts["moved_steps"], counts["actual_progress_m"]
    return {
        **counts,
        "phantom_rate": counts["phantom_steps"] / still if still else None,
        "missed_rate": counts["missed_steps"] / moved if moved else None,
        "progress_ratio": counts["predicted_progress_m"] / actual
        if actual > MIN_PROGRESS_M
        else None,
    }


def exploitation(steps: Sequence[dict[str, float]]) -> dict[str, Any]:
    """Counts, sums and rates over a sequence of :func:`step_figures` dicts."""
    pred = np.array([s["predicted_disp_m"] for s in steps], dtype=float)
    act = np.array([s["actual_disp_m"] for s in steps], dtype=float)
    still, moved = act < STILL_M, act > PUSHED_M
    return rates(
        {
            "still_steps": int(still.sum()),
            "phantom_steps": int((still & (pred > PHANTOM_M)).sum()),
            "moved_steps": int(moved.sum()),
            "missed_steps": int((moved & (pred < MISSED_M)).sum()),
            **{k: float(sum(s[k] for s in steps)) for k in SUM_KEYS},
        }
    )
