import dataclasses

import cvxpy as cp
import numpy as np
import pytest
import torch

from planner import PLANNERS, PlannerConfig, PushCost, make_planner
from scenarios import load_scenario
from tests.planner.toy import TOY_COST, CarriedDisk, optimum, toy_state

SCENARIO = load_scenario("single_box")
DT, BOUND = SCENARIO.action.dt_control_s, SCENARIO.action.max_speed_m_s
STRONG = {
    # plain CEM with a large budget (white noise, a constant population), as before the
    # iCEM defaults: this test is about the optimiser converging, not about few rollouts
    "cem": PlannerConfig(samples=256, elites=16, iterations=8, colour=0.0, shrink=1.0),
    "mppi": PlannerConfig(samples=512, iterations=20, init_std=0.2, temperature=0.02),
    "grad": PlannerConfig(grad_steps=150, grad_lr=0.01),
    "sqp": PlannerConfig(iterations=8, trust_radius=0.15),
}
MARGIN = {"cem": 0.05, "mppi": 0.05, "grad": 0.01, "sqp": 0.01}  # relative, over the optimum


@pytest.mark.parametrize("name", PLANNERS)
@pytest.mark.parametrize("goal", [(0.05, 0.02, 0.0), (0.12, -0.09, 0.0)])
def test_each_optimiser_reaches_the_known_optimum_within_its_margin(name, goal):
    state = toy_state()
    cost = PushCost(SCENARIO, torch.tensor(goal), TOY_COST)
    planner = make_planner(name, CarriedDisk(DT), cost, SCENARIO, STRONG[name])
    best = optimum(cost, state, planner.horizon, DT, BOUND)
    _, info = planner.plan(state)
    assert info.cost <= best * (1 + MARGIN[name]) + 1e-3, (info.cost, best)
    assert np.all(np.abs(info.actions) <= BOUND + 1e-7)


@pytest.mark.parametrize("name", PLANNERS)
def test_bounds_hold_and_the_same_seed_gives_the_same_plan(name):
    far = (0.28, -0.28, 0.0)  # far enough that every action saturates
    plans = []
    for _ in range(2):
        cost = PushCost(SCENARIO, torch.tensor(far), TOY_COST)
        planner = make_planner(name, CarriedDisk(DT), cost, SCENARIO, PlannerConfig(seed=3))
        state = toy_state()
        seq = []
        for _ in range(3):
            a, info = planner.plan(state)
            assert np.all(np.abs(a) <= BOUND) and np.all(np.abs(info.actions) <= BOUND)
            seq.append(a)
            to_goal = np.array(far[:2]) - state.object_pose[:2].numpy()
            total = info.actions.sum(0)  # the planned displacement heads for the goal
            assert total @ to_goal / np.linalg.norm(total) / np.linalg.norm(to_goal) > 0.7
            pose = state.object_pose + torch.tensor([*(DT * a), 0.0], dtype=torch.float32)
            state = dataclasses.replace(state, object_pose=pose, pusher_xy=pose[:2])
        plans.append(np.array(seq))
    np.testing.assert_array_equal(plans[0], plans[1])


def test_warm_start_is_the_previous_plan_shifted():
    cost = PushCost(SCENARIO, torch.tensor((0.1, 0.0, 0.0)), TOY_COST)
    planner = make_planner("cem", CarriedDisk(DT), cost, SCENARIO)
    _, info = planner.plan(toy_state())
    # the reported actions are clipped in float64 (0.15, not float32's 0.15000000596)
    np.testing.assert_array_equal(planner.nominal[:-1].numpy(), info.actions[1:].astype(np.float32))
    planner.reset()
    assert not planner.nominal.any()


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="unknown planner 'ilqr'; known: cem, mppi, grad, sqp"):
        make_planner("ilqr", CarriedDisk(DT), PushCost(SCENARIO, (0.0, 0.0, 0.0)), SCENARIO)
    with pytest.raises(ValueError, match="horizon_s must be a time in seconds above 0, got 0"):
        PlannerConfig(horizon_s=0)
    with pytest.raises(ValueError, match="samples must be a positive integer"):
        PlannerConfig(samples=-4)
    with pytest.raises(ValueError, match="not finite"):
        PushCost(SCENARIO, (float("nan"), 0.0, 0.0))
    with pytest.raises(ValueError, match=r"off the table \(x in \[-0.3, 0.3\]"):
        PushCost(SCENARIO, (0.5, 0.0, 0.0))


