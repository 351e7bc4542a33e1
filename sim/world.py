"""The push world: a MuJoCo table top, an arm with a pusher, 1-3 free objects, a depth camera.

``reset(seed)`` draws objects from the scenario and builds the model; ``step(action)`` holds
an action for ``dt_control_s`` and returns the next :class:`Observation`. An action is, by the
scenario's ``action.controls`` (``sim.controls``), a planar pusher velocity ``(vx, vy)``
turned into joint motion by the differential-IK controller, or the velocities of the arm's 4
joints, integrated into the joint servos' targets.

Parts: every pixel is labelled with the rigid part it sees: ``-1`` nothing, ``0`` the static
world (table), ``1`` the pusher, ``2 + i`` object ``i``; with ``arm.links_visible`` (a
scenario without objects) ``2 + j`` the arm's link j (``ARM_LINK_BODIES``: the base, which
turns with the yaw joint, the upper arm and the forearm; the pusher ends the chain). ``T_world_part
(P,4,4)`` holds the parts' poses, so that targets after h steps follow exactly from the stored
body-frame points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from scenarios import InputError, Scenario
from sim.camera import DepthCamera, associated_targets, invert, transform_by_part
from sim.controller import PusherIK, planar_arm_ik
from sim.controls import control_layout
from sim.mjcf import (
    ARM_JOINTS,
    ARM_LINK_BODIES,
    PUSHER_BODY,
    PUSHER_SITE,
    build_mjcf,
    object_body,
)
from sim.shapes import HULL_POINTS, ObjectSpec, hull_outline

PART_NONE, PART_STATIC, PART_PUSHER = -1, 0, 1
FIRST_OBJECT_PART = 2
MAX_PARTS = FIRST_OBJECT_PART + 3
SETTLE_S = 0.1
MAX_SPEED_STABLE_M_S = 5.0
END_REASONS = ("", "unstable", "object_off_table")
"""why an episode ends (``PushWorld.end_codes``)"""


LINK_NAMES = ("arm base", "upper arm", "forearm")
"""the arm's links (``ARM_LINK_BODIES``) as pictures name them"""


def object_part(i: int) -> int:
    """The part label (``Observation.part``, the dataset's ``part``) of object i's pixels."""
    return FIRST_OBJECT_PART + i


def part_names(scenario: Scenario, n_objects: int) -> list[str]:
    """The name of each part label 0, 1, ... of a world of ``scenario`` with ``n_objects``
    objects (see the module doc)."""
    links = list(LINK_NAMES) if scenario.arm.links_visible else []
    return ["static", "pusher", *(f"object {i}" for i in range(n_objects)), *links]


class ActionError(InputError):
    """An action was malformed, not finite, or outside the scenario's bounds."""


class EpisodeEnded(RuntimeError):
    """``step`` was called after the episode ended; call ``reset``."""


@dataclass(frozen=True)
class Observation:
    """What the world shows after a reset or a step."""

    points_cam: np.ndarray
    """(3,H,W) float64, the organised cloud in the camera frame (m); zero where invalid."""
    valid: np.ndarray
    """(H,W) bool, pixels whose ray hit something."""
    part: np.ndarray
    """(H,W) int8, the part each pixel sees (see module doc)."""
    points_part: np.ndarray
    """(3,H,W) float64, each pixel's point in its part's frame (for associations)."""
    T_world_part: np.ndarray
    """(P,4,4) poses of the parts, P = 2 + the objects + the arm's visible links."""
    object_poses: np.ndarray
    """(n,3) planar pose (x_m, y_m, yaw_rad) of each object."""
    pusher_xy_m: np.ndarray
    """(2,) pusher tip position in the world frame."""
    joint_pos_rad: np.ndarray
    """(4,) arm joint angles."""
    joint_vel_rad_s: np.ndarray
    """(4,) arm joint velocities."""
    time_s: float
    done: bool
    """The episode has ended; ``reason`` says why."""
    reason: str
    """``""``, ``"object_off_table"`` or ``"unstable"``."""

    def object_pixels(self, i: int) -> np.ndarray:
        """(H,W) bool, the pixels that see object i."""
        return self.part == object_part(i)

    @property
    def pusher_seen(self) -> bool:
        """Whether any pixel sees the pusher (a learned model cannot see it otherwise)."""
        return bool((self.part == PART_PUSHER).any())


def yaw_of(R: np.ndarray) -> float:
    """Heading of a rotation matrix's x axis in the world xy plane."""
    return math.atan2(R[1, 0], R[0, 0])


