"""The arm scenario (the paper's Baxter setting): joint-velocity controls, the links as parts,
exact associations for the links, and exploration that keeps to the joint limits and off the
table."""

from pathlib import Path

import numpy as np
import pytest

from scenarios import ScenarioError, load_scenario
from scenarios.config import scenario_fingerprint
from se3net.data import VISIBLE_DEPTH_TOL_M
from sim import ActionError, PushWorld
from sim.camera import invert
from sim.controls import JOINT_LAYOUT, PUSHER_LAYOUT, control_layout
from sim.dataset import STEP_MODES, DataConfig, EpisodeRecorder, generate, run_episode
from sim.datastore import frame_cloud
from sim.mjcf import ARM_JOINTS
from sim.world import part_names

PACKAGED = Path(__file__).resolve().parents[2] / "scenarios"
Q0 = np.array([0.1, -0.5, 1.2, 0.3])
"""a configuration with every link in view"""
LINK_BODIES = {"pusher": "pusher", "arm base": "arm_base", "upper arm": "link1",
               "forearm": "link2"}  # fmt: skip
"""the MuJoCo body behind each moving part's name"""


@pytest.fixture(scope="module")
def arm():
    return load_scenario("arm")


@pytest.fixture
def world(arm):
    w = PushWorld(arm)
    w.reset(0)
    return w


def joint_positions(world: PushWorld) -> np.ndarray:
    """(4,) the arm's joint angles as MuJoCo holds them."""
    return np.array([world.data.joint(name).qpos[0] for name in ARM_JOINTS])


def body_pose(world: PushWorld, name: str) -> np.ndarray:
    """(4,4) a body's pose as MuJoCo holds it."""
    T = np.eye(4)
    T[:3, :3] = world.data.body(name).xmat.reshape(3, 3)
    T[:3, 3] = world.data.body(name).xpos
    return T


def test_the_arm_scenario_has_joint_velocity_controls_and_every_link_a_part(arm, world):
    assert control_layout(arm) == JOINT_LAYOUT and len(JOINT_LAYOUT.names) == 4
    assert control_layout(load_scenario("single_box")) == PUSHER_LAYOUT
    names = part_names(arm, 0)
    assert names == ["static", "pusher", "arm base", "upper arm", "forearm"]  # k = 5, the paper's
    obs = world.set_arm(Q0)
    assert len(obs.T_world_part) == 5 and obs.object_poses.shape == (0, 3)
    for p in range(5):
        assert (obs.part == p).sum() >= 10, names[p]  # each in view at 64x64
    # what a model depends on tells the two apart; push scenarios keep their stored fingerprint
    assert scenario_fingerprint(arm)["action"]["controls"] == "joints"
    assert "controls" not in scenario_fingerprint(load_scenario("single_box"))["action"]


@pytest.mark.parametrize("joint", range(4))
@pytest.mark.parametrize("speed", [0.3, -0.2])
def test_a_commanded_joint_velocity_moves_that_joint_by_v_dt_and_no_other(world, joint, speed):
    world.set_arm(Q0)
    qd = np.zeros(4)
    qd[joint] = speed
    dt = world.scenario.action.dt_control_s
    world.step(qd)
    q1 = joint_positions(world)
    world.step(qd)
    q2 = joint_positions(world)
    moved = q2 - Q0
    assert moved[joint] == pytest.approx(2 * speed * dt, rel=0.03)
    assert q2[joint] - q1[joint] == pytest.approx(speed * dt, rel=0.01)  # within a scene: exact
    others = np.delete(moved, joint)
    assert np.abs(others).max() < 1e-3 * abs(moved[joint])


def test_commands_stop_at_the_joint_limits(arm, world):
    lo, hi = np.array(arm.arm.joint_limits_rad).T
    q = Q0.copy()
    q[2] = hi[2] - 0.02
    world.set_arm(q)
    bound = arm.action.max_joint_speed_rad_s
    for _ in range(4):
        world.step(np.array([0.0, 0.0, bound, 0.0]))
    q_end = joint_positions(world)
    assert hi[2] - 2e-3 < q_end[2] <= hi[2] + 1e-3  # it got there and stopped
    assert np.all(q_end >= lo - 1e-3) and np.all(q_end <= hi + 1e-3)


def test_an_action_of_the_wrong_size_or_out_of_bounds_is_refused(arm, world):
    with pytest.raises(ActionError, match="velocities of the arm's 4 joints; got shape"):
        world.step(np.array([0.1, 0.0]))
    bound = arm.action.max_joint_speed_rad_s
    with pytest.raises(ActionError, match="max_joint_speed_rad_s"):
        world.step(np.array([0.0, bound * 1.5, 0.0, 0.0]))


