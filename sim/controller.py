"""Differential-IK controller: desired pusher velocity -> joint servo targets, via an OSQP QP.

Each tick solves, for the arm's joint velocities ``qd (4,)``:

    min  w_xy |J_xy qd - v_des|^2 + w_z (J_z qd - k_z e_z)^2 + w_rot |J_rxy qd - k_rot e_rot|^2
         + damping |qd|^2
    s.t. max(-qd_max, (q_min - q) / dt) <= qd <= min(qd_max, (q_max - q) / dt)

where ``e_z`` is the pusher tip's height error and ``e_rot`` the tilt of the pusher's axis from
vertical (as a rotation vector; only its x, y components matter for a cylinder). The problem is
built once with a fixed sparsity pattern and updated in place each tick; OSQP warm-starts from
the previous solution. The joint servo targets integrate ``qd``. An unsolved QP gives a stop
command (``qd = 0``) and is counted in ``failures``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
import osqp
import scipy.sparse as sp

from scenarios import InputError, Scenario


@dataclass(frozen=True)
class IKWeights:
    """Weights and gains of the differential-IK QP."""

    w_xy: float = 1.0
    """weight of planar velocity tracking"""
    w_z: float = 1.0
    """weight of the height-holding task"""
    w_rot: float = 0.05
    """weight of the verticality task (rad/s vs m/s)"""
    k_z: float = 20.0
    """height error feedback gain (1/s)"""
    k_rot: float = 20.0
    """tilt error feedback gain (1/s)"""
    damping: float = 1e-4
    """Tikhonov damping on joint velocities"""
    max_servo_lead_rad: float = 0.1
    """servo targets stay within this of the measured joint angles"""


class PusherIK:
    """Tracks a planar pusher velocity with an arm of ``len(qpos_adr)`` joints.

    Args:
        model: the MuJoCo model.
        joint_ids: the arm's hinge joints, base to pusher.
        site_id: the pusher tip site (its z axis is the pusher's axis).
        height_m: pusher tip height to hold.
        joint_limits: (n,2) position limits.
        speed_limit: joint velocity bound (rad/s).
        dt: controller period (s).
        weights: QP weights and gains.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        *,
        joint_ids: np.ndarray,
        site_id: int,
        height_m: float,
        joint_limits: np.ndarray,
        speed_limit: float,
        dt: float,
        weights: IKWeights = IKWeights(),
    ):
        self.model = model
        self.site_id = site_id
        self.height_m = height_m
        self.q_min, self.q_max = joint_limits[:, 0].copy(), joint_limits[:, 1].copy()
        self.speed_limit = speed_limit
        self.dt = dt
        self.w = weights
        self.qpos_adr = model.jnt_qposadr[joint_ids]
        self.dof_adr = model.jnt_dofadr[joint_ids]
        self.n = len(joint_ids)
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._J = np.zeros((5, self.n))
        self._b = np.zeros(5)
        self._damping = weights.damping * np.eye(self.n)
        self._sqrt_w = np.sqrt(
            [weights.w_xy, weights.w_xy, weights.w_z, weights.w_rot, weights.w_rot]
        )
        triu = sp.triu(np.ones((self.n, self.n)), format="csc")
        self._triu_rows, self._triu_cols = triu.nonzero()
        order = np.lexsort((self._triu_rows, self._triu_cols))  # CSC order: by column, then row
        self._triu_rows, self._triu_cols = self._triu_rows[order], self._triu_cols[order]
        self._qp = osqp.OSQP()
        self._qp.setup(
            sp.csc_matrix(triu), np.zeros(self.n), sp.identity(self.n, format="csc"),
            -np.full(self.n, speed_limit), np.full(self.n, speed_limit),
            verbose=False, warm_starting=True, polishing=False, eps_abs=1e-7, eps_rel=1e-7,
            max_iter=400,
        )  # fmt: skip
        self.failures = 0
        self.solves = 0

    def joint_velocities(self, data: mujoco.MjData, v_des_xy: np.ndarray) -> np.ndarray:
        """Joint velocities ``(n,)`` that realise ``v_des_xy`` (m/s) while holding height and
        verticality; zeros (counted in ``failures``) if the QP is not solved."""
        mujoco.mj_jacSite(self.model, data, self._jacp, self._jacr, self.site_id)
        J = self._J
        J[:3] = self._jacp[:, self.dof_adr]
        J[3:] = self._jacr[:2, self.dof_adr]
        axis = data.site_xmat[self.site_id, 2::3]  # the pusher's axis (site z) in the world
        e_z = self.height_m - data.site_xpos[self.site_id, 2]
        b = self._b
        # tilt = axis x e_z_world: the rotation taking the axis to vertical (x, y components)
        b[:] = (
            v_des_xy[0],
            v_des_xy[1],
            self.w.k_z * e_z,
            self.w.k_rot * axis[1],
            -self.w.k_rot * axis[0],
        )
        Jw, bw = J * self._sqrt_w[:, None], b * self._sqrt_w
        P = Jw.T @ Jw + self._damping
        q = -(Jw.T @ bw)
        q_now = data.qpos[self.qpos_adr]
        lo = np.minimum(
            np.maximum((self.q_min - q_now) / self.dt, -self.speed_limit), self.speed_limit
        )
        hi = np.minimum(
            np.maximum((self.q_max - q_now) / self.dt, -self.speed_limit), self.speed_limit
        )
        lo = np.minimum(lo, hi)
        self._qp.update(Px=P[self._triu_rows, self._triu_cols], q=q, l=lo, u=hi)
        result = self._qp.solve(raise_error=False)
        self.solves += 1
        solved = result.info.status_val == osqp.SolverStatus.OSQP_SOLVED
        if not solved or not np.all(np.isfinite(result.x)):
            self.failures += 1
            return np.zeros(self.n)
        return np.minimum(np.maximum(result.x, lo), hi)

    def servo_targets(
        self, data: mujoco.MjData, q_ref: np.ndarray, v_des_xy: np.ndarray
    ) -> np.ndarray:
        """Next joint servo targets: ``q_ref`` advanced by one tick of the IK solution, kept
        within the joint limits and near the measured angles (no wind-up when blocked)."""
        qd = self.joint_velocities(data, v_des_xy)
        q_now = data.qpos[self.qpos_adr]
        lead = self.w.max_servo_lead_rad
        q_next = np.clip(q_ref + qd * self.dt, q_now - lead, q_now + lead)
        return np.clip(q_next, self.q_min, self.q_max)