class PushWorld:
    """A scenario's world. Not thread-safe; make one per worker.

    Args:
        scenario: the scenario to simulate.
        width, height: camera resolution override (defaults to the scenario's).
    """

    def __init__(self, scenario: Scenario, *, width: int | None = None, height: int | None = None):
        self.scenario = scenario
        self.camera = DepthCamera(scenario.camera, width=width, height=height)
        self.n_substeps = max(1, round(scenario.action.dt_control_s / scenario.action.physics_dt_s))
        self.ctrl_every = max(
            1, round(1.0 / (scenario.arm.controller_rate_hz * scenario.action.physics_dt_s))
        )
        self.layout = control_layout(scenario)
        self.joint_controls = scenario.action.controls == "joints"
        """actions are joint velocities (else planar pusher velocities)"""
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self.objects: list[ObjectSpec] = []
        self.qp_failures = 0

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | np.random.Generator) -> Observation:
        """Start an episode: draw objects and their poses, build the model, settle.

        Args:
            seed: an int or a generator; the same seed gives the same episode.
        """
        rng = np.random.default_rng(seed)
        n_lo, n_hi = self.scenario.objects.count
        self.objects = [self._draw_object(rng) for _ in range(int(rng.integers(n_lo, n_hi + 1)))]
        poses = self._place_objects(rng)
        self._build(poses)
        return self.observe()

    def _draw_object(self, rng: np.random.Generator) -> ObjectSpec:
        o = self.scenario.objects
        shape = o.shapes[int(rng.integers(len(o.shapes)))]
        detail = {}
        if shape == "cylinder":
            d = 2 * float(rng.uniform(*o.cylinder_radius_m))
            size = (d, d, float(rng.uniform(*o.cylinder_height_m)))
        else:
            ranges = {"box": o.box_size_m, "capsule": o.capsule_size_m, "hull": o.hull_size_m}
            size = tuple(float(rng.uniform(lo, hi)) for lo, hi in ranges.get(shape, o.bar_size_m))
        if shape == "capsule":  # its width is at most its length
            size = (size[0], min(size[0], size[1]), size[2])
        elif shape == "hull":
            corner = np.array(size[:2]) / 2
            points = rng.uniform(-corner, corner, size=(HULL_POINTS, 2))
            outline = hull_outline(points)
            lo, hi = outline.min(0), outline.max(0)
            outline = outline - (lo + hi) / 2  # the origin at the bounding box's centre
            size = (*(float(x) for x in hi - lo), size[2])
            detail["outline"] = tuple((float(x), float(y)) for x, y in outline)
        elif shape in ("L", "T"):
            detail["arm_m"] = min(float(rng.uniform(*o.bar_width_m)), *size[:2])
        return ObjectSpec(
            shape=shape,
            size_m=size,
            mass_kg=float(rng.uniform(*o.mass_kg)),
            friction=float(rng.uniform(*o.friction)),
            **detail,
        )

    def _place_objects(self, rng: np.random.Generator) -> list[tuple[float, float, float]]:
        o, a = self.scenario.objects, self.scenario.arm
        x0, x1, y0, y1 = o.region_m
        for _ in range(1000):
            poses: list[tuple[float, float, float]] = []
            for obj in self.objects:
                x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
                yaw = rng.uniform(-math.pi, math.pi)
                clear_pusher = math.hypot(x - a.start_xy_m[0], y - a.start_xy_m[1]) > (
                    obj.footprint_radius_m + a.pusher_radius_m + o.min_gap_m
                )
                clear_objects = all(
                    math.hypot(x - px, y - py)
                    > obj.footprint_radius_m + other.footprint_radius_m + o.min_gap_m
                    for (px, py, _), other in zip(poses, self.objects, strict=False)
                )
                if not (clear_pusher and clear_objects):
                    break
                poses.append((float(x), float(y), float(yaw)))
            if len(poses) == len(self.objects):
                return poses
        raise InputError(
            f"scenario {self.scenario.name}: could not place {len(self.objects)} objects without "
            "overlap in objects.region_m; enlarge the region or lower objects.min_gap_m"
        )

    def _build(self, poses: list[tuple[float, float, float]], *, settle: bool = True) -> None:
        s = self.scenario
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(s, self.objects))
        self.data = mujoco.MjData(self.model)
        m, d = self.model, self.data
        joint_ids = np.array([m.joint(n).id for n in ARM_JOINTS])
        self._arm_qpos = m.jnt_qposadr[joint_ids]
        self._arm_dof = m.jnt_dofadr[joint_ids]
        links = ARM_LINK_BODIES if s.arm.links_visible else ()
        self._part_bodies = np.array(
            [0, m.body(PUSHER_BODY).id]
            + [m.body(object_body(i)).id for i in range(len(poses))]
            + [m.body(name).id for name in links]
        )
        # part of every body: static 0, pusher 1, object i 2+i, then the visible links; hidden
        # links -> static (the camera never sees them)
        self._body_part = np.zeros(m.nbody, np.int8)
        self._body_part[self._part_bodies[1:]] = np.arange(1, len(self._part_bodies))
        self._geom_part = self._body_part[m.geom_bodyid]
        self._joint_limits = np.array(s.arm.joint_limits_rad).T  # (2,4) lower, upper
        obj_joints = [m.joint(object_body(i)).id for i in range(len(poses))]
        self._obj_qpos = m.jnt_qposadr[obj_joints]
        self._obj_dof = m.jnt_dofadr[obj_joints]
        self._pusher_site = m.site(PUSHER_SITE).id
        self._elbow_body, self._wrist_body = m.body(ARM_LINK_BODIES[2]).id, m.body(PUSHER_BODY).id
        self._scratch: mujoco.MjData | None = None
        for adr, (x, y, yaw), obj in zip(self._obj_qpos, poses, self.objects, strict=True):
            d.qpos[adr : adr + 7] = [
                x,
                y,
                obj.size_m[2] / 2,
                math.cos(yaw / 2),
                0,
                0,
                math.sin(yaw / 2),
            ]
        q0 = planar_arm_ik(s, s.arm.start_xy_m)
        d.qpos[self._arm_qpos] = q0
        self._q_ref = q0.copy()
        d.ctrl[:] = q0
        self.controller = PusherIK(
            m,
            joint_ids=joint_ids,
            site_id=self._pusher_site,
            height_m=s.arm.pusher_clearance_m,
            joint_limits=np.array(s.arm.joint_limits_rad),
            speed_limit=s.arm.joint_speed_limit_rad_s,
            dt=self.ctrl_every * s.action.physics_dt_s,
        )
        self.qp_failures = 0
        self._done, self._reason = False, ""
        mujoco.mj_forward(m, d)
        if settle:
            rest = np.zeros(len(self.layout.commands))
            self._advance(rest, round(SETTLE_S / s.action.physics_dt_s))
        d.time = 0.0

    def teleport_pusher(self, xy_m: np.ndarray) -> Observation:
        """Put the arm, at rest, in the configuration that holds the pusher at ``xy_m``.

        Meant for the start of an episode (data generation starts pushes near the objects);
        the objects are not touched. Raises InputError if ``xy_m`` is out of reach (see
        :func:`planar_arm_ik`), ValueError if it overlaps an object (the caller's mistake).
        """
        if self.model is None:
            raise EpisodeEnded("no episode yet: call reset(seed) first")
        xy = np.asarray(xy_m, dtype=float)
        obs = self.observe()
        for (x, y, yaw), obj in zip(obs.object_poses, self.objects, strict=True):
            c, s = math.cos(yaw), math.sin(yaw)
            local = np.array([[c, s], [-s, c]]) @ (xy - [x, y])
            if obj.distance_to_footprint_m(local) < self.scenario.arm.pusher_radius_m:
                raise ValueError(f"pusher position {xy.tolist()} overlaps an object at {x, y}")
        return self.set_arm(planar_arm_ik(self.scenario, xy))

    def set_arm(self, q: np.ndarray) -> Observation:
        """Put the arm, at rest, in the joint configuration ``q`` (4,) (rad), its servos holding
        it there; nothing else is touched. Meant for the start of an episode."""
        if self.model is None:
            raise EpisodeEnded("no episode yet: call reset(seed) first")
        q = np.asarray(q, dtype=float)
        self.data.qpos[self._arm_qpos] = q
        self.data.qvel[self._arm_dof] = 0.0
        self._q_ref = q.copy()
        self.data.ctrl[:] = q
        mujoco.mj_forward(self.model, self.data)
        return self.observe()

    def arm_points(self, q: np.ndarray) -> np.ndarray:
        """(3,3) where the elbow (the forearm's joint), the wrist (the pusher's joint) and the
        pusher's tip would be, world frame, with the arm in configuration ``q`` (4,): MuJoCo's
        own forward kinematics, on a scratch copy of the state (the world is not touched). The
        links are straight between these points, so their lowest points are among them."""
        d = self.scratch()
        d.qpos[self._arm_qpos] = q
        mujoco.mj_kinematics(self.model, d)
        return np.stack(
            [d.xpos[self._elbow_body], d.xpos[self._wrist_body], d.site_xpos[self._pusher_site]]
        )

    # ------------------------------------------------------------------- step
    def check_action(self, action: np.ndarray) -> np.ndarray:
        """The action as a float array (2,) (a pusher velocity) or (4,) (joint velocities, in a
        scenario with 'joints' controls), or an :class:`ActionError` saying what is wrong."""
        a = np.asarray(action, dtype=float)
        if self.joint_controls:
            what, shape, unit = "the velocities of the arm's 4 joints", (4,), "rad/s"
            bound, field = self.scenario.action.max_joint_speed_rad_s, "max_joint_speed_rad_s"
        else:
            what, shape, unit = "a planar pusher velocity (vx, vy)", (2,), "m/s"
            bound, field = self.scenario.action.max_speed_m_s, "max_speed_m_s"
        if a.shape != shape:
            raise ActionError(
                f"an action of scenario {self.scenario.name} is {what}; got shape {a.shape}"
            )
        if not np.all(np.isfinite(a)):
            raise ActionError(f"action {a.tolist()} is not finite")
        if np.any(np.abs(a) > bound + 1e-9):
            raise ActionError(
                f"action {a.tolist()} {unit} is outside the bounds ±{bound} {unit} per entry "
                f"(scenario {self.scenario.name}: action.{field}); clip it first"
            )
        return a

    def step(self, action: np.ndarray) -> Observation:
        """Hold ``action`` for one control step: the pusher velocity (vx, vy; m/s, world frame),
        or with 'joints' controls the joint velocities (4,) (rad/s).

        Raises:
            ActionError: the action is malformed, not finite or out of bounds.
            EpisodeEnded: the episode has already ended.
        """
        self.advance(action)
        return self.observe()

    def advance(self, action: np.ndarray) -> np.ndarray:
        """``step`` without rendering: returns the objects' planar poses (n,3). The fast path
        for simulating candidate actions (the oracle backend). Raises as ``step``."""
        a = self.check_action(action)
        if self.model is None:
            raise EpisodeEnded("no episode yet: call reset(seed) first")
        if self._done:
            raise EpisodeEnded(f"the episode ended ({self._reason}); call reset(seed)")
        self._advance(a, self.n_substeps)
        self._check_end()
        T = self.part_poses()[FIRST_OBJECT_PART : FIRST_OBJECT_PART + len(self.objects)]
        return np.column_stack([T[:, 0, 3], T[:, 1, 3], np.arctan2(T[:, 1, 0], T[:, 0, 0])])

    @property
    def ended(self) -> bool:
        """The episode has ended (object off the table, or unstable)."""
        return self._done

    def pusher_xy(self) -> np.ndarray:
        """(2,) the pusher tip's position now, world frame."""
        return self.data.site_xpos[self._pusher_site, :2].copy()

    def snapshot(self) -> dict[str, np.ndarray | float | bool | str]:
        """The dynamic state (physics, servo targets, episode status), for ``restore``."""
        d = self.data
        return {
            "qpos": d.qpos.copy(), "qvel": d.qvel.copy(), "act": d.act.copy(),
            "ctrl": d.ctrl.copy(), "time": float(d.time), "q_ref": self._q_ref.copy(),
            "done": self._done, "reason": self._reason,
        }  # fmt: skip

    def restore(self, state: dict) -> None:
        """Return to a ``snapshot`` of this world."""
        d = self.data
        d.qpos[:], d.qvel[:], d.act[:], d.ctrl[:] = (
            state["qpos"],
            state["qvel"],
            state["act"],
            state["ctrl"],
        )
        d.time, self._q_ref = state["time"], state["q_ref"].copy()
        self._done, self._reason = state["done"], state["reason"]
        mujoco.mj_forward(self.model, d)

    def _advance(self, action: np.ndarray, n_steps: int) -> None:
        m, d = self.model, self.data
        for i in range(n_steps):
            if i % self.ctrl_every == 0:
                if self.joint_controls:
                    self._q_ref = self._joint_servo_targets(action)
                else:
                    self._q_ref = self.controller.servo_targets(d, self._q_ref, action)
                d.ctrl[:] = self._q_ref
            mujoco.mj_step(m, d)
        self.qp_failures = self.controller.failures
        mujoco.mj_kinematics(m, d)

    def _joint_servo_targets(self, qd: np.ndarray) -> np.ndarray:
        """The servo targets after one controller tick of commanded joint velocities ``qd``
        (4,): integrated from the last targets, and stopped at the joint limits."""
        lo, hi = self._joint_limits
        return np.clip(self._q_ref + qd * self.controller.dt, lo, hi)

    def _check_end(self) -> None:
        code = int(self.end_codes(self.data.qpos[None], self.data.qvel[None])[0])
        if code:
            self._done, self._reason = True, END_REASONS[code]

    def end_codes(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """(...) why an episode would end in each of the states ``qpos`` (..., nq), ``qvel``
        (..., nv): 0 it goes on, else an index into ``END_REASONS`` (something not finite or
        too fast: unstable; an object off the table)."""
        unstable = ~(np.isfinite(qpos).all(-1) & np.isfinite(qvel).all(-1))
        unstable |= (np.abs(qvel) > 50.0).any(-1)
        sx, sy = self.scenario.table.size_m
        off, fast = np.zeros_like(unstable), np.zeros_like(unstable)
        for qa, da in zip(self._obj_qpos, self._obj_dof, strict=True):
            x, y, z = qpos[..., qa], qpos[..., qa + 1], qpos[..., qa + 2]
            off |= (np.abs(x) > sx / 2) | (np.abs(y) > sy / 2) | (z < 0)
            fast |= np.linalg.norm(qvel[..., da : da + 3], axis=-1) > MAX_SPEED_STABLE_M_S
        # the order the checks were made in: unstable, then off the table, then too fast
        return np.where(unstable, 1, np.where(off, 2, np.where(fast, 1, 0)))

    def servo_reference(self) -> np.ndarray:
        """(4,) where the arm's joint servos point now (the controller's reference)."""
        return self._q_ref.copy()

    def scratch(self) -> mujoco.MjData:
        """A spare MjData of this world's model, for computations that must not touch it."""
        if self._scratch is None:
            self._scratch = mujoco.MjData(self.model)
        return self._scratch

    def plan_readout(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every object's planar pose (..., n, 3) and the pusher tip's position (..., 2) in
        states ``qpos`` (..., nq), by MuJoCo's forward kinematics on the scratch data."""
        lead = qpos.shape[:-1]
        flat = qpos.reshape(-1, qpos.shape[-1])
        d = self.scratch()
        bodies = self._part_bodies[FIRST_OBJECT_PART : FIRST_OBJECT_PART + len(self.objects)]
        poses = np.empty((len(flat), len(bodies), 3))
        pusher = np.empty((len(flat), 2))
        for i, q in enumerate(flat):
            d.qpos[:] = q
            mujoco.mj_kinematics(self.model, d)
            R = d.xmat[bodies]
            poses[i, :, :2] = d.xpos[bodies, :2]
            poses[i, :, 2] = np.arctan2(R[:, 3], R[:, 0])
            pusher[i] = d.site_xpos[self._pusher_site, :2]
        return poses.reshape(*lead, len(bodies), 3), pusher.reshape(*lead, 2)

    # ---------------------------------------------------------------- observe
    def part_poses(self) -> np.ndarray:
        """(P,4,4) current poses of the parts (static, pusher, objects or visible links) in the
        world frame."""
        d = self.data
        T = np.tile(np.eye(4), (len(self._part_bodies), 1, 1))
        T[:, :3, :3] = d.xmat[self._part_bodies].reshape(-1, 3, 3)
        T[:, :3, 3] = d.xpos[self._part_bodies]
        return T

    def observe(self) -> Observation:
        """Render the camera and read the state (no simulation)."""
        m, d = self.model, self.data
        frame = self.camera.render(m, d)
        part = np.where(frame.valid, self._geom_part[np.clip(frame.geom_id, 0, None)], PART_NONE)
        part = part.astype(np.int8)
        T_world_part = self.part_poses()
        # each point in its part's frame: p_part = T_part_world · T_world_cam · p_cam
        T_part_cam = invert(T_world_part) @ self.camera.T_world_cam
        points_part = transform_by_part(frame.points_cam, part, T_part_cam)
        poses = np.array(
            [
                [*T_world_part[object_part(i), :2, 3], yaw_of(T_world_part[object_part(i), :3, :3])]
                for i in range(len(self.objects))
            ]
        ).reshape(-1, 3)
        return Observation(
            points_cam=frame.points_cam,
            valid=frame.valid,
            part=part,
            points_part=points_part,
            T_world_part=T_world_part,
            object_poses=poses,
            pusher_xy_m=self.pusher_xy(),
            joint_pos_rad=d.qpos[self._arm_qpos].copy(),
            joint_vel_rad_s=d.qvel[self._arm_dof].copy(),
            time_s=float(d.time),
            done=self._done,
            reason=self._reason,
        )

    def targets(self, obs: Observation, later: Observation) -> np.ndarray:
        """Exact targets (3,H,W) of ``obs``'s pixels at the time of ``later``."""
        return associated_targets(
            obs.points_part, obs.part, later.T_world_part, self.camera.T_cam_world
        )
