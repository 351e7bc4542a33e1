"""The dynamics protocol the planner talks to, and its backends.

A backend takes the current :class:`PlanState` and a batch of action sequences ``(K,H,2)``
and returns a :class:`Rollout`: the pushed object's predicted planar poses and the pusher's
positions over the horizon. Backends:

- ``LearnedDynamics``: an SE3-Net or flow-net checkpoint rolled forward, each predicted cloud
  fed back as the next input (as the paper does for multi-step prediction), the pusher
  position integrated from the commands into the control vector; the object's pose at each
  step is a least-squares rigid fit (Kabsch, in the table plane) of its predicted points
  to its current points, composed with its current pose. Differentiable end to end with
  respect to the actions. With a contact margin, a predicted motion of an object counts only
  at the steps where something could touch it (:func:`contact_gate`).
- ``OracleDynamics``: the MuJoCo world itself, copied and simulated for each candidate: the
  upper bound any learned model is measured against.
- ``NoMotionDynamics``: nothing but the pusher moves: the lower bound.
- ``EnsembleDynamics``: several learned checkpoints rolled side by side; it predicts their
  mean and reports their disagreement (``Rollout.spread``), which the cost can penalise so
  the planner keeps to actions the models agree on.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch

from scenarios import InputError, Scenario
from se3net.data import subsample
from se3net.rollout import pusher_path, reprojection, rollout
from sim.planar import wrap_angle

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
"""the planner's default contact margin (:func:`contact_gate`; the backends' own default is
none)"""
SKIP_BEYOND_M = 0.03
"""a learned backend skips the network for a candidate whose pusher stays this far beyond the
contact gate's reach of every object (15 softness widths: the gate is below 3e-7, so a
predicted step of a centimetre would move the object less than float32 resolves)"""
CONTACT_SOFTNESS_M = 0.002
"""how sharply :func:`contact_gate` closes: over a few millimetres beyond the reach, so that
its gradient is finite"""


def segment_distance(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(K,) the distance from points ``p`` to the segments from ``a`` to ``b`` (each (K,2))."""
    ab = b - a
    t = (((p - a) * ab).sum(-1) / ((ab**2).sum(-1) + 1e-12)).clamp(0, 1)
    return ((a + t[:, None] * ab - p) ** 2).sum(-1).add(1e-12).sqrt()


def contact_gate(
    poses: torch.Tensor, start: torch.Tensor, movers: list[tuple[torch.Tensor, float]]
) -> torch.Tensor:
    """(K,H,3) an object's predicted poses with every step's motion kept only where a mover
    could touch it: nothing moves an object from afar.

    A step's predicted motion is scaled by the gate of the nearest mover: 1 where the
    mover's path over the step (``path[:, h]`` to ``path[:, h + 1]``, (K,H+1,2)) passes
    within its ``reach`` of where the object is, falling to 0 over a few millimetres
    (``CONTACT_SOFTNESS_M``) beyond it. A learned model predicts small motions of objects
    nothing touches, and a planner that believes them shuns moves that pass near the object
    (or makes moves that push nothing); the simulator has no such motions.

    Args:
        poses: (K,H,3) the predicted poses after each step.
        start: (3,) the pose before the first.
        movers: (path (K,H+1,2), reach m) of each thing that can push the object.
    """
    K, H, _ = poses.shape
    gated, before, now = [], start.expand(K, 3), start.expand(K, 3)
    for h in range(H):
        step = poses[:, h] - before
        step = torch.cat([step[:, :2], wrap_angle(step[:, 2:])], 1)
        gate = torch.stack(
            [
                torch.sigmoid((reach - segment_distance(now[:, :2], path[:, h], path[:, h + 1]))
                              / CONTACT_SOFTNESS_M)
                for path, reach in movers
            ]
        ).amax(0)  # fmt: skip
        now = now + gate[:, None] * step
        before = poses[:, h]
        gated.append(now)
    return torch.stack(gated, 1)


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
    """The true simulator: each candidate is simulated from a copy of the world's state.

    The oracle is the one backend that holds the world (it is given it when built); it
    copies the world's current state at each rollout, and builds its copy again whenever the
    world was reset (a reset builds a new model: other objects, sizes, masses and friction).
    """

    name, differentiable = "oracle", False

    def __init__(self, world: PushWorld, object_index: int = 0):
        self.world, self.object_index = world, object_index
        self._clone: PushWorld | None = None
        self._clone_of = None  # the world's model the copy was built from

    def rollout(self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False) -> Rollout:
        if self._clone_of is not self.world.model:  # a new episode: copy its objects
            self._clone, self._clone_of = self.world.clone(), self.world.model
        start = self.world.snapshot()
        bound = self.world.scenario.action.max_speed_m_s  # float32 candidates may round past it
        a = np.clip(actions.detach().cpu().double().numpy(), -bound, bound)
        K, H, _ = a.shape
        n = len(self.world.objects)
        every = np.empty((K, H, n, 3))  # every object's pose
        pusher = np.empty((K, H, 2))
        for k in range(K):
            self._clone.restore(start)
            for h in range(H):
                if self._clone.ended:  # an object fell off: they stay where they were last seen
                    if h == 0:
                        raise ValueError("the oracle cannot plan from a world whose episode ended")
                    every[k, h], pusher[k, h] = every[k, h - 1], pusher[k, h - 1]
                    continue
                every[k, h] = self._clone.advance(a[k, h])
                pusher[k, h] = self._clone.pusher_xy()
        i = self.object_index
        others = np.delete(every, i, axis=2) if n > 1 else None
        return Rollout(
            torch.from_numpy(every[:, :, i]).to(actions),
            torch.from_numpy(pusher).to(actions),
            other_poses=None if others is None else torch.from_numpy(others).to(actions),
        )


