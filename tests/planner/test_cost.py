import math

import numpy as np
import pytest
import torch

from planner.cost import CostConfig, PushCost
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


class _CarriedDiskAmongOthers:
    """The toy's carried disk (``tests.planner.toy``), dragging along every other object it
    comes within ``REACH`` of."""

    name, differentiable, REACH = "toy", True, 0.03

    def __init__(self, dt):
        from tests.planner.toy import CarriedDisk

        self.disk = CarriedDisk(dt)

    def rollout(self, state, actions, *, clouds=False):
        from planner.dynamics import Rollout

        base = self.disk.rollout(state, actions)
        K, H, _ = actions.shape
        xy, others = base.object_poses[..., :2], state.other_poses.to(actions)
        pos, prev, out = others[:, :2].expand(K, -1, -1), state.object_pose[:2].to(actions), []
        for h in range(H):
            near = (xy[:, h, None] - pos).norm(dim=-1) < self.REACH  # (K,M)
            pos = pos + near[..., None] * (xy[:, h] - prev)[:, None]
            out.append(torch.cat([pos, others[:, 2].expand(K, -1)[..., None]], -1))
            prev = xy[:, h]
        return Rollout(base.object_poses, base.pusher_xy, other_poses=torch.stack(out, 1))


def test_the_disturbance_term_keeps_the_other_objects_in_place():
    """A straight push to the goal drags another object along; with the disturbance term the
    planner goes round it, without it the other object is moved."""
    import dataclasses

    from planner import PlannerConfig, make_planner
    from tests.planner.toy import TOY_COST, toy_state

    scenario = load_scenario("single_box")
    dt = scenario.action.dt_control_s
    state = dataclasses.replace(toy_state(), other_poses=torch.tensor([[0.06, 0.015, 0.0]]),
                                other_masks=torch.zeros(1, 4, 4, dtype=torch.bool))  # fmt: skip
    dyn = _CarriedDiskAmongOthers(dt)
    moved = {}
    for w in (0.0, 1.0):
        cost = PushCost(scenario, torch.tensor([0.12, 0.0, 0.0]),
                        dataclasses.replace(TOY_COST, w_disturb=w))  # fmt: skip
        cfg = PlannerConfig(
            horizon_s=1.2, samples=256, elites=16, iterations=8, colour=0.0, shrink=1.0
        )
        _, info = make_planner("cem", dyn, cost, scenario, cfg).plan(state)
        U = torch.from_numpy(info.actions).float()[None]
        end = dyn.rollout(state, U).other_poses[0, -1, 0, :2]
        moved[w] = float((end - state.other_poses[0, :2]).norm())
        assert info.predicted_poses[-1, 0] > 0.08  # it pushes its object toward the goal
    assert moved[0.0] > 0.03 and moved[1.0] < 0.005, moved


def test_the_keepout_term_takes_a_blind_planner_round_the_object_not_through_it():
    """A model blind to contact (the object never moves) and a pusher just off a large box's
    face on the goal's side: without the keep-out term the plan heads straight for the way round
    and its path cuts across the box's corner; with it, the path keeps to the circle that holds
    the box, which touches the box's corners (so the pusher passes them within a millimetre)."""
    import dataclasses

    from planner import PlannerConfig, make_planner
    from planner.dynamics import NoMotionDynamics
    from sim.shapes import ObjectSpec

    scenario = load_scenario("single_box")
    box = ObjectSpec("box", (0.12, 0.10, 0.06), 0.6, 0.5)
    pusher = torch.tensor([0.065 + scenario.arm.pusher_radius_m, 0.03])  # 5 mm off the +x face
    state = dataclasses.replace(_state(box, pusher.tolist()), object_pose=torch.zeros(3))
    dyn = NoMotionDynamics(scenario)
    cfg = PlannerConfig(horizon_s=0.45, samples=128, elites=12, iterations=5)
    clearance = {}
    for w in (0.0, 10.0):
        cost = PushCost(scenario, torch.tensor([0.15, 0.0, 0.0]), CostConfig(w_keepout=w))
        assert not cost.is_behind(state)
        _, info = make_planner("cem", dyn, cost, scenario, cfg).plan(state)
        path = dyn.rollout(state, torch.from_numpy(info.actions).float()[None]).pusher_xy[0]
        path = torch.cat([pusher[None], path]).numpy()
        along = [a + t * (b - a) for a, b in zip(path[:-1], path[1:], strict=True)
                 for t in np.linspace(0, 1, 21)]  # fmt: skip
        clearance[w] = min(box.distance_to_footprint_m(p) for p in along)
    radius = scenario.arm.pusher_radius_m
    assert clearance[0.0] < 0.5 * radius and clearance[10.0] > radius - 0.001, clearance


