"""The one rollout of a network: training's multi-step loss, evaluation's fed-back rows and
the planner's learned backend all call :func:`rollout`, so every "N steps fed back" figure is
the planner's.

Each predicted cloud is fed back as the next input (the paper's multi-step prediction); the
controls hold the commanded velocity and the pusher position at the step's start, integrated
from the commands (as the planner forms them: it cannot read future positions from data).
Joint-velocity controls (``sim.controls``) have no integrated state: their controls are the
commands alone.

How a predicted cloud is fed back (``reproject``):

- on the observed pixel grid (None, the paper's way): each point keeps the pixel it was seen
  in and only its coordinates move. A network trained on real clouds reads contact from where
  the pusher *appears* in the image, and there the pusher never moves: rolled over a push
  that starts a few centimetres from an object, a network whose one-step predictions from
  the real clouds along it add up to most of the motion predicts under a millimetre in all
  (``tests/se3net/test_rollout``);
- rendered again (a :class:`Reprojection`): the predicted points are projected into the
  camera as a depth image (the nearest point wins a pixel; a pixel uncovered by something
  that moved away takes its farthest neighbour, the background), so the next input looks like
  the camera's next frame. Every observed point is still followed: it moves with the
  predicted motion of the pixel it lands in (its own where it is seen, the point in front of
  it where it is hidden), so the returned clouds keep the observed points' order and every
  caller's targets, masks and pose fits stay as they are.

A saving for planning, where many action sequences start from one observed cloud:

- the observed cloud is encoded once, whatever the number of sequences (a batch of one cloud
  is broadcast over the sequences; exact).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from scenarios import CameraConfig, InputError
from sim.camera import intrinsics

FEEDBACK = ("grid", "rendered")
"""how a rollout feeds a predicted cloud back: on the observed pixel grid (the paper's way),
or rendered again by the camera (:class:`Reprojection`)"""


def check_feedback(feedback: str) -> str:
    """``feedback`` if it is one of :data:`FEEDBACK`, else an InputError naming them."""
    if feedback not in FEEDBACK:
        raise InputError(f"--feedback must be one of {', '.join(FEEDBACK)}, got {feedback!r}")
    return feedback


def reprojection(feedback: str, camera: CameraConfig, stride: int) -> Reprojection | None:
    """What :func:`rollout` is given as ``reproject`` for a ``feedback`` setting."""
    return Reprojection.of(camera, stride) if check_feedback(feedback) == "rendered" else None


FILL_PASSES = 4
"""passes of the background fill: a pixel a pass from a hole's edge, so holes up to 8 pixels
across (the pusher is 2-3 at 32x32) close; larger ones stay holes (invalid pixels)"""


@dataclass(frozen=True)
class Reprojection:
    """The camera's projection onto a network's pixel grid (every ``stride``-th camera pixel
    in each direction, ``se3net.data.subsample``): renders clouds as the camera would see
    them."""

    f: float
    """focal length (camera pixels)"""
    cx: float
    cy: float
    """principal point (camera pixels; pixel i's centre is at i + 0.5)"""
    stride: int
    """the network sees camera pixel stride * i as its pixel i"""

    @classmethod
    def of(cls, camera: CameraConfig, stride: int) -> Reprojection:
        K = intrinsics(camera, camera.width, camera.height)
        return cls(float(K[0, 0]), float(K[0, 2]), float(K[1, 2]), stride)

    def pixels(self, points: torch.Tensor, live: torch.Tensor, h: int, w: int) -> torch.Tensor:
        """(B,N) the network pixel (row * w + column) each camera-frame point (B,3,N) projects
        into; -1 for points not ``live`` (B or 1, N), behind the camera or off the image."""
        x, y, z = points.unbind(1)
        zs = z.clamp_min(1e-6)
        col = torch.round((x / zs * self.f + self.cx - 0.5) / self.stride)
        row = torch.round((y / zs * self.f + self.cy - 0.5) / self.stride)
        on = live & (z > 1e-6) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        return torch.where(on, row * w + col, -1).long().detach()

    def render(
        self, points: torch.Tensor, pixel: torch.Tensor, background: torch.Tensor, h: int, w: int
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The depth image (B,3,h,w) and its valid pixels (B,h,w) of points (B,3,N) that land
        in ``pixel`` (B,N, from :meth:`pixels`): the nearest point wins a pixel; a pixel that
        holds none but held something when observed (``background``, (1 or B,h,w)) takes its
        farthest seen neighbour in a 3x3 window (what the moved point had hidden), over
        ``FILL_PASSES`` passes; differentiable in the points' coordinates (not in which point
        wins)."""
        B, _, N = points.shape
        hw = h * w
        on = pixel >= 0
        # every point scatters at once (no boolean indexing, which syncs and copies): a point
        # off the image goes to a spare slot past the last pixel, dropped at the end
        slot = torch.where(on, torch.arange(B, device=points.device)[:, None] * hw + pixel, B * hw)
        slot, z = slot.flatten(), points[:, 2].detach().flatten()
        nearest = torch.full((B * hw + 1,), torch.inf, dtype=z.dtype, device=z.device)
        nearest = nearest.scatter_reduce(0, slot, z, "amin")
        wins = on.flatten() & (z == nearest.gather(0, slot))
        index = torch.arange(N, device=points.device).repeat(B)
        winner = torch.full((B * hw + 1,), -1, dtype=torch.long, device=z.device)
        winner = winner.scatter_reduce(0, slot, torch.where(wins, index, -1), "amax")
        winner = winner[:-1].view(B, hw)
        seen = winner >= 0
        image = points.gather(2, winner.clamp_min(0)[:, None].expand(B, 3, hw)) * seen[:, None]
        image, seen = image.view(B, 3, h, w), seen.view(B, h, w)
        background, ids = background.bool(), torch.arange(hw, device=points.device)
        for _ in range(FILL_PASSES):  # a wide hole fills in from its edges, a pixel a pass
            hole = ~seen & background
            if not hole.any():
                break
            depth = torch.where(seen, image[:, 2].detach(), -torch.inf)
            near = F.unfold(depth[:, None], 3, padding=1)  # (B,9,hw): each pixel's window
            best, k = near.max(1)  # the padding reads 0, seen depths are > 0
            fill = hole.flatten(1) & (best > 0)
            dy, dx = k // 3 - 1, k % 3 - 1
            src = torch.where(fill, (ids + dy * w + dx).clamp(0, hw - 1), ids)
            flat = image.flatten(2)
            image = flat.gather(2, src[:, None].expand(B, 3, hw)).view(B, 3, h, w)
            seen = seen | fill.view(B, h, w)
        return image, seen


def pusher_path(actions: torch.Tensor, pusher_xy: torch.Tensor, dt: float) -> torch.Tensor:
    """(B,N,2) the pusher's positions after each of N steps, integrated from the commanded
    velocities (B,N,2) from its position (B or 1, 2) when the first starts: where the
    planner expects it, the one integration of the commands."""
    return pusher_xy.to(actions).reshape(-1, 1, 2) + dt * torch.cumsum(actions, dim=1)


def pusher_controls(actions: torch.Tensor, state: torch.Tensor, dt: float) -> torch.Tensor:
    """Controls (B,N,c+s) of N steps: the commands (B,N,c) and the state integrated from them
    at each step's start (``pusher_path``), from ``state`` (B or 1, s) when the first starts:
    the pusher position (s = 2), or nothing for joint-velocity controls (s = 0: the controls
    are the commands)."""
    if state.shape[-1] == 0:
        return actions
    start = state.to(actions).expand(len(actions), -1)[:, None]
    after = pusher_path(actions[:, :-1], state, dt)
    return torch.cat([actions, torch.cat([start, after], 1)], -1)


def rollout(
    model: nn.Module,
    points: torch.Tensor,
    valid: torch.Tensor,
    actions: torch.Tensor,
    state: torch.Tensor,
    dt: float,
    *,
    reproject: Reprojection | None = None,
    **sharpen: Any,
) -> list[torch.Tensor]:
    """Roll a network over N steps, each predicted cloud fed back as the next input.

    Args:
        model: an SE3-Net or flow net (``se3net.model``).
        points: (B0,3,H,W) the observed cloud(s), camera frame (m); B0 = 1 (one cloud for
            every sequence, encoded once) or B.
        valid: (B0,H,W) bool, pixels that hold a point.
        actions: (B,N,c) the commands: pusher velocities (m/s, c = 2) or joint velocities
            (rad/s, c = 4).
        state: (B0,s) the integrated state when the first action starts: the pusher's
            position (world frame, s = 2), or nothing for joint velocities (s = 0).
        dt: the control step (s).
        reproject: feed each predicted cloud back rendered again by the camera (None: on the
            observed pixel grid; see the module's docstring).
        sharpen: ``sigma``, ``gamma``, ``generator`` for training's weight sharpening.

    Returns:
        N predicted clouds, each (B,3,H,W): where each observed point is after each step.
    """
    u = pusher_controls(actions, state, dt)
    x, out = points, []
    v, pixel = valid, None
    for h in range(actions.shape[1]):
        enc = model.encode(x, v)
        pred = model.predict(x, u[:, h], v, enc, **sharpen)
        if pixel is None:  # the observed cloud: every point is in its own pixel
            cloud = pred.points
        else:  # each observed point moves as the pixel it lands in was predicted to
            B, _, H, W = pred.points.shape
            moved = (pred.points - x).flatten(2)
            step = moved.gather(2, pixel.clamp_min(0)[:, None].expand(B, 3, -1))
            cloud = (out[-1].flatten(2) + step * (pixel >= 0)[:, None]).view(B, 3, H, W)
        out.append(cloud)
        if reproject is None:
            x = cloud
        elif h + 1 < actions.shape[1]:
            B, _, H, W = cloud.shape
            flat = cloud.flatten(2)
            pixel = reproject.pixels(flat, valid.flatten(1), H, W)
            x, v = reproject.render(flat, pixel, valid, H, W)
    return out