class LearnedDynamics:
    """An SE3-Net or flow-net checkpoint rolled forward over the horizon.

    Args:
        model: the network (from ``se3net.checkpoint.load_checkpoint``, checked against the
            scenario).
        scenario: the scenario (camera extrinsics, control timing).
        name: ``"se3net"`` or ``"flow"``.
        feedback: how each predicted cloud is fed back (``se3net.rollout.FEEDBACK``):
            ``rendered`` again by the scenario's camera, or on the observed ``grid``.
        contact_margin_m: None: every predicted motion counts. A distance: an object's
            predicted motion at a step counts only where the pusher's path (or, for the other
            objects, the pushed object's) passes within their two footprint radii and this
            margin of it (:func:`contact_gate`).
    """

    differentiable = True
    skip_out_of_reach = True
    """skip the network for candidates out of reach (:meth:`rollout`; off: to time the lever)"""

    def __init__(
        self,
        model: torch.nn.Module,
        scenario: Scenario,
        *,
        name: str,
        device: str = "cpu",
        feedback: str = "grid",
        contact_margin_m: float | None = None,
    ):
        # planning differentiates with respect to the actions only: a frozen copy of the
        # weights spares the backward pass their gradients (grad and SQP planners) and leaves
        # the caller's model as it was
        self.model = copy.deepcopy(model).eval().requires_grad_(False)
        self.name, self.device = name, torch.device(device)
        self.dt = scenario.action.dt_control_s
        self.stride = model.cfg.stride  # the network sees every stride-th pixel
        self.reproject = reprojection(feedback, scenario.camera, self.stride)
        self.contact_margin = check_contact_margin(contact_margin_m)
        self.pusher_radius = scenario.arm.pusher_radius_m

    def network_view(self, state: PlanState) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """What the network sees of a state, on its device: the cloud (3,h,w), the valid
        pixels and the pushed object's pixels (h,w), every stride-th pixel of the camera's."""
        return tuple(
            subsample(x.to(self.device), self.stride)
            for x in (state.points, state.valid, state.object_mask)
        )

    def rollout(self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False) -> Rollout:
        """Predictions for ``actions`` (K,H,2); ``clouds`` at the network's resolution.

        With a contact margin, a candidate whose pusher stays out of reach of every object over
        the whole horizon (``SKIP_BEYOND_M`` beyond the gate's reach) is not rolled through the
        network: the gate would keep under 3e-7 of whatever motion the network predicted for
        it, so its objects stay where they are, as in the full rollout. Only where no gradient
        is taken (CEM and MPPI evaluate under inference mode): the choice depends on the
        actions."""
        if (
            self.contact_margin is None
            or clouds
            or torch.is_grad_enabled()
            or not self.skip_out_of_reach
        ):
            return self._rollout(state, actions, clouds=clouds)
        far = self.out_of_reach(state, actions)
        if not far.any():
            return self._rollout(state, actions)
        K, H, _ = actions.shape
        pusher = integrate_pusher(state, actions, self.dt)
        poses = state.object_pose.to(actions).expand(K, H, 3).clone()
        others = None
        if state.n_others:
            others = state.other_poses.to(actions).expand(K, H, -1, 3).clone()
        if not far.all():
            near = self._rollout(state, actions[~far])
            poses[~far] = near.object_poses
            if others is not None:
                others[~far] = near.other_poses
        return Rollout(poses, pusher, other_poses=others)

    def out_of_reach(self, state: PlanState, actions: torch.Tensor) -> torch.Tensor:
        """(K,) bool: the candidates whose pusher path stays more than the contact gate's
        reach and ``SKIP_BEYOND_M`` from every object (as it is now) at every step."""
        K = actions.shape[0]
        pusher = integrate_pusher(state, actions, self.dt)
        path = torch.cat([state.pusher_xy.to(pusher).expand(K, 1, 2), pusher], 1)
        objects = [(state.object_pose[:2], state.footprint_radius_m)]
        if state.n_others and state.other_radii_m is not None:
            objects += list(zip(state.other_poses[:, :2], state.other_radii_m, strict=True))
        far = torch.ones(K, dtype=torch.bool, device=actions.device)
        for centre, radius in objects:
            reach = float(radius) + self.pusher_radius + self.contact_margin + SKIP_BEYOND_M
            c = centre.to(pusher).expand(K, 2)
            for h in range(path.shape[1] - 1):
                far &= segment_distance(c, path[:, h], path[:, h + 1]) > reach
        return far

    def _rollout(self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False) -> Rollout:
        """Every candidate through the network (:meth:`rollout`)."""
        K, H, _ = actions.shape
        caller = actions.device  # the network runs on self.device; results go back to the caller
        actions = actions.to(self.device)
        pusher = integrate_pusher(state, actions, self.dt)
        points, valid, obj = self.network_view(state)
        predicted = rollout(
            self.model,
            points[None],
            valid[None],
            actions,
            state.pusher_xy.to(self.device)[None],
            self.dt,
            reproject=self.reproject,
        )
        T = state.T_world_cam.to(self.device, points.dtype)

        def track(mask: torch.Tensor, pose0: torch.Tensor) -> torch.Tensor:
            """(K,H,3) an object's poses: its predicted points fitted to its observed ones."""
            sel = (mask & valid).flatten().nonzero()[:, 0]
            if len(sel) < 3:  # out of sight: nothing to predict from
                return pose0.expand(K, H, 3) + 0.0 * torch.stack(predicted, 1).sum()
            src = to_world(T, points.flatten(1)[:, sel].T)[:, :2]  # (N,2)
            poses = []
            for x in predicted:
                dst = to_world(T, x.flatten(2)[:, :, sel].transpose(1, 2))[..., :2]  # (K,N,2)
                yaw, xy = planar_fit(src, dst, pose0[:2])
                poses.append(torch.cat([xy, (pose0[2] + yaw)[:, None]], 1))
            return torch.stack(poses, 1)

        start = state.object_pose.to(self.device)
        poses = track(obj, start)
        margin = self.contact_margin
        if margin is not None:
            pusher_from = torch.cat([state.pusher_xy.to(pusher).expand(K, 1, 2), pusher], 1)
            reach = state.footprint_radius_m + self.pusher_radius + margin
            poses = contact_gate(poses, start, [(pusher_from, reach)])
        others = None
        if state.n_others:
            masks = subsample(state.other_masks.to(self.device), self.stride)
            starts = state.other_poses.to(self.device)
            others = [track(m, p) for m, p in zip(masks, starts, strict=True)]
            if margin is not None and state.other_radii_m is not None:
                pushed_from = torch.cat([start[:2].expand(K, 1, 2), poses[..., :2]], 1)
                others = [
                    contact_gate(o, p, [(pusher_from, r + self.pusher_radius + margin),
                                        (pushed_from, r + state.footprint_radius_m + margin)])
                    for o, p, r in zip(others, starts, state.other_radii_m, strict=True)
                ]  # fmt: skip
            others = torch.stack(others, 2).to(caller)
        return Rollout(
            poses.to(caller),
            pusher.to(caller),
            torch.stack(predicted, 1).to(caller) if clouds else None,
            other_poses=others,
        )


