"""Frozen dataclasses that describe a scenario: the world, its camera, its noise and its goals.

Every field carries a one-line doc and its valid range in ``metadata``; ``scenarios.loader``
checks a TOML file against them. Units are in the field names (``_m``, ``_deg``, ``_s``).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import MISSING, dataclass, field
from typing import Any

Pair = tuple[float, float]


def spec(doc: str, *, default: Any = MISSING, **limits: Any) -> Any:
    """A dataclass field with its doc and limits.

    Args:
        doc: one line saying what the field means.
        default: the value a scenario file (or a stored scenario from before the field
            existed) that leaves it out gets; without one the field is required.
        limits: any of ``ge``, ``gt``, ``le`` (bounds on every number in the value),
            ``ordered`` (a ``[lo, hi]`` pair or list of pairs must have lo <= hi),
            ``choices`` (allowed strings), ``min_len``.
    """
    return field(default=default, metadata={"doc": doc, **limits})


@dataclass(frozen=True)
class TableConfig:
    size_m: tuple[float, float] = spec("table top extent along world x and y", gt=0)
    thickness_m: float = spec("table top thickness (its top face is the plane z = 0)", gt=0)
    friction: float = spec("sliding friction coefficient of the table top", gt=0)


@dataclass(frozen=True)
class ArmConfig:
    base_xy_m: tuple[float, float] = spec("base yaw joint position in the world frame")
    shoulder_height_m: float = spec("height of the first pitch joint above the table", gt=0)
    link_lengths_m: tuple[float, float] = spec("upper arm and forearm lengths", gt=0)
    pusher_length_m: float = spec("length of the vertical cylindrical pusher", gt=0)
    pusher_radius_m: float = spec("radius of the pusher", gt=0)
    pusher_clearance_m: float = spec("gap between the pusher tip and the table", gt=0, le=0.02)
    start_xy_m: tuple[float, float] = spec("pusher position at reset, world frame")
    joint_limits_rad: tuple[Pair, Pair, Pair, Pair] = spec(
        "[lo, hi] for base yaw, pitch 1, pitch 2, pitch 3", ordered=True
    )
    joint_speed_limit_rad_s: float = spec("joint velocity bound used by the IK controller", gt=0)
    kp: float = spec("position gain of the joint servos (N m / rad)", gt=0)
    kv: float = spec("velocity gain of the joint servos (N m s / rad)", ge=0)
    controller_rate_hz: float = spec("rate at which the differential-IK QP is solved", gt=0)
    link_radii_m: tuple[float, float] = spec(
        "radii of the upper arm's and the forearm's capsules", gt=0, default=(0.018, 0.015)
    )
    links_visible: bool = spec(
        "the depth camera sees the arm's links, each its own part (else it sees only the "
        "pusher, as the paper's box data showed only the mover); only in a scenario without "
        "objects",
        default=False,
    )


@dataclass(frozen=True)
class CameraConfig:
    position_m: tuple[float, float, float] = spec("camera centre, world frame")
    target_m: tuple[float, float, float] = spec("point the optical axis passes through")
    fovy_deg: float = spec("vertical field of view", gt=1, le=150)
    width: int = spec("image width in pixels", ge=8, le=1024)
    height: int = spec("image height in pixels", ge=8, le=1024)
    max_depth_m: float = spec("rays longer than this hit nothing", gt=0)


@dataclass(frozen=True)
class ObjectsConfig:
    count: tuple[int, int] = spec(
        "[min, max] number of objects (0: none, only with 'joints' controls)",
        ge=0, le=3, ordered=True,
    )  # fmt: skip
    shapes: tuple[str, ...] = spec(
        "shapes to draw from (sim.shapes)",
        choices=("box", "cylinder", "capsule", "hull", "L", "T"),
        min_len=1,
    )
    box_size_m: tuple[Pair, Pair, Pair] = spec(
        "[lo, hi] full extents of a box along x, y, z", gt=0, ordered=True
    )
    cylinder_radius_m: tuple[float, float] = spec("[lo, hi] cylinder radius", gt=0, ordered=True)
    cylinder_height_m: tuple[float, float] = spec("[lo, hi] cylinder height", gt=0, ordered=True)
    mass_kg: tuple[float, float] = spec("[lo, hi] object mass", gt=0, ordered=True)
    friction: tuple[float, float] = spec("[lo, hi] sliding friction", gt=0, ordered=True)
    region_m: tuple[float, float, float, float] = spec(
        "[x_min, x_max, y_min, y_max] where object centres are placed at reset"
    )
    min_gap_m: float = spec("clearance between objects, and to the pusher, at reset", ge=0)
    capsule_size_m: tuple[Pair, Pair, Pair] = spec(
        "[lo, hi] length, width and height of a capsule (a stadium puck; width <= length)",
        gt=0, ordered=True, default=((0.08, 0.08), (0.04, 0.04), (0.05, 0.05)),
    )  # fmt: skip
    hull_size_m: tuple[Pair, Pair, Pair] = spec(
        "[lo, hi] x, y extents of the rectangle a hull's points are drawn in, and its height",
        gt=0, ordered=True, default=((0.07, 0.07), (0.06, 0.06), (0.05, 0.05)),
    )  # fmt: skip
    bar_size_m: tuple[Pair, Pair, Pair] = spec(
        "[lo, hi] full extents of an L or T shape along x, y, z",
        gt=0, ordered=True, default=((0.08, 0.08), (0.08, 0.08), (0.05, 0.05)),
    )  # fmt: skip
    bar_width_m: tuple[float, float] = spec(
        "[lo, hi] width of the two bars of an L or T shape (at most its x and y extents)",
        gt=0, ordered=True, default=(0.03, 0.03),
    )  # fmt: skip


CONTROLS = ("pusher", "joints")
"""what an action commands: the pusher's planar velocity, or the arm's joint velocities"""


@dataclass(frozen=True)
class ActionConfig:
    max_speed_m_s: float = spec("bound on each of vx, vy of the pusher", gt=0, le=1.0)
    dt_control_s: float = spec("how long one action is held (the paper's 0.15 s)", gt=0)
    physics_dt_s: float = spec("MuJoCo timestep", gt=0, le=0.01)
    controls: str = spec(
        "what an action commands: 'pusher' (its planar velocity vx, vy, through the IK "
        "controller) or 'joints' (the velocities of the arm's 4 joints, the paper's Baxter data)",
        choices=CONTROLS, default="pusher",
    )  # fmt: skip
    max_joint_speed_rad_s: float = spec(
        "bound on each commanded joint velocity ('joints' controls)", gt=0, default=0.5
    )


@dataclass(frozen=True)
class NoiseConfig:
    depth_sd_m: float = spec("SD of Gaussian depth noise (0 = off)", ge=0)
    depth_sd_scaled: bool = spec("scale the depth noise SD by the depth in metres")
    assoc_window: int = spec("association noise window m (m x m pixels; 0 = off)", ge=0)
    assoc_depth_threshold_m: float = spec("window targets must lie within this depth", gt=0)


@dataclass(frozen=True)
class GoalsConfig:
    region_m: tuple[float, float, float, float] = spec(
        "[x_min, x_max, y_min, y_max] where goal positions are drawn"
    )
    min_distance_m: float = spec("a goal is at least this far from the start ...", ge=0)
    min_yaw_deg: float = spec("... or turned at least this much", ge=0, le=180)
    max_distance_m: float = spec("and at most this far from the start", gt=0)


@dataclass(frozen=True)
class Scenario:
    name: str = spec("identifier, the file's stem")
    description: str = spec("one line for `se3push scenarios`")
    table: TableConfig = spec("the table")
    arm: ArmConfig = spec("the 4-joint arm and its pusher")
    camera: CameraConfig = spec("the fixed depth camera")
    objects: ObjectsConfig = spec("the free objects")
    action: ActionConfig = spec("action bounds and timing")
    noise: NoiseConfig = spec("sensor noise applied when data is read")
    goals: GoalsConfig = spec("goal distribution for trials")


def _without_defaults(obj: Any) -> Any:
    """A (nested) config as a dict, less the fields with a default that hold it."""
    if not dataclasses.is_dataclass(obj):
        return obj
    out = {}
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if f.default is not MISSING and value == f.default:
            continue
        out[f.name] = _without_defaults(value)
    return out


def scenario_dict(scenario: Scenario) -> dict[str, Any]:
    """The scenario as JSON types, as manifests and checkpoints store it. Fields with a
    default that hold it are left out, so a scenario that does not use a setting added later
    is stored as it was before the setting existed (same dataset identity, same hash);
    ``scenario_from_dict`` fills them in again."""
    return json.loads(json.dumps(_without_defaults(scenario)))


def scenario_fingerprint(scenario: Scenario) -> dict[str, Any]:
    """What a learned model depends on in a scenario: what it sees and how actions act (its
    objects may differ: a model trained on several scenarios of one fingerprint serves all).
    Settings added later are left out where they hold their default, as in ``scenario_dict``,
    so the checkpoints written before them still fit."""
    return json.loads(
        json.dumps(
            {
                "camera": _without_defaults(scenario.camera),
                "action": _without_defaults(scenario.action),
            }
        )  # fmt: skip
    )


def differences(
    old: Any,
    new: Any,
    *,
    old_has: str = "folder has",
    new_has: str = "this run asks for",
    path: str = "",
) -> list[str]:
    """Where two (nested) JSON-like configurations differ, one ``"dotted.key: <old_has> X,
    <new_has> Y"`` line each: the shared wording of every "this is not the same run" error."""
    if isinstance(old, dict) and isinstance(new, dict):
        return [
            d
            for k in [*new, *(k for k in old if k not in new)]  # in the new config's order
            for d in differences(
                old.get(k),
                new.get(k),
                old_has=old_has,
                new_has=new_has,
                path=f"{path}.{k}".lstrip("."),
            )  # fmt: skip
        ]
    return [] if old == new else [f"{path}: {old_has} {old!r}, {new_has} {new!r}"]
