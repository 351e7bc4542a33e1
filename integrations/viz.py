"""Visualisers injected into the closed loop: a no-op by default, meshcat when asked for.

``MeshcatVisualiser`` shows the table, the objects, the pusher, the goal as a green ghost, the
observed cloud (coloured by the model's mask argmax when the model has masks, else by the true
parts) and, at every step, the chosen plan's predicted object poses over the horizon as orange
ghosts beside the real motion. Live (``live=True``: meshcat's server on 127.0.0.1, its URL
printed) and/or recorded (``record=PATH``: a self-contained HTML animation, one frame per step,
from ``static_html()``). meshcat is imported only here, and only when asked for.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from planner.base import PlanInfo
from scenarios import InputError
from sim.shards import atomic_write_bytes
from sim.world import Observation, PushWorld

COLOURS = np.array(
    [
        [0.55, 0.55, 0.55],
        [0.2, 0.4, 0.9],
        [0.95, 0.8, 0.1],
        [0.6, 0.2, 0.7],
        [0.1, 0.7, 0.3],
        [0.9, 0.2, 0.2],
        [0.2, 0.8, 0.8],
        [0.5, 0.4, 0.2],
    ]  # fmt: skip
)
"""cloud colours by label: a part (0 static, 1 pusher, 2+ objects) or a mask channel"""
Y_UP_TO_Z_UP = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1.0]])
"""turns meshcat's cylinders, which stand along y, to stand along z"""


VIEW_DIRECTION = np.array([0.75, -0.25, 0.75])
"""where the recording's camera looks from (world frame, toward the table's centre): above
the +x edge, a little to the side, about 45 degrees down"""
VIEW_FOV_DEG = 75.0
"""meshcat's default camera: its vertical field of view"""


def view_position(table_size_m: tuple[float, float] | list[float], *, margin: float = 1.4) -> list:
    """The position (world frame, m) of the recording's camera from which the table, of
    ``table_size_m``, fills the view with a ``margin`` around it."""
    radius = 0.5 * math.hypot(*table_size_m)  # a sphere around the table top
    distance = margin * radius / math.tan(math.radians(VIEW_FOV_DEG / 2))
    return (distance * VIEW_DIRECTION / np.linalg.norm(VIEW_DIRECTION)).tolist()