def check_contact_margin(margin_m: float | None) -> float | None:
    """The contact margin (m), or an InputError saying what is wrong."""
    if margin_m is not None and not (np.isfinite(margin_m) and margin_m >= 0):
        raise InputError(
            f"rollout.contact_margin_m must be a distance >= 0 in metres or off, got {margin_m}"
        )
    return margin_m


def to_world(T_world_cam: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Camera-frame points (...,N,3) in the world frame."""
    return points @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]


class EnsembleDynamics:
    """Learned backends rolled side by side: the mean of their object poses, and their spread.

    The spread at a step is the root mean square, over members, of how far the object's
    footprint lies from the mean pose: position deviation plus yaw deviation times the
    footprint radius. Where the members were trained alike it is small; it grows where
    the data says little, which is where a planner exploiting one model goes wrong.
    """

    differentiable = True

    def __init__(self, members: list[LearnedDynamics]):
        if len(members) < 2:
            raise InputError(f"an ensemble needs at least two models, got {len(members)}")
        self.members = members
        self.model = getattr(members[0], "model", None)  # what the visualiser shows
        self.name = "ensemble"

    def rollout(self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False) -> Rollout:
        outs = [m.rollout(state, actions, clouds=clouds) for m in self.members]
        poses = torch.stack([o.object_poses for o in outs])  # (M,K,H,3)
        mean = poses.mean(0)  # yaws are the start yaw plus small increments: a plain mean
        dev = poses - mean
        radius = state.footprint_radius_m
        spread_sq = (dev[..., :2] ** 2).sum(-1) + (radius * dev[..., 2]) ** 2
        others = None
        if outs[0].other_poses is not None:
            others = torch.stack([o.other_poses for o in outs]).mean(0)
        return Rollout(
            mean,
            outs[0].pusher_xy,
            torch.stack([o.clouds for o in outs]).mean(0) if clouds else None,
            spread=(spread_sq.mean(0) + 1e-12).sqrt(),  # offset: a finite gradient at 0
            other_poses=others,
        )


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
    checkpoints joined by ``+``: an ensemble of them), ``oracle`` (needs the ``world`` and
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

        from se3net.checkpoint import load_checkpoint

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
