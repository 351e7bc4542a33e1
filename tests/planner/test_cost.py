import math

import numpy as np
import pytest
import torch

from planner.cost import PushCost
from planner.dynamics import PlanState
from scenarios import load_scenario
from sim import PushWorld


def _state(spec, pusher_xy):
    return PlanState(
        points=torch.zeros(3, 2, 2),
        valid=torch.zeros(2, 2, dtype=torch.bool),
        object_mask=torch.zeros(2, 2, dtype=torch.bool),
        object_pose=torch.zeros(3),
        pusher_xy=torch.tensor(pusher_xy, dtype=torch.float32),
        T_world_cam=torch.eye(4),
        footprint_radius_m=spec.footprint_radius_m,
        yaw_period_rad=spec.yaw_period_rad,
    )


def _segment_distance(a, b):
    """Distance of the origin from the segment a-b."""
    a, b = np.asarray(a), np.asarray(b)
    t = np.clip(-(a @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    return float(np.linalg.norm(a + t * (b - a)))


@pytest.mark.parametrize("angle_deg", [180, 150, -150, 120, -100, 90, 60])
def test_the_way_round_reaches_the_far_side_without_crossing_the_object(angle_deg):
    """Follow the shaping target from a pusher on the goal's side: each hop keeps clear of the
    object's footprint, and within a few hops the target is the pre-push point behind it."""
    scenario = load_scenario("single_box")
    world = PushWorld(scenario)
    world.reset(0)
    spec = world.objects[0]
    cost = PushCost(scenario, torch.tensor([0.2, 0.0, 0.0]))  # goal straight along +x
    clear = spec.footprint_radius_m + scenario.arm.pusher_radius_m
    a = math.radians(angle_deg)  # 0 is straight behind (at -x), 180 in front
    pusher = 0.08 * np.array([-math.cos(a), math.sin(a)])
    for _ in range(4):
        state = _state(spec, pusher)
        target = cost.shaping_target(state).numpy()
        assert _segment_distance(pusher, target) > clear
        if np.allclose(target, cost.pre_push_point(state).numpy()):
            break
        pusher = target
    else:
        pytest.fail(f"from {angle_deg} deg the way round never reached the pre-push point")
    assert target[0] < -spec.footprint_radius_m and abs(target[1]) < 1e-6
