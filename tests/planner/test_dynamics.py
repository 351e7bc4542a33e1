import dataclasses
import math

import numpy as np
import pytest
import torch

from planner import PlannerConfig, PushCost, make_dynamics, make_planner, plan_state
from planner.dynamics import NoMotionDynamics, integrate_pusher, planar_fit
from planner.learned import EnsembleDynamics, LearnedDynamics, contact_gate
from scenarios import load_scenario
from se3net.checkpoint import CheckpointError
from se3net.model import ModelConfig, build_model
from sim import PushWorld
from tests.planner.toy import TOY_COST, CarriedDisk, toy_state

SINGLE_BOX = load_scenario("single_box")
DT = SINGLE_BOX.action.dt_control_s


def _approach(world, obs, n=6):
    for _ in range(n):
        d = obs.object_poses[0, :2] - obs.pusher_xy_m
        obs = world.step(0.12 * d / np.linalg.norm(d))
    return obs


def test_oracle_predictions_are_what_the_world_then_does(tiny):
    """The oracle's batched rollout drives the arm along the pusher's exact path rather than
    through the controller's QP (sim.batch), so it agrees with the world to a fraction of a
    millimetre, not to the last digit."""
    world = PushWorld(tiny)
    obs = _approach(world, world.reset(2), 3)
    goal = torch.tensor([*(obs.object_poses[0, :2] + [0.05, 0.0]), 0.0])
    planner = make_planner(
        "cem",
        make_dynamics("oracle", tiny, world=world),
        PushCost(tiny, goal),
        tiny,
        PlannerConfig(samples=8, elites=2, iterations=1),
    )
    _, info = planner.plan(plan_state(obs, world))
    for h, a in enumerate(info.actions):
        obs = world.step(a)
        np.testing.assert_allclose(obs.object_poses[0], info.predicted_poses[h], atol=1e-6)
        np.testing.assert_allclose(obs.pusher_xy_m, info.predicted_pusher[h], atol=4e-4)


def test_the_oracle_simulates_the_objects_of_the_episode_after_a_reset():
    """A reset draws other sizes, masses and friction with the same number of bodies: the
    oracle must simulate the new episode's objects, not its copy of the previous ones."""
    scenario = load_scenario("multi_object")
    world = PushWorld(scenario)
    first = world.reset(0)
    oracle = make_dynamics("oracle", scenario, world=world)
    oracle.rollout(plan_state(first, world), torch.zeros(1, 3, 2))  # copies this episode
    first_objects = list(world.objects)
    obs = _approach(world, world.reset(2), 7)  # as many objects as seed 0, of other sizes
    assert len(world.objects) == len(first_objects) and world.objects != first_objects
    start = obs.object_poses[0].copy()
    d = obs.object_poses[0, :2] - obs.pusher_xy_m
    U = torch.from_numpy(np.tile(0.14 * d / np.linalg.norm(d), (1, 4, 1))).float()
    predicted = oracle.rollout(plan_state(obs, world), U).object_poses[0].numpy()
    for h in range(4):
        obs = world.step(np.clip(U[0, h].double().numpy(), -0.15, 0.15))
        # within what a nudge of the servos by a tenth of a milliradian does (sim.batch)
        np.testing.assert_allclose(obs.object_poses[0, :2], predicted[h, :2], atol=1e-3)
        np.testing.assert_allclose(obs.object_poses[0, 2], predicted[h, 2], atol=5e-3)
    assert np.hypot(*(obs.object_poses[0, :2] - start[:2])) > 0.02  # the push moved it


def test_no_motion_predicts_a_still_object_and_an_integrated_pusher(tiny):
    world = PushWorld(tiny)
    state = plan_state(world.reset(0), world)
    U = torch.full((2, 3, 2), 0.1)
    r = NoMotionDynamics(tiny).rollout(state, U)
    torch.testing.assert_close(r.object_poses, state.object_pose.expand(2, 3, 3))
    torch.testing.assert_close(
        r.pusher_xy[:, -1], (state.pusher_xy + 3 * 0.15 * torch.tensor([0.1, 0.1])).expand(2, 2)
    )


