"""MJCF for a scenario: table, 4-joint pushing arm, free objects.

The model is generated from the scenario and the objects drawn for one episode; nothing is
hand-edited per case. Geom group 0 holds what the depth camera sees (table, pusher, objects);
the arm's links are in group 1, drawn by the visualiser but hidden from the camera, as the
paper's box data showed only the mover and the objects.

Collision bits: the table collides with objects; the pusher collides with objects only (it
floats a few mm above the table); the arm's links collide with nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scenarios import Scenario

ARM_JOINTS = ("yaw", "pitch1", "pitch2", "pitch3")
PUSHER_BODY = "pusher"
PUSHER_SITE = "pusher_tip"
CAMERA_GROUP = 0
ARM_GROUP = 1


@dataclass(frozen=True)
class ObjectSpec:
    """One free object drawn for an episode."""

    shape: str
    """``"box"`` or ``"cylinder"``."""
    size_m: tuple[float, float, float]
    """Full extents along the object's x, y, z (a cylinder: 2r, 2r, height)."""
    mass_kg: float
    friction: float

    def distance_to_footprint_m(self, xy_obj: np.ndarray) -> float:
        """Distance from a point ``(2,)`` in the object's frame to its footprint (0 inside)."""
        if self.shape == "box":
            gap = np.abs(xy_obj) - np.array(self.size_m[:2]) / 2
            return float(np.linalg.norm(np.maximum(gap, 0.0)))
        return max(0.0, float(np.linalg.norm(xy_obj)) - self.size_m[0] / 2)

    @property
    def footprint_radius_m(self) -> float:
        """Radius of the circle that holds the object's footprint in any yaw."""
        return 0.5 * math.hypot(self.size_m[0], self.size_m[1])

    @property
    def yaw_period_rad(self) -> float | None:
        """The turn after which the object looks the same: π for a box, π/2 for a box with a
        square footprint, None for a cylinder (any turn)."""
        if self.shape == "cylinder":
            return None
        sx, sy, _ = self.size_m
        return math.pi / 2 if abs(sx - sy) < 1e-3 else math.pi


def object_body(i: int) -> str:
    return f"object{i}"


def _v(*xs: float) -> str:
    return " ".join(f"{x:.6g}" for x in xs)


def build_mjcf(scenario: Scenario, objects: list[ObjectSpec]) -> str:
    """MJCF text for the scenario with the given objects (placed at the origin; the world
    sets their poses after loading).
    """
    t, a = scenario.table, scenario.arm
    l1, l2 = a.link_lengths_m
    lp = a.pusher_length_m
    gains = f'kp="{a.kp:.6g}" kv="{a.kv:.6g}"'
    joints = [
        f'<joint name="{n}" type="hinge" axis="{ax}" range="{_v(*rng)}" damping="0.05" '
        f'armature="0.01" limited="true"/>'
        for n, ax, rng in zip(
            ARM_JOINTS, ("0 0 1", "0 1 0", "0 1 0", "0 1 0"), a.joint_limits_rad, strict=True
        )
    ]
    link = f'contype="0" conaffinity="0" group="{ARM_GROUP}" rgba="0.55 0.57 0.6 1"'
    bodies = []
    for i, obj in enumerate(objects):
        sx, sy, sz = obj.size_m
        if obj.shape == "box":
            geom = f'type="box" size="{_v(sx / 2, sy / 2, sz / 2)}"'
        else:
            geom = f'type="cylinder" size="{_v(sx / 2, sz / 2)}"'
        bodies.append(
            f'<body name="{object_body(i)}" pos="0 0 {sz / 2:.6g}">'
            f'<freejoint name="{object_body(i)}"/>'
            f'<geom name="{object_body(i)}" {geom} mass="{obj.mass_kg:.6g}" '
            f'friction="{obj.friction:.6g} 0.005 0.0001" contype="3" conaffinity="3" '
            f'group="{CAMERA_GROUP}" rgba="0.85 0.45 0.2 1"/></body>'
        )
    return f"""<mujoco model="se3push_{scenario.name}">
  <compiler angle="radian"/>
  <option timestep="{scenario.action.physics_dt_s:.6g}" integrator="implicitfast"/>
  <worldbody>
    <geom name="table" type="box" size="{_v(t.size_m[0] / 2, t.size_m[1] / 2, t.thickness_m / 2)}"
          pos="0 0 {-t.thickness_m / 2:.6g}" friction="{t.friction:.6g} 0.005 0.0001"
          contype="1" conaffinity="1" group="{CAMERA_GROUP}" rgba="0.75 0.7 0.6 1"/>
    <body name="arm_base" pos="{_v(*a.base_xy_m, 0.0)}">
      {joints[0]}
      <geom type="cylinder" fromto="0 0 0 0 0 {a.shoulder_height_m:.6g}" size="0.03" mass="1"
            {link}/>
      <body name="link1" pos="0 0 {a.shoulder_height_m:.6g}" gravcomp="1">
        {joints[1]}
        <geom type="capsule" fromto="0 0 0 {l1:.6g} 0 0" size="0.018" mass="0.3" {link}/>
        <body name="link2" pos="{l1:.6g} 0 0" gravcomp="1">
          {joints[2]}
          <geom type="capsule" fromto="0 0 0 {l2:.6g} 0 0" size="0.015" mass="0.2" {link}/>
          <body name="{PUSHER_BODY}" pos="{l2:.6g} 0 0" gravcomp="1">
            {joints[3]}
            <geom name="pusher" type="cylinder" fromto="0 0 0 0 0 {-lp:.6g}"
                  size="{a.pusher_radius_m:.6g}" mass="0.1" friction="0.3 0.005 0.0001"
                  contype="2" conaffinity="2" group="{CAMERA_GROUP}" rgba="0.2 0.4 0.85 1"/>
            <site name="{PUSHER_SITE}" pos="0 0 {-lp:.6g}" size="0.005"/>
          </body>
        </body>
      </body>
    </body>
    {"".join(bodies)}
  </worldbody>
  <actuator>
    {"".join(f'<position joint="{n}" {gains}/>' for n in ARM_JOINTS)}
  </actuator>
</mujoco>
"""
