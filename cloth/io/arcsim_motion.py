"""ARCSim's transformations, keyframed motions and .mot motion files, as ARCSim evaluates them.

**Transformation** (ARCSim's ``transformation.cpp``): a uniform scale s, a rotation quaternion
q = (q_s, q_x, q_y, q_z) and a translation t, acting on a point as

    T(x) = t + s R(q) x          (scale, then rotate, then translate),

where R(q) x = (q_s^2 - |v|^2) x + 2 v (v . x) + 2 q_s (v x x), v = (q_x, q_y, q_z) (the rotation
of a unit q; ARCSim normalises q before it applies an interpolated one). The config form
``{"translate": [x, y, z], "rotate": [angle_deg, ax, ay, az], "scale": s}`` (each optional) gives
q = (cos(theta/2), sin(theta/2) a/|a|), theta = angle in radians; an angle of 0 is the identity
whatever the axis. Composition is that of maps: (A * B)(x) = A(B(x)), so (A * B) has scale
s_A s_B, rotation q_A q_B (Hamilton product) and translation t_A + s_A R(q_A) t_B.

**Motion** (ARCSim's ``spline.cpp``, ``Spline<Transformation>``): keyframes (t_k, X_k) where X_k is
the 8-vector (s, t, q) of a transformation (columns :data:`SCALE`, :data:`TRANSLATION`,
:data:`ROTATION`). The 8 numbers are interpolated componentwise by a cubic Hermite spline (the
quaternion as a 4-vector, no slerp; the scale too), and the rotation is normalised afterwards.
For t_k <= t < t_{k+1}, h = t_{k+1} - t_k, u = (t - t_k)/h:

    X(t) = X_k (2u^3 - 3u^2 + 1) + X_{k+1} (-2u^3 + 3u^2) + h [V_k (u^3 - 2u^2 + u) + V_{k+1} (u^3 - u^2)]

with tangents V_k: Catmull-Rom, V_k = (X_{k+1} - X_{k-1}) / (t_{k+1} - t_{k-1}), and V = 0 at the
first and the last key, unless the keyframe gives a ``velocity`` (see :func:`keyframe_velocity`).
Before the first key X(t) = X_0 and after the last X(t) = X_K, with zero velocity: ARCSim *clamps*
(its header's "linear extrapolation" is not what its code does). The key found for t is the first
one later than t, so t = t_k belongs to the segment starting at k: the velocity at t_0 is V_0 but
the velocity at the last key is 0.

A body point X is at x(t) = t(t) + s(t) R(t) X and moves with
v = t' + s' R X + s w x (R X), where w = 2 vec(q' q^-1) is the angular velocity of the normalised
quaternion (ARCSim's ``apply_dtrans``). :class:`ArcsimMotion` gives this as
:meth:`~ArcsimMotion.transform_at` / :meth:`~ArcsimMotion.point_velocity` for any motion, and as the
project's rigid motion protocol (:meth:`~ArcsimMotion.pose`, :meth:`~ArcsimMotion.velocity`, as in
:mod:`cloth.collision.obstacles`) when the scale is constant: then world = R (s X) + p, and the
scale belongs to the body's rest vertices (multiply them by :attr:`ArcsimMotion.scale` once).

**.mot files** (ARCSim's ``mot_parser.cpp``; :func:`read_mot`): ``NumFrames: N``, then per body
part i a block ``body[i] position`` with N lines ``x y z`` and a block ``body[i] orientation`` with
N lines ``w x y z`` (a quaternion, scalar first), blocks separated by blank lines.
:func:`mot_motions` turns part i into motion i as ARCSim's ``parse_motions`` does: frame f at time
f / fps, quaternion signs made continuous (each flipped if its dot product with the previous,
already corrected one is negative), every keyframe composed on the left with the config's
``transform`` (world = transform(part frame)), Catmull-Rom tangents.
"""

from __future__ import annotations

import bisect
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cloth.io.arcsim_json import ArcsimConfigError

