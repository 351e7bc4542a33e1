"""Planar poses (x_m, y_m, yaw_rad) on the table: the one home of yaw wrapping, of the pose
error that success, trial goals and the planner's cost all measure, and of the angle between
two motions."""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

A = TypeVar("A")


def wrap_angle(angle: A, period: float = 2 * math.pi) -> A:
    """An angle difference wrapped to [-period/2, period/2) (a float, an array or a tensor).

    ``period`` is the object's yaw symmetry: 2π for no symmetry, π for a box, π/2 for a box
    with a square footprint.
    """
    return (angle + period / 2) % period - period / 2


def pose_errors(pose: np.ndarray, goal: np.ndarray, period: float | None) -> tuple[float, float]:
    """Position error (m) and symmetry-aware yaw error (deg) of a planar pose.

    Args:
        pose, goal: (3,) x_m, y_m, yaw_rad.
        period: the object's yaw symmetry (``ObjectSpec.yaw_period_rad``); None for an object
            that looks the same at any yaw (a cylinder), whose yaw error is 0.
    """
    pos = float(np.hypot(*(np.asarray(pose[:2]) - np.asarray(goal[:2]))))
    if period is None:
        return pos, 0.0
    return pos, abs(math.degrees(float(wrap_angle(pose[2] - goal[2], period))))


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The unsigned angle (deg) between planar vectors ``a`` and ``b`` (...,2), e.g. how far an
    object's step turns away from the pusher's motion (90 where either is zero: no direction)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c = (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1) + 1e-12)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
