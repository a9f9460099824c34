"""View-dependent sizing (Koh, Narain and O'Brien 2015, sections 3.1-3.3): view factors,
screen-space clamp, silhouette resampling and the per-face quantities they need from a camera.

One public function per equation of the paper, vectorised over faces:

=====================================  =========================================================
:func:`spatial_view_factor`            eq 3, spatially smoothed view factor nu~ from the distance d
                                       of a face to the view frustum
:func:`anticipated_view_factor`        eq 4, temporal smoothing and anticipation over [t, t + T]
:func:`scale_sizing`                   eq 2, M~ = nu^2 M
:func:`screen_space_clamp`             eqs 5-8, edges of visible faces no shorter than l_min pixels
:func:`resample_silhouette`            section 3.3, view factors across silhouettes
=====================================  =========================================================

The camera itself is :class:`cloth.view.camera.Camera`; camera paths are in :mod:`cloth.view.paths`.
The eigenvalue clamp of eqs 7-8 uses the closed-form 2x2 eigen-system :func:`cloth.core.tensors.eig2x2`,
shared with the sizing.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cloth.core.tensors import eig2x2
from cloth.view.camera import Camera, ViewError

# Relative slack on eq 4's tau samples: taus built as k * frame_time may overshoot T = K *
# frame_time by a rounding error (3 * 0.1 > 0.3 in floating point), which is not a bad input.
TAU_ROUNDOFF = 1e-9


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
    M = np.ascontiguousarray(M, dtype=np.float64)
    S = np.ascontiguousarray(S, dtype=np.float64)
    if not l_min > 0:
        raise ViewError(f"screen_space_clamp: l_min must be > 0 pixels, got {l_min}")
    out = M.copy()
    _screen_space_clamp_faces(M, S, float(l_min) ** -2, out)
    return out


@njit(cache=True)
def _screen_space_clamp_faces(M, S, lam_max, out):
    """Kernel of screen_space_clamp, face by face in scalars (eig_apply's closed form 2x2
    eigen-system): out[f] = S^T min(S^-T M S^-1, lam_max) S, symmetrised, where S is regular."""
    for f in range(M.shape[0]):
        s00, s01, s10, s11 = S[f, 0, 0], S[f, 0, 1], S[f, 1, 0], S[f, 1, 1]
        det = s00 * s11 - s01 * s10
        if not abs(det) > 1e-12 * (s00 * s00 + s01 * s01 + s10 * s10 + s11 * s11):
            continue
        i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det  # S^-1
        m00, m01, m10, m11 = M[f, 0, 0], M[f, 0, 1], M[f, 1, 0], M[f, 1, 1]
        # S^-T M S^-1: (i, j) = sum_kl Si[k, i] M[k, l] Si[l, j]
        a00 = i00 * (m00 * i00 + m01 * i10) + i10 * (m10 * i00 + m11 * i10)
        a01 = i00 * (m00 * i01 + m01 * i11) + i10 * (m10 * i01 + m11 * i11)
        a10 = i01 * (m00 * i00 + m01 * i10) + i11 * (m10 * i00 + m11 * i10)
        a11 = i01 * (m00 * i01 + m01 * i11) + i11 * (m10 * i01 + m11 * i11)
        lo, hi, cs, sn = eig2x2(a00, 0.5 * (a10 + a01), a11)
        lo, hi = min(lo, lam_max), min(hi, lam_max)
        h00, h11, h01 = lo * sn * sn + hi * cs * cs, lo * cs * cs + hi * sn * sn, (hi - lo) * cs * sn
        # S^T M^ S
        b00 = s00 * (h00 * s00 + h01 * s10) + s10 * (h01 * s00 + h11 * s10)
        b01 = s00 * (h00 * s01 + h01 * s11) + s10 * (h01 * s01 + h11 * s11)
        b10 = s01 * (h00 * s00 + h01 * s10) + s11 * (h01 * s00 + h11 * s10)
        b11 = s01 * (h00 * s01 + h01 * s11) + s11 * (h01 * s01 + h11 * s11)
        out[f, 0, 0], out[f, 1, 1] = b00, b11
        out[f, 0, 1] = out[f, 1, 0] = 0.5 * (b01 + b10)


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
    return camera.distance_and_facing(centroids, normals)


def material_to_screen_jacobian(camera: Camera, vert_u: np.ndarray, face_verts: np.ndarray,
                                vert_x: np.ndarray) -> np.ndarray:
    """(F, 2, 2) Jacobian S of the map material coordinates (m) -> pixels on each face.

    From the three projected verts: S = [p1 - p0, p2 - p0] [u1 - u0, u2 - u0]^-1. Faces with a
    vert behind the camera get NaN (they are not visible).
    """
    return _screen_jacobians(np.ascontiguousarray(vert_x, dtype=np.float64).reshape(-1, 3),
                             np.ascontiguousarray(vert_u, dtype=np.float64),
                             np.ascontiguousarray(face_verts, dtype=np.int64), *camera.basis,
                             float(camera.focal_px), camera.width / 2.0, camera.height / 2.0)


@njit(cache=True)
def _screen_jacobians(vert_x, vert_u, face_verts, pos, right, up, forward, focal, cx, cy):
    """Kernel of material_to_screen_jacobian: each face's verts projected as Camera.project does
    (NaN at or behind the camera plane), then [p1 - p0, p2 - p0] Dm^-1 with Dm^-1 in closed form."""
    F = face_verts.shape[0]
    out = np.empty((F, 2, 2))
    px = np.empty(3)
    py = np.empty(3)
    for f in range(F):
        for k in range(3):
            v = face_verts[f, k]
            q0, q1, q2 = vert_x[v, 0] - pos[0], vert_x[v, 1] - pos[1], vert_x[v, 2] - pos[2]
            depth = q0 * forward[0] + q1 * forward[1] + q2 * forward[2]
            if depth <= 0.0:
                px[k], py[k] = np.nan, np.nan
            else:
                px[k] = cx + focal * (q0 * right[0] + q1 * right[1] + q2 * right[2]) / depth
                py[k] = cy - focal * (q0 * up[0] + q1 * up[1] + q2 * up[2]) / depth
        a, b, c = face_verts[f, 0], face_verts[f, 1], face_verts[f, 2]
        m00, m01 = vert_u[b, 0] - vert_u[a, 0], vert_u[c, 0] - vert_u[a, 0]
        m10, m11 = vert_u[b, 1] - vert_u[a, 1], vert_u[c, 1] - vert_u[a, 1]
        det = m00 * m11 - m01 * m10
        i00, i01, i10, i11 = m11 / det, -m01 / det, -m10 / det, m00 / det
        d00, d01 = px[1] - px[0], px[2] - px[0]
        d10, d11 = py[1] - py[0], py[2] - py[0]
        out[f, 0, 0] = d00 * i00 + d01 * i10
        out[f, 0, 1] = d00 * i01 + d01 * i11
        out[f, 1, 0] = d10 * i00 + d11 * i10
        out[f, 1, 1] = d10 * i01 + d11 * i11
    return out


def face_geometry(mesh):
    """(centroids (F, 3), unit normals (F, 3); zero for a collapsed face) of the faces in world space."""
    return _centroids_and_normals(mesh.node_x, mesh.face_nodes)


@njit(cache=True)
def _centroids_and_normals(node_x, face_nodes):
    """Kernel of face_geometry: the same arithmetic as the mean of the three nodes and as
    cloth.core.mesh.Mesh.world_face_normals."""
    F = face_nodes.shape[0]
    c = np.empty((F, 3))
    n = np.empty((F, 3))
    for f in range(F):
        a, b, d = face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2]
        for k in range(3):
            c[f, k] = (node_x[a, k] + node_x[b, k] + node_x[d, k]) / 3.0
        e10, e11, e12 = node_x[b, 0] - node_x[a, 0], node_x[b, 1] - node_x[a, 1], node_x[b, 2] - node_x[a, 2]
        e20, e21, e22 = node_x[d, 0] - node_x[a, 0], node_x[d, 1] - node_x[a, 1], node_x[d, 2] - node_x[a, 2]
        n0 = e11 * e22 - e12 * e21
        n1 = e12 * e20 - e10 * e22
        n2 = e10 * e21 - e11 * e20
        ln = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if not ln > 0.0:
            ln = 1.0
        n[f, 0], n[f, 1], n[f, 2] = n0 / ln, n1 / ln, n2 / ln
    return c, n
