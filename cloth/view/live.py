"""A camera whose future is not known (``camera.lookahead=false``; beyond the paper, whose temporal
smoothing needs the whole camera path in advance, its stated limitation).

:class:`LiveCamera` stands between a camera path and the view-dependent sizing. The sizing tells it
the time of each remesh (:meth:`LiveCamera.observe`): the pose at that time is then known (a live
source hands over one pose per frame), and every later one is a prediction from the poses seen so
far:

* position at constant velocity, from the last two poses;
* viewing direction at constant angular velocity (the rotation between the last two forward
  directions, per second, about their common normal), the up hint, the distance to the look-at
  point and the field of view held;
* the predicted frustum widened by the predictor's own measured error: at every observation the
  poses predicted for it from each earlier observation (1, 2, ... remeshes back, over the window
  of ERROR_WINDOW_S seconds) are compared with it, as an angle (:func:`pose_error`: the largest
  angle between the two frustums' corner rays, plus the position error seen from the look-at
  distance), and every side plane of the predicted frustum turns outwards by the largest error
  measured for that horizon (:func:`widened`). A horizon longer than any measured takes the
  longest one's error grown quadratically (constant acceleration). So the anticipation of eq 4
  stays conservative on smooth moves.

A jump cut, which no predictor sees coming, is known once it has happened (the live source
switches shots): the history before it is dropped, and until two poses of the new shot are seen the
prediction holds the pose still. The cloth that the new shot reveals is then refined reactively,
from the first remesh after the cut.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cloth.view.camera import Camera
from cloth.view.paths import CameraPath, CameraRig, rig_paths

ERROR_WINDOW_S = 2.0  # s of observations whose prediction errors widen the frustum
HISTORY = 16  # observed poses kept (the horizons measured reach this many remeshes back)
MAX_FOV_DEG = 170.0  # a widened field of view is capped below 180 degrees
TIME_EPS = 1e-9  # s: two observations closer than this are one


def _unit(v):
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def _rotate(v, axis, angle):
    """v rotated by `angle` about the unit `axis` (Rodrigues)."""
    c, s = np.cos(angle), np.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * np.dot(axis, v) * (1.0 - c)


def _angle(a, b) -> float:
    return float(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b)))


@dataclass
class LiveCamera(CameraPath):
    """`path` replayed as a live source (module docstring): poses up to the last :meth:`observe`
    are the path's, later ones predicted and widened by the predictor's measured error."""

    path: CameraPath
    frame_time: float | None = None  # s; with it a first observation also sees the frames before (observe)
    # plain lists (a checkpoint holds only the project's classes, numpy and a few builtins)
    history: list = field(default_factory=list)  # [(t, Camera)] observed, the last HISTORY
    errors: list = field(default_factory=list)  # [(t observed, horizon s, error rad)] over ERROR_WINDOW_S

    def __post_init__(self):
        self.cuts = ()  # a live source announces no cut in advance

    # ---- what the live source hands over --------------------------------------------------
    def observe(self, t: float) -> None:
        """The pose at time t becomes known (a remesh at t); the predictions made for t from the
        earlier poses are scored, and a cut since the last pose drops the history before it.

        Time going back (a simulation restarted at an earlier frame) starts the history afresh, so
        that no pose after t is ever known at t. A first observation (or one after time went back)
        with `frame_time` first observes the frames of the last ERROR_WINDOW_S, as a live source
        running since then would have: a run restarted mid-way predicts as the uninterrupted one."""
        t = float(t)
        if self.history and t < self.history[-1][0] - TIME_EPS:
            self.history, self.errors = [], []
        if self.history and t <= self.history[-1][0] + TIME_EPS:
            return
        if not self.history and self.frame_time:
            n = int(round(ERROR_WINDOW_S / float(self.frame_time)))
            for k in range(n, 0, -1):
                if t - k * self.frame_time >= -TIME_EPS:
                    self._observe(max(t - k * self.frame_time, 0.0))
        self._observe(t)

    def _observe(self, t: float) -> None:
        if self.history and t <= self.history[-1][0] + TIME_EPS:
            return
        cam = self.path.camera_at(t)
        if self.history and any(self.history[-1][0] < c <= t + TIME_EPS for c in getattr(self.path, "cuts", ())):
            self.history = []  # a new shot: its poses have nothing to do with the last one's
        past = list(self.history)
        for k in range(len(past) - 1):  # predictions for t from the history up to past[k + 1]
            made = past[: k + 2]
            guess = _predict(made, t)
            self.errors.append((t, t - made[-1][0], pose_error(guess, cam)))
        self.errors = [e for e in self.errors if e[0] >= t - ERROR_WINDOW_S]
        self.history = (self.history + [(t, cam)])[-HISTORY:]

    # ---- what the sizing sees -------------------------------------------------------------
    def camera_at(self, t: float) -> Camera:
        t = float(t)
        if not self.history:
            self.observe(t)
        last_t, last = self.history[-1]
        if t <= last_t + TIME_EPS:
            for when, cam in reversed(self.history):
                if when <= t + TIME_EPS:
                    return cam
            return self.history[0][1]
        guess = self.best_guess_at(t)
        widen = self.error_bound(t - last_t)
        return guess if widen <= 0 else widened(guess, widen)

    def best_guess_at(self, t: float) -> Camera:
        """The predicted pose at t, not widened (the screen-space clamp's camera): the observed
        one for a time already seen."""
        if self.history and float(t) > self.history[-1][0] + TIME_EPS:
            return _predict(self.history, float(t))
        return self.camera_at(t)

    def error_bound(self, horizon: float) -> float:
        """The predictor's largest measured error (rad) for predictions `horizon` seconds ahead:
        over the errors of horizons at least as long (to a rounding), the longest measured grown
        as (horizon / its horizon)^2 beyond it; 0 before any was measured."""
        if not self.errors:
            return 0.0
        h = np.array([e[1] for e in self.errors])
        err = np.array([e[2] for e in self.errors])
        longer = h >= horizon - TIME_EPS
        if longer.any():
            return float(err[longer & (h <= h[longer].min() + TIME_EPS)].max())
        top = h.max()
        return float(err[h >= top - TIME_EPS].max() * (horizon / top) ** 2)


def _corner_rays(cam: Camera) -> np.ndarray:
    """(4, 3) unit directions of the frustum's edges through the image corners."""
    far = np.asarray(cam.frustum_corners()[4:]) - cam.center
    return far / np.linalg.norm(far, axis=1)[:, None]


def pose_error(guess: Camera, true: Camera) -> float:
    """The angle (rad) by which the true camera's view departs from the guessed one: the largest
    angle between their frustums' corner rays (direction, roll and field of view) plus the position
    error seen from the look-at distance. A frustum whose side planes each turn outwards by this
    angle holds every ray of the true one (both are convex cones), up to the position's parallax
    at other depths."""
    dist = max(float(np.linalg.norm(np.subtract(true.look_at, true.position))), 1e-9)
    shift = float(np.linalg.norm(np.subtract(true.position, guess.position)))
    a, b = _corner_rays(guess), _corner_rays(true)
    turn = max(_angle(x, y) for x, y in zip(a, b))
    return turn + float(np.arctan2(shift, dist))


def widened(cam: Camera, angle: float) -> Camera:
    """`cam` with every side plane of its frustum turned outwards by at least `angle` (rad): the
    vertical half-angle grows by it, and by more where the horizontal one (tied to it by the
    aspect ratio) would otherwise grow by less; capped at MAX_FOV_DEG."""
    tx, ty = cam.tan_half_fov
    cap = np.radians(MAX_FOV_DEG) / 2
    v = min(np.arctan(ty) + angle, cap)
    h = min(np.arctan(tx) + angle, cap)
    ty_new = max(np.tan(v), np.tan(h) * ty / tx)
    fov = min(2.0 * np.degrees(np.arctan(ty_new)), MAX_FOV_DEG)
    return Camera(cam.position, cam.look_at, cam.up, fov, cam.width, cam.height, cam.near, cam.far)


def _predict(history, t: float) -> Camera:
    """The pose at t from the observed (time, Camera) `history` (module docstring)."""
    t1, c1 = history[-1]
    if len(history) < 2:
        return c1
    t0, c0 = history[-2]
    dt = t1 - t0
    s = (t - t1) / dt
    p0, p1 = np.asarray(c0.position, float), np.asarray(c1.position, float)
    pos = p1 + s * (p1 - p0)
    f0, f1 = c0.forward, c1.forward
    axis = _unit(np.cross(f0, f1))
    angle = _angle(f0, f1)
    up = np.asarray(c1.up, float)  # the up hint held (a roll the error measure sees widens the frustum)
    fwd = f1
    if angle > 0 and np.linalg.norm(axis) > 0:
        fwd = _rotate(f1, axis, s * angle)
    dist = float(np.linalg.norm(np.subtract(c1.look_at, c1.position)))
    if abs(np.dot(_unit(up), fwd)) > 1 - 1e-9:  # looking along the up hint: the last camera's true up
        up = _rotate(_unit(up), axis, s * angle)
    return Camera(tuple(pos), tuple(pos + dist * fwd), tuple(up), c1.fov_y_deg, c1.width, c1.height, c1.near, c1.far)


def live_camera(path: CameraPath, frame_time: float | None = None) -> CameraPath:
    """`path` as a live source: a LiveCamera, or a rig of them for a rig's cameras."""
    if isinstance(path, CameraRig):
        return CameraRig([LiveCamera(p, frame_time) for _, p in rig_paths(path)], path.names)
    return LiveCamera(path, frame_time)
