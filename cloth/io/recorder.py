"""Recorders: where a run logs its meshes for viewing. The base class does nothing.

Entity tree (Rerun): ``world/cloth`` (Mesh3D), ``world/obstacles/<name>`` (Mesh3D),
``world/camera`` (Transform3D world_from_camera + Pinhole). Timelines: ``frame`` (sequence)
and ``sim_time`` (seconds).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cloth.core.mesh import Mesh

CLOTH_COLOR = (70, 130, 200, 255)  # RGBA of the cloth when no per-face colours are given
OBSTACLE_COLOR = (180, 180, 180, 255)


class Recorder:
    """The do-nothing recorder: the solver runs and is tested without visualisation."""

    def log_static(self, name: str, vertices, faces, color=None) -> None:
        pass

    def log_frame(self, frame: int, time_s: float, mesh: Mesh, face_colors=None, obstacles=(), camera=None,
                  view_factor=None, more_cameras=None) -> None:
        """`face_colors` (F, 3) RGB by view factor, `view_factor` (F,) its value (with a camera),
        `more_cameras` {name: Camera} the cameras beside the main one (a CameraRig)."""

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


NullRecorder = Recorder


class Recorders(Recorder):
    """Several recorders as one (a Rerun recording and a USD stage): each call goes to each."""

    def __init__(self, recorders):
        self.recorders = list(recorders)

    def log_static(self, name, vertices, faces, color=None):
        for r in self.recorders:
            r.log_static(name, vertices, faces, color)

    def log_frame(self, frame, time_s, mesh, face_colors=None, obstacles=(), camera=None, view_factor=None,
                  more_cameras=None):
        for r in self.recorders:
            r.log_frame(frame, time_s, mesh, face_colors=face_colors, obstacles=obstacles, camera=camera,
                        view_factor=view_factor, more_cameras=more_cameras)

    def close(self):
        for r in self.recorders:
            r.close()


def _rgba(colors) -> np.ndarray:
    c = np.asarray(colors)
    if c.dtype.kind == "f":
        c = np.clip(np.round(c * 255), 0, 255).astype(np.uint8)
    c = c.astype(np.uint8)
    if c.shape[-1] == 3:
        c = np.concatenate([c, np.full(c.shape[:-1] + (1,), 255, np.uint8)], axis=-1)
    return c


class RerunRecorder(Recorder):
    """Streams a Rerun recording to an .rrd file as it goes (a crash keeps what was logged).

    A crowd writes one file per character with a shared `recording_id` and its own `root` entity
    (``world/dancer_03``), so that the viewer merges the files into one scene; only the character
    with `log_camera` logs the shared camera.
    """

    def __init__(self, path, app_id: str = "cloth", root: str = "world", recording_id: str | None = None,
                 log_camera: bool = True):
        import rerun as rr  # noqa: PLC0415 - optional viewer; import cost ~0.85 s (-X importtime), only with output.rerun

        self.rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.root, self.log_camera = root, log_camera
        self.rec = rr.RecordingStream(app_id, recording_id=recording_id)
        self.rec.save(str(self.path))
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._static_obstacles: set[str] = set()

    def log_static(self, name, vertices, faces, color=None):
        self.rec.log(f"{self.root}/{name}", self.rr.Mesh3D(
            vertex_positions=np.asarray(vertices, np.float32), triangle_indices=np.asarray(faces, np.uint32),
            albedo_factor=color or OBSTACLE_COLOR), static=True)

    def log_frame(self, frame, time_s, mesh, face_colors=None, obstacles=(), camera=None, view_factor=None,
                  more_cameras=None):
        rr = self.rr
        self.rec.set_time("frame", sequence=int(frame))
        self.rec.set_time("sim_time", duration=float(time_s))
        x = mesh.vert_x()
        if face_colors is None:
            self.rec.log(f"{self.root}/cloth", rr.Mesh3D(
                vertex_positions=x.astype(np.float32), triangle_indices=mesh.face_verts.astype(np.uint32),
                albedo_factor=CLOTH_COLOR))
        else:  # unshared vertices, so that each face carries its own colour
            pos = x[mesh.face_verts].reshape(-1, 3).astype(np.float32)
            col = np.repeat(_rgba(face_colors), 3, axis=0)
            self.rec.log(f"{self.root}/cloth", rr.Mesh3D(
                vertex_positions=pos, triangle_indices=np.arange(pos.shape[0], dtype=np.uint32).reshape(-1, 3),
                vertex_colors=col))
        for ob in obstacles:
            moving = ob.moving
            if not moving and ob.name in self._static_obstacles:
                continue
            v, f = ob.to_mesh()
            self.rec.log(f"{self.root}/obstacles/{ob.name}", rr.Mesh3D(
                vertex_positions=np.asarray(v, np.float32), triangle_indices=np.asarray(f, np.uint32),
                albedo_factor=OBSTACLE_COLOR), static=not moving)
            if not moving:
                self._static_obstacles.add(ob.name)
        if camera is not None and self.log_camera:
            self._log_camera(camera)
            for name, cam in (more_cameras or {}).items():
                self._log_camera(cam, f"world/cameras/{name}")

    def _log_camera(self, cam, entity: str = "world/camera"):
        rr = self.rr
        pos, look, up = (np.asarray(a, float) for a in (cam.position, cam.look_at, cam.up))
        fwd = look - pos
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, up)
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        # camera frame: x right, y down, z forward (Rerun's RDF convention)
        world_from_camera = np.column_stack([right, down, fwd])
        self.rec.log(entity, rr.Transform3D(translation=pos, mat3x3=world_from_camera))
        f = 0.5 * cam.height / np.tan(np.radians(cam.fov_y_deg) / 2)
        self.rec.log(entity, rr.Pinhole(focal_length=float(f), width=cam.width, height=cam.height,
                                                camera_xyz=rr.ViewCoordinates.RDF))

    def close(self):
        if self.rec is not None:
            self.rec.flush()
            self.rec = None
