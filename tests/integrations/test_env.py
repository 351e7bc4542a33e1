"""The Gymnasium environment se3push/Push-v0 and the MPC planner driving it."""

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium", reason='the scale extra: pip install -e ".[scale]"')

from integrations.env import ENV_ID, MPCPolicy, PushEnv  # noqa: E402
from planner.loop import PushConfig, run_push  # noqa: E402
from tests.planner.test_loop import _nearby_goal  # noqa: E402

pytestmark = pytest.mark.scale


def test_gymnasium_makes_the_environment_by_its_module_qualified_id_alone():
    """In a fresh interpreter that imported nothing of ours: Gymnasium imports the module."""
    import subprocess
    import sys

    code = ("import gymnasium; env = gymnasium.make('integrations.env:se3push/Push-v0', "
            "scenario='tiny', max_steps=3); obs, _ = env.reset(seed=0); print(env.spec.id, "
            "sorted(obs))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split()[0] == ENV_ID and "'cloud'" in out.stdout


def test_the_environment_passes_gymnasiums_checker():
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make(ENV_ID, scenario="tiny", max_steps=3)
    check_env(env.unwrapped)
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    assert obs["cloud"].shape == (3, 32, 32) and obs["valid"].any()
    assert np.allclose(obs["goal"], env.unwrapped.goal) and info["pos_err_m"] > 0
    again, _ = env.reset(seed=1)
    assert all(np.array_equal(obs[k], again[k]) for k in obs)  # seeded: the same push
    for step in range(1, 4):
        obs, reward, terminated, truncated, info = env.step(np.zeros(2))
        assert reward == pytest.approx(-(info["pos_err_m"] / 0.02 + info["yaw_err_deg"] / 10))
        assert not terminated and truncated == (step == 3)  # standing still reaches nothing


def test_the_mpc_planner_drives_the_environment_as_the_closed_loop_does():
    """The oracle planner pushes the box to a nearby goal through the environment, with the
    very actions ``run_push`` takes, and the episode terminates on the tight tolerance."""
    goal = _nearby_goal()
    env = gymnasium.make(ENV_ID, scenario="tiny", max_steps=20)
    obs, _ = env.reset(options={"world_seed": 0, "goal": goal})
    policy = MPCPolicy(env, model="oracle")
    actions, rewards = [], []
    while True:
        action = policy(obs)
        assert env.action_space.contains(action)
        actions.append(action.tolist())
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        if terminated or truncated:
            break
    assert terminated and not truncated and info["success_tight"]
    assert rewards[-1] > rewards[0] and rewards[-1] > -2
    loop = run_push(PushConfig(goal=goal, scenario="tiny", model="oracle", max_steps=20))
    assert actions == [r.action for r in loop.records]


def test_bad_settings_are_refused():
    from scenarios import InputError

    with pytest.raises(InputError, match="joint-velocity controls"):
        PushEnv("arm")
    env = PushEnv("tiny")
    with pytest.raises(InputError, match="outside the reachable region"):
        env.reset(options={"goal": (5.0, 0.0, 0.0)})


def test_a_world_seed_alone_gets_a_goal_drawn_for_that_worlds_start():
    from scenarios import load_scenario
    from sim.planar import pose_errors

    env, goals = PushEnv("single_box"), load_scenario("single_box").goals
    for seed in range(40):  # none starts within the goal's tolerance, as no trial does
        obs, _ = env.reset(seed=seed, options={"world_seed": 5})
        dist, turn = pose_errors(obs["goal"], obs["object_pose"],
                                 env.world.objects[0].yaw_period_rad)  # fmt: skip
        assert dist <= goals.max_distance_m + 1e-6
        assert dist >= goals.min_distance_m or turn >= goals.min_yaw_deg


def test_a_given_goals_yaw_is_wrapped_into_the_observation_space():
    env = PushEnv("single_box")
    for yaw in (4.0, -7.0):
        obs, _ = env.reset(seed=0, options={"world_seed": 0, "goal": (0.05, 0.0, yaw)})
        assert env.observation_space.contains(obs)
        assert abs(obs["goal"][2] - np.arctan2(np.sin(yaw), np.cos(yaw))) < 1e-6
