"""Sampling optimisers: the cross-entropy method and MPPI."""

from __future__ import annotations

import math

import torch

from planner.base import Planner
from planner.dynamics import PlanState


class CEMPlanner(Planner):
    """Cross-entropy method: sample around a Gaussian, refit it to the elites, keep the best
    sequence seen (the warm start is always one of the candidates)."""

    name = "cem"

    def _optimise(self, state: PlanState, U0: torch.Tensor) -> tuple[torch.Tensor, int]:
        c = self.cfg
        mean, std = U0.clone(), torch.full_like(U0, c.init_std * self.bound)
        best, best_cost = U0, math.inf
        for _ in range(c.iterations):
            eps = self.noise(c.samples)
            if c.colour > 0:  # AR(1): noise correlated along the horizon
                for h in range(1, c.horizon):
                    eps[:, h] = c.colour * eps[:, h - 1] + math.sqrt(1 - c.colour**2) * eps[:, h]
            U = self.clamp(mean + std * eps)
            U[0] = mean
            with torch.inference_mode():
                cost, _ = self.evaluate(state, U)
            elite = torch.topk(cost, c.elites, largest=False).indices
            if cost[elite[0]] < best_cost:
                best, best_cost = U[elite[0]].clone(), float(cost[elite[0]])
            mean = U[elite].mean(0)
            std = U[elite].std(0).clamp_min(c.min_std * self.bound)
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
        """Softmin weights (K,) of the costs (K,), normalised by a robust scale."""
        scale = (cost.median() - cost.min()).clamp_min(1e-9)
        return torch.softmax(-(cost - cost.min()) / (scale * self.cfg.temperature), 0)

    def _optimise(self, state: PlanState, U0: torch.Tensor) -> tuple[torch.Tensor, int]:
        c = self.cfg
        U = U0.clone()
        best, best_cost = U0, math.inf
        for _ in range(c.iterations):
            samples = self.clamp(U + c.init_std * self.bound * self.noise(c.samples))
            samples[0] = U
            with torch.inference_mode():
                cost, _ = self.evaluate(state, samples)
            i = int(cost.argmin())
            if cost[i] < best_cost:
                best, best_cost = samples[i].clone(), float(cost[i])
            w = self._weights(cost)
            U = self.clamp((w[:, None, None] * samples).sum(0))
        with torch.inference_mode():
            cost, _ = self.evaluate(state, U[None])
        if float(cost[0]) < best_cost:
            best = U
        return best, c.iterations