def _arm_geometry(scenario: Scenario) -> tuple[float, float, float]:
    """The links' lengths and how far the wrist sits below the shoulder (m)."""
    a = scenario.arm
    l1, l2 = a.link_lengths_m
    return l1, l2, a.shoulder_height_m - (a.pusher_clearance_m + a.pusher_length_m)


def planar_arm_reach(scenario: Scenario, xy_m: np.ndarray) -> np.ndarray:
    """Joint angles (..., 4) that put the pusher tip at each of ``xy_m`` (..., 2) at its working
    height, vertical, elbow up; a point out of reach gets the angles of the nearest reachable
    point on its line from the base (the elbow straight or folded)."""
    a = scenario.arm
    l1, l2, down = _arm_geometry(scenario)
    dx, dy = xy_m[..., 0] - a.base_xy_m[0], xy_m[..., 1] - a.base_xy_m[1]
    # the reach along the line: at the working height the arm spans |l1 - l2| to l1 + l2 from
    # the shoulder, so r outside it is clipped (else the tip rose above the working height)
    r_min = np.sqrt(max((l1 - l2) ** 2 - down * down, 0.0))
    r = np.clip(np.hypot(dx, dy), r_min, np.sqrt((l1 + l2) ** 2 - down * down))
    c2 = np.clip((r * r + down * down - l1 * l1 - l2 * l2) / (2 * l1 * l2), -1.0, 1.0)
    p2 = np.arccos(c2)
    p1 = np.arctan2(down, r) - np.arctan2(l2 * np.sin(p2), l1 + l2 * np.cos(p2))
    return np.stack([np.arctan2(dy, dx), p1, p2, -(p1 + p2)], -1)


def planar_arm_xy(scenario: Scenario, q: np.ndarray) -> np.ndarray:
    """(..., 2) where the pusher tip is over the table with the arm at ``q`` (..., 4), its
    pusher vertical: the inverse of :func:`planar_arm_reach`."""
    a = scenario.arm
    l1, l2, _ = _arm_geometry(scenario)
    r = l1 * np.cos(q[..., 1]) + l2 * np.cos(q[..., 1] + q[..., 2])
    return np.stack([a.base_xy_m[0] + r * np.cos(q[..., 0]),
                     a.base_xy_m[1] + r * np.sin(q[..., 0])], -1)  # fmt: skip


def planar_arm_ik(scenario: Scenario, xy_m: tuple[float, float] | np.ndarray) -> np.ndarray:
    """Joint angles (4,) that put the pusher tip at ``xy_m`` at its working height, vertical,
    elbow up.

    Raises:
        InputError: the point is out of reach (a scenario's ``arm.start_xy_m``, or a region
            the arm cannot cover).
    """
    a = scenario.arm
    l1, l2, down = _arm_geometry(scenario)
    dx, dy = xy_m[0] - a.base_xy_m[0], xy_m[1] - a.base_xy_m[1]
    r = math.hypot(dx, dy)
    c2 = (r * r + down * down - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    if not -1.0 <= c2 <= 1.0:
        lo = math.sqrt(max((l1 - l2) ** 2 - down**2, 0.0))
        hi = math.sqrt(max((l1 + l2) ** 2 - down**2, 0.0))
        raise InputError(
            f"scenario {scenario.name}: pusher position {tuple(map(float, xy_m))} is out of the "
            f"arm's reach ({lo:.3f}-{hi:.3f} m from arm.base_xy_m {tuple(a.base_xy_m)}, it is "
            f"{r:.3f} m); move arm.start_xy_m or objects.region_m within it"
        )
    # scalar math, not planar_arm_reach's numpy: the episodes' start poses keep their last bits
    p2 = math.acos(c2)
    p1 = math.atan2(down, r) - math.atan2(l2 * math.sin(p2), l1 + l2 * math.cos(p2))
    return np.array([math.atan2(dy, dx), p1, p2, -(p1 + p2)])