def test_gradients_through_the_se3net_rollout_match_finite_differences(tiny):
    torch.manual_seed(0)
    world = PushWorld(tiny)
    obs = _approach(world, world.reset(2), 4)
    model = build_model(ModelConfig(height=32, width=32, k=3))
    with torch.no_grad():  # a model whose predictions depend on the actions
        model.se3_head[-1].weight.normal_(0, 0.05)
    model = model.double().eval()
    dyn = LearnedDynamics(model, tiny, name="se3net")
    state = plan_state(obs, world)
    state = type(state)(
        **{
            **state.__dict__,
            "points": state.points.double(),
            "object_pose": state.object_pose.double(),
            "pusher_xy": state.pusher_xy.double(),
        }
    )
    goal = torch.tensor([*(obs.object_poses[0, :2] + [0.05, 0.02]), 0.3])
    cost = PushCost(tiny, goal)

    def f(U):
        return cost.cost(state, dyn.rollout(state, U), U, last_action=torch.zeros(2)).sum()

    U = (0.05 * torch.randn(1, 3, 2, dtype=torch.float64)).requires_grad_()
    f(U).backward()
    eps = 1e-5
    numeric = torch.zeros_like(U)
    for i in range(3):
        for j in range(2):
            d = torch.zeros_like(U)
            d[0, i, j] = eps
            numeric[0, i, j] = (f(U.detach() + d) - f(U.detach() - d)) / (2 * eps)
    assert U.grad.abs().max() > 1e-3
    torch.testing.assert_close(U.grad, numeric, rtol=1e-3, atol=1e-5)


def test_a_stride_2_network_plans_from_full_resolution_observations(tiny):
    """A planning-resolution network gets every other pixel of the observation, the object's
    pixels with them: a network that moves every point by a known step predicts the object
    moved by that step, and clouds at its own resolution."""
    world = PushWorld(tiny)
    state = plan_state(_approach(world, world.reset(2), 2), world)
    model = build_model(ModelConfig(height=16, width=16, k=3, stride=2))
    step = torch.tensor([0.01, -0.02, 0.0])  # world frame, each step
    R_wc = state.T_world_cam[:3, :3]
    with torch.no_grad():
        model.se3_head[-1].bias.copy_(torch.cat([R_wc.T @ step, torch.zeros(3)]).repeat(3))
    dyn = LearnedDynamics(model.eval(), tiny, name="se3net")
    out = dyn.rollout(state, torch.zeros(2, 3, 2), clouds=True)
    assert out.clouds.shape == (2, 3, 3, 16, 16)
    h = torch.arange(1, 4, dtype=torch.float32)[:, None]
    expected = state.object_pose[:2] + h * step[:2]
    torch.testing.assert_close(out.object_poses[0, :, :2], expected, atol=1e-5, rtol=0)
    torch.testing.assert_close(out.object_poses[..., 2], state.object_pose[2].expand(2, 3))


def _two_objects():
    scenario = load_scenario("multi_object")
    world = PushWorld(scenario)
    seed = next(s for s in range(50) if len(world.reset(s).object_poses) >= 2)
    return scenario, world, world.reset(seed)


def test_backends_predict_the_other_objects_too():
    """Among other objects every backend predicts their poses: the oracle what the world then
    does, a network that moves every point by a known step each of them moved by it."""
    scenario, world, obs = _two_objects()
    state = plan_state(obs, world, 1)
    M = len(world.objects) - 1
    assert state.n_others == M and state.other_masks.shape == (M, *obs.valid.shape)
    U = 0.1 * torch.ones(2, 3, 2)
    oracle = make_dynamics("oracle", scenario, world=world, object_index=1).rollout(state, U)
    for a in U[0].numpy():
        obs = world.step(a)
    np.testing.assert_allclose(oracle.other_poses[0, -1].numpy(),
                               np.delete(obs.object_poses, 1, 0), atol=1e-6)  # fmt: skip
    model = build_model(ModelConfig(k=3))
    step = torch.tensor([0.01, -0.02, 0.0])
    with torch.no_grad():
        model.se3_head[-1].bias.copy_(torch.cat([state.T_world_cam[:3, :3].T @ step,
                                                 torch.zeros(3)]).repeat(3))  # fmt: skip
    learned = LearnedDynamics(model.eval(), scenario, name="se3net").rollout(state, U)
    expected = state.other_poses[:, :2] + 3 * step[:2]
    torch.testing.assert_close(learned.other_poses[0, -1, :, :2], expected, atol=1e-5, rtol=0)
    still = NoMotionDynamics(scenario).rollout(state, U).other_poses
    torch.testing.assert_close(still[1, 2], state.other_poses)


