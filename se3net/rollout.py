"""The one rollout of a network: training's multi-step loss, evaluation's fed-back rows and
the planner's learned backend all call :func:`rollout`, so every "N steps fed back" figure is
the planner's.

Each predicted cloud is fed back as the next input (the paper's multi-step prediction); the
controls hold the commanded velocity and the pusher position at the step's start, integrated
from the commands (as the planner forms them: it cannot read future positions from data).
Joint-velocity controls (``sim.controls``) have no integrated state: their controls are the
commands alone.

Two savings for planning, where many action sequences start from one observed cloud:

- the observed cloud is encoded once, whatever the number of sequences (a batch of one cloud
  is broadcast over the sequences; exact);
- with ``carry_masks`` the masks decoded at the first step stay with their points over the
  horizon, so later steps run the encoder and the SE(3) head but not the mask decoder (an
  approximation whose cost is measured by the study's horizon error and by trials). Flow
  nets have no masks and ignore it.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn


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
    carry_masks: bool = False,
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
        carry_masks: keep the first step's masks for the later steps (SE3-Nets).
        sharpen: ``sigma``, ``gamma``, ``generator`` for training's weight sharpening.

    Returns:
        N predicted clouds, each (B,3,H,W).
    """
    u = pusher_controls(actions, state, dt)
    x, masks, out = points, None, []
    for h in range(actions.shape[1]):
        enc = model.encode(x, valid)
        pred = model.predict(x, u[:, h], valid, enc, masks=masks, **sharpen)
        x = pred.points
        if carry_masks:
            masks = pred.masks
        out.append(x)
    return out
