"""Model-predictive pushing over a dynamics protocol: CEM, MPPI, gradient and SQP."""

from __future__ import annotations

from planner.base import PlanInfo, Planner, PlannerConfig
from planner.cost import CostConfig, PushCost
from planner.dynamics import BACKENDS, Dynamics, PlanState, Rollout, make_dynamics
from planner.gradient import GradPlanner, SQPPlanner
from planner.observe import plan_state
from planner.sampling import CEMPlanner, MPPIPlanner
from planner.settings import PlanSettings, RolloutConfig
from scenarios import InputError, Scenario

PLANNERS: dict[str, type[Planner]] = {
    "cem": CEMPlanner,
    "mppi": MPPIPlanner,
    "grad": GradPlanner,
    "sqp": SQPPlanner,
}


def make_planner(
    name: str,
    dynamics: Dynamics,
    cost: PushCost,
    scenario: Scenario,
    cfg: PlannerConfig | None = None,
) -> Planner:
    """A planner by name (``cem``, ``mppi``, ``grad``, ``sqp``)."""
    if name not in PLANNERS:
        raise InputError(f"unknown planner {name!r}; known: {', '.join(PLANNERS)}")
    return PLANNERS[name](dynamics, cost, scenario, cfg or PlannerConfig())


__all__ = [
    "BACKENDS",
    "PLANNERS",
    "CostConfig",
    "Dynamics",
    "PlanInfo",
    "PlanState",
    "Planner",
    "PlannerConfig",
    "PlanSettings",
    "PushCost",
    "Rollout",
    "RolloutConfig",
    "make_dynamics",
    "make_planner",
    "plan_state",
]
