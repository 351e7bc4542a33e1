import numpy as np

from sim import PushWorld, look_at
from tests.conftest import with_fields


def test_look_at_is_a_rotation_with_optical_axis_to_target():
    T = look_at(np.array([0.4, 0.1, 0.6]), np.array([0.0, 0.0, 0.0]))
    R = T[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0)
    axis = -np.array([0.4, 0.1, 0.6]) / np.linalg.norm([0.4, 0.1, 0.6])
    np.testing.assert_allclose(R[:, 2], axis, atol=1e-12)
    assert R[2, 1] < 0  # image y (down) points downward in the world


def test_straight_down_camera_sees_table_point_where_computed_by_hand(tiny):
    # camera 0.5 m above the table centre, looking straight down, 32x32, fovy 45 deg;
    # objects and pusher moved out of the view.
    s = with_fields(tiny, "camera", position_m=(0.0, 0.0, 0.5), target_m=(0.0, 0.0, 0.0))
    s = with_fields(s, "objects", region_m=(0.12, 0.13, 0.12, 0.13))
    s = with_fields(s, "arm", start_xy_m=(-0.12, -0.12))
    world = PushWorld(s)
    obs = world.reset(0)
    f = 16 / np.tan(np.deg2rad(45.0) / 2)  # focal length in pixels
    v, u = 5, 20
    dx, dy = (u + 0.5 - 16) / f, (v + 0.5 - 16) / f  # normalised image coordinates
    assert obs.part[v, u] == 0  # the table
    np.testing.assert_allclose(obs.points_cam[:, v, u], [0.5 * dx, 0.5 * dy, 0.5], atol=1e-9)
    # image x is world -y and image y is world -x for this camera
    p_world = world.camera.T_world_cam @ np.append(obs.points_cam[:, v, u], 1.0)
    np.testing.assert_allclose(p_world[:3], [-0.5 * dy, -0.5 * dx, 0.0], atol=1e-9)
    np.testing.assert_allclose(world.camera.project(obs.points_cam[:, v, u]), [u + 0.5, v + 0.5])


def test_segmentation_labels_the_right_bodies(tiny_world):
    obs = tiny_world.reset(3)
    T_world_cam = tiny_world.camera.T_world_cam
    pts = (
        np.einsum("ij,jhw->ihw", T_world_cam[:3, :3], obs.points_cam)
        + T_world_cam[:3, 3, None, None]
    )
    for k in (0, 1, 2):
        assert (obs.part == k).sum() > 3, f"part {k} is barely visible"
    # table pixels lie on the table top (or its sides)
    assert np.all(pts[2][obs.part == 0] < 1e-6)
    # object pixels lie inside the object's box, in the object's frame
    half = np.array(tiny_world.objects[0].size_m) / 2
    local = obs.points_part[:, obs.part == 2].T
    assert np.all(np.abs(local) <= half + 1e-6)
    np.testing.assert_allclose(np.abs(local).max(axis=0).max(), half.max(), atol=0.01)
    # pusher pixels lie on the pusher's cylinder
    r = tiny_world.scenario.arm.pusher_radius_m
    radial = np.linalg.norm(obs.points_part[:2, obs.part == 1], axis=0)
    assert np.all(radial <= r + 1e-6)
    assert not obs.valid[obs.part == -1].any() and obs.valid[obs.part >= 0].all()


def test_no_point_lies_beyond_the_cameras_range(tiny):
    world = PushWorld(tiny)
    world.reset(3)
    full = world.camera.render(world.model, world.data)
    ranges = np.linalg.norm(full.points_cam, axis=0)[full.valid]
    cut = float(np.quantile(ranges, 0.5))  # a range that ends inside the scene
    world.camera.max_depth_m = cut
    near = world.camera.render(world.model, world.data)
    assert np.linalg.norm(near.points_cam, axis=0)[near.valid].max() <= cut + 1e-9
    assert (near.geom_id[~near.valid] == -1).all()
    # what lies within the range is seen as before
    within = full.valid & (np.linalg.norm(full.points_cam, axis=0) <= cut)
    assert (near.valid == within).all()
