"""Exploration for joint-velocity controls: the paper's Baxter data.

The paper's Baxter data applied "a constant, randomly chosen velocity to 1-4 randomly chosen
joints" for a scene of one second, then brought the arm to rest, and reset the arm's pose
every 20 scenes. Here an episode starts from a random configuration of the arm and is a
sequence of scenes, each of one mode:

- ``joints``: 1-4 joints drawn at random, each given a constant velocity (random sign, a
  speed drawn as a fraction of ``action.max_joint_speed_rad_s``), the others commanded 0, for
  a few steps (the paper's one-second scene is 7 of our 0.15 s steps);
- ``rest``: every joint commanded 0, so the arm comes to rest.

A scene is cut short before its commanded path would take a joint within a margin of its
limits, bring the elbow, the wrist or the pusher's tip closer to the table than a clearance,
or take them out of the camera's view: the arm never touches the table (nor collides with
it: its links collide with nothing) and its links stay in view. The path is checked with the
world's own forward kinematics (``PushWorld.arm_points``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim.controller import planar_arm_ik
from sim.world import PushWorld

JOINT_MODES = ("joints", "rest")


@dataclass(frozen=True)
class JointExplorationConfig:
    """Shape of the joint-velocity exploration's scenes."""

    joints_moved: tuple[int, int] = (1, 4)
    """[min, max] number of joints a scene moves (the paper's 1-4)"""
    speed_fraction: tuple[float, float] = (0.2, 1.0)
    """range of a moved joint's speed, as a fraction of the bound"""
    scene_steps: tuple[int, int] = (3, 7)
    """range of the number of steps of a moving scene (7 steps: the paper's one second)"""
    p_rest: float = 0.15
    """probability that a scene is rest"""
    rest_steps: tuple[int, int] = (1, 2)
    """range of the number of steps of a rest scene"""
    limit_margin_rad: float = 0.05
    """joints keep this far inside their limits"""
    table_clearance_m: float = 0.04
    """the elbow, the wrist and the pusher's tip keep this high above the table (more than the
    links' radii)"""
    view_margin_px: float = 1.0
    """the elbow, the wrist and the tip keep this far inside the image's borders"""
    checks_per_step: int = 4
    """points of the commanded path checked per step"""
    tries: int = 30
    """scenes drawn before giving up and resting"""


class JointExploration:
    """Chooses joint-velocity actions scene by scene; deterministic given its generator.

    Args:
        world: the episode's world (after ``reset``): its scenario, camera and kinematics.
        rng: the episode's generator.
        cfg: the scenes' shape.
    """

    def __init__(
        self,
        world: PushWorld,
        rng: np.random.Generator,
        cfg: JointExplorationConfig = JointExplorationConfig(),
    ):
        self.world, self.rng, self.cfg = world, rng, cfg
        s = world.scenario
        self.bound = s.action.max_joint_speed_rad_s
        self.dt = s.action.dt_control_s
        lo, hi = np.array(s.arm.joint_limits_rad).T
        self.lo, self.hi = lo + cfg.limit_margin_rad, hi - cfg.limit_margin_rad
        self._plan: list[tuple[str, np.ndarray]] = []

    def allowed(self, q: np.ndarray) -> bool:
        """The configuration ``q`` (4,) keeps the margins: inside the joint limits, the arm
        above the table by the clearance and in the camera's view."""
        if np.any(q < self.lo) or np.any(q > self.hi):
            return False
        points = self.world.arm_points(q)  # (3,3) elbow, wrist, tip
        if np.any(points[:, 2] < self.cfg.table_clearance_m):
            return False
        cam = self.world.camera
        p_cam = points @ cam.T_cam_world[:3, :3].T + cam.T_cam_world[:3, 3]
        uv = cam.project(p_cam)
        m = self.cfg.view_margin_px
        return bool(
            np.all(p_cam[:, 2] > 0)
            and np.all((uv >= m) & (uv <= np.array([cam.width, cam.height]) - m))
        )

    def start_configuration(self) -> np.ndarray:
        """A random configuration (4,) that keeps the margins (the arm's pose at an episode's
        start; the scenario's start pose if none is found)."""
        for _ in range(1000):
            q = self.rng.uniform(self.lo, self.hi)
            if self.allowed(q):
                return q
        return planar_arm_ik(self.world.scenario, self.world.scenario.arm.start_xy_m)

    def _safe_steps(self, q: np.ndarray, qd: np.ndarray, steps: int) -> int:
        """How many of ``steps`` steps of velocities ``qd`` from ``q`` keep the margins."""
        n = self.cfg.checks_per_step
        for k in range(steps):
            for j in range(1, n + 1):
                if not self.allowed(q + qd * self.dt * (k + j / n)):
                    return k
        return steps

    def _new_scene(self, q: np.ndarray) -> None:
        cfg, rng = self.cfg, self.rng
        if rng.uniform() < cfg.p_rest:
            n = int(rng.integers(cfg.rest_steps[0], cfg.rest_steps[1] + 1))
            self._plan = [("rest", np.zeros(4))] * n
            return
        for _ in range(cfg.tries):
            n_joints = int(rng.integers(cfg.joints_moved[0], cfg.joints_moved[1] + 1))
            joints = rng.choice(4, size=n_joints, replace=False)
            qd = np.zeros(4)
            qd[joints] = rng.choice([-1.0, 1.0], size=n_joints) * (
                self.bound * rng.uniform(*cfg.speed_fraction, size=n_joints)
            )
            steps = self._safe_steps(q, qd, int(rng.integers(cfg.scene_steps[0],
                                                             cfg.scene_steps[1] + 1)))  # fmt: skip
            if steps > 0:
                self._plan = [("joints", qd)] * steps
                return
        self._plan = [("rest", np.zeros(4))]

    def __call__(self, obs) -> tuple[np.ndarray, str]:
        """The next action (4,) (joint velocities, rad/s) and the mode that chose it."""
        if not self._plan:
            self._new_scene(obs.joint_pos_rad)
        mode, qd = self._plan.pop(0)
        return qd.copy(), mode


def describe_joint_exploration(cfg: JointExplorationConfig) -> dict:
    """The policy's configuration and mode names, for a dataset manifest."""
    return {"modes": list(JOINT_MODES), **asdict(cfg)}