def test_sqp_goes_on_when_osqp_fails(monkeypatch):
    solve, calls = cp.Problem.solve, []

    def fails_once(self, *args, **kwargs):  # as OSQP does on a KKT matrix it cannot factorise
        calls.append(1)
        if len(calls) == 1:
            raise cp.SolverError("Solver 'OSQP' failed.")
        return solve(self, *args, **kwargs)

    monkeypatch.setattr(cp.Problem, "solve", fails_once)
    cost = PushCost(SCENARIO, torch.tensor((0.05, 0.02, 0.0)), TOY_COST)
    planner = make_planner("sqp", CarriedDisk(DT), cost, SCENARIO, PlannerConfig(iterations=4))
    state = toy_state()
    with torch.no_grad():
        rest, _ = planner.evaluate(state, torch.zeros(1, planner.horizon, 2))
    _, info = planner.plan(state)  # the first QP fails: a smaller region, and on
    assert len(calls) > 1 and info.cost < 0.9 * float(rest[0])


def test_sqp_steps_stay_in_the_trust_region_when_osqp_stops_at_its_iteration_limit(monkeypatch):
    solve = cp.Problem.solve

    def capped(self, *args, **kwargs):  # its iterate then lies well outside the QP's box
        return solve(self, *args, **{**kwargs, "max_iter": 10})

    monkeypatch.setattr(cp.Problem, "solve", capped)
    cost = PushCost(SCENARIO, torch.tensor((0.28, -0.28, 0.0)), TOY_COST)
    cfg = PlannerConfig(iterations=1, trust_radius=0.01)
    planner = make_planner("sqp", CarriedDisk(DT), cost, SCENARIO, cfg)
    _, info = planner.plan(toy_state())  # one step from rest: within 0.01 m/s of it
    assert np.abs(info.actions).max() <= cfg.trust_radius + 1e-6


def test_sqp_reports_the_iterations_it_ran():
    cost = PushCost(SCENARIO, torch.tensor((0.1, 0.05, 0.0)), TOY_COST)
    tiny = PlannerConfig(iterations=6, trust_radius=1e-9)  # below its stopping radius at once
    _, info = make_planner("sqp", CarriedDisk(DT), cost, SCENARIO, tiny).plan(toy_state())
    assert info.iterations == 0 and not info.actions.any()
    _, info = make_planner("sqp", CarriedDisk(DT), cost, SCENARIO,
                           PlannerConfig(iterations=6)).plan(toy_state())  # fmt: skip
    assert 1 <= info.iterations <= 6 and info.actions.any()


def test_sqp_trust_region_grows_after_good_steps():
    goal = (0.12, -0.09, 0.0)  # the optimum saturates the actions (0.15 m/s)
    cost = PushCost(SCENARIO, torch.tensor(goal), TOY_COST)
    cfg = PlannerConfig(iterations=8, trust_radius=0.01)  # 8 steps of 0.01 could not get there
    planner = make_planner("sqp", CarriedDisk(DT), cost, SCENARIO, cfg)
    best = optimum(cost, toy_state(), cfg.steps(DT), DT, BOUND)
    _, info = planner.plan(toy_state())
    assert info.cost <= best * (1 + MARGIN["sqp"]) + 1e-3, (info.cost, best)


class Counting:
    """Wraps a dynamics backend, counting its rollouts."""

    def __init__(self, inner):
        self.inner, self.calls = inner, 0
        self.name, self.differentiable = inner.name, inner.differentiable

    def rollout(self, state, actions, *, clouds=False):
        self.calls += 1
        return self.inner.rollout(state, actions, clouds=clouds)


class Treacherous(CarriedDisk):
    """The carried disk, pulled back from a goal on +x by a drift that grows with the square of
    the actions: flat at rest, so a linearisation at rest misses it and any step from rest
    (down to the smallest trust region of a few iterations) costs more than staying."""

    def rollout(self, state, actions, *, clouds=False):
        out = super().rollout(state, actions, clouds=clouds)
        drift = 1e4 * (actions**2).sum((1, 2))  # (K,) m
        back = torch.zeros_like(out.object_poses)
        back[..., 0] = drift[:, None]
        return dataclasses.replace(out, object_poses=out.object_poses - back)


def test_sqp_rejected_steps_reuse_the_linearisation():
    cost = PushCost(SCENARIO, torch.tensor((0.1, 0.0, 0.0)), TOY_COST)
    dynamics = Counting(Treacherous(DT))
    cfg = PlannerConfig(iterations=6)
    planner = make_planner("sqp", dynamics, cost, SCENARIO, cfg)
    _, info = planner.plan(toy_state())
    assert not info.actions.any()  # every step was rejected
    # residuals and Jacobian at the warm start, one trial per iteration, plan()'s report
    assert dynamics.calls == 2 + cfg.iterations + 1


