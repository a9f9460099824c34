"""The run as a USD stage (``output.usd_every=N``): the cloth, the obstacles and the camera at the
scene's frame rate, for usdview, Blender's USD importer and other artists' tools.

Stage ``<run>/cloth.usdc`` (Z up, metres; time code = frame number, ``timeCodesPerSecond`` =
``framesPerSecond`` = 1 / frame time):

* ``/World/Cloth`` (Mesh): a mesh whose topology changes over time, since the remesher changes
  it. Its points (the simulation's nodes), ``faceVertexCounts``, ``faceVertexIndices`` and
  ``extent`` are time-sampled at every N-th frame (and frame 0); the primvar ``st`` (faceVarying)
  holds the material coordinates of each face corner in metres, so that a texture follows the
  cloth through the remeshing and a seam keeps both sides' coordinates; the primvar
  ``viewFactor`` (uniform: one per face, in [0, 1]) is the spatial view factor of the paper's
  eqs 2-3 at that frame (1 in view, towards nu_out out of it; without temporal smoothing), present
  when the scene has a camera.
* ``/World/Obstacles/<name>`` (Mesh): each obstacle's display mesh, points time-sampled when it
  moves.
* ``/World/Camera`` (Camera), and ``/World/Camera_<name>`` for each further camera of a rig:
  its pose (``xformOp:transform``, time-sampled) and intrinsics: the vertical aperture is
  VERTICAL_APERTURE_MM and the focal length gives the camera's vertical field of view, the
  horizontal aperture its image's aspect ratio. USD cameras look down their -Z axis with +Y up.

The stage is saved after every frame it takes, so that a run that stops keeps what it wrote; a
run resumed from a checkpoint (experiments.resume) drops the samples after the checkpoint's frame
and continues the same stage. Needs the ``pxr`` package (``usd-core``, the ``usd`` extra).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from cloth.io.recorder import Recorder

USD_FILE = "cloth.usdc"
# A 35 mm film back's height: USD's apertures and focal length share a unit (tenths of a scene
# unit by convention, millimetres to a DCC tool); only their ratio sets the field of view.
VERTICAL_APERTURE_MM = 24.0


def _name(text: str) -> str:
    """A valid USD prim name from an obstacle's name."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", str(text)) or "obstacle"
    return name if not name[0].isdigit() else f"_{name}"


def _stage_settings(stage, frame_time: float) -> None:
    """Z up, metres, the frame rate as time codes per second, and /World as the default prim."""
    from pxr import UsdGeom  # noqa: PLC0415 - see UsdRecorder

    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    fps = 1.0 / float(frame_time)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())


def camera_matrix(cam) -> np.ndarray:
    """(4, 4) world-from-camera of a pinhole camera in USD's convention (row vectors: a point p
    maps to [p, 1] @ M; the camera looks down its -Z axis with +Y up)."""
    pos, look, up = (np.asarray(a, dtype=np.float64) for a in (cam.position, cam.look_at, cam.up))
    back = pos - look
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    true_up = np.cross(back, right)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3], m[3, :3] = right, true_up, back, pos
    return m


