"""Exploration policy for training data: what the SE3-Net gets to see.

The paper stresses that the network must see the mover moving on its own, or it masks mover
and object together. An episode is a sequence of segments, each of one mode:

- ``aimed``: approach a pre-push point behind a random object (going round it if needed),
  then push through its centre from a random side, with noisy heading and speed;
- ``glance``: the same with the line of push offset to the object's edge, so that the push
  rotates the object or misses it;
- ``free``: pusher motion that keeps clear of every object;
- ``rest``: the pusher stays still.

Approaches are themselves free motion, so the mover is seen moving alone often.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from scenarios import Scenario
from sim.planar import wrap_angle
from sim.shapes import ObjectSpec
from sim.world import Observation

MODES = ("aimed", "glance", "free", "rest", "approach")


@dataclass(frozen=True)
class ExplorationConfig:
    """Mixture and shape of the exploration policy's segments."""

    p_aimed: float = 0.45
    """probability that a segment is a push through an object's centre"""
    p_glance: float = 0.2
    """probability that a segment is an off-centre push that rotates the object or misses"""
    p_free: float = 0.23
    """probability that a segment is free pusher motion touching nothing"""
    p_rest: float = 0.12
    """probability that a segment is rest"""
    heading_noise_rad: float = 0.25
    """SD of the per-step heading noise during a push"""
    speed_fraction: tuple[float, float] = (0.35, 1.0)
    """range of push and free-motion speeds, as fractions of the action bound"""
    push_steps: tuple[int, int] = (4, 10)
    """range of the number of pushing steps in a push segment"""
    free_steps: tuple[int, int] = (2, 5)
    """range of the number of steps of a free-motion segment"""
    rest_steps: tuple[int, int] = (1, 3)
    """range of the number of steps of a rest segment"""
    clearance_m: float = 0.01
    """gap between pusher and object at a pre-push point, and round objects on the way"""
    workspace_margin_m: float = 0.04
    """the pusher stays this far inside the table's edges"""
    object_margin_m: float = 0.06
    """pushes are aimed so that the object's centre stays this far inside the table"""
    push_sides: int = 8
    """of this many random sides to push from, the one nearest the pusher is taken"""

    def mixture(self) -> dict[str, float]:
        return {
            "aimed": self.p_aimed,
            "glance": self.p_glance,
            "free": self.p_free,
            "rest": self.p_rest,
        }