class _Turnstile:
    """An object that only turns: while the pusher is within ``TOUCH`` of its centre, it turns
    by the pusher's motion along x over the pusher's y (a push along -x at +y turns it
    anticlockwise); it never slides."""

    name, differentiable, TOUCH = "toy", True, 0.055

    def __init__(self, dt):
        self.dt = dt

    def rollout(self, state, actions, *, clouds=False):
        from planner.dynamics import Rollout, integrate_pusher

        pusher = integrate_pusher(state, actions, self.dt)  # (K,H,2)
        before = torch.cat([state.pusher_xy.to(actions).expand(len(actions), 1, 2), pusher], 1)
        touch = (before[:, :-1].norm(dim=-1) < self.TOUCH).to(actions)
        turn = -touch * (before[:, 1:, 0] - before[:, :-1, 0]) / before[:, :-1, 1].clamp_min(0.02)
        yaw = state.object_pose[2].to(actions) + torch.cumsum(turn, 1)
        xy = state.object_pose[:2].to(actions).expand(*yaw.shape, 2)
        return Rollout(torch.cat([xy, yaw[..., None]], -1), pusher)


def test_near_the_goal_the_pusher_may_work_at_the_object_s_side():
    """An object 5 mm from its goal, 40 degrees off, that turns only when the pusher works at
    its side inside the keep-out circle: with the terms faded near the goal the plan goes in
    and turns it; without the fade (``near_goal_m`` 0) the keep-out term holds the pusher out
    and the object stays turned away."""
    import dataclasses

    from planner import PlannerConfig, make_planner
    from sim.shapes import ObjectSpec

    scenario = load_scenario("single_box")
    bar = ObjectSpec("box", (0.12, 0.04, 0.05), 0.3, 0.5)
    state = dataclasses.replace(_state(bar, [0.0, 0.08]), object_pose=torch.zeros(3))
    dyn = _Turnstile(scenario.action.dt_control_s)
    cfg = PlannerConfig(horizon_s=0.9, samples=128, elites=12, iterations=5)
    left = {}
    for near in (0.0, 0.03):
        cost = PushCost(scenario, torch.tensor([0.005, 0.0, math.radians(-40)]),
                        CostConfig(near_goal_m=near))  # fmt: skip
        assert not cost.is_behind(state)
        _, info = make_planner("cem", dyn, cost, scenario, cfg).plan(state)
        left[near] = abs(math.degrees(info.predicted_poses[-1, 2]) + 40)
    assert left[0.03] < 5 and left[0.0] > 35, left


class _PhantomNudge:
    """A learned model's phantom: whenever the pusher is within ``REACH`` of the object's
    centre, whatever it does, the object is predicted to creep ``NUDGE`` per step toward +x
    (toward the goal), though nothing pushes it that way."""

    name, differentiable, REACH, NUDGE = "toy", True, 0.07, 0.003

    def __init__(self, dt):
        self.dt = dt

    def rollout(self, state, actions, *, clouds=False):
        from planner.dynamics import Rollout, integrate_pusher

        pusher = integrate_pusher(state, actions, self.dt)  # (K,H,2)
        start = state.object_pose.to(actions)
        near = ((pusher - start[:2]).norm(dim=-1) < self.REACH).to(actions)  # (K,H)
        x = start[0] + self.NUDGE * torch.cumsum(near, 1)
        y, yaw = start[1].expand_as(x), start[2].expand_as(x)
        return Rollout(torch.stack([x, y, yaw], -1), pusher)