def test_sqp_accepted_steps_cost_two_rollouts():
    cost = PushCost(SCENARIO, torch.tensor((0.1, 0.05, 0.0)), TOY_COST)
    dynamics = Counting(CarriedDisk(DT))
    cfg = PlannerConfig(iterations=6)
    planner = make_planner("sqp", dynamics, cost, SCENARIO, cfg)
    planner.plan(toy_state())
    # the warm start's residuals, then per step a trial and (once accepted) its Jacobian
    assert dynamics.calls <= 1 + 2 * cfg.iterations + 1


class WithOutlier(PushCost):
    """The push cost, plus an enormous penalty on the worst sample of each batch (as if it had
    left the table)."""

    def cost(self, *args, **kwargs):
        cost = super().cost(*args, **kwargs)
        if len(cost) > 1:
            cost = cost.clone()
            cost[cost.argmax()] += 1e6
        return cost


def test_mppi_weights_ignore_an_outlier():
    plans = []
    for kind in (PushCost, WithOutlier):
        cost = kind(SCENARIO, torch.tensor((0.1, -0.05, 0.0)), TOY_COST)
        planner = make_planner("mppi", CarriedDisk(DT), cost, SCENARIO)
        _, info = planner.plan(toy_state())
        plans.append(info.actions)
    np.testing.assert_allclose(plans[1], plans[0], atol=1e-6)


@pytest.mark.parametrize("temperature", [0.05, 1.0])
def test_mppi_plan_never_costs_more_than_its_warm_start(temperature):
    goal, state = torch.tensor((0.03, 0.01, 0.0)), toy_state()
    cost = PushCost(SCENARIO, goal, TOY_COST)
    _, exact = make_planner("sqp", CarriedDisk(DT), cost, SCENARIO, STRONG["sqp"]).plan(state)
    for seed in range(3):
        cost = PushCost(SCENARIO, goal, TOY_COST)
        cfg = PlannerConfig(temperature=temperature, seed=seed)
        planner = make_planner("mppi", CarriedDisk(DT), cost, SCENARIO, cfg)
        # warm start at the optimum: any weighted mean of noisy samples around it overshoots
        planner.nominal = torch.from_numpy(exact.actions).float()
        with torch.no_grad():
            warm, _ = planner.evaluate(state, planner.nominal[None])
        _, info = planner.plan(state)
        assert info.cost <= float(warm[0]) * (1 + 1e-6), (info.cost, float(warm[0]))


class _Counting:
    """A dynamics wrapper that records the batch size of every rollout."""

    def __init__(self, inner):
        self.inner, self.batches = inner, []
        self.name, self.differentiable = inner.name, inner.differentiable

    def rollout(self, state, actions, *, clouds=False):
        self.batches.append(len(actions))
        return self.inner.rollout(state, actions, clouds=clouds)


@pytest.mark.parametrize("name", ["cem", "mppi", "grad"])
def test_planners_report_the_rollout_of_the_plan_without_rolling_it_again(name):
    dyn = _Counting(CarriedDisk(DT))
    cost = PushCost(SCENARIO, torch.tensor((0.08, 0.03, 0.0)), TOY_COST)
    cfg = PlannerConfig(samples=16, elites=4, iterations=3, grad_steps=5)
    planner = make_planner(name, dyn, cost, SCENARIO, cfg)
    _, info = planner.plan(toy_state())
    rollouts = {  # no re-roll of the chosen plan
        "cem": cfg.iterations,
        "mppi": cfg.iterations + 1,  # its final weighted mean, once
        "grad": 1 + cfg.grad_steps + 1,  # the starts, each Adam step, the last step's result
    }
    assert len(dyn.batches) == rollouts[name]
    again = CarriedDisk(DT).rollout(toy_state(), torch.from_numpy(info.actions).float()[None])
    np.testing.assert_allclose(info.predicted_poses, again.object_poses[0].numpy(), atol=1e-6)
    np.testing.assert_allclose(info.predicted_pusher, again.pusher_xy[0].numpy(), atol=1e-6)


@pytest.mark.parametrize("goal", [(0.08, 0.03, 0.0), (0.02, -0.1, 0.0)])
def test_grad_runs_its_starts_in_one_batch_each_as_it_would_alone(goal):
    """Adam runs from the best few starts at once; each start's cost is its own, so the best
    start takes the steps it takes alone and more starts never plan worse than one."""
    cost = PushCost(SCENARIO, torch.tensor(goal), TOY_COST)
    plans = {}
    for starts in (1, 4):
        dyn = _Counting(CarriedDisk(DT))
        cfg = PlannerConfig(grad_steps=6, grad_init_samples=12, grad_starts=starts, seed=3)
        _, plans[starts] = make_planner("grad", dyn, cost, SCENARIO, cfg).plan(toy_state())
        assert dyn.batches == [12] + [starts] * (cfg.grad_steps + 1)
    assert plans[4].cost <= plans[1].cost * (1 + 1e-6)


