import math

import mujoco
import numpy as np
import pytest

from scenarios import InputError
from se3net.data import VISIBLE_DEPTH_TOL_M
from sim import SHAPES, ActionError, EpisodeEnded, PushWorld, associated_targets
from sim.camera import invert
from tests.conftest import with_fields


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


@pytest.mark.parametrize("shape", SHAPES)
def test_associations_are_exact_for_a_known_object_motion(tiny, shape):
    world = PushWorld(with_fields(tiny, "objects", shapes=(shape,)))  # a mesh body for a hull
    obs = world.reset(5)
    # move object 0 by a known transform: 3 cm along x, 2 cm along y, 25 deg about its centre
    T_move = np.eye(4)
    T_move[:3, :3] = _rot_z(math.radians(25))
    centre = obs.T_world_part[2, :3, 3]
    T_move[:3, 3] = centre + [0.03, 0.02, 0.0] - T_move[:3, :3] @ centre
    T_new = T_move @ obs.T_world_part[2]
    adr = world.model.jnt_qposadr[world.model.joint("object0").id]
    world.data.qpos[adr : adr + 3] = T_new[:3, 3]
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, T_new[:3, :3].reshape(-1))
    world.data.qpos[adr + 3 : adr + 7] = quat
    mujoco.mj_kinematics(world.model, world.data)
    later = world.observe()

    targets = world.targets(obs, later)
    on_object = obs.part == 2
    p_world = world.camera.T_world_cam @ np.vstack(
        [obs.points_cam[:, on_object], np.ones(on_object.sum())]
    )
    expected = (world.camera.T_cam_world @ T_move @ p_world)[:3]
    assert on_object.sum() > 10
    assert np.abs(targets[:, on_object] - expected).max() < 1e-5
    # where a moved point is in view, the later frame sees that part there
    K, z = world.camera.K, targets[2, on_object]
    u = np.floor(targets[0, on_object] / z * K[0, 0] + K[0, 2]).astype(int)
    v = np.floor(targets[1, on_object] / z * K[1, 1] + K[1, 2]).astype(int)
    inside = (u >= 0) & (u < later.part.shape[1]) & (v >= 0) & (v < later.part.shape[0])
    u, v = u.clip(0, later.part.shape[1] - 1), v.clip(0, later.part.shape[0] - 1)
    near = np.abs(later.points_cam[2, v, u] - z) < VISIBLE_DEPTH_TOL_M
    assert np.mean(inside & (later.part[v, u] == 2) & near) > 0.6
    # static points do not move; pixels that hit nothing have no target
    np.testing.assert_allclose(
        targets[:, obs.part == 0], obs.points_cam[:, obs.part == 0], atol=1e-9
    )
    assert np.all(targets[:, obs.part == -1] == 0)


def test_targets_equal_points_with_current_poses(tiny_world):
    obs = tiny_world.reset(1)
    same = associated_targets(
        obs.points_part, obs.part, obs.T_world_part, tiny_world.camera.T_cam_world
    )
    np.testing.assert_allclose(same, obs.points_cam, atol=1e-9)
    assert np.allclose(invert(invert(obs.T_world_part)), obs.T_world_part)


def test_controller_tracks_velocity_in_free_space(tiny):
    s = with_fields(tiny, "objects", region_m=(0.10, 0.12, 0.10, 0.12))  # out of the way
    world = PushWorld(s)
    obs = world.reset(0)
    v = np.array([0.08, -0.06])
    lo, hi = np.array(s.arm.joint_limits_rad).T
    heights, start = [], obs.pusher_xy_m.copy()
    for _ in range(6):
        obs = world.step(v)
        heights.append(world.data.site_xpos[world._pusher_site, 2])
        assert np.all(obs.joint_pos_rad >= lo) and np.all(obs.joint_pos_rad <= hi)
    mean_velocity = (obs.pusher_xy_m - start) / obs.time_s
    assert abs(np.linalg.norm(mean_velocity) / np.linalg.norm(v) - 1) < 0.10
    assert (
        np.degrees(np.arccos(mean_velocity @ v / np.linalg.norm(mean_velocity) / np.linalg.norm(v)))
        < 3
    )
    assert np.max(np.abs(np.array(heights) - s.arm.pusher_clearance_m)) < 0.003
    np.testing.assert_allclose(
        obs.object_poses, world.reset(0).object_poses, atol=1e-4
    )  # untouched
    assert world.qp_failures == 0