@pytest.mark.parametrize("fade", ["behind", "everywhere"])
def test_predicted_motion_does_not_stop_the_way_round_until_the_pusher_is_behind(fade):
    """A pusher beside the object on the goal's side, a model predicting a phantom creep toward
    the goal while the pusher stays near: with the shaping term faded only behind the object
    the plan heads round to the far side; faded everywhere (the cost before), the phantom
    switches the shaping off and the pusher stays where it is. (The keep-out term is off: the
    test is of the fade alone.)"""
    import dataclasses

    from planner import PlannerConfig, make_planner
    from tests.planner.toy import toy_state

    scenario = load_scenario("single_box")
    cost = PushCost(scenario, torch.tensor([0.12, 0.0, 0.0]),
                    CostConfig(shaping_fade=fade, w_keepout=0.0))  # fmt: skip
    pusher = 0.06 * torch.tensor([math.cos(math.radians(30)), math.sin(math.radians(30))])
    state = dataclasses.replace(toy_state(), pusher_xy=pusher)
    assert not cost.is_behind(state)  # on the goal's side, 150 degrees round from behind
    target = cost.shaping_target(state)
    cfg = PlannerConfig(horizon_s=0.6, samples=64, elites=8, iterations=4)
    dyn = _PhantomNudge(scenario.action.dt_control_s)
    _, info = make_planner("cem", dyn, cost, scenario, cfg).plan(state)
    U = torch.from_numpy(info.actions).float()[None]
    end = dyn.rollout(state, U).pusher_xy[0, -1]
    before, after = float((pusher - target).norm()), float((end - target).norm())
    if fade == "behind":  # 7.4 cm to go, within the horizon's reach: it ends within 1 cm
        assert after < 0.01, (before, after)
    else:  # it stays put
        assert after > 0.95 * before, (before, after)


def test_the_cost_terms_sum_to_the_total_and_a_plan_reports_them():
    """Each term's share of the cost, for every candidate: they sum to the cost the optimiser
    minimised, and the chosen plan carries them (the keep-out term is there only while the
    pusher is not behind the object, the spread term only for an ensemble)."""
    from planner import PlannerConfig, make_planner
    from planner.cost import TERMS
    from tests.planner.toy import TOY_COST, CarriedDisk, toy_state

    scenario = load_scenario("single_box")
    cost = PushCost(scenario, torch.tensor([0.1, -0.05, 0.5]), TOY_COST)
    planner = make_planner("cem", CarriedDisk(scenario.action.dt_control_s), cost, scenario,
                           PlannerConfig(samples=16, iterations=2, elites=4))  # fmt: skip
    state = toy_state()
    U = 0.1 * torch.randn(5, 3, 2, generator=torch.Generator().manual_seed(0))
    rollout = planner.dynamics.rollout(state, U)
    terms = cost.cost_terms(state, rollout, U, last_action=torch.zeros(2))
    assert set(terms) <= {t.name for t in TERMS} and {"position", "action", "smooth"} <= set(terms)
    assert "yaw" not in terms  # a disk has no heading to turn
    total = cost.cost(state, rollout, U, last_action=torch.zeros(2))
    torch.testing.assert_close(sum(terms.values()), total)
    assert all((v >= 0).all() for v in terms.values()) and terms["position"].max() > 0
    _, info = planner.plan(state)
    assert set(info.cost_terms) == set(terms)
    assert sum(info.cost_terms.values()) == pytest.approx(info.cost, rel=1e-5)


@pytest.mark.parametrize("scenario_name", ["single_box", "heldout_objects"])
def test_the_surface_pre_push_point_is_just_clear_of_the_object_s_far_side(scenario_name):
    """The pre-push point (``pre_push`` surface) leaves at most a centimetre between the pusher
    and the object's true far side, and never less than nothing, for every goal direction; the
    circle's point (the earlier planners') leaves more, most of all for a T."""
    from planner.observe import plan_state

    scenario = load_scenario(scenario_name)
    world = PushWorld(scenario)
    obs = world.reset(3)
    spec, state = world.objects[0], plan_state(obs, world)
    radius = scenario.arm.pusher_radius_m
    surface = PushCost(scenario, torch.zeros(3), CostConfig(pre_push="surface"))
    circle = PushCost(scenario, torch.zeros(3), CostConfig(pre_push="circle"))
    x, y, yaw = obs.object_poses[0]
    gaps, circle_gaps = [], []
    for a in np.linspace(-math.pi, math.pi, 12, endpoint=False):
        goal = torch.tensor([x + 0.1 * math.cos(a), y + 0.1 * math.sin(a), 0.0])
        surface.goal, circle.goal = goal, goal
        back = -np.array([math.cos(a), math.sin(a)])  # from the centre toward the pre-push point
        in_object = [back[0] * math.cos(yaw) + back[1] * math.sin(yaw),
                     -back[0] * math.sin(yaw) + back[1] * math.cos(yaw)]  # fmt: skip
        face = spec.support_m(np.array(in_object))
        for cost, out in ((surface, gaps), (circle, circle_gaps)):
            point = cost.pre_push_point(state).numpy() - obs.object_poses[0, :2]
            assert abs(point @ np.array([-back[1], back[0]])) < 1e-6  # on the line to the goal
            out.append(point @ back - face - radius)  # the gap between pusher and object
    assert min(gaps) > 0.002 and max(gaps) < 0.011  # measured: 2.4 to 9.9 mm
    assert np.median(circle_gaps) > np.median(gaps) + 0.003  # measured: 3.7 and 11 mm more