def _pose_matrix(x: float, y: float, yaw: float, z: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [x, y, z]
    return T


class MeshcatVisualiser:
    """Meshcat scene of one closed-loop push.

    Args:
        live: keep the server's page updated while the loop runs (prints the URL).
        record: write the animation as a self-contained HTML file there at the end.
    """

    def __init__(self, *, live: bool = False, record: str | Path | None = None):
        self.live, self.record = live, Path(record) if record else None
        if self.record is not None and self.record.is_dir():  # found before the push, not after
            raise InputError(f"--record {record} is a folder; give the HTML file's path")
        self.frames = 0
        self.vis: Any = None

    def start(self, world: PushWorld, obs: Observation, goal: np.ndarray, *, object_index: int = 0,
              horizon: int = 3,
              model: torch.nn.Module | None = None) -> None:  # fmt: skip
        import meshcat
        import meshcat.animation

        self.vis = meshcat.Visualizer()  # starts meshcat's server on 127.0.0.1 and prints its URL
        try:
            self.anim = meshcat.animation.Animation(
                default_framerate=1 / world.scenario.action.dt_control_s
            )
            self._scene(world, obs, goal, object_index, horizon, model)
        except BaseException:
            self._stop_server()  # the loop's finish() never runs for a start that failed
            self.vis = None
            raise

    def _scene(self, world: PushWorld, obs: Observation, goal: np.ndarray, object_index: int,
               horizon: int, model: torch.nn.Module | None) -> None:  # fmt: skip
        """The table, pusher, objects, goal, predicted ghosts and cloud, and the view."""
        import meshcat.geometry as g

        self.world, self.index, self.horizon = world, object_index, horizon
        t = world.scenario.table
        self.vis["table"].set_object(
            g.Box([*t.size_m, t.thickness_m]), g.MeshLambertMaterial(color=0xC8B89A)
        )
        self.vis["table"].set_transform(_pose_matrix(0, 0, 0, -t.thickness_m / 2))
        a = world.scenario.arm
        pusher = g.Cylinder(a.pusher_length_m, a.pusher_radius_m)
        self.vis["pusher"].set_object(pusher, g.MeshLambertMaterial(color=0x3366DD))
        for i, spec in enumerate(world.objects):
            self._object(f"objects/{i}", spec, g.MeshLambertMaterial(color=0xDD7733))
        spec = world.objects[object_index]
        self._object(
            "goal", spec, g.MeshLambertMaterial(color=0x33CC55, opacity=0.35, transparent=True)
        )
        self.vis["goal"].set_transform(self._T(goal, spec))
        for h in range(horizon):
            ghost = g.MeshLambertMaterial(
                color=0xFF9900, opacity=0.15 + 0.5 * (h + 1) / horizon, transparent=True
            )
            self._object(f"predicted/{h}", spec, ghost)
        self._cloud(obs, model)
        self._place(self.vis, obs, None)
        # the table filling the view, from the camera's side, without the floor grid and axes
        self.vis["/Grid"].set_property("visible", False)
        self.vis["/Axes"].set_property("visible", False)
        self.vis["/Cameras/default"].set_transform(np.eye(4))
        x, y, z = view_position(t.size_m)  # meshcat's camera frame is y-up: (x, z, -y)
        self.vis["/Cameras/default/rotated/<object>"].set_property("position", [x, z, -y])

    def _object(self, path: str, spec, material) -> None:
        """The object's prisms (``sim.shapes``): boxes, upright cylinders, convex meshes."""
        import meshcat.geometry as g

        sz = spec.size_m[2]
        solids = []  # (geometry, transform in the object's frame)
        for piece in spec.pieces():
            v, r = piece.array, piece.radius
            ends = v if len(v) <= 2 else []
            for end in ends:  # a disc, or the round ends of a stadium
                T = _pose_matrix(float(end[0]), float(end[1]), 0.0, 0.0) @ Y_UP_TO_Z_UP
                solids.append((g.Cylinder(sz, r), T))
            if len(v) == 2:
                d = v[1] - v[0]
                mid, yaw = (v[0] + v[1]) / 2, math.atan2(d[1], d[0])
                box = g.Box([float(np.linalg.norm(d)), 2 * r, sz])
                solids.append((box, _pose_matrix(float(mid[0]), float(mid[1]), yaw, 0.0)))
            elif len(v) >= 3:
                n = len(v)
                verts = np.array([(x, y, z) for z in (-sz / 2, sz / 2) for x, y in v])
                sides = [
                    f
                    for i in range(n)
                    for f in ((i, (i + 1) % n, n + i), ((i + 1) % n, n + (i + 1) % n, n + i))
                ]
                caps = [(0, i + 1, i) for i in range(1, n - 1)]
                caps += [(n, n + i, n + i + 1) for i in range(1, n - 1)]  # fmt: skip
                mesh = g.TriangularMeshGeometry(verts, np.array(sides + caps))
                solids.append((mesh, np.eye(4)))
        for k, (geom, T) in enumerate(solids):
            self.vis[path]["shape"][str(k)].set_object(geom, material)
            self.vis[path]["shape"][str(k)].set_transform(T)

    def _T(self, pose: np.ndarray, spec) -> np.ndarray:
        return _pose_matrix(float(pose[0]), float(pose[1]), float(pose[2]), spec.size_m[2] / 2)

    def _cloud(self, obs: Observation, model: torch.nn.Module | None) -> None:
        import meshcat.geometry as g

        labels = obs.part.astype(int)
        if model is not None and hasattr(model, "se3_head"):
            from se3net.data import subsample

            s = model.cfg.stride  # a planning-resolution network sees every s-th pixel
            dev = next(model.parameters()).device  # the planner's device (--device)
            with torch.no_grad():
                pts = subsample(torch.from_numpy(obs.points_cam).float(), s)[None].to(dev)
                valid = subsample(torch.from_numpy(obs.valid), s)[None].to(dev)
                u = torch.tensor([[0.0, 0.0, *obs.pusher_xy_m]], dtype=torch.float32, device=dev)
                masks = model(pts, u, valid).masks
            # each camera pixel coloured by the network pixel it falls in
            labels = masks[0].argmax(0).cpu().numpy().repeat(s, 0).repeat(s, 1)
        T = self.world.camera.T_world_cam
        p = (T[:3, :3] @ obs.points_cam.reshape(3, -1) + T[:3, 3:])[:, obs.valid.ravel()]
        colours = COLOURS[labels.ravel()[obs.valid.ravel()] % len(COLOURS)].T
        self.vis["cloud"].set_object(g.PointCloud(p, colours, size=0.006))

    def _place(self, target: Any, obs: Observation, info: PlanInfo | None) -> None:
        a = self.world.scenario.arm
        x, y = obs.pusher_xy_m
        target["pusher"].set_transform(
            _pose_matrix(x, y, 0, a.pusher_clearance_m + a.pusher_length_m / 2) @ Y_UP_TO_Z_UP
        )
        for i, spec in enumerate(self.world.objects):
            target[f"objects/{i}"].set_transform(self._T(obs.object_poses[i], spec))
        spec = self.world.objects[self.index]
        for h in range(self.horizon):
            pose = (
                obs.object_poses[self.index]
                if info is None
                else info.predicted_poses[min(h, len(info.predicted_poses) - 1)]
            )
            target[f"predicted/{h}"].set_transform(self._T(pose, spec))

    def step(self, obs: Observation, info: PlanInfo) -> None:
        """One frame: the real poses after the step and the plan's predicted poses."""
        with self.anim.at_frame(self.vis, self.frames) as frame:
            self._place(frame, obs, info)
        if self.live:
            self._place(self.vis, obs, info)
        self.frames += 1

    def finish(self) -> None:
        """Attach the animation, write the HTML file if asked, stop the server. A push that
        ends in an exception (Ctrl-C, SIGTERM, a bug) still writes what it recorded, but does
        not wait for Enter."""
        if self.vis is None:
            return
        try:
            self.vis.set_animation(self.anim, play=False)
            if self.record is not None:
                self.record.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_bytes(self.record, self.vis.static_html().encode())
            if self.live and sys.stdin.isatty() and sys.exc_info()[0] is None:
                input(f"the push is shown at {self.vis.url()}; press Enter to close the "
                      "visualiser ")  # fmt: skip
        finally:
            self._stop_server()

    def _stop_server(self) -> None:
        """Never leave meshcat's server behind."""
        self.vis.window.server_proc.kill()
        self.vis.window.server_proc.wait()
