"""Ray-cast depth camera: organised clouds, segmentation and exact point associations.

Camera frame (OpenCV): x right, y down, z along the optical axis; pixel (v, u) looks through
its centre ``(u + 0.5, v + 0.5)``. Rendering casts one ray per pixel with
``mujoco.mj_multiRay`` against the geoms of group 0: no OpenGL, headless, CPU.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from scenarios import CameraConfig, InputError
from sim.mjcf import CAMERA_GROUP


def look_at(position_m: np.ndarray, target_m: np.ndarray) -> np.ndarray:
    """Camera pose ``T_world_cam (4,4)`` at ``position_m`` looking at ``target_m``, image y
    pointing as close to world -z as the view allows."""
    position_m, target_m = np.asarray(position_m, float), np.asarray(target_m, float)
    z = target_m - position_m
    norm = np.linalg.norm(z)
    if norm < 1e-9:
        raise InputError(
            "camera position_m and target_m coincide; move the target (camera.target_m)"
        )
    z /= norm
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-6:  # looking straight up or down: image x along world -y
        x = np.array([0.0, -1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, position_m
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(...,4,4)``."""
    R, t = T[..., :3, :3], T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


@dataclass(frozen=True)
class Frame:
    """One rendered frame."""

    points_cam: np.ndarray
    """(3,H,W) float64, metres, camera frame; zero where ``valid`` is False."""
    valid: np.ndarray
    """(H,W) bool: the pixel's ray hit a geom within ``max_depth_m``."""
    geom_id: np.ndarray
    """(H,W) int32: the geom each ray hit, -1 for none."""

    @property
    def depth_m(self) -> np.ndarray:
        """(H,W) depth along the optical axis; zero where invalid."""
        return self.points_cam[2]


class DepthCamera:
    """A fixed pinhole depth camera rendered by ray casting.

    Args:
        cfg: pose, field of view, resolution and range from the scenario.
        width, height: override the scenario's resolution (the field of view is kept).
    """

    def __init__(self, cfg: CameraConfig, *, width: int | None = None, height: int | None = None):
        self.width = width or cfg.width
        self.height = height or cfg.height
        self.max_depth_m = cfg.max_depth_m
        self.T_world_cam = look_at(np.array(cfg.position_m), np.array(cfg.target_m))
        self.T_cam_world = invert(self.T_world_cam)
        self.K = intrinsics(cfg, self.width, self.height)
        f = self.K[0, 0]
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        rays = np.stack(
            [(u + 0.5 - self.K[0, 2]) / f, (v + 0.5 - self.K[1, 2]) / f, np.ones(u.shape)], -1
        ).reshape(-1, 3)
        self._rays_cam = rays / np.linalg.norm(rays, axis=1, keepdims=True)  # (N,3) unit
        self._rays_world = np.ascontiguousarray(self._rays_cam @ self.T_world_cam[:3, :3].T)
        self._origin = np.ascontiguousarray(self.T_world_cam[:3, 3])
        n = self.width * self.height
        self._geom = np.empty(n, np.int32)
        self._dist = np.empty(n, np.float64)
        self._groups = np.zeros(6, np.uint8)
        self._groups[CAMERA_GROUP] = 1

    def render(self, model: mujoco.MjModel, data: mujoco.MjData) -> Frame:
        """Cast every pixel's ray into the scene (``data`` must have current kinematics)."""
        n = self.width * self.height
        mujoco.mj_multiRay(
            model, data, self._origin, self._rays_world.reshape(-1), self._groups, 1, -1,
            self._geom, self._dist, None, n, self.max_depth_m,
        )  # fmt: skip
        # mj_multiRay's cutoff only skips geoms whose bounds lie beyond it: a hit beyond
        # max_depth_m on a nearer geom comes back too, and counts as nothing here
        beyond = self._dist > self.max_depth_m
        self._geom[beyond] = -1
        valid = self._geom >= 0
        dist = np.where(valid, self._dist, 0.0)
        points = (self._rays_cam * dist[:, None]).T.reshape(3, self.height, self.width)
        return Frame(
            points_cam=points,
            valid=valid.reshape(self.height, self.width),
            geom_id=self._geom.reshape(self.height, self.width).copy(),
        )

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates ``(...,2)`` (u, v; continuous) of camera-frame points ``(...,3)``."""
        z = points_cam[..., 2:3]
        uv = points_cam[..., :2] / np.where(np.abs(z) < 1e-12, 1e-12, z)
        return uv * self.K[0, 0] + self.K[:2, 2]


def intrinsics(cfg: CameraConfig, width: int, height: int) -> np.ndarray:
    """(3,3) the pinhole matrix of a ``width`` x ``height`` image with the scenario's vertical
    field of view (square pixels, principal point at the image centre)."""
    f = 0.5 * height / np.tan(np.deg2rad(cfg.fovy_deg) / 2)
    return np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])


def transform_by_part(points: np.ndarray, part: np.ndarray, T_part: np.ndarray) -> np.ndarray:
    """Apply to each pixel's point the transform of the part it sees.

    Args:
        points: (3,H,W) points.
        part: (H,W) int part index of each pixel; < 0 where nothing was hit.
        T_part: (P,4,4) one rigid transform per part.

    Returns:
        (3,H,W) ``T_part[part_j] · points_j``; zero where ``part < 0``.
    """
    idx = np.clip(part, 0, None)
    R, t = T_part[idx, :3, :3], T_part[idx, :3, 3]  # (H,W,3,3), (H,W,3)
    out = np.einsum("hwij,jhw->hwi", R, points) + t
    out[part < 0] = 0.0
    return np.moveaxis(out, -1, 0)


def associated_targets(
    points_part: np.ndarray, part: np.ndarray, T_world_part: np.ndarray, T_cam_world: np.ndarray
) -> np.ndarray:
    """Exact targets of every pixel: ``T_cam_world · T_world_part[part_j] · p_part_j``.

    This is the paper's point-wise data association given by the simulator: with the parts'
    poses at t + h, it gives where each point seen at t has moved to, in the camera frame.

    Args:
        points_part: (3,H,W) each pixel's point in the frame of the part it hit.
        part: (H,W) int, the part index of each pixel; < 0 where nothing was hit.
        T_world_part: (P,4,4) poses of the parts at the target time.
        T_cam_world: (4,4) the camera's extrinsics.

    Returns:
        (3,H,W) targets in the camera frame; zero where ``part < 0``.
    """
    return transform_by_part(points_part, part, T_cam_world @ T_world_part)