# Columns of a transformation as an 8-vector (what a motion interpolates).
SCALE = 0  # uniform scale s
TRANSLATION = slice(1, 4)  # t, metres
ROTATION = slice(4, 8)  # quaternion (q_s, q_x, q_y, q_z)
TRANSFORM_SIZE = 8


class ArcsimMotionError(ValueError):
    """A motion evaluated where it has no value: a rigid pose of a motion whose scale changes, or
    an interpolated quaternion of zero length."""


# ---- quaternions -------------------------------------------------------------------------------

def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a b of quaternions (..., 4) stored (s, x, y, z); broadcasts."""
    a_s, a_v = a[..., 0], a[..., 1:]
    b_s, b_v = b[..., 0], b[..., 1:]
    s = a_s * b_s - np.sum(a_v * b_v, axis=-1)
    v = a_s[..., None] * b_v + b_s[..., None] * a_v + np.cross(a_v, b_v)
    return np.concatenate([s[..., None], v], axis=-1)


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """(3, 3) matrix of ARCSim's Quaternion::rotate, x -> (s^2 - |v|^2) x + 2 v (v . x) + 2 s (v x x):
    the rotation of q when q is a unit quaternion (|q|^2 times it otherwise)."""
    s, v = float(q[0]), np.asarray(q[1:], dtype=np.float64)
    cross = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return (s * s - v @ v) * np.eye(3) + 2.0 * np.outer(v, v) + 2.0 * s * cross


def quat_from_axis_angle(axis, angle_rad: float) -> np.ndarray:
    """(4,) unit quaternion of a rotation by `angle_rad` about `axis` (ARCSim's from_axisangle:
    the identity for an angle of 0, whatever the axis). ValueError for a zero axis otherwise."""
    if angle_rad == 0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    axis = np.asarray(axis, dtype=np.float64)
    length = float(np.sqrt(axis @ axis))
    if length == 0:
        raise ValueError("a rotation by a nonzero angle needs a nonzero axis")
    return np.concatenate([[math.cos(angle_rad / 2)], math.sin(angle_rad / 2) * axis / length])


# ---- transformations ---------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Transformation:
    """x -> translation + scale R(rotation) x (module docstring). Arrays are read-only copies."""

    translation: np.ndarray  # (3,) float64, metres
    rotation: np.ndarray  # (4,) float64, quaternion (s, x, y, z); unit for a transform read from a config
    scale: float = 1.0  # uniform, dimensionless

    def __post_init__(self) -> None:
        translation = np.array(self.translation, dtype=np.float64).reshape(3)
        rotation = np.array(self.rotation, dtype=np.float64).reshape(4)
        translation.flags.writeable = rotation.flags.writeable = False
        object.__setattr__(self, "translation", translation)
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "scale", float(self.scale))

    @classmethod
    def identity(cls) -> Transformation:
        return cls(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), 1.0)

    @classmethod
    def from_config(cls, translate=(0.0, 0.0, 0.0), rotate=(0.0, 1.0, 0.0, 0.0), scale: float = 1.0) -> Transformation:
        """The transformation of a config's ``{"translate", "rotate": [angle_deg, ax, ay, az], "scale"}``."""
        angle_deg, *axis = (float(r) for r in rotate)
        return cls(np.asarray(translate, dtype=np.float64), quat_from_axis_angle(axis, angle_deg * math.pi / 180),
                   scale)

    @classmethod
    def from_vector(cls, x: np.ndarray) -> Transformation:
        """From the 8-vector layout (:data:`SCALE`, :data:`TRANSLATION`, :data:`ROTATION`)."""
        return cls(x[TRANSLATION], x[ROTATION], x[SCALE])

    def as_vector(self) -> np.ndarray:
        """(8,) float64 in the layout a motion interpolates."""
        x = np.empty(TRANSFORM_SIZE)
        x[SCALE], x[TRANSLATION], x[ROTATION] = self.scale, self.translation, self.rotation
        return x

    def rotation_matrix(self) -> np.ndarray:
        """(3, 3) R of x -> t + s R x."""
        return quat_matrix(self.rotation)

    def apply(self, points) -> np.ndarray:
        """(..., 3) points mapped: translation + scale R points."""
        points = np.asarray(points, dtype=np.float64)
        return self.translation + self.scale * (points @ self.rotation_matrix().T)

    def apply_vector(self, vectors) -> np.ndarray:
        """(..., 3) directions rotated (ARCSim's apply_vec: neither scaled nor translated)."""
        return np.asarray(vectors, dtype=np.float64) @ self.rotation_matrix().T

    def __mul__(self, other: Transformation) -> Transformation:
        """Composition: (self * other).apply(x) == self.apply(other.apply(x))."""
        return Transformation(self.translation + self.rotation_matrix() @ (other.translation * self.scale),
                              quat_mul(self.rotation, other.rotation), self.scale * other.scale)

    def inverse(self) -> Transformation:
        """The inverse map (ARCSim's inverse: scale 1/s, rotation q^-1, translation -R(q^-1) t / s)."""
        q = self.rotation
        if self.scale == 0 or not np.any(q):
            raise ArcsimMotionError(f"{self!r} has no inverse (zero scale or rotation)")
        q_inv = np.concatenate([[q[0]], -q[1:]]) / float(q @ q)
        scale = 1.0 / self.scale
        return Transformation(-(quat_matrix(q_inv) @ (scale * self.translation)), q_inv, scale)

    def normalized(self) -> Transformation:
        """The same with a unit rotation quaternion (ARCSim's get_trans); ArcsimMotionError for q = 0."""
        norm = float(np.sqrt(self.rotation @ self.rotation))
        if norm == 0:
            raise ArcsimMotionError("the rotation quaternion is zero: no rotation to normalise")
        return Transformation(self.translation, self.rotation / norm, self.scale)

    def __repr__(self) -> str:
        return (f"Transformation(translation={self.translation.tolist()}, rotation={self.rotation.tolist()}, "
                f"scale={self.scale})")


