"""Plans as splines through a few knots: the map from knots to actions, the warm start shifted
in time, and every optimiser optimising the knots."""

import numpy as np
import pytest
import torch

from planner import PLANNERS, PlannerConfig, PushCost, make_planner
from planner.base import shift_operator, spline_basis
from scenarios import InputError, load_scenario
from tests.planner.toy import TOY_COST, CarriedDisk, optimum, toy_state

SCENARIO = load_scenario("single_box")
DT, BOUND = SCENARIO.action.dt_control_s, SCENARIO.action.max_speed_m_s


def test_knots_reproduce_a_known_action_sequence():
    z = np.array([1.0, -2.0, 4.0])
    np.testing.assert_array_equal(spline_basis(6, 3, "zoh") @ z, [1, 1, -2, -2, 4, 4])
    # linear: knots at steps 0, 3, 6 of 7, straight lines between
    np.testing.assert_allclose(spline_basis(7, 3, "linear") @ z, [1, 0, -1, -2, 0, 2, 4],
                               atol=1e-12)  # fmt: skip
    # a natural cubic spline is exact for a line: knots on one give the line at every step
    at = np.linspace(0, 9, 4)
    np.testing.assert_allclose(spline_basis(10, 4, "cubic") @ (0.5 - 0.1 * at),
                               0.5 - 0.1 * np.arange(10), atol=1e-12)  # fmt: skip
    for spline in ("zoh", "linear", "cubic"):  # a knot per step: the actions themselves
        np.testing.assert_allclose(spline_basis(5, 5, spline), np.eye(5), atol=1e-12)


def test_shifting_in_time_keeps_the_plan():
    plain = shift_operator(np.eye(4))  # the plain shift: drop the first, repeat the last
    np.testing.assert_array_equal(plain @ np.array([1.0, 2.0, 3.0, 4.0]), [2, 3, 4, 4])
    for spline in ("zoh", "linear", "cubic"):
        B = spline_basis(8, 3, spline)
        const = np.full(3, 0.07)  # a constant plan is the same plan a step later
        np.testing.assert_allclose(B @ shift_operator(B) @ const, B @ const, atol=1e-12)
    # a ramp, a step later: its actions advanced by one step, but at the end, where the plan
    # holds its last action (measured: 0.0055 of the ramp's 0.14 span)
    B = spline_basis(8, 4, "linear")
    ramp = np.interp(np.linspace(0, 7, 4), [0, 7], [-0.07, 0.07])
    later = B @ shift_operator(B) @ ramp
    assert np.abs(later[:6] - (B @ ramp)[1:7]).max() < 0.007


@pytest.mark.parametrize("name", PLANNERS)
def test_every_optimiser_finds_the_best_plan_over_the_knots(name):
    """The toy's exact optimum over 8-step plans through 3 knots of a linear spline."""
    strong = {"cem": dict(samples=256, elites=16, iterations=8, colour=0.0, shrink=1.0),
              "mppi": dict(samples=512, iterations=20, init_std=0.2, temperature=0.02),
              "grad": dict(grad_steps=150, grad_lr=0.01),
              "sqp": dict(iterations=8, trust_radius=0.15)}[name]  # fmt: skip
    cfg = PlannerConfig(horizon_s=1.2, knots=3, spline="linear", **strong)
    cost = PushCost(SCENARIO, torch.tensor((0.12, -0.09, 0.0)), TOY_COST)
    planner = make_planner(name, CarriedDisk(DT), cost, SCENARIO, cfg)
    B = spline_basis(8, 3, "linear")
    best = optimum(cost, toy_state(), 8, DT, BOUND, basis=B)
    free = optimum(cost, toy_state(), 8, DT, BOUND)
    assert free < best  # three knots constrain the plan: the test can tell them apart
    _, info = planner.plan(toy_state())
    assert info.cost <= best * 1.05 + 1e-3, (info.cost, best)
    knots, *_ = np.linalg.lstsq(B, info.actions, rcond=None)  # the plan is on the spline
    np.testing.assert_allclose(B @ knots, info.actions, atol=1e-6)
    assert planner.nominal.shape == (3, 2)  # the warm start is knots too


def test_a_cubic_plan_stays_inside_the_bounds():
    cfg = PlannerConfig(horizon_s=1.5, knots=4, spline="cubic", seed=2)
    cost = PushCost(SCENARIO, torch.tensor((0.28, -0.28, 0.0)), TOY_COST)
    _, info = make_planner("cem", CarriedDisk(DT), cost, SCENARIO, cfg).plan(toy_state())
    assert np.abs(info.actions).max() <= BOUND + 1e-7


BAD = [
    ({"knots": -1}, "knots must be 0"),
    ({"knots": 1, "spline": "cubic"}, "2 knots"),
    ({"spline": "bezier"}, "spline must be"),
]


@pytest.mark.parametrize(("fields", "message"), BAD)
def test_bad_spline_settings_are_refused(fields, message):
    with pytest.raises(InputError, match=message):
        PlannerConfig(horizon_s=1.2, **fields)


def test_more_knots_than_the_horizon_has_steps_are_refused():
    cfg = PlannerConfig(horizon_s=1.2, knots=9)
    assert PlannerConfig(horizon_s=1.2, knots=8).steps(0.15) == 8
    with pytest.raises(
        InputError,
        match=r"knots must be 0 \(one per step\) or 1..8 \(the steps "
        r"of 0.15 s in horizon_s 1.2\), got 9",
    ):
        cfg.steps(0.15)


@pytest.mark.parametrize(("horizon_s", "steps"), [(0.225, 2), (0.375, 3), (0.45, 3), (1.2, 8)])
def test_a_horizon_is_the_nearer_number_of_steps_halves_up(horizon_s, steps):
    assert PlannerConfig(horizon_s=horizon_s).steps(0.15) == steps


def test_a_horizon_too_long_to_plan_is_refused_in_one_line():
    assert PlannerConfig(horizon_s=15.0).steps(0.15) == 100
    with pytest.raises(InputError, match=r"horizon_s 1e\+09 is .* steps of 0.15 s; a plan looks "
                       r"at most 100 steps ahead"):  # fmt: skip
        PlannerConfig(horizon_s=1e9).steps(0.15)
