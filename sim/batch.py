"""Many candidate pushes simulated at once, in C (``mujoco.rollout``): the oracle's fast path.

``PushWorld.advance`` runs the arm's differential-IK controller in Python, an OSQP solve every
controller tick, so simulating a batch of candidate plans one control step at a time costs
about 2.6 ms a step. Here the controller is replaced by what it tracks: the pusher's exact
path, integrated from the commanded velocities tick by tick from where the servos point now,
turned into joint servo targets by the arm's closed-form inverse kinematics
(:func:`sim.controller.planar_arm_reach`). Those targets are open-loop controls, so every
candidate runs in one ``mujoco.rollout`` call on the world's own model (its arm, servos,
objects, contacts and timestep).

What differs from ``advance``: the controller's QP holds the pusher's height and verticality
by feedback and keeps the servo targets within ``max_servo_lead_rad`` of the measured angles,
so a blocked pusher's servos do not wind up; the closed-form targets have neither. In free
motion the pusher lands within a fraction of a millimetre of where the controller takes it,
and a pushed object within about a millimetre, what a nudge of the servos by 0.1 mrad does
to the simulator itself (tests/sim/test_batch.py); a pusher held against a heavy object
pushes harder here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from sim.controller import planar_arm_reach, planar_arm_xy

if TYPE_CHECKING:
    from sim.world import PushWorld

STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


def ticks_per_step(world: PushWorld) -> int:
    """Controller ticks in a control step: ``advance`` ticks at every ``ctrl_every``-th
    physics step of each control step, the first included."""
    return -(-world.n_substeps // world.ctrl_every)


def servo_targets(world: PushWorld, actions: np.ndarray) -> np.ndarray:
    """(K, H * ticks, 4) the joint servo targets at each controller tick of plans ``actions``
    (K,H,2) (pusher velocities, m/s): the pusher's reference point, where the servos point now,
    moved by each tick's commanded velocity, through the arm's closed-form IK, kept inside the
    joint limits (as the controller keeps them)."""
    s = world.scenario
    dt = world.ctrl_every * s.action.physics_dt_s
    start = planar_arm_xy(s, world.servo_reference())
    v = np.repeat(actions, ticks_per_step(world), axis=1)  # (K, H * ticks, 2)
    path = start + np.cumsum(v * dt, axis=1)  # the reference after each tick
    q = planar_arm_reach(s, path)
    lo, hi = np.array(s.arm.joint_limits_rad).T
    return np.clip(q, lo, hi)


def simulate_plans(world: PushWorld, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every object's planar pose (K,H,n,3) and the pusher tip's position (K,H,2) after each
    step of plans ``actions`` (K,H,2), each simulated from the world's current state; the world
    is not touched. A candidate whose episode ends (an object off the table, or unstable) keeps
    its poses from the step it ended at, as ``advance`` would leave them.

    Raises:
        ValueError: the world's episode has already ended.
    """
    if world.ended:
        raise ValueError("the oracle cannot plan from a world whose episode ended")
    m, d = world.model, world.data
    K, H, _ = actions.shape
    every = world.n_substeps
    # the target each physics step holds: its control step's latest tick's
    sub = np.arange(every)
    tick = np.arange(H)[:, None] * ticks_per_step(world) + sub[None] // world.ctrl_every
    ctrl = servo_targets(world, actions)[:, tick.ravel()]  # (K, H * every, 4)
    start = np.empty(mujoco.mj_stateSize(m, STATE))
    mujoco.mj_getState(m, d, start, STATE)
    states, _ = mj_rollout.rollout(
        m, world.scratch(), start[None], ctrl, initial_warmstart=d.qacc_warmstart[None]
    )
    ends = states[:, every - 1 :: every]  # (K,H,nstate): after each control step
    # the state vector is time, qpos, qvel, act, ... (mjSTATE_FULLPHYSICS)
    qpos = ends[..., 1 : 1 + m.nq]
    qvel = ends[..., 1 + m.nq : 1 + m.nq + m.nv]
    poses, pusher = world.plan_readout(qpos)
    ended = world.end_codes(qpos, qvel) > 0  # (K,H)
    first = np.where(ended.any(1), ended.argmax(1), H)  # the step each candidate ended at
    after = np.arange(H)[None] > first[:, None]  # (K,H) steps after the end
    idx = np.where(after, first[:, None], np.arange(H)[None])
    poses = np.take_along_axis(poses, idx[:, :, None, None], axis=1)
    pusher = np.take_along_axis(pusher, idx[:, :, None], axis=1)
    return poses, pusher