def test_from_the_surface_pre_push_point_a_short_push_moves_the_object():
    """Why the pre-push point is at the far side: a 0.45 s push toward the goal at half speed
    (about as fast as the pushes iCEM samples about a still plan) moves every held-out object
    from it, in the simulator; from the circle's point (the earlier planners') most of them
    do not move, so to an exact model no such plan is worth leaving that point for."""
    from planner.dynamics import make_dynamics
    from planner.observe import plan_state

    scenario = load_scenario("heldout_objects")
    bound = scenario.action.max_speed_m_s
    push = torch.tensor([[0.5 * bound, 0.0]] * 3)[None]  # 3 steps along +x, toward the goal
    moved = {"surface": [], "circle": []}
    for seed in range(4):
        for pre_push, out in moved.items():
            world = PushWorld(scenario)
            obs = world.reset(seed)
            x, y, _ = obs.object_poses[0]
            goal = torch.tensor([x + 0.1, y, 0.0])
            cost = PushCost(scenario, goal, CostConfig(pre_push=pre_push))
            obs = world.teleport_pusher(cost.pre_push_point(plan_state(obs, world)).numpy())
            state = plan_state(obs, world)
            rollout = make_dynamics("oracle", scenario, world=world).rollout(state, push)
            out.append(float((rollout.object_poses[0, -1, :2] - state.object_pose[:2]).norm()))
    assert min(moved["surface"]) > 0.002  # measured: 2.4 to 17 mm
    assert sum(m < 1e-4 for m in moved["circle"]) >= 3  # measured: 3 of 4 did not move


@pytest.mark.parametrize("optimiser", ["cem", "mppi", "grad", "sqp"])
def test_charged_at_every_step_the_shaping_term_makes_a_long_plan_head_off_now(optimiser):
    """The pusher behind the object, 9 cm from the pre-push point, nothing pushed on the way, a
    1.2 s plan (8 steps through 4 cubic knots). Charged at the last step only, a plan that
    waits 4 steps and then goes costs what one that goes now does, and the receding-horizon
    loop crawls: each replan puts the going off again. Charged at every step, waiting costs
    more, and the pusher gets there, with every optimiser."""
    import dataclasses

    from planner import PlannerConfig, make_planner
    from planner.dynamics import NoMotionDynamics
    from tests.planner.toy import toy_state

    scenario = load_scenario("single_box")
    dt = scenario.action.dt_control_s
    start = dataclasses.replace(toy_state(), pusher_xy=torch.tensor([-0.10, 0.05]))
    dyn = NoMotionDynamics(scenario)
    left = {}
    for at in ("last", "every"):
        cost = PushCost(scenario, torch.tensor([0.12, 0.0, 0.0]), CostConfig(shaping_at=at))
        assert cost.is_behind(start)
        target = cost.shaping_target(start)
        gap = target - start.pusher_xy
        now = torch.cat([(gap / (4 * dt)).expand(4, 2), torch.zeros(4, 2)])
        U = torch.stack([now, now.flip(0)])  # go now, or wait and then go: the same end
        terms = cost.cost_terms(start, dyn.rollout(start, U), U, last_action=torch.zeros(2))
        go_now, go_later = terms["shaping"].tolist()
        if at == "last":
            assert go_now == pytest.approx(go_later, abs=1e-6)
        else:
            assert go_later > 2 * go_now
        cfg = PlannerConfig(horizon_s=1.2, knots=4, spline="cubic")
        planner = make_planner(optimiser, dyn, cost, scenario, cfg)
        state = start
        for _ in range(4):  # 0.6 s of the loop: the pusher moves as commanded
            action, _ = planner.plan(state)
            state = dataclasses.replace(
                state, pusher_xy=state.pusher_xy + dt * torch.as_tensor(action).float()
            )
        left[at] = float((state.pusher_xy - target).norm())
    # 9.3 cm to go: after 0.6 s, 6.0-7.6 cm are left charged at the last step (sqp and mppi
    # 6.0, grad 6.9, cem 7.6), 0.3-1.9 cm charged at every step (sqp 0.3, grad 0.5, mppi 1.3,
    # cem 1.9)
    assert left["last"] > 0.055 and left["every"] < 0.025, left
