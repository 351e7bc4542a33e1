"""The oracle's batched rollouts (sim.batch) against the world stepped through its controller."""

import numpy as np
import pytest

from scenarios import load_scenario
from sim import PushWorld
from sim.batch import simulate_plans
from sim.controller import planar_arm_reach, planar_arm_xy


def _sequential(world: PushWorld, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What ``advance`` does with each plan, from the world's state (restored after)."""
    start = world.snapshot()
    K, H, _ = actions.shape
    poses, pusher = np.empty((K, H, len(world.objects), 3)), np.empty((K, H, 2))
    for k in range(K):
        world.restore(start)
        for h in range(H):
            poses[k, h], pusher[k, h] = world.advance(actions[k, h]), world.pusher_xy()
    world.restore(start)
    return poses, pusher


def test_the_arms_closed_form_kinematics_invert_each_other():
    s = load_scenario("single_box")
    xy = np.random.default_rng(0).uniform([-0.2, -0.2], [0.2, 0.2], (50, 2))
    np.testing.assert_allclose(planar_arm_xy(s, planar_arm_reach(s, xy)), xy, atol=1e-12)


def test_a_point_out_of_reach_gets_the_angles_of_the_nearest_reachable_one_on_its_line():
    s = load_scenario("single_box")
    a = s.arm
    l1, l2 = a.link_lengths_m
    down = a.shoulder_height_m - (a.pusher_clearance_m + a.pusher_length_m)
    edge = np.sqrt((l1 + l2) ** 2 - down**2)  # the farthest the tip reaches at working height
    way = np.array([np.cos(0.3), np.sin(0.3)])
    far = np.array(a.base_xy_m) + (edge + np.array([0.05, 0.2]))[:, None] * way
    np.testing.assert_allclose(planar_arm_reach(s, far),
                               planar_arm_reach(s, np.array(a.base_xy_m) + edge * way)[None]
                               .repeat(2, 0), atol=1e-12)  # fmt: skip


def test_batched_pushes_land_where_the_controller_takes_them():
    """Pushes of held-out objects 8 steps long, from a random side: the batched rollout's
    object ends within what the simulator's own sensitivity gives (a nudge of the servos by a
    tenth of a milliradian moves a pushed object's yaw by about 2 mrad)."""
    s = load_scenario("heldout_objects")
    rng = np.random.default_rng(0)
    final, tip, moved = [], [], []
    for seed in range(3):
        world = PushWorld(s)
        pose = world.reset(seed).object_poses[0]
        side = rng.uniform(-np.pi, np.pi)
        toward = -np.array([np.cos(side), np.sin(side)])
        world.teleport_pusher(pose[:2] - (max(world.objects[0].size_m[:2]) / 2 + 0.035) * toward)
        U = np.clip(0.08 * toward + rng.normal(0, 0.05, (8, 8, 2)), -0.15, 0.15)
        ref, ref_tip = _sequential(world, U)
        got, got_tip = simulate_plans(world, U)
        final.append(np.linalg.norm(got[:, -1, 0, :2] - ref[:, -1, 0, :2], axis=-1))
        tip.append(np.linalg.norm(got_tip - ref_tip, axis=-1).max())
        moved.append(np.linalg.norm(ref[:, -1, 0, :2] - pose[:2], axis=-1))
    assert np.median(moved) > 0.03  # they were pushes
    assert np.median(final) < 1.5e-3  # measured 0.6-1.0 mm
    assert max(tip) < 2e-3  # measured 1.6 mm


def test_a_candidate_whose_episode_ends_keeps_the_poses_it_ended_with(monkeypatch):
    """A plan whose episode ends (an object off the table) at step 3: its later steps repeat
    that step's poses, as the world stepped one step at a time would leave them; the other
    candidate is not touched."""
    s = load_scenario("single_box")
    world = PushWorld(s)
    pose = world.reset(0).object_poses[0]
    world.teleport_pusher(pose[:2] - [0.07, 0.0])
    U = np.tile([0.12, 0.0], (2, 8, 1))
    free, free_tip = simulate_plans(world, U)
    ends = world.end_codes

    def end_at_3(qpos, qvel):
        codes = ends(qpos, qvel)
        codes[0, 3:] = 2
        return codes

    monkeypatch.setattr(world, "end_codes", end_at_3)
    poses, tip = simulate_plans(world, U)
    np.testing.assert_array_equal(poses[0, :4], free[0, :4])
    np.testing.assert_array_equal(poses[0, 4:], np.repeat(free[0, 3:4], 4, 0))
    np.testing.assert_array_equal(tip[0, 4:], np.repeat(free_tip[0, 3:4], 4, 0))
    np.testing.assert_array_equal(poses[1], free[1])
    assert np.linalg.norm(free[0, -1, 0, :2] - free[0, 3, 0, :2]) > 0.01  # it would have moved


def test_an_ended_world_is_refused():
    s = load_scenario("single_box")
    world = PushWorld(s)
    world.reset(0)
    world._done = True
    with pytest.raises(ValueError, match="episode ended"):
        simulate_plans(world, np.zeros((1, 2, 2)))
