"""Analytic rigid obstacles with prescribed motion: plane, sphere, capsule, union of capsules.

Every obstacle answers one query, used by contact (and later by the proximity sizing):
``query(points) -> (phi, normal, velocity)``: the signed distance from each point to the
surface (negative inside), the outward unit normal at the closest surface point, and the
velocity of the obstacle's surface there. Animated characters are capsule unions driven
capsule by capsule through :meth:`CapsuleUnion.set_capsules` (cloth.scenes.character); triangle-mesh
obstacles with per-frame vertex positions answer the same interface (cloth.collision.meshobstacle).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit


# --------------------------------------------------------------------------------------------
# motions: pose(t) -> (R, p) with world = R @ local + p; velocity(t) -> (omega, v of the origin)
class Static:
    def pose(self, t):
        return np.eye(3), np.zeros(3)

    def velocity(self, t):
        return np.zeros(3), np.zeros(3)


class Linear:
    def __init__(self, velocity):
        self.v = np.asarray(velocity, dtype=np.float64)  # m/s

    def pose(self, t):
        return np.eye(3), self.v * t

    def velocity(self, t):
        return np.zeros(3), self.v.copy()


class Oscillate:
    """Translation a sin(2 pi f t + phase)."""

    def __init__(self, amplitude, frequency_hz, phase=0.0):
        self.a = np.asarray(amplitude, dtype=np.float64)  # m
        self.f, self.phase = float(frequency_hz), float(phase)  # Hz, rad

    def pose(self, t):
        return np.eye(3), self.a * np.sin(2 * np.pi * self.f * t + self.phase)

    def velocity(self, t):
        w = 2 * np.pi * self.f
        return np.zeros(3), self.a * w * np.cos(w * t + self.phase)


class Ramp:
    """Translation from 0 to `displacement` between t0 and t1 along a smoothstep (3u^2 - 2u^3,
    so the velocity starts and ends at zero), at rest before and after."""

    def __init__(self, displacement, t0, t1):
        self.d = np.asarray(displacement, dtype=np.float64)  # m
        self.t0, self.t1 = float(t0), float(t1)  # s
        if not self.t1 > self.t0:
            raise ValueError(f"Ramp needs t1 > t0, got t0 = {t0}, t1 = {t1}")

    def _u(self, t):
        return min(max((t - self.t0) / (self.t1 - self.t0), 0.0), 1.0)

    def pose(self, t):
        u = self._u(t)
        return np.eye(3), self.d * (3 * u * u - 2 * u ** 3)

    def velocity(self, t):
        u = self._u(t)
        return np.zeros(3), self.d * (6 * u - 6 * u * u) / (self.t1 - self.t0)


class Spin:
    """Rotation about `axis` through `center` at a constant angular velocity (rad/s)."""

    def __init__(self, axis, angular_velocity_rad_s, center=(0.0, 0.0, 0.0)):
        axis = np.asarray(axis, dtype=np.float64)
        self.axis = axis / np.linalg.norm(axis)
        self.w = float(angular_velocity_rad_s)
        self.c = np.asarray(center, dtype=np.float64)

    def pose(self, t):
        a, th = self.axis, self.w * t
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
        return R, self.c - R @ self.c

    def velocity(self, t):
        omega = self.w * self.axis
        return omega, -np.cross(omega, self.c)  # v(x) = omega x (x - c), at the origin


# --------------------------------------------------------------------------------------------
# distance kernels over all points
@njit(cache=True)
def _plane_query(points, p0, n, phi, normal, closest):
    for i in range(points.shape[0]):
        d = (points[i, 0] - p0[0]) * n[0] + (points[i, 1] - p0[1]) * n[1] + (points[i, 2] - p0[2]) * n[2]
        phi[i] = d
        for k in range(3):
            normal[i, k] = n[k]
            closest[i, k] = points[i, k] - d * n[k]


@njit(cache=True)
def _capsules_query(points, ends, radii, phi, normal, closest, which, param):
    """Closest capsule to each point. A sphere is a capsule whose two ends coincide.

    ends (K, 2, 3): segment end points; radii (K,). Writes phi, normal, closest surface point,
    the index of the closest capsule and the segment parameter s in [0, 1] of its axis point.
    """
    for i in range(points.shape[0]):
        best = np.inf
        x0, x1, x2 = points[i, 0], points[i, 1], points[i, 2]
        for k in range(ends.shape[0]):
            a0, a1, a2 = ends[k, 0, 0], ends[k, 0, 1], ends[k, 0, 2]
            e0, e1, e2 = ends[k, 1, 0] - a0, ends[k, 1, 1] - a1, ends[k, 1, 2] - a2
            ee = e0 * e0 + e1 * e1 + e2 * e2
            s = 0.0
            if ee > 0.0:
                s = ((x0 - a0) * e0 + (x1 - a1) * e1 + (x2 - a2) * e2) / ee
                s = min(max(s, 0.0), 1.0)
            d0, d1, d2 = x0 - (a0 + s * e0), x1 - (a1 + s * e1), x2 - (a2 + s * e2)
            dist = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            value = dist - radii[k]
            if value < best:
                best = value
                which[i] = k
                param[i] = s
                if dist > 0.0:
                    n0, n1, n2 = d0 / dist, d1 / dist, d2 / dist
                else:  # on the axis: any direction normal to it is a closest direction
                    n0, n1, n2 = 0.0, 0.0, 1.0
                    if ee > 0.0 and abs(e2) > 0.9 * np.sqrt(ee):
                        n0, n2 = 1.0, 0.0
                normal[i, 0], normal[i, 1], normal[i, 2] = n0, n1, n2
                closest[i, 0] = x0 - value * n0
                closest[i, 1] = x1 - value * n1
                closest[i, 2] = x2 - value * n2
        phi[i] = best


# --------------------------------------------------------------------------------------------
class Obstacle:
    """A rigid obstacle: geometry in its own frame, moved by a motion (pose(t), velocity(t))."""

    name = "obstacle"

    def __init__(self, motion=None, name=None):
        self.motion = motion if motion is not None else Static()
        if name is not None:
            self.name = name
        self.set_time(0.0)

    def set_time(self, t: float) -> None:
        self.R, self.p = self.motion.pose(t)
        self.omega, self.v0 = self.motion.velocity(t)
        self._place()

    def _place(self) -> None:
        """Update world-space geometry from (R, p)."""

    @property
    def moving(self) -> bool:
        """False for an obstacle that never moves (it is drawn once, as static data)."""
        return not isinstance(self.motion, Static) or getattr(self, "driven", False)

    def _rigid_velocity(self, closest: np.ndarray) -> np.ndarray:
        return np.cross(self.omega, closest) + self.v0

    def query(self, points: np.ndarray):
        """(phi (n,), outward normal (n,3), surface velocity (n,3)) at the closest points."""
        raise NotImplementedError

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) phi alone, as query's (an obstacle may compute it without normals or velocities)."""
        return self.query(points)[0]

    def to_mesh(self, resolution: int = 16):
        """(vertices (k,3), faces (l,3)) triangle mesh at the current pose, for display."""
        raise NotImplementedError

    @staticmethod
    def _alloc(n):
        return np.empty(n), np.empty((n, 3)), np.empty((n, 3))


