"""MJCF for a scenario: table, 4-joint pushing arm, free objects.

The model is generated from the scenario and the objects drawn for one episode; nothing is
hand-edited per case. Geom group 0 holds what the depth camera sees (table, pusher, objects);
the arm's links are in group 1, drawn by the visualiser but hidden from the camera, as the
paper's box data showed only the mover and the objects, unless the scenario has
``arm.links_visible`` (the paper's Baxter data: the arm's links in view).

Collision bits: the table collides with objects; the pusher collides with objects only (it
floats a few mm above the table); the arm's links collide with nothing.
"""

from __future__ import annotations

from scenarios import Scenario
from sim.shapes import ObjectSpec, mjcf_numbers

ARM_JOINTS = ("yaw", "pitch1", "pitch2", "pitch3")
PUSHER_BODY = "pusher"
PUSHER_SITE = "pusher_tip"
ARM_LINK_BODIES = ("arm_base", "link1", "link2")
"""the arm's bodies before the pusher, from the base: each turns with one joint (base yaw,
pitch 1, pitch 2; the pusher body turns with pitch 3)"""
CAMERA_GROUP = 0
ARM_GROUP = 1


def object_body(i: int) -> str:
    return f"object{i}"


def build_mjcf(scenario: Scenario, objects: list[ObjectSpec]) -> str:
    """MJCF text for the scenario with the given objects (placed at the origin; the world
    sets their poses after loading).
    """
    t, a = scenario.table, scenario.arm
    l1, l2 = a.link_lengths_m
    r1, r2 = a.link_radii_m
    lp = a.pusher_length_m
    gains = f'kp="{a.kp:.6g}" kv="{a.kv:.6g}"'
    joints = [
        f'<joint name="{n}" type="hinge" axis="{ax}" range="{mjcf_numbers(*rng)}" damping="0.05" '
        f'armature="0.01" limited="true"/>'
        for n, ax, rng in zip(
            ARM_JOINTS, ("0 0 1", "0 1 0", "0 1 0", "0 1 0"), a.joint_limits_rad, strict=True
        )
    ]
    group = CAMERA_GROUP if a.links_visible else ARM_GROUP
    link = f'contype="0" conaffinity="0" group="{group}" rgba="0.55 0.57 0.6 1"'
    table_size = mjcf_numbers(t.size_m[0] / 2, t.size_m[1] / 2, t.thickness_m / 2)
    bodies, assets = [], []
    for i, obj in enumerate(objects):
        asset, geoms = obj.mjcf(
            object_body(i),
            f'friction="{obj.friction:.6g} 0.005 0.0001" contype="3" conaffinity="3" '
            f'group="{CAMERA_GROUP}" rgba="0.85 0.45 0.2 1"',
        )
        assets.append(asset)
        bodies.append(
            f'<body name="{object_body(i)}" pos="0 0 {obj.size_m[2] / 2:.6g}">'
            f'<freejoint name="{object_body(i)}"/>{geoms}</body>'
        )
    return f"""<mujoco model="se3push_{scenario.name}">
  <compiler angle="radian"/>
  <option timestep="{scenario.action.physics_dt_s:.6g}" integrator="implicitfast"/>
  <asset>{"".join(assets)}</asset>
  <worldbody>
    <geom name="table" type="box" size="{table_size}"
          pos="0 0 {-t.thickness_m / 2:.6g}" friction="{t.friction:.6g} 0.005 0.0001"
          contype="1" conaffinity="1" group="{CAMERA_GROUP}" rgba="0.75 0.7 0.6 1"/>
    <body name="{ARM_LINK_BODIES[0]}" pos="{mjcf_numbers(*a.base_xy_m, 0.0)}">
      {joints[0]}
      <geom type="cylinder" fromto="0 0 0 0 0 {a.shoulder_height_m:.6g}" size="0.03" mass="1"
            {link}/>
      <body name="{ARM_LINK_BODIES[1]}" pos="0 0 {a.shoulder_height_m:.6g}" gravcomp="1">
        {joints[1]}
        <geom type="capsule" fromto="0 0 0 {l1:.6g} 0 0" size="{r1:.6g}" mass="0.3" {link}/>
        <body name="{ARM_LINK_BODIES[2]}" pos="{l1:.6g} 0 0" gravcomp="1">
          {joints[2]}
          <geom type="capsule" fromto="0 0 0 {l2:.6g} 0 0" size="{r2:.6g}" mass="0.2" {link}/>
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
