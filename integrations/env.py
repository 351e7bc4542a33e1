"""The push world as a Gymnasium environment, ``se3push/Push-v0``, and the MPC planner as a
policy of it.

::

    import gymnasium

    # "module:id": Gymnasium imports the module, which registers the id (Gymnasium 1.x has no
    # plugin entry points, so a bare "se3push/Push-v0" needs `import integrations.env` first)
    env = gymnasium.make("integrations.env:se3push/Push-v0", scenario="single_box")
    obs, info = env.reset(seed=0)
    policy = MPCPolicy(env, model="default")  # plan=PlanSettings(...) for other settings
    while True:
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        if terminated or truncated:
            break

An episode is a closed-loop push as ``plan-push`` and ``se3push trials`` run it: the world
reset with a trial's seed, a goal drawn as trial goals are (``evaluation.trials.draw_trial``) or
given, one action per control step, the object's pose error measured with its symmetry
(``sim.planar.pose_errors``), success within the tight tolerance (``planner.loop.TIGHT``).

- Observation (a dict): ``cloud`` (3,H,W) float32, the organised cloud in the camera frame
  (m, zero where invalid); ``valid`` (H,W) 0/1, pixels whose ray hit something;
  ``pusher_xy`` (2,) m; ``object_pose`` (3,) and ``goal`` (3,), x_m, y_m, yaw_rad of the
  pushed object (object 0) and of its goal, in the world frame.
- Action: the pusher velocity (vx, vy) in m/s, a float64 Box of the scenario's bound
  (clipped to it).
- Reward: minus the pose error in units of the tight tolerance,
  ``-(pos_err_m / 0.02 + yaw_err_deg / 10)``: above -2 when both are within it.
- Terminated: the object is within the tight tolerance of the goal, or the episode ended in
  the world (an object left the table, or the simulation became unstable).
- Truncated: ``max_steps`` actions were taken without either.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from evaluation.trials import draw_goal, draw_trial
from planner.loop import TIGHT, PushConfig, check_reachable, push_planner, push_scenario, within
from planner.observe import plan_state
from planner.settings import PlanSettings
from sim import Observation, PushWorld
from sim.planar import pose_errors, wrap_angle

ENV_ID = "se3push/Push-v0"
FAR_M = 10.0
"""bound of every coordinate in an observation (m): the camera and the table are within it"""


class PushEnv(gymnasium.Env):
    """Push object 0 of a scenario's world to a goal pose (see the module doc).

    Args:
        scenario: a push scenario's name or TOML path.
        max_steps: actions before the episode is truncated (``--max-steps``).

    ``reset(options=...)`` takes ``world_seed`` (the world's reset seed) and ``goal`` (x_m,
    y_m, yaw_rad; the yaw is wrapped into [-pi, pi)) to pose a given push; what is not given
    comes from the environment's random generator (seeded by ``reset(seed=...)``): a trial
    drawn as ``se3push trials`` draws them, or, given a ``world_seed`` alone, a goal drawn
    from that world's start as a trial's is.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, scenario: str = "single_box", *, max_steps: int = 60) -> None:
        if max_steps < 1:
            raise ValueError(f"max_steps must be positive, got {max_steps}")
        self.scenario_name, self.max_steps = scenario, max_steps
        self.scenario = push_scenario(scenario)
        self.world = PushWorld(self.scenario)
        cam = self.scenario.camera
        h, w = cam.height, cam.width
        bound = self.scenario.action.max_speed_m_s
        # float64, as the world takes it: the planner's actions pass through unrounded
        self.action_space = spaces.Box(-bound, bound, shape=(2,), dtype=np.float64)
        far, pi = FAR_M, np.pi  # a table-top scene lies well within FAR_M of anything
        lo, hi = np.array([-far, -far, -pi], np.float32), np.array([far, far, pi], np.float32)
        pose = spaces.Box(lo, hi, dtype=np.float32)
        self.observation_space = spaces.Dict({
            "cloud": spaces.Box(-far, far, shape=(3, h, w), dtype=np.float32),
            "valid": spaces.MultiBinary((h, w)),
            "pusher_xy": spaces.Box(-far, far, shape=(2,), dtype=np.float32),
            "object_pose": pose,
            "goal": pose,
        })  # fmt: skip
        self.obs: Observation | None = None
        self.goal = np.zeros(3)
        self.world_seed, self.steps, self.episode = 0, 0, 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        trial_seed = int(self.np_random.integers(1 << 31))  # drawn always: one stream of resets
        if "world_seed" in options:
            self.world_seed = int(options["world_seed"])
            if "goal" not in options:  # a goal for this world's start
                options = {**options, "goal": draw_goal(self.scenario, self.world_seed,
                                                        self.np_random)[1]}  # fmt: skip
        else:
            trial = draw_trial(self.scenario, trial_seed, 0)
            self.world_seed = trial["reset_seed"]
            options = {"goal": trial["goal"], **options}
        goal = tuple(float(g) for g in options["goal"])
        check_reachable(self.scenario, goal)
        self.goal = np.array([goal[0], goal[1], wrap_angle(goal[2])])  # yaw in [-pi, pi)
        self.obs = self.world.reset(self.world_seed)
        self.steps, self.episode = 0, self.episode + 1
        return self._observation(), self._info()

    def step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        bound = self.scenario.action.max_speed_m_s
        self.obs = self.world.step(np.clip(np.asarray(action, dtype=float), -bound, bound))
        self.steps += 1
        errors = self.errors()
        terminated = within(errors, TIGHT) or self.obs.done
        truncated = not terminated and self.steps >= self.max_steps
        reward = -(errors[0] / TIGHT[0] + errors[1] / TIGHT[1])
        return self._observation(), float(reward), terminated, truncated, self._info()

    def errors(self) -> tuple[float, float]:
        """The pushed object's position (m) and symmetry-aware yaw (deg) error to the goal."""
        period = self.world.objects[0].yaw_period_rad
        return pose_errors(self.obs.object_poses[0], self.goal, period)

    def _observation(self) -> dict[str, np.ndarray]:
        o = self.obs
        return {
            "cloud": o.points_cam.astype(np.float32),
            "valid": o.valid.astype(np.int8),
            "pusher_xy": o.pusher_xy_m.astype(np.float32),
            "object_pose": o.object_poses[0].astype(np.float32),
            "goal": self.goal.astype(np.float32),
        }

    def _info(self) -> dict[str, Any]:
        pos_err, yaw_err = self.errors()
        return {
            "pos_err_m": pos_err,
            "yaw_err_deg": yaw_err,
            "success_tight": within((pos_err, yaw_err), TIGHT),
            "world_seed": self.world_seed,
            "reason": self.obs.reason,
        }


