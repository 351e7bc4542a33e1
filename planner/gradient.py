"""Gradient-based optimisers through the differentiable rollout: Adam and SQP."""

from __future__ import annotations

import math

import numpy as np
import torch

from planner.base import Best, Planner
from planner.dynamics import PlanState
from scenarios import InputError


def _require_gradients(planner: Planner) -> None:
    if not planner.dynamics.differentiable:
        raise InputError(
            f"the {planner.name} planner needs a differentiable backend; "
            f"{planner.dynamics.name!r} is not (use cem or mppi with it)"
        )


class GradPlanner(Planner):
    """Adam on action sequences through the differentiable rollout, projected onto the
    bounds after every step; it starts from the best few of the warm start and random
    samples (plain gradient steps from a poor start drift out of the data's distribution),
    all of them at once: one batched rollout a step, each start's cost its own, so each start
    follows the steps it would follow alone."""

    name = "grad"

    def _optimise(self, state: PlanState, U0: torch.Tensor) -> tuple[Best, int]:
        _require_gradients(self)
        c = self.cfg
        starts = self.clamp(U0 + c.init_std * self.bound * self.noise(c.grad_init_samples))
        starts[0] = U0
        best = Best()
        with torch.inference_mode():
            cost, rollout = self.evaluate(state, starts)
        best.offer(starts, cost, rollout)
        order = torch.argsort(cost.nan_to_num(nan=math.inf))[: c.grad_starts]
        U = starts[order].clone().requires_grad_()
        opt = torch.optim.Adam([U], lr=c.grad_lr)  # elementwise: the starts stay independent
        for _ in range(c.grad_steps):
            cost, rollout = self.evaluate(state, U)
            best.offer(U.detach(), cost.detach(), rollout)
            opt.zero_grad()
            cost.sum().backward()
            opt.step()
            with torch.no_grad():
                U.clamp_(-self.bound, self.bound)
        with torch.no_grad():
            best.offer(U.detach(), *self.evaluate(state, U))
        return best, c.grad_steps