def test_backend_errors(tiny):
    with pytest.raises(
        ValueError,
        match="unknown dynamics backend 'mujoco'; known: se3net, flow, oracle, no-motion",
    ):
        make_dynamics("mujoco", tiny)
    with pytest.raises(CheckpointError, match="does not fit scenario 'tiny'"):
        make_dynamics("se3net", tiny)  # the shipped model is for single_box
    with pytest.raises(ValueError, match="needs a differentiable backend"):
        world = PushWorld(tiny)
        state = plan_state(world.reset(0), world)
        make_planner(
            "grad",
            make_dynamics("oracle", tiny, world=world),
            PushCost(tiny, (0.0, 0.0, 0.0)),
            tiny,
        ).plan(state)


def test_planar_fit_recovers_a_known_planar_motion():
    g = torch.Generator().manual_seed(0)
    src = torch.randn(20, 2, generator=g)
    th, t = 0.3, torch.tensor([0.1, -0.2])
    R = torch.tensor([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]], dtype=torch.float32)
    dst = torch.stack([src @ R.T + t, src])  # moved, and not moved
    centre = torch.tensor([0.5, 0.5])
    yaw, xy = planar_fit(src, dst, centre)
    torch.testing.assert_close(yaw, torch.tensor([th, 0.0]), atol=1e-5, rtol=0)
    torch.testing.assert_close(xy, torch.stack([R @ centre + t, centre]), atol=1e-5, rtol=0)


class _Carried(CarriedDisk):
    """The toy disk, carried with per-axis gains: a member of a disagreeing ensemble."""

    def __init__(self, gain: tuple[float, float]):
        super().__init__(DT)
        self.gain = torch.tensor(gain)

    def rollout(self, state, actions, *, clouds=False):
        moved = super().rollout(state, actions * self.gain.to(actions))
        return dataclasses.replace(moved, pusher_xy=integrate_pusher(state, actions, DT))


def test_an_ensemble_predicts_the_members_mean_and_their_spread():
    state = toy_state()
    U = 0.1 * torch.randn(5, 4, 2, generator=torch.Generator().manual_seed(0))
    r = EnsembleDynamics([_Carried((1.0, 1.0)), _Carried((0.0, 0.0))]).rollout(state, U)
    moved = DT * torch.cumsum(U, 1)
    torch.testing.assert_close(r.object_poses[..., :2], 0.5 * moved)
    torch.testing.assert_close(r.pusher_xy, moved)
    torch.testing.assert_close(r.spread, 0.5 * moved.norm(dim=-1), atol=1e-6, rtol=1e-5)
    same = EnsembleDynamics([_Carried((1.0, 1.0)), _Carried((1.0, 1.0))]).rollout(state, U)
    assert same.spread.max() < 1e-5
    with pytest.raises(ValueError, match="at least two models"):
        EnsembleDynamics([_Carried((1.0, 1.0))])


def test_the_planner_keeps_to_pushes_the_ensemble_agrees_on():
    # the members agree on motion along x and disagree along y (one says it does not move)
    ensemble = EnsembleDynamics([_Carried((1.0, 1.0)), _Carried((1.0, 0.0))])
    # 4 steps, the horizon its thresholds were set for (with 3 the penalty curbs less)
    strong = PlannerConfig(horizon_s=0.6, samples=256, elites=16, iterations=8)

    def planned(goal, w_spread):
        cost = PushCost(
            SINGLE_BOX, torch.tensor(goal), dataclasses.replace(TOY_COST, w_spread=w_spread)
        )
        return make_planner("cem", ensemble, cost, SINGLE_BOX, strong).plan(toy_state())[1].actions

    along_x = (0.06, 0.0, 0.0)
    # where they agree the penalty changes nothing but the sampled sideways noise
    np.testing.assert_allclose(planned(along_x, 1.0), planned(along_x, 0.0), atol=0.02)
    along_y = (0.0, 0.06, 0.0)
    free, careful = planned(along_y, 0.0)[:, 1].sum(), planned(along_y, 1.0)[:, 1].sum()
    assert free > 0.3  # without the penalty it pushes hard toward the goal
    assert careful < 0.7 * free  # with it, much less where the members disagree