def keyframe_velocity(translate=(0.0, 0.0, 0.0), rotate=(0.0, 1.0, 0.0, 0.0), scale: float = 1.0) -> np.ndarray:
    """(8,) tangent of a keyframe's ``velocity`` object, read as ARCSim reads it: like a transform
    (translate, rotate, scale), then a scale of 1 (the default, or written) becomes 0, and a rotation
    quaternion whose scalar part is 1 (no rotate, or angle 0) becomes 0. So ``translate`` is the
    velocity of the translation (m/s), ``scale`` the rate of the scale (except that 1 means 0), and
    a ``rotate`` [angle, axis] enters the rotation's tangent as the unit quaternion
    (cos(angle/2), sin(angle/2) axis) itself, as ARCSim does."""
    v = Transformation.from_config(translate, rotate, scale).as_vector()
    if v[SCALE] == 1:
        v[SCALE] = 0.0
    if v[ROTATION][0] == 1:
        v[ROTATION] = 0.0
    return v


def catmull_rom_tangents(key_time: np.ndarray, key_transform: np.ndarray) -> np.ndarray:
    """(K, 8) ARCSim's fill_in_velocity for every key: (X_{k+1} - X_{k-1}) / (t_{k+1} - t_{k-1})
    inside, zero at the first and last key."""
    tangents = np.zeros_like(key_transform)
    if len(key_time) > 2:
        tangents[1:-1] = (key_transform[2:] - key_transform[:-2]) / (key_time[2:] - key_time[:-2])[:, None]
    return tangents


