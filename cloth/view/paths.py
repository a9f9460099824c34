"""Camera paths: a prescribed camera at any time (static, orbit, keyframes, jump cuts).

The view-dependent sizing needs the camera now and over the next T seconds (anticipation,
paper eq 4), so a path is a pure function of time. Paths are built from plain dicts
(`path_from_config`), which is what `conf/camera/*.yaml` holds:

    type: static     camera: {position, look_at, up, fov_y_deg}   (or those keys at the top level:
                     conf/camera/fixed.yaml, whose `target` its `look_at` follows)
    type: orbit      center, radius, height, period_s, phase_deg, fov_y_deg, up
    type: keyframes  keys: [{t, position, look_at, up?, fov_y_deg?}, ...]   (C1 Catmull-Rom)
    type: cuts       shots: [{start, <a path>}, ...]   an instant switch at each start time

and, at the top level, `image: {width, height, near, far}` shared by every shot.

A camera or keyframe may carry `fit: stage` or `fit: dancer` (ignored by `path_from_config`):
:func:`fit_shots` moves those to a stage of another size (a crowd of another number of dancers,
experiments.camerasetup.stage_camera_config says by how much).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cloth.view.camera import Camera, ViewError

DEFAULT_IMAGE = {"width": 1280, "height": 720, "near": 0.05, "far": 100.0}
# A shot starting at time s is on from s - CUT_TIME_EPS: times reached by adding step lengths
# may land a few ulps short of a cut given in the config.
CUT_TIME_EPS = 1e-9


class CameraPath:
    """A camera for every time t (seconds of simulated time)."""

    cuts: tuple = ()  # times of jump cuts

    def camera_at(self, t: float) -> Camera:  # pragma: no cover - interface
        raise NotImplementedError


@dataclass
class StaticPath(CameraPath):
    camera: Camera

    def camera_at(self, t):
        return self.camera


@dataclass
class OrbitPath(CameraPath):
    """Circles `center` at `radius` and `height` above it, once every `period_s`, looking at the centre."""

    center: tuple
    radius: float
    height: float
    period_s: float
    phase_deg: float = 0.0
    fov_y_deg: float = 40.0
    up: tuple = (0.0, 0.0, 1.0)
    image: dict = field(default_factory=lambda: dict(DEFAULT_IMAGE))

    def __post_init__(self):
        if not self.radius > 0 or not self.period_s > 0:
            raise ViewError(f"orbit camera: radius and period_s must be > 0, got {self.radius}, {self.period_s}")

    def camera_at(self, t):
        a = np.radians(self.phase_deg) + 2.0 * np.pi * t / self.period_s
        c = np.asarray(self.center, float)
        pos = c + [self.radius * np.cos(a), self.radius * np.sin(a), self.height]
        return Camera(tuple(pos), tuple(c), tuple(self.up), self.fov_y_deg, **self.image)


@dataclass
class KeyframePath(CameraPath):
    """Position, look-at, up and field of view through keyframes, C1 (Catmull-Rom), held at the ends."""

    times: np.ndarray
    positions: np.ndarray
    targets: np.ndarray
    ups: np.ndarray
    fovs: np.ndarray
    image: dict = field(default_factory=lambda: dict(DEFAULT_IMAGE))

    def __post_init__(self):
        self.times = np.asarray(self.times, float)
        if self.times.size < 1 or np.any(np.diff(self.times) <= 0):
            raise ViewError(f"keyframe camera: key times must be increasing, got {self.times.tolist()}")

    def _interp(self, values, t):
        ts = self.times
        if t <= ts[0] or ts.size == 1:
            return values[0]
        if t >= ts[-1]:
            return values[-1]
        i = int(np.searchsorted(ts, t, side="right") - 1)
        t0, t1 = ts[i], ts[i + 1]
        h = t1 - t0
        s = (t - t0) / h

        def tangent(k):  # Catmull-Rom slope (per second), one-sided at the ends
            lo, hi = max(k - 1, 0), min(k + 1, ts.size - 1)
            return (values[hi] - values[lo]) / (ts[hi] - ts[lo])

        m0, m1 = tangent(i) * h, tangent(i + 1) * h
        h00, h10 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s
        h01, h11 = -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
        return h00 * values[i] + h10 * m0 + h01 * values[i + 1] + h11 * m1

    def camera_at(self, t):
        return Camera(tuple(self._interp(self.positions, t)), tuple(self._interp(self.targets, t)),
                      tuple(self._interp(self.ups, t)), float(self._interp(self.fovs, t)), **self.image)


@dataclass
class CutPath(CameraPath):
    """Shots that replace each other instantly at their start times (jump cuts)."""

    starts: np.ndarray
    shots: list

    def __post_init__(self):
        self.starts = np.asarray(self.starts, float)
        if self.starts.size < 1 or np.any(np.diff(self.starts) <= 0):
            raise ViewError(f"cut camera: shot start times must be increasing, got {self.starts.tolist()}")
        self.cuts = tuple(float(s) for s in self.starts[1:])

    def camera_at(self, t):
        i = max(int(np.searchsorted(self.starts - CUT_TIME_EPS, t, side="right")) - 1, 0)
        return self.shots[i].camera_at(t)


@dataclass
class CameraRig(CameraPath):
    """Several cameras at once (beyond the paper, which has one): `paths` with their `names`, the
    first being the main camera. The view-dependent sizing takes, per face, the largest view
    factor over the cameras and the finest screen-space clamp (cloth.view.viewdep), buckling
    compensation acts only out of every frustum, and the records count faces in view per camera;
    what shows one shot (stills, the accuracy measures) uses the main camera, `camera_at`."""

    paths: tuple
    names: tuple

    def __post_init__(self):
        self.paths, self.names = tuple(self.paths), tuple(str(n) for n in self.names)
        if len(self.paths) < 1 or len(self.names) != len(self.paths):
            raise ViewError(f"camera rig: {len(self.paths)} paths for {len(self.names)} names")
        if len(set(self.names)) != len(self.names):
            raise ViewError(f"camera rig: camera names must differ, got {list(self.names)}")
        self.cuts = tuple(sorted({c for p in self.paths for c in p.cuts}))

    def camera_at(self, t):
        return self.paths[0].camera_at(t)


def rig_paths(path: CameraPath | None) -> list[tuple[str, CameraPath]]:
    """[(name, path), ...] of every camera of `path`: a rig's, or the one path's named 'main'
    ([] for None)."""
    if path is None:
        return []
    if isinstance(path, CameraRig):
        return list(zip(path.names, path.paths))
    return [("main", path)]


def cameras_at(path: CameraPath | None, t: float) -> list[Camera]:
    """Every camera of `path` (a rig's or the one) at time t."""
    return [p.camera_at(t) for _, p in rig_paths(path)]


def _vec(d, key, default=None):
    v = d.get(key, default)
    if v is None:
        raise ViewError(f"camera: missing '{key}'")
    v = np.asarray(v, dtype=float)
    if v.shape != (3,):
        raise ViewError(f"camera: '{key}' must be 3 numbers, got {d.get(key)}")
    return v


def path_from_config(cfg: dict, image: dict | None = None) -> CameraPath:
    """Build a camera path from a plain dict (see the module docstring); raises ViewError naming the key."""
    cfg = dict(cfg)
    image = dict(DEFAULT_IMAGE, **(image or {}), **cfg.get("image", {}) or {})
    kind = cfg.get("type")
    if kind == "static":
        c = cfg.get("camera", cfg)
        return StaticPath(Camera(tuple(_vec(c, "position")), tuple(_vec(c, "look_at")),
                                 tuple(_vec(c, "up", (0, 0, 1))), float(c.get("fov_y_deg", 40.0)), **image))
    if kind == "orbit":
        return OrbitPath(tuple(_vec(cfg, "center")), float(cfg["radius"]), float(cfg.get("height", 0.0)),
                         float(cfg["period_s"]), float(cfg.get("phase_deg", 0.0)), float(cfg.get("fov_y_deg", 40.0)),
                         tuple(_vec(cfg, "up", (0, 0, 1))), image)
    if kind == "keyframes":
        keys = list(cfg.get("keys") or [])
        if not keys:
            raise ViewError("keyframe camera: 'keys' is empty")
        return KeyframePath(np.array([float(k["t"]) for k in keys]),
                            np.array([_vec(k, "position") for k in keys]),
                            np.array([_vec(k, "look_at") for k in keys]),
                            np.array([_vec(k, "up", (0, 0, 1)) for k in keys]),
                            np.array([float(k.get("fov_y_deg", 40.0)) for k in keys]), image)
    if kind == "cuts":
        shots = list(cfg.get("shots") or [])
        if not shots:
            raise ViewError("cut camera: 'shots' is empty")
        return CutPath(np.array([float(s.get("start", 0.0)) for s in shots]),
                       [path_from_config({k: v for k, v in s.items() if k != "start"}, image) for s in shots])
    raise ViewError(f"camera type must be one of static, orbit, keyframes, cuts; got {kind!r}")


FITS = ("stage", "dancer")  # the values of a camera's or keyframe's `fit` tag


def _fitted(cam: dict, scale: float, shift: np.ndarray) -> dict:
    """One camera or keyframe moved by its `fit` tag (see :func:`fit_shots`); as it is when the
    move is none (scale 1, shift 0), to the last bit."""
    fit = cam.get("fit")
    if fit is not None and fit not in FITS:
        raise ViewError(f"camera: fit must be one of {', '.join(FITS)} (or absent), got {fit!r}")
    out = dict(cam)
    if fit == "stage" and scale != 1.0:  # p' = a + s (p - a): same direction, s times as far from its look-at a
        target = _vec(cam, "look_at")
        out["position"] = (target + scale * (_vec(cam, "position") - target)).tolist()
    elif fit == "dancer" and np.any(shift != 0.0):  # moved with its dancer
        out["position"] = (_vec(cam, "position") + shift).tolist()
        out["look_at"] = (_vec(cam, "look_at") + shift).tolist()
    return out


def _fit_path(cfg: dict, scale: float, shift: np.ndarray) -> dict:
    kind = cfg.get("type")
    out = dict(cfg)
    if kind == "static":
        if "camera" in cfg:
            out["camera"] = _fitted(cfg["camera"], scale, shift)
        else:
            out = _fitted(cfg, scale, shift)
    elif kind == "keyframes":
        out["keys"] = [_fitted(k, scale, shift) for k in cfg.get("keys") or []]
    elif kind == "cuts":
        out["shots"] = [_fit_path(s, scale, shift) for s in cfg.get("shots") or []]
    elif cfg.get("fit") is not None:
        raise ViewError(f"camera: a {kind} camera cannot be fitted to a stage (fit: {cfg.get('fit')})")
    return out


def fit_shots(cfg: dict, scale: float, shift) -> dict:
    """A camera config (see the module docstring) fitted to a stage of another size: every camera
    or keyframe tagged `fit: stage` (a wide shot of the whole stage) keeps its look-at point and
    direction at `scale` times its distance from it, and the far plane goes `scale` times as far;
    every one tagged `fit: dancer` (a shot of one dancer) moves by `shift` (3,) m, with its dancer.
    Untagged ones, times, fields of view and the image size stay. With scale 1 and shift 0 the
    config comes back as it was. Raises ViewError naming a bad tag or scale."""
    scale = float(scale)
    if not (np.isfinite(scale) and scale > 0):
        raise ViewError(f"camera: a stage's scale must be a number > 0, got {scale}")
    shift = np.asarray(shift, dtype=float)
    if shift.shape != (3,) or not np.all(np.isfinite(shift)):
        raise ViewError(f"camera: a dancer's shift must be 3 finite numbers, got {shift.tolist()}")
    out = _fit_path(cfg, scale, shift)
    if scale != 1.0:  # the image is shared by every shot: at the top level only
        image = dict(cfg.get("image") or {})
        image["far"] = float(image.get("far", DEFAULT_IMAGE["far"])) * scale
        out["image"] = image
    return out
