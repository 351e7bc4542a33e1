"""The planner's view of the simulated world: the one place where a world observation becomes
a :class:`PlanState` (the optimisers, the cost and the learned backends see only that)."""

from __future__ import annotations

import numpy as np
import torch

from planner.dynamics import PlanState
from sim import Observation, PushWorld


def plan_state(obs: Observation, world: PushWorld, object_index: int = 0) -> PlanState:
    """The planner's view of a world observation, pushing object ``object_index``."""
    spec = world.objects[object_index]
    others = [j for j in range(len(world.objects)) if j != object_index]
    return PlanState(
        points=torch.from_numpy(obs.points_cam).float(),
        valid=torch.from_numpy(obs.valid),
        object_mask=torch.from_numpy(obs.object_pixels(object_index)),
        object_pose=torch.from_numpy(obs.object_poses[object_index]).float(),
        pusher_xy=torch.from_numpy(obs.pusher_xy_m).float(),
        T_world_cam=torch.from_numpy(world.camera.T_world_cam).float(),
        footprint_radius_m=spec.footprint_radius_m,
        yaw_period_rad=spec.yaw_period_rad,
        other_poses=torch.from_numpy(obs.object_poses[others]).float().reshape(-1, 3),
        other_masks=torch.from_numpy(
            np.stack([obs.object_pixels(j) for j in others])
            if others
            else np.zeros((0, *obs.valid.shape), bool)
        ),
        other_radii_m=tuple(world.objects[j].footprint_radius_m for j in others),
    )