class MPCPolicy:
    """The MPC planner of ``plan-push`` as a policy of a :class:`PushEnv`: a planner built
    for each episode exactly as the closed loop builds it (``planner.loop.push_planner``,
    seeded with the world's seed), fed the planner's view of the environment's world.

    Args:
        env: the environment (or a wrapper of it, such as ``gymnasium.make`` returns).
        model: dynamics, as ``plan-push --model`` (default, a checkpoint, oracle, ...).
        plan: the planning settings (``planner.settings.PlanSettings``; a preset of
            ``planner.presets``, or today's defaults).
        device: device of a learned model.
    """

    def __init__(self, env: gymnasium.Env, *, model: str = "default",
                 plan: PlanSettings | None = None, device: str = "cpu") -> None:  # fmt: skip
        self.env: PushEnv = env.unwrapped
        self.options = {"model": model, "plan": plan or PlanSettings(), "device": device}
        self.planner, self.episode = None, -1

    def __call__(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """The planned action for the environment's current state (``observation`` is that
        state's; the planner reads the world's own view of it): (2,) within the action space."""
        env = self.env
        if self.episode != env.episode:  # a new episode: a new planner, as the loop makes
            cfg = PushConfig(goal=tuple(env.goal), scenario=env.scenario_name,
                             seed=env.world_seed, max_steps=env.max_steps,
                             **self.options)  # fmt: skip
            self.planner, self.episode = push_planner(cfg, env.scenario, env.world), env.episode
        action, _ = self.planner.plan(plan_state(env.obs, env.world))
        return action


if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="integrations.env:PushEnv")