def test_controller_respects_joint_limits_at_the_edge_of_reach(tiny):
    s = with_fields(tiny, "objects", region_m=(0.10, 0.12, 0.10, 0.12))
    world = PushWorld(s)
    world.reset(0)
    lo, hi = np.array(s.arm.joint_limits_rad).T
    for _ in range(25):  # drive straight away from the base, beyond reach
        obs = world.step([0.15, 0.0])
        assert np.all(obs.joint_pos_rad >= lo - 1e-6) and np.all(obs.joint_pos_rad <= hi + 1e-6)
    assert abs(world.data.site_xpos[world._pusher_site, 2] - s.arm.pusher_clearance_m) < 0.01


def test_same_seed_gives_identical_observations(tiny):
    runs = []
    for _ in range(2):
        world = PushWorld(tiny)
        obs = [world.reset(11)]
        obs += [world.step(a) for a in ([0.1, 0.0], [0.1, 0.02], [0.05, -0.1])]
        runs.append(obs)
    for a, b in zip(*runs, strict=True):
        for field in ("points_cam", "part", "points_part", "T_world_part", "object_poses"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(PushWorld(tiny).reset(12).points_cam, runs[0][0].points_cam)


def test_pushing_moves_the_object(tiny_world):
    obs = tiny_world.reset(2)
    start = obs.object_poses[0, :2].copy()
    for _ in range(12):
        d = obs.object_poses[0, :2] - obs.pusher_xy_m
        obs = tiny_world.step(0.12 * d / np.linalg.norm(d))
    assert np.linalg.norm(obs.object_poses[0, :2] - start) > 0.01


@pytest.mark.parametrize(
    ("action", "pattern"),
    [
        ([0.2, 0.0], "outside the bounds"),
        ([np.nan, 0.0], "not finite"),
        ([0.0, np.inf], "not finite"),
        ([0.1, 0.0, 0.0], "shape"),
    ],
)
def test_bad_actions_are_refused_before_simulating(tiny_world, action, pattern):
    obs = tiny_world.reset(0)
    with pytest.raises(ActionError, match=pattern):
        tiny_world.step(action)
    assert tiny_world.data.time == obs.time_s
    assert np.all(np.isfinite(tiny_world.data.qpos))


def test_object_off_the_table_ends_the_episode(tiny_world):
    world = tiny_world
    world.reset(0)
    adr = world.model.jnt_qposadr[world.model.joint("object0").id]
    world.data.qpos[adr] = world.scenario.table.size_m[0]  # beyond the far edge
    obs = world.step([0.0, 0.0])
    assert obs.done and obs.reason == "object_off_table"
    with pytest.raises(EpisodeEnded, match="object_off_table"):
        world.step([0.0, 0.0])


def test_unreachable_start_is_reported(tiny):
    with pytest.raises(InputError, match=r"out of the arm's reach .*move arm\.start_xy_m"):
        PushWorld(with_fields(tiny, "arm", start_xy_m=(0.5, 0.0))).reset(0)


def test_the_observation_says_when_the_camera_cannot_see_the_pusher():
    """single_box's camera sees the table's middle but not its corner at (+x, +y): driven
    there, the pusher drops out of the image, and the observation says so."""
    from scenarios import load_scenario

    scenario = load_scenario("single_box")
    world = PushWorld(scenario)
    obs = world.reset(0)
    assert obs.pusher_seen
    target = np.array([0.2, 0.25])  # on the table, outside the camera's view
    speed, dt = scenario.action.max_speed_m_s, scenario.action.dt_control_s
    seen = []
    for _ in range(40):
        d = target - obs.pusher_xy_m
        if np.linalg.norm(d) < 0.01:
            break
        obs = world.step(speed * d / max(np.linalg.norm(d), speed * dt))  # no overshoot
        seen.append(obs.pusher_seen)
    assert np.linalg.norm(target - obs.pusher_xy_m) < 0.03
    assert not obs.pusher_seen and seen[0]