class SQPPlanner(Planner):
    """Sequential quadratic programming (Gauss-Newton on the cost's residuals): linearise the
    rollout around the nominal sequence with autograd Jacobians, solve a trust-region QP with
    the box bounds (cvxpy on OSQP, compiled once as a parametrised problem), and accept a step
    only if the true rollout cost drops.

    The trust region (a box of half-width ``radius`` on each action change) follows the ratio
    rho of the actual cost reduction to the QP's predicted one, |r0|^2 - |r0 + J d|^2 (Nocedal
    & Wright, Numerical Optimization, Algorithm 4.1): rho > 0.75 with the step at the region's
    edge doubles the radius (up to 2x the action bound, the width of the action box, where the
    region stops binding); rho < 0.25 or a rejected step halves it. A QP that OSQP cannot solve
    (``cvxpy.SolverError``, its iteration limit, a non-optimal status) also halves it: a solver
    failure never ends a closed loop. Residuals and Jacobian are computed only at accepted
    points: a rejected step costs one rollout, the trial's."""

    name = "sqp"
    grow_above, shrink_below = 0.75, 0.25
    """thresholds on the ratio of actual to predicted cost reduction"""

    def __init__(self, *args, **kwargs):
        self._problems: dict[tuple[int, int], tuple] = {}
        super().__init__(*args, **kwargs)

    def _problem(self, m: int, n: int) -> tuple:
        """The parametrised QP for m residuals and n action variables (built once)."""
        if (m, n) not in self._problems:
            import cvxpy as cp  # here, so that nothing but the SQP planner waits for it

            J, r0 = cp.Parameter((m, n)), cp.Parameter(m)
            lo, hi = cp.Parameter(n), cp.Parameter(n)
            d = cp.Variable(n)
            prob = cp.Problem(cp.Minimize(cp.sum_squares(r0 + J @ d)), [d >= lo, d <= hi])
            self._problems[(m, n)] = (prob, J, r0, lo, hi, d)
        return self._problems[(m, n)]

    def _residuals(self, state: PlanState, flat: torch.Tensor) -> torch.Tensor:
        U = self.actions(flat.view(1, self.n_knots, 2))
        rollout = self.dynamics.rollout(state, U)
        return self.cost.residuals(state, rollout, U, last_action=self.last_action)[0]

    def _jacobian(self, state: PlanState, flat: torch.Tensor) -> torch.Tensor:
        """(m, n) Jacobian of the residuals with respect to the n = M*2 knot values."""
        # forward mode, vectorised: one batched pass for the few (M x 2) inputs
        return torch.autograd.functional.jacobian(
            lambda x: self._residuals(state, x), flat, vectorize=True, strategy="forward-mode"
        ).detach()

    def _step(
        self, J: np.ndarray, r0: np.ndarray, u: np.ndarray, radius: float
    ) -> np.ndarray | None:
        """The QP's step d (n,) inside the trust region and the action bounds, or None where
        OSQP gives no solution (an error, its iteration limit, an infeasible status)."""
        import cvxpy as cp

        prob, Jp, rp, lo, hi, d = self._problem(*J.shape)
        Jp.value, rp.value = J, r0
        hi.value = np.minimum(self.bound - u, radius)
        lo.value = np.minimum(np.maximum(-self.bound - u, -radius), hi.value)
        try:
            # no warm start: OSQP refuses cvxpy's in-place update of the bounds after a
            # rejected step ("osqp_update_data_vec: Problem data validation") and cvxpy then
            # reports the previous QP's solution as optimal; a fresh setup costs ~1 ms
            prob.solve(solver=cp.OSQP, warm_start=False, eps_abs=1e-7, eps_rel=1e-7)
        except cp.SolverError:
            return None
        # at its iteration limit (status user_limit) OSQP's iterate may lie outside the box
        if prob.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or d.value is None:
            return None
        if not np.all(np.isfinite(d.value)):
            return None
        if np.max(np.maximum(d.value - hi.value, lo.value - d.value)) > 1e-6:
            return None  # a solution of another QP, or of none: not a step of this one
        return np.clip(d.value, lo.value, hi.value)  # an inaccurate solution's tiny violations

    def _optimise(self, state: PlanState, U0: torch.Tensor) -> tuple[torch.Tensor, int]:
        _require_gradients(self)
        c = self.cfg
        U = U0.flatten().clone()
        with torch.no_grad():
            r0 = self._residuals(state, U)
        cost = float((r0**2).sum())
        J = None  # the Jacobian at U, computed when a step from U is first needed
        radius = c.trust_radius
        run = 0
        for _ in range(c.iterations):
            if radius < 1e-4 * self.bound or not math.isfinite(cost):
                break
            run += 1
            if J is None:
                J = self._jacobian(state, U)
                if not torch.isfinite(J).all():
                    break  # a degenerate linearisation: no step can be computed from here
            Jd, rd = J.double().numpy(), r0.double().numpy()
            d = self._step(Jd, rd, U.double().numpy(), radius)
            predicted = -math.inf if d is None else float(rd @ rd - np.sum((rd + Jd @ d) ** 2))
            if predicted <= 0:  # no solution, or none that the model expects to help
                radius *= 0.5
                continue
            trial = self.clamp(U + torch.from_numpy(d).float())
            with torch.no_grad():
                r_trial = self._residuals(state, trial)
            trial_cost = float((r_trial**2).sum())
            if not trial_cost < cost:  # rejected (or not finite): keep U, r0 and J
                radius *= 0.5
                continue
            rho = (cost - trial_cost) / predicted
            if rho > self.grow_above and np.abs(d).max() >= 0.99 * radius:
                radius = min(2.0 * radius, 2.0 * self.bound)
            elif rho < self.shrink_below:
                radius *= 0.5
            U, cost, r0, J = trial, trial_cost, r_trial, None
        return U.view(self.n_knots, 2), run
