"""The MuJoCo push world: scenario -> MJCF, arm controller, ray-cast depth camera."""

from sim.camera import DepthCamera, associated_targets, look_at
from sim.mjcf import ObjectSpec, build_mjcf
from sim.world import ActionError, EpisodeEnded, Observation, PushWorld

__all__ = [
    "ActionError",
    "DepthCamera",
    "EpisodeEnded",
    "ObjectSpec",
    "Observation",
    "PushWorld",
    "associated_targets",
    "build_mjcf",
    "look_at",
]
