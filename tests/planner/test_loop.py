import json
import math

import numpy as np
import pytest

from planner import CostConfig, PlannerConfig, PlanSettings
from planner.loop import PushConfig, run_push
from scenarios import load_scenario
from se3push.plan_push import main as plan_push_main
from sim import PushWorld
from sim.planar import pose_errors


def _nearby_goal(dx=0.04):
    obs = PushWorld(load_scenario("tiny")).reset(0)
    x, y, yaw = obs.object_poses[0]
    return float(x + dx), float(y), float(yaw)


def test_closed_loop_with_the_oracle_reaches_a_nearby_goal():
    steps = []
    result = run_push(
        PushConfig(goal=_nearby_goal(), scenario="tiny", model="oracle", max_steps=20),
        on_step=steps.append,
    )
    assert result.success_tight and result.reason == "reached"
    assert result.final_pos_err_m <= 0.02 and len(steps) == result.steps
    assert steps[-1].pos_err_m < steps[0].pos_err_m
    assert len(steps[0].predicted_poses) == PlannerConfig().steps(0.15) == 3
    # the oracle is the simulator: what it predicts for each executed action happens
    d = result.diagnostics
    assert d["moved_steps"] > 0 and d["phantom_steps"] == 0 and d["missed_steps"] == 0
    assert 0.8 <= d["progress_ratio"] <= 1.25
    for s in steps:
        assert abs(s.predicted_disp_m - s.actual_disp_m) < 2e-3


def test_pose_errors_respect_symmetry():
    goal = np.array([0.0, 0.0, 0.0])
    assert pose_errors(np.array([0.03, 0.04, math.pi]), goal, math.pi) == pytest.approx((0.05, 0.0))
    assert pose_errors(np.array([0.0, 0.0, math.radians(100)]), goal, math.pi / 2)[
        1
    ] == pytest.approx(10.0)
    assert pose_errors(np.array([0.0, 0.0, 2.0]), goal, None)[1] == 0.0


def test_plan_push_json_and_exit_codes(capsys):
    x, y, yaw = _nearby_goal()
    args = [
        "--goal",
        str(x),
        str(y),
        str(math.degrees(yaw)),
        "--scenario",
        "tiny",
        "--model",
        "oracle",
        "--max-steps",
        "20",
    ]
    assert plan_push_main([*args, "--json"]) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in (
        "seed",
        "success_tight",
        "success_loose",
        "final_pos_err_m",
        "final_yaw_err_deg",
        "steps",
        "replan_ms_median",
    ):
        assert key in line
    assert line["success_tight"] is True
    assert len(line["per_step"]) == line["steps"]
    moved = sum(s["actual_disp_m"] > 3e-3 for s in line["per_step"])
    assert line["diagnostics"]["moved_steps"] == moved
    # a step budget too small to get there: failure, exit code 1
    assert plan_push_main([*args[:-1], "1"]) == 1
    assert "FAILURE" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--goal", "0.5", "0.0", "0"], "outside the reachable region of scenario tiny: x in"),
        (["--goal", "nan", "0.0", "0"], "three finite numbers"),
        (["--goal", "0.05", "0.0", "0", "--object", "2"], "object 2 does not exist"),
        (["--goal", "0.05", "0.0", "0", "--model", "missing.pt"], "does not exist"),
        (["--goal", "0.05", "0.0", "0", "--model", "default"], "does not fit scenario 'tiny'"),
        (
            ["--goal", "0.05", "0.0", "0", "--model", "oracle", "--planner", "ilqr"],
            "unknown planner 'ilqr'",
        ),
        (
            ["--goal", "0.05", "0.0", "0", "--model", "oracle", "--set", "cost.w_spread=-1"],
            "cost.w_spread must be a finite number >= 0, got -1.0",
        ),
        (["--goal", "0.05", "0.0", "0", "--seed", "-1"], "--seed must be an integer in [0, 2**63)"),
        (["--goal", "0.05", "0.0", "0", "--seed", str(2**64)], "got 18446744073709551616"),
    ],
)
def test_plan_push_bad_input_is_exit_code_2(args, message, capsys):
    assert plan_push_main([*args, "--scenario", "tiny"]) == 2
    assert message in capsys.readouterr().err