class UsdRecorder(Recorder):
    """Writes every `every`-th frame (and frame 0) into a USD stage at `path` (module docstring).
    `resume_from` (a checkpoint's frame): continue the stage already at `path`, its samples after
    that frame dropped. `log_camera` false: no camera (a crowd's characters but the first)."""

    def __init__(self, path, every: int, frame_time: float, resume_from: int | None = None, log_camera: bool = True):
        from pxr import Sdf, Usd, UsdGeom  # noqa: PLC0415 - optional (the usd extra), only with output.usd_every

        if int(every) < 1:
            raise ValueError(f"USD: every must be >= 1 frame, got {every}")
        self.Sdf, self.Usd, self.UsdGeom = Sdf, Usd, UsdGeom
        self.path, self.every, self.log_camera = Path(path), int(every), bool(log_camera)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if resume_from is not None and self.path.is_file():
            self.stage = Usd.Stage.Open(str(self.path))
            self._drop_after(int(resume_from))
        else:
            self.path.unlink(missing_ok=True)
            self.stage = Usd.Stage.CreateNew(str(self.path))
        stage = self.stage
        _stage_settings(stage, frame_time)
        self.cloth = UsdGeom.Mesh.Define(stage, "/World/Cloth")
        self.cloth.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        pv = UsdGeom.PrimvarsAPI(self.cloth)
        self.st = pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        self.view = pv.CreatePrimvar("viewFactor", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.uniform)
        self._static: set[str] = set()
        self._frames = [int(t) for t in self.cloth.GetPointsAttr().GetTimeSamples()]

    def _drop_after(self, frame: int) -> None:
        for prim in self.stage.Traverse():
            for attr in prim.GetAttributes():
                for t in attr.GetTimeSamples():
                    if t > frame:
                        attr.ClearAtTime(t)

    def log_frame(self, frame, time_s, mesh, face_colors=None, obstacles=(), camera=None, view_factor=None,
                  more_cameras=None):
        frame = int(frame)
        if frame % self.every != 0:
            return
        from pxr import Gf, Vt  # noqa: PLC0415 - see __init__

        t = float(frame)
        x = np.ascontiguousarray(mesh.node_x, dtype=np.float32)
        m = self.cloth
        m.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(x), t)
        m.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(mesh.n_faces, 3, dtype=np.int32)), t)
        m.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(mesh.face_nodes.astype(np.int32).ravel()), t)
        m.GetExtentAttr().Set(Vt.Vec3fArray.FromNumpy(np.stack([x.min(axis=0), x.max(axis=0)])), t)
        st = np.ascontiguousarray(mesh.vert_u[mesh.face_verts].reshape(-1, 2), dtype=np.float32)
        self.st.Set(Vt.Vec2fArray.FromNumpy(st), t)
        if view_factor is not None:
            self.view.Set(Vt.FloatArray.FromNumpy(np.asarray(view_factor, dtype=np.float32)), t)
        for ob in obstacles:
            self._obstacle(ob, t)
        if camera is not None and self.log_camera:
            self._camera(camera, t, Gf)
            for name, cam in (more_cameras or {}).items():
                self._camera(cam, t, Gf, f"/World/Camera_{_name(name)}")
        self._frames = sorted(set(self._frames) | {frame})
        self.stage.SetStartTimeCode(self._frames[0])
        self.stage.SetEndTimeCode(self._frames[-1])
        self.stage.Save()  # a run that stops keeps every frame written so far

    def _obstacle(self, ob, t: float) -> None:
        from pxr import Vt  # noqa: PLC0415 - see __init__

        path = f"/World/Obstacles/{_name(ob.name)}"
        if not ob.moving and path in self._static:
            return
        v, f = ob.to_mesh()
        mesh = self.UsdGeom.Mesh.Define(self.stage, path)
        pts = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(v, dtype=np.float32))
        if path not in self._static:  # topology once: an obstacle's display mesh keeps it
            f = np.asarray(f, dtype=np.int32)
            mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(len(f), 3, dtype=np.int32)))
            mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(f.ravel()))
            mesh.CreateSubdivisionSchemeAttr(self.UsdGeom.Tokens.none)
            self._static.add(path)
        if ob.moving:
            mesh.GetPointsAttr().Set(pts, t)
        else:
            mesh.GetPointsAttr().Set(pts)

    def _camera(self, cam, t: float, Gf, path: str = "/World/Camera") -> None:
        UsdGeom = self.UsdGeom
        c = UsdGeom.Camera.Define(self.stage, path)
        ops = c.GetOrderedXformOps()
        op = ops[0] if ops else c.AddTransformOp()
        op.Set(Gf.Matrix4d(camera_matrix(cam).tolist()), t)
        v = VERTICAL_APERTURE_MM
        c.GetVerticalApertureAttr().Set(v, t)
        c.GetHorizontalApertureAttr().Set(v * float(cam.width) / float(cam.height), t)
        c.GetFocalLengthAttr().Set(0.5 * v / float(np.tan(np.radians(cam.fov_y_deg) / 2)), t)

    def close(self) -> None:
        if self.stage is not None:
            self.stage.Save()
            self.stage = None


CROWD_USD_FILE = "crowd.usda"


def write_crowd_stage(path, characters, frame_time: float) -> Path:
    """A crowd's stage (a small text layer at `path`): each character's own stage (its run folder's
    cloth.usdc) referenced under /World/<its folder's name>, at the crowd's frame rate, from the
    first frame any of them holds to the last."""
    from pxr import Usd, UsdGeom  # noqa: PLC0415 - see UsdRecorder

    path = Path(path)
    path.unlink(missing_ok=True)
    stage = Usd.Stage.CreateNew(str(path))
    _stage_settings(stage, frame_time)
    start, end = [], []
    for folder in characters:
        layer = Path(folder) / USD_FILE
        if not layer.is_file():
            continue
        sub = Usd.Stage.Open(str(layer))
        start.append(sub.GetStartTimeCode())
        end.append(sub.GetEndTimeCode())
        prim = UsdGeom.Xform.Define(stage, f"/World/{_name(Path(folder).name)}").GetPrim()
        prim.GetReferences().AddReference(str(layer.relative_to(path.parent)), "/World")
    if start:
        stage.SetStartTimeCode(min(start))
        stage.SetEndTimeCode(max(end))
    stage.Save()
    return path
