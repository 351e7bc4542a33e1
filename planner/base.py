"""One interface for every optimiser: ``plan(state) -> (action, info)`` and ``reset()``.

Each planner keeps its warm start explicit: the previous plan shifted by one step (its last
action repeated). All actions stay inside the scenario's bounds.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from planner.cost import PushCost
from planner.dynamics import Dynamics, PlanState, Rollout
from scenarios import InputError, Scenario

SPLINES = ("zoh", "linear", "cubic")
"""how knots make actions (``PlannerConfig.spline``)"""
MAX_STEPS = 100
"""the most control steps a plan looks ahead (15 s at 0.15 s a step, a trial's budget and
more): a horizon of a million steps would only exhaust the memory"""


def spline_basis(horizon: int, knots: int, spline: str) -> np.ndarray:
    """(H, M) the actions' linear map from the knots: ``U = basis @ Z`` for knots Z (M, 2).
    ``knots`` 0 or ``horizon`` (a knot at every step) gives the identity."""
    if knots == 0:
        return np.eye(horizon)
    steps = np.arange(horizon, dtype=float)
    if spline == "zoh":  # knot j holds over steps [j H / M, (j + 1) H / M)
        owner = np.minimum((steps * knots / horizon).astype(int), knots - 1)
        return (owner[:, None] == np.arange(knots)[None]).astype(float)
    at = np.linspace(0.0, horizon - 1, knots)
    if spline == "linear":
        return np.stack([np.interp(steps, at, np.eye(knots)[j]) for j in range(knots)], 1)
    from scipy.interpolate import CubicSpline

    if knots == 2:  # a cubic through two points is the line
        return spline_basis(horizon, knots, "linear")
    return CubicSpline(at, np.eye(knots), bc_type="natural")(steps)


def shift_operator(basis: np.ndarray) -> np.ndarray:
    """(M, M) the warm start one control step later: the knots whose actions best fit (least
    squares) the plan's actions advanced by a step, its last action held. The identity basis
    gives the plain shift (drop the first action, repeat the last)."""
    H = basis.shape[0]
    advance = np.eye(H, k=1)
    advance[-1, -1] = 1.0
    return np.linalg.pinv(basis) @ advance @ basis


@dataclass(frozen=True)
class PlannerConfig:
    """Settings shared by the optimisers (each reads the ones it uses).

    The CEM defaults are iCEM's (Pinneri et al., 2020): 32, 26 and 20 sequences over 3
    iterations (78 rollouts a replan, 80 with the 2 kept elites, against 144 for the earlier
    48 x 3 with white noise), correlated noise, 30 % of the elites kept, a warm SD of a
    quarter of the bound. Chosen on 50 paired single_box trials against the earlier settings
    (docs/planner.md); 24/19/15 was faster but lost success."""

    horizon_s: float = 0.45
    """how far ahead a plan looks (s), in whole control steps (0.15 s each; a horizon between
    two is rounded to the nearer). 0.45 s, 3 steps: a learned model's later steps are its
    least reliable (a glancing push is predicted to keep the object in front of the pusher,
    which slides off it), and with 3 the default model succeeded in more paired dev trials on
    every scenario than with 4 (docs/planner.md: three steps ahead, not four)"""
    knots: int = 0
    """the plan's free values per action dimension: a spline through this many knots spread
    over the horizon gives the action at each control step (0: one per step, the actions
    themselves; at most one per step); every optimiser optimises the knots"""
    spline: str = "linear"
    """how the knots make actions (with ``knots`` > 0): ``zoh`` (each knot held over its share
    of the steps), ``linear`` or ``cubic`` (a natural cubic spline) through knots at evenly
    spaced steps from the first to the last"""
    samples: int = 32
    """candidate sequences per iteration (CEM: the first iteration's; MPPI)"""
    iterations: int = 3
    """optimiser iterations per replan"""
    elites: int = 6
    """CEM: elite sequences refitted"""
    init_std: float = 0.5
    """sampling SD at a fresh start, as a fraction of the action bound"""
    min_std: float = 0.05
    """CEM: the SD never shrinks below this fraction of the bound"""
    colour: float = 0.5
    """CEM: temporal correlation of the noise (AR(1) coefficient; 0 = white)"""
    shrink: float = 1.25
    """CEM: each iteration samples this many times fewer sequences than the last (iCEM's
    decay; at least twice the elites); 1 = the same number"""
    keep_elites: float = 0.3
    """CEM: share of the last replan's elites, shifted by one step, sampled again at the
    next replan's first iteration (iCEM)"""
    warm_std: float | None = 0.25
    """CEM: sampling SD when warm-started from the previous plan, as a fraction of the bound
    (None: init_std, as at a fresh start)"""
    temperature: float = 0.05
    """MPPI: temperature on costs less their minimum, divided by (median - minimum)"""
    grad_steps: int = 10
    """grad: Adam steps"""
    grad_lr: float = 0.02
    """grad: Adam step size (m/s)"""
    grad_init_samples: int = 16
    """grad: candidate starts, this many in all: the warm start and random sequences about it"""
    grad_starts: int = 4
    """grad: Adam runs from the best this many of those at once (one batched rollout a
    step), and the plan is the best sequence any of them reached"""
    trust_radius: float = 0.05
    """SQP: initial trust region on each action change (m/s)"""
    seed: int = 0
    """seed of the planner's generator"""

    def steps(self, dt_s: float) -> int:
        """The horizon in control steps of ``dt_s`` seconds (rounded to the nearer, halves up;
        at least one), or an InputError where there are fewer steps than knots or more than
        ``MAX_STEPS``."""
        steps = max(1, math.floor(self.horizon_s / dt_s + 0.5 + 1e-9))
        if steps > MAX_STEPS:
            raise InputError(
                f"horizon_s {self.horizon_s:g} is {steps} steps of {dt_s:g} s; a plan looks at "
                f"most {MAX_STEPS} steps ahead ({MAX_STEPS * dt_s:g} s)"
            )
        if self.knots > steps:
            raise InputError(
                f"knots must be 0 (one per step) or 1..{steps} (the steps of "
                f"{dt_s:g} s in horizon_s {self.horizon_s:g}), got {self.knots}"
            )
        return steps

    def population(self, iteration: int) -> int:
        """CEM: sequences sampled at an iteration (0-based), before kept elites join the
        first: ``samples`` shrunk by ``shrink`` each iteration, at least twice the elites."""
        return max(2 * self.elites, round(self.samples / self.shrink**iteration))

    def __post_init__(self) -> None:
        positive = ("samples", "iterations", "elites", "grad_steps", "grad_starts",
                    "grad_init_samples")  # fmt: skip
        for name in positive:
            if getattr(self, name) < 1:
                raise InputError(f"{name} must be a positive integer, got {getattr(self, name)}")
        if not (math.isfinite(self.horizon_s) and self.horizon_s > 0):
            raise InputError(f"horizon_s must be a time in seconds above 0, got {self.horizon_s}")
        if self.knots < 0:
            raise InputError(f"knots must be 0 (one per step) or more, got {self.knots}")
        if self.spline not in SPLINES:
            raise InputError(f"spline must be one of {', '.join(SPLINES)}, got {self.spline!r}")
        if self.spline != "zoh" and self.knots == 1:
            raise InputError(f"a {self.spline} spline needs at least 2 knots (1: spline zoh)")
        if self.elites < 2:  # CEM refits an SD to them
            raise InputError(
                f"elites must be at least 2 (CEM fits a spread to them), got {self.elites}"
            )
        if self.elites > self.samples:
            raise InputError(f"elites ({self.elites}) cannot exceed samples ({self.samples})")
        if not (math.isfinite(self.shrink) and self.shrink >= 1.0):
            raise InputError(f"shrink must be a number of at least 1, got {self.shrink}")
        if not 0.0 <= self.keep_elites <= 1.0:
            raise InputError(f"keep_elites must be in [0, 1], got {self.keep_elites}")
        if not 0.0 <= self.colour < 1.0:
            raise InputError(f"colour must be in [0, 1), got {self.colour}")
        for name in ("init_std", "min_std", "temperature", "grad_lr", "trust_radius"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise InputError(f"{name} must be a positive number, got {getattr(self, name)}")
        if self.warm_std is not None and not (math.isfinite(self.warm_std) and self.warm_std > 0):
            raise InputError(f"warm_std must be a positive number or None, got {self.warm_std}")


ONE_PLANNER_SETTINGS = {
    "temperature": "mppi",
    "grad_steps": "grad",
    "grad_lr": "grad",
    "grad_init_samples": "grad",
    "grad_starts": "grad",
    "trust_radius": "sqp",
}
"""PlannerConfig fields that one optimiser alone reads: runs of the others do not depend on
them (so a trial folder of cem trials is not another set for a new grad setting)"""


@dataclass
class PlanInfo:
    """What a replan found."""

    actions: np.ndarray
    """(H,2) the chosen sequence"""
    predicted_poses: np.ndarray
    """(H,3) the object poses the backend predicts for it"""
    predicted_pusher: np.ndarray
    """(H,2) the pusher positions it predicts"""
    cost: float
    iterations: int
    wall_ms: float
    cost_terms: dict[str, float] = field(default_factory=dict)
    """each term's share of ``cost`` (``planner.cost.TERMS``), which they sum to"""


class Best:
    """The lowest-cost plan (its knots) an optimiser has evaluated, with its rollout, so that
    the chosen plan is not rolled out a second time."""

    def __init__(self) -> None:
        self.actions: torch.Tensor | None = None
        self.cost = math.inf
        self.rollout: Rollout | None = None

    def offer(self, U: torch.Tensor, cost: torch.Tensor, rollout: Rollout) -> None:
        """Keep the cheapest of candidates U (K,M,2) with costs (K,) if it beats the best."""
        cost = cost.nan_to_num(nan=math.inf)  # a NaN never wins (argmin would pick it)
        i = int(cost.argmin())
        if self.actions is None or float(cost[i]) < self.cost:
            self.actions, self.cost = U[i].clone(), float(cost[i])

            def pick(x: torch.Tensor | None) -> torch.Tensor | None:
                """The chosen candidate's part of an optional prediction."""
                return None if x is None else x[i : i + 1].detach().clone()

            self.rollout = Rollout(
                pick(rollout.object_poses), pick(rollout.pusher_xy),
                spread=pick(rollout.spread), other_poses=pick(rollout.other_poses),
            )  # fmt: skip


class Planner:
    """Base class: subclasses implement ``_optimise``."""

    name = "base"

    def __init__(
        self,
        dynamics: Dynamics,
        cost: PushCost,
        scenario: Scenario,
        cfg: PlannerConfig = PlannerConfig(),
    ):
        self.dynamics, self.cost, self.cfg = dynamics, cost, cfg
        self.bound = scenario.action.max_speed_m_s
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.horizon = cfg.steps(scenario.action.dt_control_s)
        """H, the plan's control steps"""
        basis = spline_basis(self.horizon, cfg.knots, cfg.spline)
        self.identity = cfg.knots in (0, self.horizon)  # a knot per step: the actions
        self.basis = torch.from_numpy(basis).float()  # (H, M): actions from knots
        self.shift = torch.from_numpy(shift_operator(basis)).float()  # (M, M)
        self.reset()

    @property
    def n_knots(self) -> int:
        """M, the knots (free values per action dimension) of a plan."""
        return self.basis.shape[1]

    def reset(self) -> None:
        """Forget the warm start (a new episode)."""
        self.nominal = torch.zeros(self.n_knots, 2)  # the warm start's knots
        self.last_action = torch.zeros(2)  # the action executed before this plan
        self.gen.manual_seed(self.cfg.seed)

    def clamp(self, Z: torch.Tensor) -> torch.Tensor:
        return Z.clamp(-self.bound, self.bound)

    def actions(self, Z: torch.Tensor) -> torch.Tensor:
        """(..., H, 2) the actions of knots Z (..., M, 2), inside the bounds (a cubic spline
        through knots inside them can overshoot)."""
        if self.identity:
            return Z
        return self.clamp(torch.einsum("hm,...mc->...hc", self.basis.to(Z), Z))

    def shifted(self, Z: torch.Tensor) -> torch.Tensor:
        """Knots Z (..., M, 2) one control step later (:func:`shift_operator`)."""
        if self.identity:
            return torch.cat([Z[..., 1:, :], Z[..., -1:, :]], -2)
        return self.clamp(torch.einsum("nm,...mc->...nc", self.shift.to(Z), Z))

    def evaluate(self, state: PlanState, Z: torch.Tensor) -> tuple[torch.Tensor, Rollout]:
        """Costs (K,) and rollouts of the plans of knots Z (K,M,2)."""
        U = self.actions(Z)
        rollout = self.dynamics.rollout(state, U)
        return self.cost.cost(state, rollout, U, last_action=self.last_action), rollout

    def noise(self, K: int) -> torch.Tensor:
        """Standard normal noise (K,M,2) on knots, from the planner's generator."""
        return torch.randn(K, self.n_knots, 2, generator=self.gen)

    def _optimise(
        self, state: PlanState, Z0: torch.Tensor
    ) -> tuple[torch.Tensor, int] | tuple[Best, int]:
        """The plan's knots (M,2), or the :class:`Best` candidate with its rollout, and the
        number of iterations run, from the warm start's knots Z0 (M,2)."""
        raise NotImplementedError

    def executed(self, action: np.ndarray) -> None:
        """The action the world ran, where it is not the plan's first (noise was added to it):
        the next plan's smoothness term is taken from it."""
        self.last_action = torch.as_tensor(action, dtype=torch.float32).clone()

    def plan(self, state: PlanState) -> tuple[np.ndarray, PlanInfo]:
        """The action (2,) to apply now, and the plan it came from."""
        t0 = time.perf_counter()
        found, iterations = self._optimise(state, self.clamp(self.nominal))
        if isinstance(found, Best):  # evaluated already: its rollout is the plan's
            Z, rollout, cost = found.actions, found.rollout, torch.tensor([found.cost])
        else:
            Z = self.clamp(found.detach())
            with torch.no_grad():
                cost, rollout = self.evaluate(state, Z[None])
        U = self.actions(Z)
        with torch.no_grad():
            terms = self.cost.cost_terms(state, rollout, U[None], last_action=self.last_action)
        self.nominal = self.shifted(Z)  # warm start for the next replan
        self.last_action = U[0].clone()
        # float32 0.15 is 0.15000000596: clip in float64 so that the world accepts the action
        actions = np.clip(U.double().numpy(), -self.bound, self.bound)
        info = PlanInfo(
            actions=actions,
            predicted_poses=rollout.object_poses[0].detach().cpu().numpy(),
            predicted_pusher=rollout.pusher_xy[0].detach().cpu().numpy(),
            cost=float(cost[0]),
            iterations=iterations,
            wall_ms=1e3 * (time.perf_counter() - t0),
            cost_terms={name: float(v[0]) for name, v in terms.items()},
        )
        return actions[0].copy(), info