def test_plan_push_wrong_number_of_goal_values_is_exit_code_2(capsys):
    with pytest.raises(SystemExit) as exc:
        plan_push_main(["--goal", "0.1", "0.0"])
    assert exc.value.code == 2
    assert "--goal" in capsys.readouterr().err


def test_the_planning_and_cost_settings_reach_the_planner(monkeypatch):
    import planner.loop as loop

    seen = []
    real = loop.make_planner

    def spy(name, dynamics, cost, scenario, cfg):
        seen.append((cost.cfg.w_spread, cfg.horizon_s, cfg.samples, cfg.seed))
        return real(name, dynamics, cost, scenario, cfg)

    monkeypatch.setattr(loop, "make_planner", spy)
    goal = _nearby_goal()
    run_push(PushConfig(goal=goal, scenario="tiny", model="no-motion", max_steps=1, seed=5))
    run_push(PushConfig(goal=goal, scenario="tiny", model="no-motion", max_steps=1, seed=5,
                        plan=PlanSettings(cost=CostConfig(w_spread=0.25),
                                          optimiser=PlannerConfig(horizon_s=0.3, samples=9,
                                                                  seed=99))))  # fmt: skip
    assert seen == [(1.0, 0.45, 32, 5), (0.25, 0.3, 9, 5)]  # the planner's seed is the push's


def test_the_next_plan_is_smoothed_from_the_noisy_action_the_world_ran(monkeypatch):
    import planner.loop as loop

    planners = []
    real = loop.make_planner

    def spy(*args):
        planners.append(real(*args))
        return planners[-1]

    monkeypatch.setattr(loop, "make_planner", spy)
    quick = PlanSettings(optimiser=PlannerConfig(samples=8, iterations=1))
    cfg = PushConfig(goal=_nearby_goal(), scenario="tiny", model="no-motion", max_steps=2,
                     action_noise=0.3, plan=quick)  # fmt: skip
    result = run_push(cfg)
    ran = np.array(result.records[-1].action, dtype=np.float32)
    np.testing.assert_array_equal(planners[0].last_action.numpy(), ran)


def test_each_step_records_whether_the_pusher_was_seen_when_it_was_planned(monkeypatch):
    from sim.world import Observation

    # a camera that loses sight of the pusher from 0.2 s on: steps planned at 0, 0.15, 0.3 s
    monkeypatch.setattr(Observation, "pusher_seen", property(lambda obs: obs.time_s < 0.2))
    quick = PlanSettings(optimiser=PlannerConfig(samples=8, iterations=1))
    result = run_push(PushConfig(goal=_nearby_goal(), scenario="tiny", model="no-motion",
                                 max_steps=3, plan=quick))  # fmt: skip
    assert [r.pusher_seen for r in result.records] == [True, True, False]
    assert [s["pusher_seen"] for s in result.summary()["per_step"]] == [True, True, False]


@pytest.mark.parametrize("steps", ["0", "-3"])
def test_plan_push_refuses_a_step_budget_below_one(steps, capsys):
    code = plan_push_main(["--goal", "0.1", "0.0", "0", "--max-steps", steps])
    assert code == 2
    assert "--max-steps must be a positive integer" in capsys.readouterr().err


def test_results_report_how_far_the_other_objects_were_moved():
    from planner.loop import disturbance

    assert disturbance(np.zeros((0, 2)), np.zeros((0, 2))) is None
    assert disturbance(np.zeros((2, 2)), np.array([[0.03, 0.04], [0.0, 0.01]])) == 0.05
    scenario = load_scenario("multi_object")
    world = PushWorld(scenario)
    seed = next(s for s in range(50) if len(world.reset(s).object_poses) >= 2)
    alone = run_push(PushConfig(goal=(0.1, 0.0, 0.0), model="no-motion", max_steps=1))
    among = run_push(PushConfig(goal=(0.1, 0.0, 0.0), scenario="multi_object", seed=seed,
                                model="no-motion", max_steps=2))  # fmt: skip
    assert alone.others_moved_m is None and among.others_moved_m is not None
    assert "others_moved_m" in among.summary()