def test_checkpoints_joined_by_plus_make_an_ensemble():
    world = PushWorld(SINGLE_BOX)
    state = plan_state(world.reset(0), world)
    U = 0.1 * torch.randn(3, 2, 2, generator=torch.Generator().manual_seed(1))
    pair = make_dynamics("se3net", SINGLE_BOX, model="default+default")
    assert isinstance(pair, EnsembleDynamics) and len(pair.members) == 2
    one = make_dynamics("se3net", SINGLE_BOX, model="default")
    with torch.no_grad():
        r, r1 = pair.rollout(state, U), one.rollout(state, U)
    torch.testing.assert_close(r.object_poses, r1.object_poses)
    assert r.spread.max() < 1e-5
    with pytest.raises(CheckpointError, match="nowhere.pt"):
        make_dynamics("se3net", SINGLE_BOX, model="default+nowhere.pt")


def test_the_contact_gate_keeps_a_step_s_motion_only_where_a_mover_passes_within_reach():
    """Three predicted steps of 1 cm and 0.05 rad (the second across the yaw wrap); the
    mover passes the object in the second step only: the object makes that step's motion
    (not the motion since the start) and no other."""
    poses = torch.tensor([[[0.01, 0.0, 3.10], [0.02, 0.0, 3.10 + 0.05 - 2 * math.pi],
                           [0.03, 0.0, 3.20 - 2 * math.pi]]])  # fmt: skip
    start = torch.tensor([0.0, 0.0, 3.05])
    path = torch.tensor([[[-0.1, 0.5], [-0.1, 0.1], [0.1, -0.1], [0.1, -0.5]]])  # far, through, far
    gated = contact_gate(poses, start, [(path, 0.05)])
    expected = torch.tensor([[[0.0, 0.0, 3.05], [0.01, 0.0, 3.10], [0.01, 0.0, 3.10]]])
    torch.testing.assert_close(gated, expected, atol=1e-6, rtol=0)
    # the nearest of several movers opens the gate: one that touches at every step
    always = contact_gate(poses, start, [(path, 0.05), (torch.zeros(1, 4, 2), 0.05)])
    unwrapped = torch.tensor([[[0.01, 0.0, 3.10], [0.02, 0.0, 3.15], [0.03, 0.0, 3.20]]])
    torch.testing.assert_close(always, unwrapped, atol=1e-6, rtol=0)


def test_with_a_contact_margin_a_network_that_moves_everything_moves_only_what_is_touched():
    """A stand-in network moves every point by 1 mm a step, touched or not. Two objects; the
    pusher stands still 2 cm from the pushed one's centre, on the side away from the other:
    ungated, both move 3 mm in three steps; with a margin that lets the pushed object reach
    the other (and not the pusher), both move; with no margin, only the pushed one (the
    reset keeps a gap between them)."""
    scenario = load_scenario("multi_object")
    world = PushWorld(scenario)
    seed = next(s for s in range(50) if len(world.reset(s).object_poses) == 2)
    state = plan_state(world.reset(seed), world, 0)
    pushed, other = state.object_pose[:2], state.other_poses[0, :2]
    gap = float((other - pushed).norm())
    state = dataclasses.replace(state, pusher_xy=pushed + 0.02 * (pushed - other) / gap)
    model = build_model(ModelConfig(k=3))
    step = torch.tensor([0.001, 0.0, 0.0])
    with torch.no_grad():
        model.se3_head[-1].bias.copy_(torch.cat([state.T_world_cam[:3, :3].T @ step,
                                                 torch.zeros(3)]).repeat(3))  # fmt: skip

    def moved(margin):
        with torch.inference_mode():
            r = LearnedDynamics(
                model.eval(), scenario, name="se3net", contact_margin_m=margin
            ).rollout(state, torch.zeros(1, 3, 2))
        return [float((r.object_poses[0, -1, :2] - pushed).norm()),
                float((r.other_poses[0, -1, 0, :2] - other).norm())]  # fmt: skip

    np.testing.assert_allclose(moved(None), [0.003, 0.003], atol=2e-5)
    reach = gap - state.other_radii_m[0] - state.footprint_radius_m + 0.02
    np.testing.assert_allclose(moved(reach), [0.003, 0.003], atol=2e-5)
    np.testing.assert_allclose(moved(0.0), [0.003, 0.0], atol=2e-5)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_contact_gate_keeps_the_shipped_model_s_push_and_drops_its_motion_from_afar(seed):
    """The pusher 8 cm from the box's centre, four full-speed steps straight at it: the gate
    leaves the predicted push (about 5 cm, fed back rendered) as it was. The same steps
    10 cm to the box's side: the shipped model predicts a little motion of a box nothing
    touches (measured, seeds 0-3: 0.16, 0.09, 0.31, 0.30 mm), the gate none."""
    scenario = load_scenario("single_box")
    world = PushWorld(scenario)
    box = world.reset(seed).object_poses[0, :2]
    d = -box / np.linalg.norm(box)  # toward the table's centre
    actions = torch.tensor(0.15 * d, dtype=torch.float32).expand(1, 4, 2)

    def moved(pusher, margin):
        state = plan_state(world.teleport_pusher(pusher), world)
        dynamics = make_dynamics("se3net", scenario, feedback="rendered",
                                 contact_margin_m=margin)  # fmt: skip
        with torch.inference_mode():
            poses = dynamics.rollout(state, actions).object_poses
        return float((poses[0, -1, :2] - state.object_pose[:2]).norm())

    at = box - 0.08 * d
    assert moved(at, None) > 0.03
    assert moved(at, 0.01) == pytest.approx(moved(at, None), abs=1e-6)
    past = box - 0.06 * d + 0.10 * np.array([-d[1], d[0]])
    assert moved(past, None) > 5e-5
    assert moved(past, 0.01) < 1e-7