def test_icem_shrinks_the_population_and_keeps_shifted_elites_for_the_next_replan():
    dyn = _Counting(CarriedDisk(DT))
    cost = PushCost(SCENARIO, torch.tensor((0.08, 0.03, 0.0)), TOY_COST)
    cfg = PlannerConfig(samples=40, elites=10, iterations=3, shrink=1.25, keep_elites=0.3)
    planner = make_planner("cem", dyn, cost, SCENARIO, cfg)
    planner.plan(toy_state())
    assert dyn.batches == [40, 32, 26]  # 40, 40/1.25, 40/1.25^2 (rounded; >= 2 x elites)
    kept = planner.kept.clone()
    assert kept.shape == (3, cfg.steps(DT), 2)  # 30 % of the 10 elites
    torch.testing.assert_close(kept[:, -1], kept[:, -2])  # shifted: the last action repeated
    dyn.batches.clear()
    planner.plan(toy_state())
    assert dyn.batches == [43, 32, 26]  # the kept elites join the first iteration


def test_a_warm_start_samples_with_the_warm_sd():
    cost = PushCost(SCENARIO, torch.tensor((0.08, 0.03, 0.0)), TOY_COST)
    seen = []

    class Spy(CarriedDisk):
        def rollout(self, state, actions, *, clouds=False):
            seen.append((actions[1:] - actions[0]).std().item())
            return super().rollout(state, actions, clouds=clouds)

    cfg = PlannerConfig(samples=256, elites=8, iterations=1, init_std=0.5, warm_std=0.1)
    planner = make_planner("cem", Spy(DT), cost, SCENARIO, cfg)
    planner.plan(toy_state())
    planner.plan(toy_state())
    cold, warm = seen
    assert cold > 3 * warm  # 0.5 x bound at a fresh start, 0.1 x bound warm (before clamping)


class _NaNDisk(CarriedDisk):
    """Predicts NaN poses for every sequence but the first of each batch."""

    def rollout(self, state, actions, *, clouds=False):
        r = super().rollout(state, actions, clouds=clouds)
        poses = r.object_poses.clone()
        poses[1:] = float("nan")
        return type(r)(poses, r.pusher_xy)


@pytest.mark.parametrize("name", ["cem", "mppi"])
def test_a_nan_cost_never_becomes_the_plan(name):
    cost = PushCost(SCENARIO, torch.tensor((0.08, 0.03, 0.0)), TOY_COST)
    planner = make_planner(name, _NaNDisk(DT), cost, SCENARIO, PlannerConfig(samples=16))
    a, info = planner.plan(toy_state())
    assert np.all(np.isfinite(a)) and np.isfinite(info.cost)


class _OneNaN(CarriedDisk):
    """Predicts a NaN pose for one sequence of the first batch, and records every batch."""

    def __init__(self, dt):
        super().__init__(dt)
        self.batches = []

    def rollout(self, state, actions, *, clouds=False):
        r = super().rollout(state, actions, clouds=clouds)
        self.batches.append(actions.clone())
        if len(self.batches) == 1:
            poses = r.object_poses.clone()
            poses[1] = float("nan")
            r = type(r)(poses, r.pusher_xy)
        return r


@pytest.mark.parametrize("name", ["cem", "mppi"])
def test_one_nan_cost_does_not_spoil_the_later_samples(name):
    cost = PushCost(SCENARIO, torch.tensor((0.08, 0.03, 0.0)), TOY_COST)
    dynamics = _OneNaN(DT)
    make_planner(name, dynamics, cost, SCENARIO, PlannerConfig(samples=16)).plan(toy_state())
    assert len(dynamics.batches) >= 3
    assert all(torch.isfinite(b).all() for b in dynamics.batches)


@pytest.mark.parametrize(
    ("field", "value"),
    [("colour", 1.0), ("colour", -0.1), ("warm_std", 0.0), ("temperature", 0.0), ("shrink", 0.5),
     ("keep_elites", 1.5), ("init_std", -1.0), ("elites", 1), ("grad_init_samples", 0),
     ("init_std", float("inf")), ("grad_lr", float("inf")), ("trust_radius", float("nan")),
     ("warm_std", float("inf")), ("shrink", float("inf"))],
)  # fmt: skip
def test_unusable_planner_settings_are_refused(field, value):
    from scenarios import InputError

    with pytest.raises(InputError, match=field):
        PlannerConfig(**{field: value})
