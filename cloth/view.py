"""View-dependent sizing (Koh, Narain and O'Brien 2015, sections 3.1-3.3): camera, view factors,
screen-space clamp and silhouette resampling.

One public function per equation of the paper, vectorised over faces:

=====================================  =========================================================
:func:`spatial_view_factor`            eq 3, spatially smoothed view factor nu~ from the distance d
                                       of a face to the view frustum
:func:`anticipated_view_factor`        eq 4, temporal smoothing and anticipation over [t, t + T]
:func:`scale_sizing`                   eq 2, M~ = nu^2 M
:func:`screen_space_clamp`             eqs 5-8, edges of visible faces no shorter than l_min pixels
:func:`resample_silhouette`            section 3.3, view factors across silhouettes
=====================================  =========================================================

:class:`Camera` is a pinhole camera; camera paths (a camera at any time: static, orbit,
keyframes, jump cuts) are in :mod:`cloth.camera`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

# Relative slack on eq 4's tau samples: taus built as k * frame_time may overshoot T = K *
# frame_time by a rounding error (3 * 0.1 > 0.3 in floating point), which is not a bad input.
TAU_ROUNDOFF = 1e-9

class ViewError(ValueError):
    """A camera or view-factor parameter that cannot work; the message names it."""


def _unit(v, name):
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0.0:
        raise ViewError(f"camera {name} must be a non-zero finite vector, got {v.tolist()}")
    return v / n


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
        right = np.cross(forward, _unit(self.up, "up"))
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
        object.__setattr__(self, "_up", np.cross(right, forward))
        # tangents of the half-angles of the frustum, vertical and horizontal
        ty = float(np.tan(np.radians(self.fov_y_deg) / 2.0))
        object.__setattr__(self, "_tan", (ty * self.width / self.height, ty))

    # ---- basic geometry --------------------------------------------------------------
    @property
    def forward(self) -> np.ndarray:
        return self._forward.copy()

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
    _FACES = ((0, 1, 2, 3), (7, 6, 5, 4), (0, 4, 5, 1), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 4, 0))
    _EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))

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


@lru_cache(maxsize=64)
def _frustum_geometry(tx: float, ty: float, near: float, far: float):
    """The frustum in camera coordinates (distances are the same as in the world): per face a
    corner and the outward normal, per face side its start and inward normal, per edge a segment."""
    corners = np.array([[sx * tx * d, sy * ty * d, d] for d in (near, far)
                        for sx, sy in ((-1, 1), (1, 1), (1, -1), (-1, -1))])
    center = corners.mean(axis=0)
    plane = np.empty((6, 2, 3))
    sides = np.empty((6, 4, 2, 3))
    for f, quad in enumerate(Camera._FACES):
        q = corners[list(quad)]
        n = np.cross(q[1] - q[0], q[2] - q[0])
        n /= np.linalg.norm(n)
        if (center - q[0]) @ n > 0:
            n = -n
        plane[f] = q[0], n
        for k in range(4):
            a, b = q[k], q[(k + 1) % 4]
            m = np.cross(n, b - a)
            if (q.mean(axis=0) - a) @ m < 0:
                m = -m
            sides[f, k] = a, m
    seg = np.array([[corners[i], corners[j] - corners[i]] for i, j in Camera._EDGES])
    for arr in (plane, sides, seg):
        arr.setflags(write=False)
    return plane, sides, seg


@njit(cache=True)
def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def _frustum_distance(p, plane, sides, seg, tx, ty, near, far):
    """Kernel of Camera.distance_to_frustum, all in camera coordinates."""
    cam = p
    n = p.shape[0]
    out = np.empty(n)
    d = np.empty(3)
    for i in range(n):
        z = cam[i, 2]
        if near <= z <= far and abs(cam[i, 0]) <= tx * z and abs(cam[i, 1]) <= ty * z:
            out[i] = 0.0
            continue
        best = np.inf
        for f in range(6):
            for c in range(3):
                d[c] = p[i, c] - plane[f, 0, c]
            h = _dot3(d, plane[f, 1])
            if h <= 0.0 or h >= best:
                continue
            within = True
            for k in range(4):  # the foot p - h n against each side's inward normal
                s = 0.0
                for c in range(3):
                    s += (p[i, c] - h * plane[f, 1, c] - sides[f, k, 0, c]) * sides[f, k, 1, c]
                if s < 0.0:
                    within = False
                    break
            if within:
                best = h
        for e in range(seg.shape[0]):
            for c in range(3):
                d[c] = p[i, c] - seg[e, 0, c]
            ab = seg[e, 1]
            t = min(max(_dot3(d, ab) / _dot3(ab, ab), 0.0), 1.0)
            r2 = 0.0
            for c in range(3):
                r = d[c] - t * ab[c]
                r2 += r * r
            if r2 < best * best:
                best = np.sqrt(r2)
        out[i] = best
    return out


# ---- the paper's equations -----------------------------------------------------------------

def spatial_view_factor(d, front_facing, nu_front: float, nu_back: float, nu_out: float, margin: float) -> np.ndarray:
    """Eq 3, the spatially smoothed view factor nu~_i of each face.

    nu~_i = nu_fb                            if d_i = 0,
            nu_fb - (d_i / m) (nu_fb - nu_out)  if 0 < d_i < m,
            nu_out                           if d_i >= m,

    with d_i >= 0 the world distance of face i to the view frustum, m = `margin` (metres) and
    nu_fb = nu_front where `front_facing` else nu_back. Continuous in d for m > 0; m = 0 gives
    the unsmoothed step.
    """
    d = np.asarray(d, dtype=np.float64)
    if np.any(d < 0) or not np.all(np.isfinite(d)):
        raise ViewError("spatial_view_factor: distances d must be finite and >= 0")
    if margin < 0:
        raise ViewError(f"spatial_view_factor: margin m must be >= 0 m, got {margin}")
    nu_fb = np.where(np.asarray(front_facing, dtype=bool), float(nu_front), float(nu_back))
    if margin == 0:
        return np.where(d > 0, float(nu_out), nu_fb)
    t = np.minimum(d / margin, 1.0)
    return nu_fb - t * (nu_fb - float(nu_out))


def anticipated_view_factor(nu_future, taus, T: float) -> np.ndarray:
    """Eq 4, nu_i(t) = max over tau in [0, T] of w(tau) nu~_i(t + tau), with w(tau) = 1 - tau / T.

    `nu_future` (K, F): eq 3 for each face held fixed, the camera at its prescribed pose at
    t + taus[k]; `taus` (K,) with taus[0] = 0 and taus <= T (the maximum over [0, T] is taken
    over these samples). Conservative: nu(t) >= nu~(t) (the tau = 0 term), so visible faces
    keep nu_front; a face that becomes visible at t + tau has nu >= (1 - tau/T) nu_front already
    at t, rising continuously to the jump. T = 0 turns anticipation off (nu = nu~(t)).
    """
    nu_future = np.atleast_2d(np.asarray(nu_future, dtype=np.float64))
    taus = np.asarray(taus, dtype=np.float64).reshape(-1)
    if taus.size != nu_future.shape[0]:
        raise ViewError(f"anticipated_view_factor: {taus.size} taus for {nu_future.shape[0]} rows of nu_future")
    slack = TAU_ROUNDOFF * max(float(T), 1.0)
    if abs(taus[0]) > slack or np.any(taus < -slack) or np.any(taus > T + slack):
        raise ViewError(f"anticipated_view_factor: taus must start at 0 and lie in [0, T = {T}], got {taus.tolist()}")
    if T == 0:
        return nu_future[0].copy()
    w = np.clip(1.0 - taus / float(T), 0.0, 1.0)
    return np.max(w[:, None] * nu_future, axis=0)


def scale_sizing(M, nu) -> np.ndarray:
    """Eq 2, M~_i = nu_i^2 M_i: target edge lengths grow by 1 / nu_i. M (F, 2, 2), nu (F,) (or a scalar)."""
    nu = np.asarray(nu, dtype=np.float64)
    return nu[..., None, None] ** 2 * np.asarray(M, dtype=np.float64)


def screen_space_clamp(M, S, l_min: float) -> np.ndarray:
    """Eqs 5-8: the smallest change to M so that no edge is shorter than `l_min` pixels on screen.

    With S (F, 2, 2) the Jacobian of the map from material coordinates (m) to screen
    coordinates (pixels) on each face, the screen-space sizing tensor is
    S(M~) = S^-T M~ S^-1 = Q diag(lambda_1, lambda_2) Q^T (eqs 5-6); its eigenvalues are clamped,
    lambda^_i = min(lambda_i, l_min^-2) (eq 7), M^ = Q diag(lambda^) Q^T (eq 8), and the result
    M_vd = S^T M^ S. It never refines (M_vd <= M~ in the positive semi-definite order) and leaves
    M~ unchanged where every edge it asks for is at least l_min pixels long. Faces whose S is
    singular (seen edge-on) keep M~.
    """
    M = np.asarray(M, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    if not l_min > 0:
        raise ViewError(f"screen_space_clamp: l_min must be > 0 pixels, got {l_min}")
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    scale = np.einsum("fij,fij->f", S, S)
    ok = np.abs(det) > 1e-12 * scale
    out = M.copy()
    if not ok.any():
        return out
    Si = np.linalg.inv(S[ok])
    Ms = np.einsum("fki,fkl,flj->fij", Si, M[ok], Si)  # S^-T M S^-1
    Ms = 0.5 * (Ms + np.transpose(Ms, (0, 2, 1)))
    lam, Q = np.linalg.eigh(Ms)
    lam = np.minimum(lam, float(l_min) ** -2)
    Mh = np.einsum("fik,fk,fjk->fij", Q, lam, Q)
    Mvd = np.einsum("fki,fkl,flj->fij", S[ok], Mh, S[ok])  # S^T M^ S
    out[ok] = 0.5 * (Mvd + np.transpose(Mvd, (0, 2, 1)))
    return out


def resample_silhouette(nu, visible, edge_faces, threshold: float) -> np.ndarray:
    """Section 3.3: smooth view factors across silhouettes before the transfer to verts.

    Across every edge (`edge_faces` (E, 2), -1 on boundary edges) whose two faces' view factors
    differ by more than `threshold` and where exactly one face is `visible`, the non-visible face
    takes the average of the two. Visible faces never change. A face with several such edges
    takes the largest of its averages (the finest sizing asked for; independent of edge order).
    """
    nu = np.asarray(nu, dtype=np.float64)
    visible = np.asarray(visible, dtype=bool)
    ef = np.asarray(edge_faces, dtype=np.int64).reshape(-1, 2)
    out = nu.copy()
    inner = ef[(ef[:, 0] >= 0) & (ef[:, 1] >= 0)]
    if inner.size == 0:
        return out
    a, b = inner[:, 0], inner[:, 1]
    jump = (np.abs(nu[a] - nu[b]) > threshold) & (visible[a] != visible[b])
    a, b = a[jump], b[jump]
    hidden = np.where(visible[a], b, a)
    np.maximum.at(out, hidden, 0.5 * (nu[a] + nu[b]))
    return out


# ---- per-face quantities of a mesh under a camera -------------------------------------------

def face_view_data(camera: Camera, centroids: np.ndarray, normals: np.ndarray):
    """(distance to the frustum (F,), front_facing (F,)) of faces with the given centroids and unit normals.

    A face is front-facing when its normal points towards the camera; the cloth is thin, so
    which side is "front" is the side the face normal (counter-clockwise in material space) is on.
    """
    d = camera.distance_to_frustum(centroids)
    front = np.einsum("ij,ij->i", normals, camera._pos - centroids) > 0.0
    return d, front


def material_to_screen_jacobian(camera: Camera, vert_u: np.ndarray, face_verts: np.ndarray,
                                vert_x: np.ndarray) -> np.ndarray:
    """(F, 2, 2) Jacobian S of the map material coordinates (m) -> pixels on each face.

    From the three projected verts: S = [p1 - p0, p2 - p0] [u1 - u0, u2 - u0]^-1. Faces with a
    vert behind the camera get NaN (they are not visible).
    """
    px, depth = camera.project(vert_x.reshape(-1, 3))
    px = px.reshape(vert_x.shape[0], 2)
    p = px[face_verts]
    u = vert_u[face_verts]
    Ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=-1)
    Dm = np.stack([u[:, 1] - u[:, 0], u[:, 2] - u[:, 0]], axis=-1)
    return Ds @ np.linalg.inv(Dm)