def _observed(calibrated, ratio, steps, size_m=0.01, turn=0.0, central=True):
    """Feed ``steps`` executed steps of a model that predicts ``size_m`` along x where the
    object moves ``ratio`` times as far (and turns ``turn`` rad where none is predicted); the
    pusher, 6 cm behind the object's centre, moves 1 cm at it (``central``) or across
    (glancing, 50° off). Returns the gain of the steps' kind (the only one, ``online``)."""
    pose = np.array([0.1, -0.05, 3.1])
    for _ in range(steps):
        pusher = pose[:2] - [0.06, 0.0]
        heading = 0.0 if central else math.radians(50)
        moved = pusher + 0.01 * np.array([math.cos(heading), math.sin(heading)])
        kind = -1 if central else 0  # the central gain is the last
        predicted = pose + calibrated.gains[kind] * np.array([size_m, 0.0, 0.0])
        after = pose + np.array([ratio * size_m, 0.0, turn])
        calibrated.observe(pose, predicted, after, 0.05, (pusher, moved))
        pose = after
    return calibrated.gains[kind]


def test_an_ensemble_with_an_empty_name_is_refused():
    from scenarios import InputError

    with pytest.raises(InputError, match="an empty name between the"):
        make_dynamics("se3net", load_scenario("single_box"), model="default+")


def test_skipping_the_network_out_of_reach_gives_the_full_rollout_to_within_a_micrometre():
    """Candidates whose pusher stays out of reach of the box skip the network; the rollout is
    the full one (every candidate through the network) to the gate's leak, here below 1 um;
    candidates that reach the box go through the network as before, exactly."""
    from planner.learned import SKIP_BEYOND_M

    scenario = load_scenario("single_box")
    world = PushWorld(scenario)
    obs = world.reset(3)
    state = plan_state(obs, world)
    dyn = make_dynamics("se3net", scenario, feedback="rendered", contact_margin_m=0.01)
    gen = torch.Generator().manual_seed(0)
    to_box = state.object_pose[:2] - state.pusher_xy
    towards = (0.15 * to_box / to_box.norm()).expand(16, 8, 2)
    U = torch.cat([towards, 0.15 * (2 * torch.rand(48, 8, 2, generator=gen) - 1)])
    with torch.inference_mode():
        far = dyn.out_of_reach(state, integrate_pusher(state, U, scenario.action.dt_control_s))
        skipped = dyn.rollout(state, U)
        full = dyn._rollout(state, U)
    assert 0 < far.sum() < len(U) and not far[:16].any()  # both kinds, the straight pushes near
    reach = state.footprint_radius_m + scenario.arm.pusher_radius_m + 0.01 + SKIP_BEYOND_M
    assert (state.pusher_xy - state.object_pose[:2]).norm() > reach  # it starts out of reach
    torch.testing.assert_close(skipped.object_poses[~far], full.object_poses[~far])
    assert (skipped.object_poses[far] - full.object_poses[far]).abs().max() < 1e-6
    assert (skipped.object_poses[far] == state.object_pose).all()
    torch.testing.assert_close(skipped.pusher_xy, full.pusher_xy)
