"""Sampling optimisers: the cross-entropy method and MPPI."""

from __future__ import annotations

import math

import torch

from planner.base import Best, Planner
from planner.dynamics import PlanState


class CEMPlanner(Planner):
    """Cross-entropy method: sample around a Gaussian, refit it to the elites, keep the best
    sequence seen (the warm start is always one of the candidates).

    With the iCEM settings (Pinneri et al., 2020) it needs fewer rollouts for the same plan:
    noise correlated along the horizon (``colour``), a population that shrinks over the
    iterations (``shrink``), a share of the last replan's elites kept, shifted by one step
    (``keep_elites``), and a smaller SD when warm-started (``warm_std``). It samples the
    plan's knots (``PlannerConfig.knots``; one per step by default)."""

    name = "cem"

    def reset(self) -> None:
        super().reset()
        self.kept: torch.Tensor | None = None  # the last replan's elites, shifted (iCEM)

    def _optimise(self, state: PlanState, U0: torch.Tensor) -> tuple[Best, int]:
        c = self.cfg
        warm = self.kept is not None
        sd = c.warm_std if warm and c.warm_std is not None else c.init_std
        mean, std = U0.clone(), torch.full_like(U0, sd * self.bound)
        best = Best()
        for it in range(c.iterations):
            n = c.population(it)
            eps = self.noise(n)
            if c.colour > 0:  # AR(1): noise correlated along the horizon
                for h in range(1, self.n_knots):
                    eps[:, h] = c.colour * eps[:, h - 1] + math.sqrt(1 - c.colour**2) * eps[:, h]
            U = self.clamp(mean + std * eps)
            U[0] = mean
            if it == 0 and warm and len(self.kept):
                U = torch.cat([U, self.kept])
            with torch.inference_mode():
                cost, rollout = self.evaluate(state, U)
            best.offer(U, cost, rollout)
            elite = torch.topk(cost, c.elites, largest=False).indices
            mean = U[elite].mean(0)
            std = U[elite].std(0).clamp_min(c.min_std * self.bound)
        keep = round(c.keep_elites * c.elites)
        self.kept = self.shifted(U[elite[:keep]])
        return best, c.iterations


class MPPIPlanner(Planner):
    """Model-predictive path integral control: the nominal sequence moves to the
    softmin-weighted mean of noisy samples, weights exp(-(c - c_min) / (s * temperature)).

    The scale s is robust, the median cost less the minimum (the lower middle value for an
    even count): the temperature does not depend on the cost's scale, and a tail of outliers
    (a sample that leaves the workspace and pays its penalty) changes neither s nor the other
    samples' weights, as dividing by the range (max - min) would, flattening them all.

    As CEM does, it keeps the best sequence it evaluated (the nominal is always sample 0) and
    returns it unless the final weighted mean, evaluated once more, costs less: the plan never
    costs more than the warm start."""

    name = "mppi"

    def _weights(self, cost: torch.Tensor) -> torch.Tensor:
        """Softmin weights (K,) of the costs (K,), normalised by a robust scale. A sample whose
        cost is not finite (NaN) gets none; with none finite, the nominal (sample 0) keeps
        all, so one bad sample does not turn the nominal and every later sample into NaN."""
        finite = torch.isfinite(cost)
        if not finite.any():
            return (torch.arange(len(cost), device=cost.device) == 0).to(cost.dtype)
        low, mid = cost[finite].min(), cost[finite].median()
        scale = (mid - low).clamp_min(1e-9)
        cost = torch.where(finite, cost, torch.full_like(cost, math.inf))
        return torch.softmax(-(cost - low) / (scale * self.cfg.temperature), 0)

    def _optimise(self, state: PlanState, U0: torch.Tensor) -> tuple[Best, int]:
        c = self.cfg
        U = U0.clone()
        best = Best()
        for _ in range(c.iterations):
            samples = self.clamp(U + c.init_std * self.bound * self.noise(c.samples))
            samples[0] = U
            with torch.inference_mode():
                cost, rollout = self.evaluate(state, samples)
            best.offer(samples, cost, rollout)
            w = self._weights(cost)
            U = self.clamp((w[:, None, None] * samples).sum(0))
        with torch.inference_mode():
            best.offer(U[None], *self.evaluate(state, U[None]))
        return best, c.iterations