# ---- motions ------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ArcsimMotion:
    """A keyframed transformation, interpolated as ARCSim does (module docstring).

    Also the project's motion protocol (:mod:`cloth.collision.obstacles`): ``pose(t) -> (R, p)``
    with world = R local + p, ``velocity(t) -> (omega, v0)`` with v(x) = omega x x + v0, for
    local = scale * (the body's rest coordinates) — defined only when the scale is constant
    (:attr:`scale` is not None); :meth:`transform_at` and :meth:`point_velocity` hold for any motion.
    """

    key_time: np.ndarray  # (K,) float64, s, strictly increasing
    key_transform: np.ndarray  # (K, 8) float64: X_k, columns SCALE, TRANSLATION (m), ROTATION (quaternion)
    key_velocity: np.ndarray  # (K, 8) float64: Hermite tangents V_k, the same columns per second

    def __post_init__(self) -> None:
        key_time = np.array(self.key_time, dtype=np.float64).reshape(-1)
        k = key_time.shape[0]
        key_transform = np.array(self.key_transform, dtype=np.float64).reshape(k, TRANSFORM_SIZE)
        key_velocity = np.array(self.key_velocity, dtype=np.float64).reshape(k, TRANSFORM_SIZE)
        if k == 0:
            raise ValueError("a motion needs at least one keyframe")
        if np.any(np.diff(key_time) <= 0):
            raise ValueError(f"keyframe times must increase strictly, got {key_time.tolist()}")
        for name, a in (("key_time", key_time), ("key_transform", key_transform), ("key_velocity", key_velocity)):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{name} must be finite")
            a.flags.writeable = False
            object.__setattr__(self, name, a)

    @classmethod
    def from_keys(cls, key_time, transforms, velocities=None) -> ArcsimMotion:
        """A motion through `transforms` (Transformation per key) at `key_time`; `velocities`:
        per key an (8,) tangent or None for Catmull-Rom (all Catmull-Rom when omitted)."""
        key_time = np.asarray(key_time, dtype=np.float64)
        key_transform = np.array([tr.as_vector() for tr in transforms]).reshape(-1, TRANSFORM_SIZE)
        if key_time.shape[0] != key_transform.shape[0]:
            raise ValueError(f"{key_time.shape[0]} times for {key_transform.shape[0]} transforms")
        cls(key_time, key_transform, np.zeros_like(key_transform))  # checks times before the tangents divide by them
        key_velocity = catmull_rom_tangents(key_time, key_transform)
        for k, v in enumerate(velocities if velocities is not None else ()):
            if v is not None:
                key_velocity[k] = v
        return cls(key_time, key_transform, key_velocity)

    @property
    def start_time(self) -> float:
        return float(self.key_time[0])

    @property
    def end_time(self) -> float:
        return float(self.key_time[-1])

    @property
    def scale(self) -> float | None:
        """The scale when it is the same at every key and never changes (every tangent's scale is
        0), else None. Then X(t)'s scale is this value (to rounding: the Hermite weights of the two
        keys sum to 1) and the motion is rigid on bodies scaled by it."""
        s = self.key_transform[:, SCALE]
        if np.all(s == s[0]) and np.all(self.key_velocity[:, SCALE] == 0):
            return float(s[0])
        return None

    def interpolate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(X(t) (8,), X'(t) (8,)): ARCSim's Spline::pos and Spline::vel, before normalisation."""
        t = float(t)
        i = bisect.bisect_right(self.key_time, t)  # the first key later than t
        if i == 0:
            return self.key_transform[0].copy(), np.zeros(TRANSFORM_SIZE)
        if i == self.key_time.shape[0]:
            return self.key_transform[-1].copy(), np.zeros(TRANSFORM_SIZE)
        t0, t1 = self.key_time[i - 1], self.key_time[i]
        x0, x1 = self.key_transform[i - 1], self.key_transform[i]
        v0, v1 = self.key_velocity[i - 1], self.key_velocity[i]
        h = t1 - t0
        u = (t - t0) / h
        u2, u3 = u * u, u * u * u
        x = x0 * (2 * u3 - 3 * u2 + 1) + x1 * (-2 * u3 + 3 * u2) + (v0 * (u3 - 2 * u2 + u) + v1 * (u3 - u2)) * h
        dx = (x0 * (6 * u2 - 6 * u) + x1 * (-6 * u2 + 6 * u)) / h + v0 * (3 * u2 - 4 * u + 1) + v1 * (3 * u2 - 2 * u)
        return x, dx

    def transform_at(self, t: float) -> Transformation:
        """T(t) with a unit rotation (ARCSim's get_trans): a body point X is at T(t).apply(X)."""
        x, _ = self.interpolate(t)
        return Transformation.from_vector(x).normalized()

    def _angular(self, t: float) -> tuple[Transformation, np.ndarray, np.ndarray]:
        """(T(t) normalised, X'(t) with the derivative of the normalised quaternion, world angular
        velocity w = 2 vec(q' q^-1)) (ARCSim's get_dtrans and apply_dtrans)."""
        x, dx = self.interpolate(t)
        q, dq = x[ROTATION], dx[ROTATION]
        qq = float(q @ q)
        if qq == 0:
            raise ArcsimMotionError(f"the interpolated rotation quaternion is zero at t = {t}")
        norm = math.sqrt(qq)
        dx[ROTATION] = dq / norm - q / norm * float(q @ dq) / qq
        T = Transformation(x[TRANSLATION], q / norm, x[SCALE])
        q_conj = T.rotation * np.array([1.0, -1.0, -1.0, -1.0])  # the inverse of a unit quaternion
        omega = 2.0 * quat_mul(dx[ROTATION], q_conj)[1:]
        return T, dx, omega

    def point_velocity(self, points, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(x (..., 3), v (..., 3)) of body points `points` (rest coordinates) at time t:
        x = T(t) X, v = t' + s' R X + s w x (R X) (ARCSim's apply_dtrans; any scale)."""
        T, dx, omega = self._angular(t)
        rx = np.asarray(points, dtype=np.float64) @ T.rotation_matrix().T
        v = dx[TRANSLATION] + dx[SCALE] * rx + T.scale * np.cross(omega, rx)
        return T.translation + T.scale * rx, v

    def _rigid_scale(self) -> float:
        s = self.scale
        if s is None:
            raise ArcsimMotionError("this motion's scale changes over time (from "
                                    f"{self.key_transform[:, SCALE].tolist()}), so it has no rigid pose; "
                                    "use transform_at(t) and point_velocity(points, t)")
        return s

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(R (3, 3), p (3,)) with world = R local + p, local = scale * rest coordinates (the
        project's motion protocol); ArcsimMotionError if the scale changes (see :attr:`scale`)."""
        self._rigid_scale()
        T = self.transform_at(t)
        return T.rotation_matrix(), T.translation.copy()

    def velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(omega (3,), v0 (3,)): the velocity of world point x is omega x x + v0, so v0 = t' - omega x t
        (the project's motion protocol); ArcsimMotionError if the scale changes."""
        self._rigid_scale()
        T, dx, omega = self._angular(t)
        return omega, dx[TRANSLATION] - np.cross(omega, T.translation)

    def carry(self, points, t0: float, t: float) -> np.ndarray:
        """(..., 3): where world points attached to the moving frame at time t0 are at time t,
        T(t) T(t0)^-1 x (ARCSim's NodeHandle: a handle's nodes are attached when it activates)."""
        return self.transform_at(t).apply(self.transform_at(t0).inverse().apply(points))


# ---- .mot files ---------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class MotFile:
    """The rigid body parts of a .mot file, frame by frame."""

    path: Path
    part_position: np.ndarray  # (n_parts, n_frames, 3) float64, the file's units (metres in ARCSim's files)
    part_orientation: np.ndarray  # (n_parts, n_frames, 4) float64, quaternion (w, x, y, z) as written

    @property
    def n_parts(self) -> int:
        return self.part_position.shape[0]

    @property
    def n_frames(self) -> int:
        return self.part_position.shape[1]


_HEADER = re.compile(r"body\[(\d+)\]\s+(position|orientation)")


def read_mot(path) -> MotFile:
    """Read a .mot file (format in the module docstring). Headers must name the parts in order
    (``body[0] position``, ``body[0] orientation``, ``body[1] position``, ...), every block must
    hold exactly N lines of 3 (position) or 4 (orientation) numbers, and there must be at least
    one part; ArcsimConfigError naming the file and line otherwise."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ArcsimConfigError(f"{path}: cannot be read ({exc})", path=path) from None

    def fail(line_no: int, message: str):
        return ArcsimConfigError(f"{path}: line {line_no}: {message}", path=path)

    if not any(line.strip() for line in lines):
        raise ArcsimConfigError(f"{path}: the file is empty", path=path)
    first = lines[0].split()
    if len(first) != 2 or first[0] != "NumFrames:" or not first[1].isdigit() or int(first[1]) < 1:
        raise fail(1, "expected 'NumFrames: <N>' with N >= 1")
    n_frames = int(first[1])

    def skip_blank(i: int) -> int:
        while i < len(lines) and not lines[i].strip():
            i += 1
        return i

    def block(i: int, part: int, kind: str, width: int) -> np.ndarray:
        """The block whose header is line index i: (n_frames, width)."""
        m = _HEADER.fullmatch(lines[i].strip())
        if m is None or int(m.group(1)) != part or m.group(2) != kind:
            raise fail(i + 1, f"expected 'body[{part}] {kind}', found {lines[i].strip()!r}")
        values = np.empty((n_frames, width))
        for f in range(n_frames):
            j = i + 1 + f
            if j >= len(lines):
                raise fail(j, f"body[{part}] {kind}: the file ends after {f} of {n_frames} frames")
            fields = lines[j].split()
            try:
                if len(fields) != width:
                    raise ValueError
                values[f] = [float(x) for x in fields]
            except ValueError:
                raise fail(j + 1, f"body[{part}] {kind}: expected {width} numbers, found "
                                  f"{lines[j].strip()!r}") from None
            if not np.all(np.isfinite(values[f])):
                raise fail(j + 1, f"body[{part}] {kind}: numbers must be finite")
        return values

    positions, orientations = [], []
    i = skip_blank(1)
    while i < len(lines):
        part = len(positions)
        positions.append(block(i, part, "position", 3))
        i = skip_blank(i + 1 + n_frames)
        if i == len(lines):
            raise fail(i, f"the file ends before 'body[{part}] orientation'")
        orientations.append(block(i, part, "orientation", 4))
        i = skip_blank(i + 1 + n_frames)
    if not positions:
        raise fail(2, "no body parts")
    return MotFile(path=path, part_position=np.stack(positions), part_orientation=np.stack(orientations))


def continuous_quaternions(quats: np.ndarray) -> np.ndarray:
    """(F, 4) copy of `quats` with signs made continuous (ARCSim's clean_up_quaternions): each
    quaternion is negated if its dot product with the previous, already corrected one is < 0."""
    out = np.array(quats, dtype=np.float64)
    for f in range(1, out.shape[0]):
        if out[f - 1] @ out[f] < 0:
            out[f] = -out[f]
    return out


def mot_motions(mot: MotFile, fps: float, transform: Transformation) -> list[ArcsimMotion]:
    """One motion per body part, as ARCSim's parse_motions makes them from a motfile: keyframe f
    at f / fps (s), the part's frame (translation = position, rotation = the sign-corrected
    orientation, scale 1) composed on the left with `transform`, Catmull-Rom tangents."""
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be > 0, got {fps}")
    key_time = np.arange(mot.n_frames) / fps
    R = transform.rotation_matrix()
    motions = []
    for position, orientation in zip(mot.part_position, mot.part_orientation):
        key_transform = np.empty((mot.n_frames, TRANSFORM_SIZE))
        key_transform[:, SCALE] = transform.scale
        key_transform[:, TRANSLATION] = transform.translation + (position * transform.scale) @ R.T
        key_transform[:, ROTATION] = quat_mul(transform.rotation[None, :], continuous_quaternions(orientation))
        motions.append(ArcsimMotion(key_time, key_transform, catmull_rom_tangents(key_time, key_transform)))
    return motions
