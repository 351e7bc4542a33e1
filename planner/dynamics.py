"""The dynamics protocol the planner talks to, and its backends.

A backend takes the current :class:`PlanState` and a batch of action sequences ``(K,H,2)``
and returns a :class:`Rollout`: the pushed object's predicted planar poses and the pusher's
positions over the horizon. Backends:

- ``LearnedDynamics`` (``planner.learned``): an SE3-Net or flow-net checkpoint rolled
  forward, each predicted cloud fed back as the next input (as the paper does for multi-step
  prediction), the pusher position integrated from the commands into the control vector; the
  object's pose at each step is a least-squares rigid fit (Kabsch, in the table plane) of
  its predicted points to its current points, composed with its current pose. Differentiable
  end to end with respect to the actions. With a contact margin, a predicted motion of an
  object counts only at the steps where something could touch it
  (``planner.learned.contact_gate``).
- ``OracleDynamics``: the MuJoCo world itself, every candidate simulated from its current
  state (in one batched rollout): the upper bound any learned model is measured against.
- ``NoMotionDynamics``: nothing but the pusher moves: the lower bound.
- ``PoseDynamics`` (``planner.learned``): a pose-space model (``se3net.pose_model``): the
  object's shape encoded once from its observed points, its pose rolled by a small network;
  a checkpoint of variant ``pose`` given as the model makes one.
- ``EnsembleDynamics``: several learned checkpoints rolled side by side; it predicts their
  mean and reports their disagreement (``Rollout.spread``), which the cost can penalise so
  the planner keeps to actions the models agree on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch

from scenarios import InputError, Scenario
from se3net.rollout import pusher_path

if TYPE_CHECKING:
    from sim import PushWorld

BACKENDS = ("se3net", "flow", "oracle", "no-motion")


@dataclass(frozen=True)
class PlanState:
    """What the planner knows at one control step (the object's pixels and pose stand in for
    an object tracker, as the paper used DART; the object's motion comes from the backend).
    ``planner.observe.plan_state`` makes one from a world's observation."""

    points: torch.Tensor
    """(3,H,W) observed cloud, camera frame (m)"""
    valid: torch.Tensor
    """(H,W) bool, pixels that hold a point"""
    object_mask: torch.Tensor
    """(H,W) bool, the pushed object's pixels"""
    object_pose: torch.Tensor
    """(3,) x_m, y_m, yaw_rad of the pushed object, world frame"""
    pusher_xy: torch.Tensor
    """(2,) pusher tip position, world frame"""
    T_world_cam: torch.Tensor
    """(4,4) the camera's pose in the world frame"""
    footprint_radius_m: float
    """radius of the circle that holds the pushed object's footprint (the pre-push point)"""
    yaw_period_rad: float | None
    """the turn after which the pushed object looks the same (None: any turn, a cylinder)"""
    other_poses: torch.Tensor | None = None
    """(M,3) the poses of the other objects on the table (None or M = 0: there are none)"""
    other_masks: torch.Tensor | None = None
    """(M,H,W) bool, their pixels"""
    other_radii_m: tuple[float, ...] | None = None
    """the radii of the circles that hold their footprints (None: not known)"""

    @property
    def n_others(self) -> int:
        return 0 if self.other_poses is None else len(self.other_poses)


def planar_fit(
    src: torch.Tensor, dst: torch.Tensor, centre: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Kabsch in the table plane: the rotation (yaw) and where ``centre`` goes
    under the rigid planar motion that best takes ``src`` (N,2) to each ``dst`` (K,N,2).

    Closed form (``atan2`` of the summed cross and dot products of the centred points), so
    its gradients stay finite where an SVD's would not (nearly symmetric point sets, no
    motion); objects slide on the table, so their motion is planar.
    """
    mu_s, mu_d = src.mean(0), dst.mean(1)  # (2,), (K,2)
    s, d = src - mu_s, dst - mu_d[:, None]
    cross = (s[:, 0] * d[..., 1] - s[:, 1] * d[..., 0]).sum(-1)
    dot = (s * d).sum((-1, -2))
    yaw = torch.atan2(cross, dot)
    c, sn = torch.cos(yaw), torch.sin(yaw)
    r = centre - mu_s
    xy = torch.stack([c * r[0] - sn * r[1], sn * r[0] + c * r[1]], -1) + mu_d
    return yaw, xy


@dataclass(frozen=True)
class Rollout:
    """Predictions for K action sequences over H steps."""

    object_poses: torch.Tensor
    """(K,H,3) the pushed object's pose after each step (x_m, y_m, yaw_rad)"""
    pusher_xy: torch.Tensor
    """(K,H,2) the pusher's position after each step"""
    clouds: torch.Tensor | None = None
    """(K,H,3,Hi,Wi) predicted clouds, if asked for (learned backends)"""
    spread: torch.Tensor | None = None
    """(K,H) how much an ensemble's members disagree on the object's pose after each step (m:
    the RMS over members of the deviation of the object's footprint from the mean pose)"""
    other_poses: torch.Tensor | None = None
    """(K,H,M,3) the other objects' predicted poses after each step (None: no others)"""


PLAN_FEEDBACK = "rendered"
"""how the planner feeds a learned model's predicted clouds back over its horizon by default
(``se3net.rollout.FEEDBACK``; the backends' own default is the paper's grid)"""
CONTACT_MARGIN_M = 0.01
"""the planner's default contact margin (``planner.learned.contact_gate``; the backends' own
default is none)"""


def segment_distance(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(K,) the distance from points ``p`` to the segments from ``a`` to ``b`` (each (K,2))."""
    ab = b - a
    t = (((p - a) * ab).sum(-1) / ((ab**2).sum(-1) + 1e-12)).clamp(0, 1)
    return ((a + t[:, None] * ab - p) ** 2).sum(-1).add(1e-12).sqrt()


def to_world(T_world_cam: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Camera-frame points (...,N,3) in the world frame."""
    return points @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]


class Dynamics(Protocol):
    """Anything that predicts how the object moves under candidate pushes."""

    name: str
    differentiable: bool

    def rollout(
        self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False
    ) -> Rollout: ...


def integrate_pusher(state: PlanState, actions: torch.Tensor, dt: float) -> torch.Tensor:
    """(K,H,2) pusher positions after each step (``se3net.rollout.pusher_path``)."""
    return pusher_path(actions, state.pusher_xy, dt)


class NoMotionDynamics:
    """Predicts that the object never moves (the lower bound)."""

    name, differentiable = "no-motion", True

    def __init__(self, scenario: Scenario):
        self.dt = scenario.action.dt_control_s

    def rollout(self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False) -> Rollout:
        K, H, _ = actions.shape
        poses = state.object_pose.to(actions).expand(K, H, 3) + 0.0 * actions.sum()
        others = None
        if state.n_others:
            others = state.other_poses.to(actions).expand(K, H, -1, 3) + 0.0 * actions.sum()
        return Rollout(poses, integrate_pusher(state, actions, self.dt), other_poses=others)


class OracleDynamics:
    """The true simulator: every candidate simulated from the world's current state, all of
    them in one batched MuJoCo rollout on the world's own model (``sim.batch``: the arm's
    servos driven along the pusher's exact path, as its controller drives them)."""

    name, differentiable = "oracle", False

    def __init__(self, world: PushWorld, object_index: int = 0):
        self.world, self.object_index = world, object_index

    def rollout(self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False) -> Rollout:
        from sim.batch import simulate_plans

        bound = self.world.scenario.action.max_speed_m_s  # float32 candidates may round past it
        a = np.clip(actions.detach().cpu().double().numpy(), -bound, bound)
        every, pusher = simulate_plans(self.world, a)  # (K,H,n,3), (K,H,2)
        i, n = self.object_index, every.shape[2]
        others = np.delete(every, i, axis=2) if n > 1 else None
        return Rollout(
            torch.from_numpy(every[:, :, i]).to(actions),
            torch.from_numpy(pusher).to(actions),
            other_poses=None if others is None else torch.from_numpy(others).to(actions),
        )


def check_contact_margin(margin_m: float | None) -> float | None:
    """The contact margin (m), or an InputError saying what is wrong."""
    if margin_m is not None and not (np.isfinite(margin_m) and margin_m >= 0):
        raise InputError(
            f"rollout.contact_margin_m must be a distance >= 0 in metres or off, got {margin_m}"
        )
    return margin_m


ENSEMBLE_SEP = "+"
"""checkpoints joined by this form an ensemble (``--model default+runs/b/best.pt``)"""


def make_dynamics(
    name: str,
    scenario: Scenario,
    *,
    model: str | None = None,
    device: str = "cpu",
    world: PushWorld | None = None,
    object_index: int = 0,
    feedback: str = "grid",
    contact_margin_m: float | None = None,
) -> Dynamics:
    """A backend by name: ``se3net``/``flow`` (a checkpoint; the shipped model by default;
    a pose model's checkpoint makes a :class:`PoseDynamics`; checkpoints joined by ``+``: an
    ensemble of them), ``oracle`` (needs the ``world`` and
    the pushed object's index) or ``no-motion``; ``feedback``: how a learned one feeds its
    predicted clouds back (``se3net.rollout.FEEDBACK``); ``contact_margin_m``: within what
    margin of touch a learned one's predicted motions count (``contact_gate``).

    Raises:
        ValueError: an unknown name. CheckpointError: a model that does not fit the scenario.
    """
    if name == "oracle":
        if world is None:
            raise ValueError("the oracle backend simulates the world: pass world=")
        return OracleDynamics(world, object_index)
    if name == "no-motion":
        return NoMotionDynamics(scenario)
    if name in ("se3net", "flow"):
        from pathlib import Path

        from planner.learned import EnsembleDynamics, LearnedDynamics, PoseDynamics
        from se3net.checkpoint import load_checkpoint
        from se3net.pose_model import POSE_VARIANT

        if model is not None and ENSEMBLE_SEP in model and not Path(model).exists():
            parts = model.split(ENSEMBLE_SEP)
            if not all(parts):  # "a+" would add the shipped model unasked
                raise InputError(
                    f"--model {model}: an empty name between the {ENSEMBLE_SEP!r}s; join "
                    "checkpoints as A+B"
                )
            return EnsembleDynamics(
                [
                    make_dynamics(
                        name,
                        scenario,
                        model=m,
                        device=device,
                        feedback=feedback,
                        contact_margin_m=contact_margin_m,
                    )
                    for m in parts
                ]
            )

        net, blob = load_checkpoint(model or "default", scenario=scenario, device=device)
        if blob["model"]["variant"] == POSE_VARIANT:
            return PoseDynamics(net, scenario, contact_margin_m=contact_margin_m)
        kind = "flow" if blob["model"]["variant"].startswith("flow") else "se3net"
        return LearnedDynamics(
            net,
            scenario,
            name=kind,
            device=device,
            feedback=feedback,
            contact_margin_m=contact_margin_m,
        )
    raise ValueError(f"unknown dynamics backend {name!r}; known: {', '.join(BACKENDS)}")
