"""A toy with known dynamics and a known optimum: a disk carried by a point pusher.

The disk moves exactly with the pusher (x_{h+1} = x_h + dt a_h), so the push cost without its
shaping term is a box-constrained linear least-squares problem in the actions, whose optimum
cvxpy finds exactly.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import torch

from planner.cost import CostConfig, PushCost
from planner.dynamics import PlanState, Rollout, integrate_pusher
from sim.shapes import ObjectSpec

TOY_COST = CostConfig(w_shaping=0.0)
DISK = ObjectSpec("cylinder", (0.06, 0.06, 0.05), 0.2, 0.5)


class CarriedDisk:
    name, differentiable = "toy", True

    def __init__(self, dt: float):
        self.dt = dt

    def rollout(self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False) -> Rollout:
        pusher = integrate_pusher(state, actions, self.dt)
        xy = state.object_pose[:2].to(actions) + self.dt * torch.cumsum(actions, 1)
        yaw = state.object_pose[2].to(actions).expand(xy.shape[:2])
        return Rollout(torch.cat([xy, yaw[..., None]], -1), pusher)


def toy_state(start=(0.0, 0.0)) -> PlanState:
    return PlanState(
        points=torch.zeros(3, 4, 4),
        valid=torch.ones(4, 4, dtype=torch.bool),
        object_mask=torch.ones(4, 4, dtype=torch.bool),
        object_pose=torch.tensor([start[0], start[1], 0.0]),
        pusher_xy=torch.tensor([start[0], start[1]]),
        T_world_cam=torch.eye(4),
        footprint_radius_m=DISK.footprint_radius_m,
        yaw_period_rad=DISK.yaw_period_rad,
    )


def optimum(
    cost: PushCost,
    state: PlanState,
    horizon: int,
    dt: float,
    bound: float,
    last_action: np.ndarray | None = None,
    basis: np.ndarray | None = None,
) -> float:
    """The exact minimum of the toy's cost over sequences within the bounds (``last_action``:
    the action executed before the plan; ``basis`` (H, M): over the sequences of M knots
    within the bounds, ``basis @ knots``, a zoh or linear spline's)."""
    if basis is None:
        U = cp.Variable((horizon, 2))
        box = [U >= -bound, U <= bound]
    else:
        Z = cp.Variable((basis.shape[1], 2))
        U, box = basis @ Z, [Z >= -bound, Z <= bound]
    c = cost.cfg
    w = np.full(horizon, np.sqrt(c.w_running))
    w[-1] = np.sqrt(c.w_terminal)
    goal = cost.goal.double().numpy()
    start = state.object_pose[:2].double().numpy()
    terms = []
    for h in range(horizon):
        xy = start + dt * cp.sum(U[: h + 1], axis=0)
        terms.append(cp.sum_squares((xy - goal[:2]) * w[h] / c.pos_scale_m))
        terms.append(c.w_action * cp.sum_squares(U[h]) / bound**2)
        prev = (np.zeros(2) if last_action is None else last_action) if h == 0 else U[h - 1]
        terms.append(c.w_smooth * cp.sum_squares(U[h] - prev) / bound**2)
    prob = cp.Problem(cp.Minimize(sum(terms)), box)
    prob.solve(solver=cp.CLARABEL)
    return float(prob.value)
