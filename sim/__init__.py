"""The MuJoCo push world: scenario -> MJCF, arm controller, ray-cast depth camera."""

from sim.camera import DepthCamera, associated_targets, look_at
from sim.mjcf import build_mjcf
from sim.planar import pose_errors, wrap_angle
from sim.shapes import SHAPES, ObjectSpec
from sim.world import ActionError, EpisodeEnded, Observation, PushWorld, object_part

__all__ = [
    "ActionError",
    "DepthCamera",
    "EpisodeEnded",
    "ObjectSpec",
    "SHAPES",
    "Observation",
    "PushWorld",
    "associated_targets",
    "build_mjcf",
    "look_at",
    "object_part",
    "pose_errors",
    "wrap_angle",
]