class ExplorationPolicy:
    """Chooses actions segment by segment; deterministic given its generator.

    Args:
        scenario: the world's scenario (bounds, table, pusher size).
        objects: the episode's objects (their footprints).
        rng: the episode's generator.
        cfg: the mixture.
    """

    def __init__(
        self,
        scenario: Scenario,
        objects: list[ObjectSpec],
        rng: np.random.Generator,
        cfg: ExplorationConfig = ExplorationConfig(),
    ):
        self.s, self.objects, self.rng, self.cfg = scenario, objects, rng, cfg
        self.vmax = scenario.action.max_speed_m_s
        self.step_m = self.vmax * scenario.action.dt_control_s
        hx, hy = (np.array(scenario.table.size_m) / 2) - cfg.workspace_margin_m
        self.workspace = np.array([[-hx, hx], [-hy, hy]])
        # segments to come: [mode, waypoint, velocity, steps left]
        self._plan: list[list] = []

    # ---------------------------------------------------------------- helpers
    def _radius(self, i: int) -> float:
        """Distance from object i's centre at which the pusher keeps its clearance."""
        return self._contact_radius(i) + self.cfg.clearance_m

    def _contact_radius(self, i: int) -> float:
        """Distance from object i's centre within which the pusher may touch it."""
        return self.objects[i].footprint_radius_m + self.s.arm.pusher_radius_m + 0.005

    def _speed(self) -> float:
        return self.vmax * self.rng.uniform(*self.cfg.speed_fraction)

    def _clear(
        self, p: np.ndarray, obs: Observation, *, touching: bool = False, skip: int = -1
    ) -> bool:
        """``p`` is in the workspace and keeps the clearance from every object but ``skip``
        (or, with ``touching``, merely cannot touch any)."""
        radius = self._contact_radius if touching else self._radius
        inside = np.all(p >= self.workspace[:, 0]) and np.all(p <= self.workspace[:, 1])
        return bool(inside) and all(
            np.linalg.norm(p - obs.object_poses[i, :2]) > radius(i)
            for i in range(len(self.objects))
            if i != skip
        )

    def _extent_along(self, i: int, u: np.ndarray, obs: Observation) -> float:
        """How far object i's footprint reaches from its centre along the world direction
        ``u``."""
        yaw = obs.object_poses[i, 2]
        ux = u[0] * math.cos(yaw) + u[1] * math.sin(yaw)  # u in the object's frame
        uy = -u[0] * math.sin(yaw) + u[1] * math.cos(yaw)
        return self.objects[i].support_m(np.array([ux, uy]))

    def start_position(self, obs: Observation) -> np.ndarray:
        """Where to put the pusher at the start of an episode: at the pre-push point of a
        first push (with probability ``p_aimed + p_glance``), else at a random position
        clear of every object."""
        mix = self.cfg.mixture()
        if self.rng.uniform() < (mix["aimed"] + mix["glance"]) / sum(mix.values()):
            mode = (
                "aimed"
                if self.rng.uniform() < mix["aimed"] / (mix["aimed"] + mix["glance"])
                else "glance"
            )
            anywhere = self.rng.uniform(self.workspace[:, 0], self.workspace[:, 1])
            start = self._plan_push(obs, mode, from_xy=anywhere)
            if start is not None:
                self._plan = [e for e in self._plan if e[0] != "approach"]
                return start
        for _ in range(200):
            p = self.rng.uniform(self.workspace[:, 0], self.workspace[:, 1])
            if self._clear(p, obs):
                return p
        return np.asarray(self.s.arm.start_xy_m, dtype=float)

    def _velocity_to(self, pusher: np.ndarray, goal: np.ndarray, speed: float) -> np.ndarray:
        d = goal - pusher
        dist = np.linalg.norm(d)
        v = d / max(dist, 1e-9) * min(speed, dist / self.s.action.dt_control_s)
        return np.clip(v, -self.vmax, self.vmax)

    # --------------------------------------------------------------- segments
    def _new_segment(self, obs: Observation) -> None:
        mix = self.cfg.mixture()
        mode = str(self.rng.choice(list(mix), p=np.array(list(mix.values())) / sum(mix.values())))
        if mode in ("aimed", "glance") and self._plan_push(obs, mode) is not None:
            return
        if mode == "rest":
            n = int(self.rng.integers(self.cfg.rest_steps[0], self.cfg.rest_steps[1] + 1))
            self._plan = [["rest", None, None, 1] for _ in range(n)]
            return
        self._plan_free(obs)

    def _plan_push(
        self, obs: Observation, mode: str, *, from_xy: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Plan an approach and a push of a random object; of a few random sides, the one
        nearest the pusher (``from_xy``, default the pusher's position) is taken, so that
        approaches stay short. Returns the pre-push point, or None if no side was found."""
        pusher = obs.pusher_xy_m if from_xy is None else from_xy
        i = int(self.rng.integers(len(self.objects)))
        c = obs.object_poses[i, :2]
        n_push = int(self.rng.integers(self.cfg.push_steps[0], self.cfg.push_steps[1] + 1))
        speed = self._speed()
        half = self.objects[i].footprint_radius_m + self.s.arm.pusher_radius_m
        candidates = []
        for _ in range(30):
            theta = self.rng.uniform(-math.pi, math.pi)
            u = np.array([math.cos(theta), math.sin(theta)])
            if mode == "aimed":
                offset = self.rng.normal(0.0, 0.15) * half
            else:
                offset = self.rng.choice([-1.0, 1.0]) * self.rng.uniform(0.5, 1.2) * half
            clear = self.s.arm.pusher_radius_m + self.cfg.clearance_m
            back = self._extent_along(i, -u, obs) + clear  # behind the object's far side
            start = c - u * back + np.array([-u[1], u[0]]) * offset
            end = c + u * speed * self.s.action.dt_control_s * n_push
            if self._inside_table(end) and self._clear(start, obs, skip=i):
                candidates.append((np.linalg.norm(start - pusher), start, u))
                if len(candidates) == self.cfg.push_sides:
                    break
        if not candidates:
            return None
        _, start, u = min(candidates, key=lambda c: c[0])
        prev, self._plan = pusher, []
        for w in self._route(pusher, start, obs):  # a step budget: no stall at unreachable points
            budget = int(np.ceil(np.linalg.norm(w - prev) / self.step_m)) + 2
            self._plan.append(["approach", w, None, budget])
            prev = w
        self._plan += [[mode, None, u * speed, 1] for _ in range(n_push)]
        return start

    def _inside_table(self, p: np.ndarray) -> bool:
        h = np.array(self.s.table.size_m) / 2 - self.cfg.object_margin_m
        return bool(np.all(np.abs(p) <= h))

    def _route(self, a: np.ndarray, b: np.ndarray, obs: Observation) -> list[np.ndarray]:
        """Waypoints from ``a`` to ``b`` that keep off the objects: for an object in the way,
        back off to its clearance circle, follow the circle round in steps of at most 45
        degrees, then go to ``b``."""
        for i in range(len(self.objects)):
            c, r = obs.object_poses[i, :2], self._contact_radius(i)
            ab = b - a
            t = np.clip((c - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
            if np.linalg.norm(a + t * ab - c) >= r:
                continue
            R = self._radius(i)
            ang_a = math.atan2(a[1] - c[1], a[0] - c[0])
            ang_b = math.atan2(b[1] - c[1], b[0] - c[0])
            turn = wrap_angle(ang_b - ang_a)
            n = max(1, math.ceil(abs(turn) / (math.pi / 4)))
            arc = [ang_a + turn * k / n for k in range(n + 1)]
            return [c + R * np.array([math.cos(g), math.sin(g)]) for g in arc] + [b]
        return [b]

    def _plan_free(self, obs: Observation) -> None:
        n = int(self.rng.integers(self.cfg.free_steps[0], self.cfg.free_steps[1] + 1))
        speed = self._speed()
        for _ in range(30):
            theta = self.rng.uniform(-math.pi, math.pi)
            v = speed * np.array([math.cos(theta), math.sin(theta)])
            path = [obs.pusher_xy_m + v * self.s.action.dt_control_s * k for k in range(1, n + 1)]
            if all(self._clear(p, obs, touching=True) for p in path):
                v = np.clip(v, -self.vmax, self.vmax)
                self._plan = [["free", None, v, 1] for _ in range(n)]
                return
        self._plan = [["rest", None, None, 1]]

    # ------------------------------------------------------------------- act
    def __call__(self, obs: Observation) -> tuple[np.ndarray, str]:
        """The next action (2,) and the mode that chose it."""
        while True:
            if not self._plan:
                self._new_segment(obs)
            mode, waypoint, velocity, left = self._plan[0]
            if mode == "approach":
                if left <= 0 or np.linalg.norm(waypoint - obs.pusher_xy_m) < 0.004:
                    self._plan.pop(0)
                    continue
                self._plan[0][3] -= 1
                return self._velocity_to(obs.pusher_xy_m, waypoint, self.vmax), mode
            self._plan.pop(0)
            if mode == "rest":
                return np.zeros(2), mode
            if mode == "free":
                return velocity, mode
            noise = self.rng.normal(0.0, self.cfg.heading_noise_rad)
            c, s = math.cos(noise), math.sin(noise)
            v = np.array([c * velocity[0] - s * velocity[1], s * velocity[0] + c * velocity[1]])
            return np.clip(v, -self.vmax, self.vmax), mode


def describe_exploration(cfg: ExplorationConfig) -> dict:
    """The policy's configuration and mode names, for a dataset manifest."""
    return {"modes": list(MODES), **asdict(cfg)}
