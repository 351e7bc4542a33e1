"""How far off-centre pushes turn the pushed object away from the pusher's motion, how far a
model rolled as the planner rolls it says they do, and how much of the object its predicted
cloud leaves behind (``se3push deflection``), by shape and off-centre angle, on held-out data.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from evaluation.study import _moving_windows, _window_states
from planner.dynamics import PlanState, planar_fit, to_world
from sim.planar import angle_between_deg

STILL_M = 1e-4
"""a predicted displacement shorter than this has no direction: ``push_deflection`` leaves
it out of the angle medians (it counts such windows as ``predicted_still``)"""

OFF_CENTRE_BINS_DEG = ((0, 15), (15, 30), (30, 45), (45, 90))
"""how far off the object's centre a push was aimed (deg), the bins of ``push_deflection``"""

LEFT_BEHIND = 0.5
"""a point of the pushed object is left behind by a predicted step that moves it less than this
share of how far the rigid motion fitted to the object's predicted points moves it"""


def left_behind(state: PlanState, cloud: torch.Tensor) -> float:
    """The share of the pushed object's seen points that a predicted cloud leaves behind
    (``LEFT_BEHIND``), measured against the planar rigid motion that best fits the object's
    predicted points (``planar_fit``, as the planner tracks it): a model that moves the object
    as one body leaves none, however far it moves it (a short step is the length ratio's to
    measure, not this); one whose masks tear it (part of it kept on a static mask) leaves
    that part.

    Args:
        state: the step's planner state (its cloud at the camera's resolution).
        cloud: (3,h,w) the predicted cloud after the step, camera frame, at the model's
            resolution (every ``H // h``-th pixel of the camera's).

    Returns:
        The share, or nan where no point of the object is seen at the model's resolution or
        the fitted motion moves its points less than ``STILL_M`` on average (no step to tear).
    """
    from se3net.data import subsample

    stride = state.points.shape[-2] // cloud.shape[-2]
    seen = subsample(state.object_mask & state.valid, stride).flatten()
    if not seen.any():  # hidden at the model's resolution
        return float("nan")
    T = state.T_world_cam.to(cloud)
    before = to_world(T, subsample(state.points, stride).flatten(1)[:, seen].T)[:, :2].double()
    after = to_world(T, cloud.flatten(1)[:, seen].T)[:, :2].double()
    centre = before.mean(0)
    yaw, xy = planar_fit(before, after[None], centre)
    c, s = torch.cos(yaw[0]), torch.sin(yaw[0])
    fitted = (before - centre) @ torch.stack([torch.stack([c, s]), torch.stack([-s, c])]) + xy
    rigid = (fitted - before).norm(dim=1)
    if float(rigid.mean()) < STILL_M:
        return float("nan")
    moved = (after - before).norm(dim=1)
    return float((moved < LEFT_BEHIND * rigid).double().mean())


@torch.no_grad()
def push_deflection(
    models: list,
    data: str | Path,
    *,
    object_index: int = 0,
    max_windows: int = 2000,
    split: str = "test",
) -> list[list[dict[str, Any]]]:
    """How far a push turns the object's motion away from the pusher's, and how far each model
    says it does, over the same one-step held-out windows where the object moves (read once;
    ``split``: the data's test split, or ``all`` of a dataset held out as a whole).

    A push aimed off the object's centre (the angle between the pusher's commanded velocity
    and the line from the pusher to the centre) deflects the object: a round one moves along
    the contact normal, not the pusher's way. For each of ``models`` (backends as the planner
    rolls them, ``make_dynamics``), one row per object shape and off-centre bin
    (``OFF_CENTRE_BINS_DEG``): the windows, and the medians of the true and the predicted
    deflection (deg from the pusher's velocity), of the angle between the predicted and the
    true displacement (over windows where the model predicts motion; None where it predicts
    none), and of their length ratio; and the mean share of the object's points the predicted
    cloud leaves behind (:func:`left_behind`; None for a backend without clouds).
    """
    from se3net.data import PushDataset

    ds = PushDataset(data, split=split, horizon=1)
    pick, start, end = _moving_windows(ds, data, object_index, max_windows, split)
    cells: list[dict[tuple[str, int], list[tuple[float, ...]]]] = [{} for _ in models]
    for k, (state, actions, obj) in enumerate(_window_states(ds, pick, start, object_index)):
        v = actions[0, 0].numpy()
        to_centre = start[k, :2] - state.pusher_xy.numpy()
        if np.linalg.norm(v) < 1e-6 or np.linalg.norm(to_centre) < 1e-6:
            continue  # no push to measure from
        off = angle_between_deg(v, to_centre)
        b = next((i for i, (lo, hi) in enumerate(OFF_CENTRE_BINS_DEG) if lo <= off < hi), None)
        if b is None:  # moving away from the centre: not a push
            continue
        true = end[k, :2] - start[k, :2]
        for dynamics, mine in zip(models, cells, strict=True):
            roll = dynamics.rollout(state, actions, clouds=True)
            pred = roll.object_poses[0, -1].numpy()[:2] - start[k, :2]
            still = np.linalg.norm(pred) < STILL_M  # no predicted direction to measure
            behind = np.nan if roll.clouds is None else left_behind(state, roll.clouds[0, -1])
            mine.setdefault((obj.shape, b), []).append(
                (angle_between_deg(v, true), np.nan if still else angle_between_deg(v, pred),
                 np.nan if still else angle_between_deg(pred, true),
                 float(np.linalg.norm(pred) / np.linalg.norm(true)), behind)
            )  # fmt: skip
    return [_deflection_rows(mine) for mine in cells]


def _deflection_rows(cells: dict[tuple[str, int], list[tuple[float, ...]]]) -> list[dict]:
    """``push_deflection``'s rows of one model from its (shape, bin) cells of windows."""
    rows = []
    for (shape, b), vals in sorted(cells.items()):
        a = np.array(vals)
        moved = a[np.isfinite(a[:, 1])]
        pred_deg, err_deg = np.median(moved[:, 1:3], 0) if len(moved) else (None, None)
        rows.append({
            "shape": shape, "off_centre_deg": list(OFF_CENTRE_BINS_DEG[b]), "windows": len(vals),
            "predicted_still": len(a) - len(moved),
            "true_deflection_deg": float(np.median(a[:, 0])),
            "predicted_deflection_deg": None if pred_deg is None else float(pred_deg),
            "direction_error_deg": None if err_deg is None else float(err_deg),
            "length_ratio": float(np.median(a[:, 3])),
            "left_behind": None if np.isnan(a[:, 4]).all() else float(np.nanmean(a[:, 4])),
        })  # fmt: skip
    return rows
