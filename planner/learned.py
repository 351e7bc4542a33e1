"""The learned backends: an SE3-Net or flow-net checkpoint rolled forward
(:class:`LearnedDynamics`), a pose-space model rolled forward (:class:`PoseDynamics`), an
ensemble of them (:class:`EnsembleDynamics`), and the contact
gate that keeps a predicted motion only where something could touch the object
(:func:`contact_gate`). ``planner.dynamics.make_dynamics`` builds them.
"""

from __future__ import annotations

import copy

import torch

from planner.dynamics import (
    PlanState,
    Rollout,
    check_contact_margin,
    integrate_pusher,
    planar_fit,
    segment_distance,
    to_world,
)
from scenarios import InputError, Scenario
from se3net.data import subsample
from se3net.rollout import reprojection, rollout
from sim.planar import wrap_angle

SKIP_BEYOND_M = 0.03
"""a learned backend skips the network for a candidate whose pusher stays this far beyond the
contact gate's reach of every object (15 softness widths: the gate is below 3e-7, so a
predicted step of a centimetre would move the object less than float32 resolves)"""
CONTACT_SOFTNESS_M = 0.002
"""how sharply :func:`contact_gate` closes: over a few millimetres beyond the reach, so that
its gradient is finite"""


def contact_gate(
    poses: torch.Tensor, start: torch.Tensor, movers: list[tuple[torch.Tensor, float]]
) -> torch.Tensor:
    """(K,H,3) an object's predicted poses with every step's motion kept only where a mover
    could touch it: nothing moves an object from afar.

    A step's predicted motion is scaled by the widest open of the movers' gates, each 1 where
    the mover's path over the step (``path[:, h]`` to ``path[:, h + 1]``, (K,H+1,2)) passes
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
        is taken (every CEM and MPPI rollout; the rollouts grad and SQP only score), since
        the choice depends on the actions."""
        if (
            self.contact_margin is None
            or clouds
            or torch.is_grad_enabled()
            or not self.skip_out_of_reach
        ):
            return self._rollout(state, actions, clouds=clouds)
        pusher = integrate_pusher(state, actions, self.dt)
        far = self.out_of_reach(state, pusher)
        if not far.any():
            return self._rollout(state, actions)
        K, H, _ = actions.shape
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

    def out_of_reach(self, state: PlanState, pusher: torch.Tensor) -> torch.Tensor:
        """(K,) bool: the candidates whose pusher path, ``pusher`` (K,H,2) after each step
        (``integrate_pusher``), stays more than the contact gate's reach and ``SKIP_BEYOND_M``
        from every object (as it is now) at every step."""
        K = pusher.shape[0]
        path = torch.cat([state.pusher_xy.to(pusher).expand(K, 1, 2), pusher], 1)
        objects = [(state.object_pose[:2], state.footprint_radius_m)]
        if state.n_others and state.other_radii_m is not None:
            objects += list(zip(state.other_poses[:, :2], state.other_radii_m, strict=True))
        far = torch.ones(K, dtype=torch.bool, device=pusher.device)
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


class EnsembleDynamics:
    """Learned backends rolled side by side: the mean of their object poses, and their spread.

    The spread at a step is the root mean square, over members, of how far the object's
    footprint lies from the mean pose: position deviation plus yaw deviation times the
    footprint radius. Where the members were trained alike it is small; it grows where
    the data says little, which is where a planner exploiting one model goes wrong.
    """

    differentiable = True

    def __init__(self, members: list[LearnedDynamics | PoseDynamics]):
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
        # a pose model predicts no clouds: an ensemble with one has none either
        with_clouds = clouds and all(o.clouds is not None for o in outs)
        return Rollout(
            mean,
            outs[0].pusher_xy,
            torch.stack([o.clouds for o in outs]).mean(0) if with_clouds else None,
            spread=(spread_sq.mean(0) + 1e-12).sqrt(),  # offset: a finite gradient at 0
            other_poses=others,
        )


class PoseDynamics:
    """A pose-space model (``se3net.pose_model``) rolled forward: the object's shape encoded
    once a rollout from its observed points (its support function in its own frame), then its
    pose rolled step by step, every candidate at once; the other objects likewise, each pushed
    by the pusher alone (an object pushed into another is not modelled). With a contact
    margin, predicted motion counts only within reach (:func:`contact_gate`), as for the cloud
    models. The network runs on its own device; results come back on the caller's."""

    differentiable = True
    model = None  # no cloud model to show

    def __init__(self, net: torch.nn.Module, scenario: Scenario, *,
                 contact_margin_m: float | None = None):  # fmt: skip
        self.net, self.name = net, "pose"
        self.device = next(net.parameters()).device
        self.dt = scenario.action.dt_control_s
        self.contact_margin = check_contact_margin(contact_margin_m)
        self.pusher_radius = scenario.arm.pusher_radius_m

    def support(self, state: PlanState, mask: torch.Tensor, pose: torch.Tensor,
                radius: float) -> torch.Tensor:  # fmt: skip
        """(D,) the support function of an object's observed points in its own frame."""
        from se3net.pose_model import rotate, support_function

        sel = (mask & state.valid).flatten()
        world = to_world(state.T_world_cam.double(), state.points.flatten(1)[:, sel].T.double())
        local = rotate(world[:, :2] - pose[:2].double(), -pose[2])  # cos, sin in float32
        return support_function(local, radius)

    def rollout(self, state: PlanState, actions: torch.Tensor, *, clouds: bool = False) -> Rollout:
        K = actions.shape[0]
        pusher = integrate_pusher(state, actions, self.dt)
        pusher_from = torch.cat([state.pusher_xy.to(pusher).expand(K, 1, 2), pusher], 1)
        margin = self.contact_margin
        on = actions.to(self.device)

        def roll(mask: torch.Tensor, pose0: torch.Tensor, radius: float) -> torch.Tensor:
            support = self.support(state, mask, pose0, radius).to(on)
            start = pose0.to(actions)
            poses = self.net.rollout(start[None].to(on), state.pusher_xy.to(on)[None], on,
                                     support[None]).to(actions)  # fmt: skip
            if margin is not None:
                reach = radius + self.pusher_radius + margin
                poses = contact_gate(poses, start, [(pusher_from, reach)])
            return poses

        poses = roll(state.object_mask, state.object_pose, state.footprint_radius_m)
        others = None
        if state.n_others:
            radii = state.other_radii_m or (state.footprint_radius_m,) * state.n_others
            others = torch.stack(
                [roll(m, p, r) for m, p, r in
                 zip(state.other_masks, state.other_poses, radii, strict=True)], 2
            )  # fmt: skip
        return Rollout(poses, pusher, other_poses=others)