class Plane(Obstacle):
    """The half-space below the plane through `point` with outward normal `normal`."""

    name = "ground"

    def __init__(self, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), motion=None, display_size=4.0, name=None):
        n = np.asarray(normal, dtype=np.float64)
        self.local_point = np.asarray(point, dtype=np.float64)
        self.local_normal = n / np.linalg.norm(n)
        self.display_size = float(display_size)  # m, side of the square drawn for it
        super().__init__(motion, name)

    def _place(self):
        self.point = self.R @ self.local_point + self.p
        self.normal = self.R @ self.local_normal

    def query(self, points):
        phi, normal, closest = self._alloc(points.shape[0])
        _plane_query(np.ascontiguousarray(points, dtype=np.float64), self.point, self.normal, phi, normal, closest)
        return phi, normal, self._rigid_velocity(closest)

    def to_mesh(self, resolution=16):
        n = self.normal
        t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        h = self.display_size / 2
        v = np.array([self.point + h * (sa * t1 + sb * t2) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        return v, np.array([[0, 1, 2], [0, 2, 3]])


class CapsuleUnion(Obstacle):
    """A union of capsules (segments swept by spheres); the base of sphere and capsule too.

    endpoints (K, 2, 3) in the obstacle's frame, radii (K,). A character drives its capsules
    one by one with :meth:`set_capsules` (world endpoints and their velocities); otherwise the
    union moves rigidly with its motion.
    """

    name = "capsules"

    def __init__(self, endpoints, radii, motion=None, name=None):
        self.local_ends = np.ascontiguousarray(endpoints, dtype=np.float64).reshape(-1, 2, 3)
        self.radii = np.ascontiguousarray(radii, dtype=np.float64).reshape(-1)
        if self.radii.shape[0] != self.local_ends.shape[0]:
            raise ValueError(f"{self.radii.shape[0]} radii for {self.local_ends.shape[0]} capsules")
        if np.any(self.radii <= 0):
            raise ValueError("capsule radii must be > 0")
        self.driven = False
        super().__init__(motion, name)

    def _place(self):
        if self.driven:
            return
        self.ends = np.ascontiguousarray(self.local_ends @ self.R.T + self.p)
        self.end_velocities = np.cross(self.omega, self.ends) + self.v0

    def set_capsules(self, endpoints, endpoint_velocities) -> None:
        """Drive each capsule directly: world endpoints (K,2,3) and their velocities (K,2,3)."""
        self.driven = True
        self.ends = np.ascontiguousarray(endpoints, dtype=np.float64).reshape(self.local_ends.shape)
        self.end_velocities = np.ascontiguousarray(endpoint_velocities, dtype=np.float64).reshape(self.local_ends.shape)

    def distance(self, points):  # query's kernel, without the surface velocities
        n = points.shape[0]
        phi, normal, closest = self._alloc(n)
        _capsules_query(np.ascontiguousarray(points, dtype=np.float64), self.ends, self.radii,
                        phi, normal, closest, np.empty(n, dtype=np.int64), np.empty(n))
        return phi

    def query(self, points):
        n = points.shape[0]
        phi, normal, closest = self._alloc(n)
        which, s = np.empty(n, dtype=np.int64), np.empty(n)
        _capsules_query(np.ascontiguousarray(points, dtype=np.float64), self.ends, self.radii,
                        phi, normal, closest, which, s)
        va, vb = self.end_velocities[which, 0], self.end_velocities[which, 1]
        velocity = (1.0 - s)[:, None] * va + s[:, None] * vb
        if not self.driven and np.any(self.omega):  # exact rigid field at the surface point
            velocity = self._rigid_velocity(closest)
        return phi, normal, velocity

    def to_mesh(self, resolution=16):
        verts, faces = [], []
        for (a, b), r in zip(self.ends, self.radii):
            v, f = capsule_tessellation(a, b, r, resolution)
            faces.append(f + sum(len(x) for x in verts))
            verts.append(v)
        return np.vstack(verts), np.vstack(faces)


class Sphere(CapsuleUnion):
    name = "sphere"

    def __init__(self, center=(0.0, 0.0, 0.0), radius=0.5, motion=None, name=None):
        c = np.asarray(center, dtype=np.float64)
        super().__init__(np.stack([c, c])[None], [radius], motion, name)


class Capsule(CapsuleUnion):
    name = "capsule"

    def __init__(self, a, b, radius, motion=None, name=None):
        super().__init__(np.stack([np.asarray(a, float), np.asarray(b, float)])[None], [radius], motion, name)


def capsule_tessellation(a, b, radius: float, segments: int = 12):
    """(vertices, faces) of a closed capsule around segment ab: `segments` around the axis,
    max(2, segments // 4) rings per hemispherical cap, single vertices at the poles, outward
    wound. Every vertex lies on the capsule (the facets are inside it, by at most about
    radius * (1 - cos(pi / segments))). The faces depend only on `segments` (capsule_faces)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    n = max(int(segments), 3)
    rings = max(2, n // 4)
    axis = b - a
    length = np.linalg.norm(axis)
    w = axis / length if length > 0 else np.array([0.0, 0.0, 1.0])
    u = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    phi = 2 * np.pi * np.arange(n) / n
    around = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v  # (n, 3)
    lat = np.linspace(0, np.pi / 2, rings + 1)[1:]  # from the b pole down to the equator
    cos, sin = np.cos(lat)[:, None, None], np.sin(lat)[:, None, None]
    top = b + radius * (cos * w + sin * around)  # (rings, n, 3): rings from the b pole to the equator
    bottom = a + radius * (-cos[::-1] * w + sin[::-1] * around)  # equator at a, then up to the a pole
    verts = np.concatenate([(b + radius * w)[None], top.reshape(-1, 3), bottom.reshape(-1, 3),
                            (a - radius * w)[None]])
    return verts, capsule_faces(n).copy()


@lru_cache(maxsize=8)
def capsule_faces(segments: int) -> np.ndarray:
    """(L, 3) int64 faces of capsule_tessellation with `segments` (>= 3) around (read-only):
    a fan at each pole and two triangles per quad between consecutive rings."""
    n = int(segments)
    rings = max(2, n // 4)
    n_rings = 2 * rings
    ring = lambda r, j: 1 + r * n + (j % n)  # noqa: E731
    faces = [[0, ring(0, j), ring(0, j + 1)] for j in range(n)]
    for r in range(n_rings - 1):
        for j in range(n):
            faces += [[ring(r, j), ring(r + 1, j), ring(r + 1, j + 1)],
                      [ring(r, j), ring(r + 1, j + 1), ring(r, j + 1)]]
    last = 1 + n_rings * n
    faces += [[last, ring(n_rings - 1, j + 1), ring(n_rings - 1, j)] for j in range(n)]
    out = np.asarray(faces, dtype=np.int64)
    out.setflags(write=False)
    return out


class ObstacleSet:
    """All obstacles of a scene; a query returns, per point, the obstacle with the smallest phi."""

    def __init__(self, obstacles):
        self.obstacles = list(obstacles)

    def set_time(self, t: float) -> None:
        for ob in self.obstacles:
            ob.set_time(t)

    def query_each(self, points: np.ndarray):
        """Per-obstacle queries stacked: phi (K, n), normal (K, n, 3), velocity (K, n, 3)."""
        out = [ob.query(points) for ob in self.obstacles]
        return (np.stack([o[0] for o in out]), np.stack([o[1] for o in out]), np.stack([o[2] for o in out]))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) query's phi alone: the signed distance to the nearest obstacle (inf with none)."""
        phi = np.full(points.shape[0], np.inf)
        for ob in self.obstacles:
            d = ob.distance(points) if hasattr(ob, "distance") else ob.query(points)[0]
            np.fmin(phi, d, out=phi)  # as query's `p < phi`: a NaN never wins
        return phi

    def query(self, points: np.ndarray):
        n = points.shape[0]
        phi = np.full(n, np.inf)
        normal, velocity = np.zeros((n, 3)), np.zeros((n, 3))
        for ob in self.obstacles:
            p, nn, vv = ob.query(points)
            closer = p < phi
            phi[closer], normal[closer], velocity[closer] = p[closer], nn[closer], vv[closer]
        return phi, normal, velocity
