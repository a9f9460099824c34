"""The pinhole camera: projection to pixels, the view frustum and the distance of points to it.

:class:`Camera` is a camera at one instant; camera paths (a camera at any time: static, orbit,
keyframes, jump cuts) are in :mod:`cloth.view.paths`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit


class ViewError(ValueError):
    """A camera or view-factor parameter that cannot work; the message names it."""


def _unit(v, name):
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0.0:
        raise ViewError(f"camera {name} must be a non-zero finite vector, got {v.tolist()}")
    return v / n


def _cross(a, b):
    """np.cross of two 3-vectors, as Python floats (the same bits; numpy's call costs 20x more)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with a vertical field of view of `fov_y_deg` and a `width` x `height` image.

    Pixels are square; pixel (0, 0) is the top-left corner of the image, x to the right, y down.
    The view frustum is the solid between the `near` and `far` planes (distances along the
    viewing direction, in metres) inside the four side planes through the image borders.
    """

    position: tuple
    look_at: tuple
    up: tuple = (0.0, 0.0, 1.0)
    fov_y_deg: float = 40.0
    width: int = 1280
    height: int = 720
    near: float = 0.05
    far: float = 100.0

    def __post_init__(self):
        pos = np.asarray(self.position, dtype=np.float64)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ViewError(f"camera position must be 3 finite numbers, got {self.position}")
        forward = _unit(np.asarray(self.look_at, float) - pos, "look_at - position")
        right = _cross(forward, _unit(self.up, "up"))
        if np.linalg.norm(right) < 1e-9:
            raise ViewError(f"camera up {tuple(self.up)} is parallel to the viewing direction {tuple(forward)}")
        right /= np.linalg.norm(right)
        if not 0.0 < float(self.fov_y_deg) < 180.0:
            raise ViewError(f"camera fov_y_deg must be in (0, 180) degrees, got {self.fov_y_deg}")
        if int(self.width) < 1 or int(self.height) < 1:
            raise ViewError(f"camera image must be at least 1 x 1 pixels, got {self.width} x {self.height}")
        if not 0.0 < float(self.near) < float(self.far):
            raise ViewError(f"camera needs 0 < near < far, got near={self.near}, far={self.far}")
        object.__setattr__(self, "_pos", pos)
        object.__setattr__(self, "_forward", forward)
        object.__setattr__(self, "_right", right)
        object.__setattr__(self, "_up", _cross(right, forward))
        # tangents of the half-angles of the frustum, vertical and horizontal
        ty = float(np.tan(np.radians(self.fov_y_deg) / 2.0))
        object.__setattr__(self, "_tan", (ty * self.width / self.height, ty))

    # ---- basic geometry --------------------------------------------------------------
    @property
    def forward(self) -> np.ndarray:
        return self._forward.copy()

    @property
    def center(self) -> np.ndarray:
        """(3,) float64, m: the centre of projection (`position` as an array; do not modify)."""
        return self._pos

    @property
    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(center, right, up, forward), (3,) float64 each: the camera's frame in world
        coordinates, for kernels that project many points (do not modify)."""
        return self._pos, self._right, self._up, self._forward

    @property
    def tan_half_fov(self) -> tuple[float, float]:
        """Tangents of the frustum's half-angles, (horizontal, vertical)."""
        return self._tan

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: height / (2 tan(fov_y / 2))."""
        return self.height / (2.0 * self._tan[1])

    def rotation(self) -> np.ndarray:
        """(3, 3) world-from-camera rotation, columns right, down, forward (the image's x, y, depth)."""
        return np.column_stack([self._right, -self._up, self._forward])

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """Camera coordinates (right, up, forward) of world points, (N, 3)."""
        p = np.asarray(points, dtype=np.float64) - self._pos
        return np.column_stack([p @ self._right, p @ self._up, p @ self._forward])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(pixels (N, 2), depth (N,)): image position and distance along the viewing direction.

        Points at or behind the camera plane (depth <= 0) get non-finite pixels.
        """
        c = self.to_camera(points)
        depth = c[:, 2]
        f = self.focal_px
        with np.errstate(divide="ignore", invalid="ignore"):
            px = np.column_stack([self.width / 2.0 + f * c[:, 0] / depth,
                                  self.height / 2.0 - f * c[:, 1] / depth])
        px[depth <= 0] = np.nan
        return px, depth

    def frustum_corners(self) -> np.ndarray:
        """(8, 3): near plane then far plane, each as top-left, top-right, bottom-right, bottom-left."""
        tx, ty = self._tan
        out = []
        for d in (self.near, self.far):
            for sx, sy in ((-1, 1), (1, 1), (1, -1), (-1, -1)):
                out.append(self._pos + d * (self._forward + sx * tx * self._right + sy * ty * self._up))
        return np.array(out)

    # ---- distance to the frustum ---------------------------------------------------------
    # the frustum's corners (frustum_corners: near plane 0-3, far plane 4-7) by face and by edge
    FRUSTUM_FACES = ((0, 1, 2, 3), (7, 6, 5, 4), (0, 4, 5, 1), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 4, 0))
    FRUSTUM_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: points in the closed frustum."""
        c = self.to_camera(points)
        tx, ty = self._tan
        d = c[:, 2]
        return (d >= self.near) & (d <= self.far) & (np.abs(c[:, 0]) <= tx * d) & (np.abs(c[:, 1]) <= ty * d)

    def distance_to_frustum(self, points: np.ndarray) -> np.ndarray:
        """(N,) exact Euclidean distance from each point to the frustum as a closed solid (0 inside).

        Outside, the nearest point of a convex solid lies on its boundary: in the interior of
        one of its six faces (then the distance is that face's plane distance and the point
        projects inside the face) or on one of its twelve edges (a segment distance).
        """
        cam = np.ascontiguousarray(self.to_camera(np.asarray(points, dtype=np.float64).reshape(-1, 3)))
        plane, sides, seg = _frustum_geometry(self._tan[0], self._tan[1], float(self.near), float(self.far))
        return _frustum_distance(cam, plane, sides, seg, self._tan[0], self._tan[1], float(self.near), float(self.far))

    def distance_and_facing(self, points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((N,) distance to the frustum as distance_to_frustum, (N,) bool: the normal points
        towards the camera, n . (center - point) > 0), in one pass over the points."""
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        normals = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
        plane, sides, seg = _frustum_geometry(self._tan[0], self._tan[1], float(self.near), float(self.far))
        return _distance_and_facing(points, normals, self._pos, self._right, self._up, self._forward, plane, sides,
                                    seg, self._tan[0], self._tan[1], float(self.near), float(self.far))


@lru_cache(maxsize=64)
def _frustum_geometry(tx: float, ty: float, near: float, far: float):
    """The frustum in camera coordinates (distances are the same as in the world): per face a
    corner and the outward normal, per face side its start and inward normal, per edge a segment."""
    corners = np.array([[sx * tx * d, sy * ty * d, d] for d in (near, far)
                        for sx, sy in ((-1, 1), (1, 1), (1, -1), (-1, -1))])
    plane, sides = _frustum_planes(corners, np.array(Camera.FRUSTUM_FACES, dtype=np.int64))
    edges = np.array(Camera.FRUSTUM_EDGES, dtype=np.int64)
    seg = np.stack([corners[edges[:, 0]], corners[edges[:, 1]] - corners[edges[:, 0]]], axis=1)
    for arr in (plane, sides, seg):
        arr.setflags(write=False)
    return plane, sides, seg


@njit(cache=True)
def _cross3(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@njit(cache=True)
def _frustum_planes(corners, faces):
    """Kernel of _frustum_geometry: (plane (6, 2, 3), sides (6, 4, 2, 3)) of the frustum's faces."""
    center = np.zeros(3)
    for i in range(8):
        center += corners[i]
    center /= 8.0
    plane = np.empty((6, 2, 3))
    sides = np.empty((6, 4, 2, 3))
    for f in range(6):
        q = corners[faces[f]]
        n = _cross3(q[1] - q[0], q[2] - q[0])
        n /= np.sqrt(_dot3(n, n))
        if _dot3(center - q[0], n) > 0:
            n = -n
        plane[f, 0], plane[f, 1] = q[0], n
        qc = (q[0] + q[1] + q[2] + q[3]) / 4.0
        for k in range(4):
            a, b = q[k], q[(k + 1) % 4]
            m = _cross3(n, b - a)
            if _dot3(qc - a, m) < 0:
                m = -m
            sides[f, k, 0], sides[f, k, 1] = a, m
    return plane, sides


@njit(cache=True)
def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def _point_frustum_distance(px, py, pz, plane, sides, seg, tx, ty, near, far):
    """Distance of one point in camera coordinates to the frustum (scalar code: no array views)."""
    if near <= pz <= far and abs(px) <= tx * pz and abs(py) <= ty * pz:
        return 0.0
    best = np.inf
    for f in range(6):
        nx, ny, nz = plane[f, 1, 0], plane[f, 1, 1], plane[f, 1, 2]
        h = (px - plane[f, 0, 0]) * nx + (py - plane[f, 0, 1]) * ny + (pz - plane[f, 0, 2]) * nz
        if h <= 0.0 or h >= best:
            continue
        within = True
        for k in range(4):  # the foot p - h n against each side's inward normal
            s = ((px - h * nx - sides[f, k, 0, 0]) * sides[f, k, 1, 0]
                 + (py - h * ny - sides[f, k, 0, 1]) * sides[f, k, 1, 1]
                 + (pz - h * nz - sides[f, k, 0, 2]) * sides[f, k, 1, 2])
            if s < 0.0:
                within = False
                break
        if within:
            best = h
    for e in range(seg.shape[0]):
        dx, dy, dz = px - seg[e, 0, 0], py - seg[e, 0, 1], pz - seg[e, 0, 2]
        ax, ay, az = seg[e, 1, 0], seg[e, 1, 1], seg[e, 1, 2]
        t = min(max((dx * ax + dy * ay + dz * az) / (ax * ax + ay * ay + az * az), 0.0), 1.0)
        rx, ry, rz = dx - t * ax, dy - t * ay, dz - t * az
        r2 = rx * rx + ry * ry + rz * rz
        if r2 < best * best:
            best = np.sqrt(r2)
    return best


@njit(cache=True)
def _frustum_distance(p, plane, sides, seg, tx, ty, near, far):
    """Kernel of Camera.distance_to_frustum, all in camera coordinates."""
    out = np.empty(p.shape[0])
    for i in range(p.shape[0]):
        out[i] = _point_frustum_distance(p[i, 0], p[i, 1], p[i, 2], plane, sides, seg, tx, ty, near, far)
    return out


@njit(cache=True)
def _distance_and_facing(points, normals, pos, right, up, forward, plane, sides, seg, tx, ty, near, far):
    """Kernel of Camera.distance_and_facing: each point taken to camera coordinates, its distance
    to the frustum, and whether its normal points towards the camera."""
    n = points.shape[0]
    d = np.empty(n)
    front = np.empty(n, dtype=np.bool_)
    for i in range(n):
        q0, q1, q2 = points[i, 0] - pos[0], points[i, 1] - pos[1], points[i, 2] - pos[2]
        px = q0 * right[0] + q1 * right[1] + q2 * right[2]
        py = q0 * up[0] + q1 * up[1] + q2 * up[2]
        pz = q0 * forward[0] + q1 * forward[1] + q2 * forward[2]
        d[i] = _point_frustum_distance(px, py, pz, plane, sides, seg, tx, ty, near, far)
        front[i] = -(normals[i, 0] * q0 + normals[i, 1] * q1 + normals[i, 2] * q2) > 0.0
    return d, front