def test_associations_are_exact_for_every_link_after_a_joint_motion(arm, world):
    obs = world.set_arm(Q0)
    before = {name: body_pose(world, body) for name, body in LINK_BODIES.items()}
    rec = EpisodeRecorder(world, 1, obs)
    later = world.step(np.array([0.2, -0.25, 0.3, -0.3]))  # all four joints
    rec.step(np.array([0.2, -0.25, 0.3, -0.3]), "joints", later)
    episode = {k: v[None] for k, v in rec.finish().items()}  # as a dataset holds it
    stored = frame_cloud(episode, 0, 0, world.camera.T_cam_world, at=1)
    targets = world.targets(obs, later)
    T_world_cam, T_cam_world = world.camera.T_world_cam, world.camera.T_cam_world
    for p, name in enumerate(part_names(arm, 0)):
        if name == "static":
            continue
        pixels = obs.part == p
        p_world = T_world_cam @ np.vstack([obs.points_cam[:, pixels], np.ones(pixels.sum())])
        # MuJoCo's own poses of the link's body, before and after the motion
        T_move = body_pose(world, LINK_BODIES[name]) @ invert(before[name])
        expected = (T_cam_world @ T_move @ p_world)[:3]
        flow = np.linalg.norm(expected - obs.points_cam[:, pixels], axis=0)
        if name != "arm base":  # it turns about its own axis: small flow
            assert flow.max() > 5e-3, name
        assert np.abs(targets[:, pixels] - expected).max() < 1e-6, name
        assert np.abs(stored[:, pixels] - expected).max() < 2.5e-4, name  # float16 points
        # where a moved point is in view, the later frame sees that part there
        K, z = world.camera.K, targets[2, pixels]
        u = np.floor(targets[0, pixels] / z * K[0, 0] + K[0, 2]).astype(int)
        v = np.floor(targets[1, pixels] / z * K[1, 1] + K[1, 2]).astype(int)
        inside = (u >= 0) & (u < 64) & (v >= 0) & (v < 64)
        u, v = u.clip(0, 63), v.clip(0, 63)
        near = np.abs(later.points_cam[2, v, u] - z) < VISIBLE_DEPTH_TOL_M
        assert np.mean(inside & (later.part[v, u] == p) & near) > 0.6, name
    # the upper arm's pixels lie on its capsule, between the shoulder and the elbow
    seg0, seg1 = before["upper arm"][:3, 3], before["forearm"][:3, 3]
    pixels = obs.part == part_names(arm, 0).index("upper arm")
    pts = (T_world_cam @ np.vstack([obs.points_cam[:, pixels], np.ones(pixels.sum())]))[:3].T
    s = np.clip((pts - seg0) @ (seg1 - seg0) / np.sum((seg1 - seg0) ** 2), 0, 1)
    dist = np.linalg.norm(pts - (seg0 + s[:, None] * (seg1 - seg0)), axis=1)
    np.testing.assert_allclose(dist, arm.arm.link_radii_m[0], atol=1e-6)


def test_exploration_moves_1_to_4_joints_within_the_limits_and_above_the_table(arm):
    cfg = DataConfig("arm", episodes=6, steps_per_episode=20)
    lo, hi = np.array(arm.arm.joint_limits_rad).T
    bound = arm.action.max_joint_speed_rad_s
    sizes = set()
    for i in range(6):
        ep = run_episode(arm, cfg, i)
        n = int(ep["length"])
        assert n == 20
        # inside the limits by most of the policy's margin: no command is cut short by them
        q, margin = ep["joint_pos"][: n + 1], cfg.joint_exploration.limit_margin_rad / 2
        assert np.all(q >= lo + margin) and np.all(q <= hi - margin)
        actions = ep["actions"][:n]
        moving = np.count_nonzero(actions, axis=1)
        rest = ep["modes"][:n] == STEP_MODES.index("rest")
        assert np.all(moving[rest] == 0) and np.all((moving[~rest] >= 1) & (moving[~rest] <= 4))
        assert np.abs(actions).max() <= bound
        sizes |= set(moving[~rest].tolist())
        # the elbow (the forearm's origin), the wrist (the pusher's) and the tip stay clear of
        # the table by more than the links' radii
        T = ep["T_world_part"][: n + 1]
        tip = T[:, 1] @ np.array([0.0, 0.0, -arm.arm.pusher_length_m, 1.0])
        lowest = np.minimum.reduce([T[:, 4, 2, 3], T[:, 1, 2, 3], tip[:, 2]])
        assert lowest.min() > max(arm.arm.link_radii_m)
    assert len(sizes) >= 3  # scenes of various numbers of joints


def test_arm_data_is_the_same_bytes_for_the_same_seed(tmp_path):
    cfg = DataConfig("arm", episodes=2, steps_per_episode=3, episodes_per_shard=1)
    a = generate(cfg, tmp_path / "a", progress=False)
    b = generate(cfg, tmp_path / "b", workers=2, progress=False)
    assert a["shards"] == b["shards"]
    assert a["identity"]["control_layout"] == list(JOINT_LAYOUT.names)
    assert a["identity"]["exploration"]["joints_moved"] == [1, 4]


def _variant(tmp_path: Path, stem: str, old: str, new: str) -> Path:
    text = (PACKAGED / f"{stem}.toml").read_text()
    assert old in text
    path = tmp_path / "variant.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("stem", "old", "new", "pattern"),
    [
        ("arm", "count = [0, 0]", "count = [1, 1]", r"objects\.count': expected \[0, 0\] with "
         "action.controls 'joints'"),
        ("tiny", "count = [1, 1]", "count = [0, 0]", r"objects\.count': expected at least 1"),
        ("tiny", "controller_rate_hz = 100.0", "controller_rate_hz = 100.0\nlinks_visible = true",
         r"objects\.count': expected \[0, 0\] with arm\.links_visible"),
        ("arm", 'controls = "joints"', 'controls = "wheels"', r"action\.controls': expected "
         "entries from"),
    ],
)  # fmt: skip
def test_combinations_that_cannot_work_are_refused(tmp_path, stem, old, new, pattern):
    with pytest.raises(ScenarioError, match=r"variant\.toml: field '" + pattern):
        load_scenario(_variant(tmp_path, stem, old, new))
