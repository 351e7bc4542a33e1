import math

import numpy as np
import pytest

from scenarios import load_scenario
from sim import SHAPES, ObjectSpec, PushWorld
from sim.dataset import DataConfig, episode_objects, generate
from sim.datastore import load_episodes
from sim.shapes import hull_outline
from tests.conftest import with_fields

NEW = ("capsule", "hull", "L", "T")


def _world(tiny, shape: str) -> PushWorld:
    return PushWorld(with_fields(tiny, "objects", shapes=(shape,)))


def _boundary(spec: ObjectSpec, n: int = 400) -> np.ndarray:
    """Dense points on the outline of every piece (a brute-force footprint)."""
    out = []
    for piece in spec.pieces():
        v = piece.array
        ring = np.vstack([v, v[:1]])
        for a, b in zip(ring[:-1], ring[1:], strict=True):
            out.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
        if piece.radius > 0:
            angles = np.linspace(0, 2 * math.pi, n)
            circle = piece.radius * np.stack([np.cos(angles), np.sin(angles)], 1)
            out += [c + circle for c in v]
    return np.vstack(out)


@pytest.mark.parametrize("shape", SHAPES)
def test_footprint_support_and_radius_agree_with_brute_force(tiny, shape):
    world = _world(tiny, shape)
    for seed in range(3):
        world.reset(seed)
        spec = world.objects[0]
        pts = _boundary(spec)
        assert spec.footprint_radius_m == pytest.approx(np.linalg.norm(pts, axis=1).max(), abs=2e-4)
        for theta in np.linspace(0, 2 * math.pi, 13):
            u = np.array([math.cos(theta), math.sin(theta)])
            assert spec.support_m(u) == pytest.approx((pts @ u).max(), abs=2e-4)
        lo, hi = pts.min(0), pts.max(0)  # the origin is the bounding box's centre
        np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=2e-4)
        np.testing.assert_allclose(hi - lo, spec.size_m[:2], atol=2e-4)


def test_distance_to_the_footprint_knows_the_notch_of_an_l_and_the_sides_of_a_t():
    L = ObjectSpec("L", (0.10, 0.08, 0.05), 0.3, 0.5, arm_m=0.02)
    assert L.distance_to_footprint_m(np.array([-0.045, 0.03])) == 0.0  # in the upright bar
    assert L.distance_to_footprint_m(np.array([0.03, 0.02])) == pytest.approx(0.04)  # notch
    T = ObjectSpec("T", (0.10, 0.08, 0.05), 0.3, 0.5, arm_m=0.02)
    assert T.distance_to_footprint_m(np.array([0.0, -0.03])) == 0.0  # the stem
    assert T.distance_to_footprint_m(np.array([0.04, -0.03])) == pytest.approx(0.03)
    capsule = ObjectSpec("capsule", (0.10, 0.04, 0.05), 0.3, 0.5)
    assert capsule.distance_to_footprint_m(np.array([0.07, 0.0])) == pytest.approx(0.02)
    assert capsule.distance_to_footprint_m(np.array([0.045, 0.0])) == 0.0
    assert [s.yaw_period_rad for s in (L, T, capsule)] == [2 * math.pi, 2 * math.pi, math.pi]


def test_hull_outline_is_the_counter_clockwise_convex_hull():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, size=(30, 2))
    hull = hull_outline(pts)
    edges = np.roll(hull, -1, 0) - hull
    for p in pts:  # every point on the left of (or on) every edge
        cross = edges[:, 0] * (p[1] - hull[:, 1]) - edges[:, 1] * (p[0] - hull[:, 0])
        assert np.all(cross >= -1e-12)
    assert all(any(np.allclose(v, p) for p in pts) for v in hull)


@pytest.mark.parametrize("shape", NEW)
def test_each_shape_rests_flat_and_the_camera_sees_it_inside_its_footprint(tiny, shape):
    """The physics (MJCF geoms, a mesh for a hull) and the footprint geometry are one shape:
    every pixel on the object lies in its footprint and height, and it stands upright."""
    world = _world(tiny, shape)
    for seed in range(3):
        obs = world.reset(seed)
        spec = world.objects[0]
        on = obs.part == 2
        assert on.sum() > 5
        local = obs.points_part[:, on]  # the object's frame
        assert max(spec.distance_to_footprint_m(p) for p in local[:2].T) < 1e-3
        assert np.all(np.abs(local[2]) <= spec.size_m[2] / 2 + 1e-3)
        R = obs.T_world_part[2, :3, :3]
        assert R[2, 2] > math.cos(math.radians(2))  # upright: no tipping, no rolling
        assert obs.T_world_part[2, 2, 3] == pytest.approx(spec.size_m[2] / 2, abs=2e-3)


def test_datasets_store_every_shape_as_the_world_drew_it(tmp_path):
    scenario = load_scenario("household")
    generate(DataConfig("household", episodes=6, steps_per_episode=2, episodes_per_shard=3),
             tmp_path, progress=False)  # fmt: skip
    arrays = load_episodes(tmp_path, "all").arrays
    world = PushWorld(scenario)
    seen = set()
    for e in range(6):
        world.reset(np.random.default_rng([0, e]))
        stored = episode_objects(arrays, e)
        assert len(stored) == len(world.objects)
        for a, b in zip(stored, world.objects, strict=True):
            assert a.shape == b.shape and a.arm_m == b.arm_m
            np.testing.assert_allclose(a.size_m, b.size_m)
            np.testing.assert_allclose(np.array(a.outline).reshape(-1, 2),
                                       np.array(b.outline).reshape(-1, 2))  # fmt: skip
            seen.add(a.shape)
    assert len(seen) >= 2


def test_the_held_out_objects_lie_outside_the_training_ranges():
    """Every object of heldout_objects is of a family household never draws or beyond its
    sizes and masses; household's own objects are never flagged, nor are household_large's
    (the generalist's fine-tuning data: household's largest boxes, inside its ranges)."""
    from sim.shapes import outside_ranges

    train, held = load_scenario("household"), load_scenario("heldout_objects")
    large = load_scenario("household_large")
    for scenario, outside in ((held, True), (train, False), (large, False)):
        world = PushWorld(scenario)
        for seed in range(25):
            world.reset(seed)
            for spec in world.objects:
                assert bool(outside_ranges(spec, train.objects)) == outside, spec


def test_a_capsule_as_wide_as_it_is_long_builds_and_l_bars_share_mass_by_area():
    import mujoco

    from sim import build_mjcf

    scenario = load_scenario("tiny")
    round_capsule = ObjectSpec("capsule", (0.05, 0.05, 0.04), 0.2, 0.5)
    L = ObjectSpec("L", (0.10, 0.08, 0.05), 0.3, 0.5, arm_m=0.03)
    model = mujoco.MjModel.from_xml_string(build_mjcf(scenario, [round_capsule, L]))
    body = model.body("object1").id
    assert model.body_mass[body] == pytest.approx(0.3)
    # the L's centre of mass, by area: bar x in [-.05, .05], y in [-.04, -.01] (30 cm^2) and
    # bar x in [-.05, -.02], y in [-.01, .04] (15 cm^2)
    com = (30 * np.array([0.0, -0.025]) + 15 * np.array([-0.035, 0.015])) / 45
    np.testing.assert_allclose(model.body_ipos[body][:2], com, atol=1e-4)
