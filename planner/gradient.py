"""Gradient-based optimisers through the differentiable rollout: Adam and SQP."""

from __future__ import annotations

import math

import cvxpy as cp
import numpy as np
import torch

from planner.base import Planner
from planner.dynamics import PlanState


def _require_gradients(planner: Planner) -> None:
    if not planner.dynamics.differentiable:
        raise ValueError(
            f"the {planner.name} planner needs a differentiable backend; "
            f"{planner.dynamics.name!r} is not (use cem or mppi with it)"
        )


class GradPlanner(Planner):
    """Adam on the action sequence through the differentiable rollout, projected onto the
    bounds after every step; starts from the best of the warm start and a few samples (plain
    gradient steps from a poor start drift out of the data's distribution)."""

    name = "grad"

    def _optimise(self, state: PlanState, U0: torch.Tensor) -> tuple[torch.Tensor, int]:
        _require_gradients(self)
        c = self.cfg
        starts = self.clamp(U0 + c.init_std * self.bound * self.noise(c.grad_init_samples))
        starts[0] = U0
        with torch.inference_mode():
            cost, _ = self.evaluate(state, starts)
        U = starts[int(cost.argmin())].clone().requires_grad_()
        best, best_cost = U.detach().clone(), float(cost.min())
        opt = torch.optim.Adam([U], lr=c.grad_lr)
        for _ in range(c.grad_steps):
            cost, _ = self.evaluate(state, U[None])
            if float(cost.detach()) < best_cost:
                best, best_cost = U.detach().clone(), float(cost.detach())
            opt.zero_grad()
            cost.sum().backward()
            opt.step()
            with torch.no_grad():
                U.clamp_(-self.bound, self.bound)
        with torch.no_grad():
            cost, _ = self.evaluate(state, U[None])
        if float(cost) < best_cost:
            best = U.detach().clone()
        return best, c.grad_steps


class SQPPlanner(Planner):
    """Sequential quadratic programming (Gauss-Newton on the cost's residuals): linearise the
    rollout around the nominal sequence with autograd Jacobians, solve a trust-region QP with
    the box bounds (cvxpy on OSQP, compiled once as a parametrised problem), and accept a step
    only if the true rollout cost drops (else halve the trust region)."""

    name = "sqp"

    def __init__(self, *args, **kwargs):
        self._problems: dict[tuple[int, int], tuple] = {}
        super().__init__(*args, **kwargs)

    def _problem(self, m: int, n: int) -> tuple:
        """The parametrised QP for m residuals and n action variables (built once)."""
        if (m, n) not in self._problems:
            J, r0 = cp.Parameter((m, n)), cp.Parameter(m)
            lo, hi = cp.Parameter(n), cp.Parameter(n)
            d = cp.Variable(n)
            prob = cp.Problem(cp.Minimize(cp.sum_squares(r0 + J @ d)), [d >= lo, d <= hi])
            self._problems[(m, n)] = (prob, J, r0, lo, hi, d)
        return self._problems[(m, n)]

    def _residuals(self, state: PlanState, flat: torch.Tensor) -> torch.Tensor:
        U = flat.view(1, self.cfg.horizon, 2)
        return self.cost.residuals(state, self.dynamics.rollout(state, U), U)[0]

    def _optimise(self, state: PlanState, U0: torch.Tensor) -> tuple[torch.Tensor, int]:
        _require_gradients(self)
        c = self.cfg
        U = U0.flatten().clone()
        with torch.no_grad():
            cost = float((self._residuals(state, U) ** 2).sum())
        radius = c.trust_radius
        for _ in range(c.iterations):
            r0 = self._residuals(state, U).detach()
            # forward mode, vectorised: one batched pass for the few (H x 2) action inputs
            J = torch.autograd.functional.jacobian(
                lambda x: self._residuals(state, x), U, vectorize=True, strategy="forward-mode"
            ).detach()
            if not (torch.isfinite(J).all() and torch.isfinite(r0).all()):
                radius *= 0.5  # a degenerate linearisation: try a smaller step
                continue
            prob, Jp, rp, lo, hi, d = self._problem(*J.shape)
            u = U.double().numpy()
            Jp.value, rp.value = J.double().numpy(), r0.double().numpy()
            hi.value = np.minimum(self.bound - u, radius)
            lo.value = np.minimum(np.maximum(-self.bound - u, -radius), hi.value)
            prob.solve(solver=cp.OSQP, warm_start=True, eps_abs=1e-7, eps_rel=1e-7)
            if d.value is None or not np.all(np.isfinite(d.value)):
                radius *= 0.5
                continue
            trial = self.clamp(U + torch.from_numpy(d.value).float())
            with torch.no_grad():
                trial_cost = float((self._residuals(state, trial) ** 2).sum())
            if trial_cost < cost:
                U, cost = trial, trial_cost
            else:
                radius *= 0.5
            if radius < 1e-4 * self.bound or not math.isfinite(cost):
                break
        return U.view(c.horizon, 2), c.iterations
