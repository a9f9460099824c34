"""The z-buffer rasteriser: triangle meshes through a :class:`cloth.view.camera.Camera`, sampled at
pixel centres (pixel (i, j) covers [i, i+1] x [j, j+1] with the origin at the image's top-left
corner, as :meth:`Camera.project`), two-sided, clipped at the near plane, with perspective-correct
depth. Every pixel keeps the nearest surface: its depth (distance along the viewing direction,
metres), which mesh it belongs to (``CLOTH`` or ``OCCLUDER``; ``EMPTY`` where nothing is seen)
and the face index within that mesh.

Shared by the screen-space accuracy measures (:mod:`cloth.eval.screenspace`, which renders saved
states) and the occlusion test of the view-dependent sizing (:mod:`cloth.view.occlusion`, which
renders the live mesh every remesh), so both see the same pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

EMPTY, CLOTH, OCCLUDER = 0, 1, 2  # values of ScreenImage.mesh_id
# A pixel centre on a shared edge belongs to both triangles: barycentric weights down to -EDGE_EPS
# count as inside, so round-off on an edge never leaves a one-pixel hole between two faces.
EDGE_EPS = 1e-9


@dataclass
class ScreenImage:
    """A z-buffer image. depth (H, W) float64, metres along the viewing direction (inf: empty);
    mesh_id (H, W) int8 (EMPTY, CLOTH, OCCLUDER); face (H, W) int32, the face index within its
    mesh (-1: empty); focal_px: focal length in pixels of this image; scale: pixels of this image
    per pixel of the camera's own image."""

    depth: np.ndarray
    mesh_id: np.ndarray
    face: np.ndarray
    focal_px: float
    scale: float

    @property
    def cloth(self) -> np.ndarray:
        """(H, W) bool: pixels whose nearest surface is cloth."""
        return self.mesh_id == CLOTH

    @property
    def resolution(self) -> tuple:
        """(width, height) in pixels."""
        return int(self.depth.shape[1]), int(self.depth.shape[0])


@njit(cache=True)
def _draw_triangle(a, b, c, f, ox, oy, far, depth, mesh_id, face, mid, fid):
    """Rasterise one triangle given in camera coordinates (right, up, forward), all in front of the
    near plane, into the buffers (accumulates into depth, mesh_id, face): pixel centres inside or
    on its edges take its perspective-correct depth where it is nearer than what they hold."""
    H, W = depth.shape
    u0, v0 = ox + f * a[0] / a[2], oy - f * a[1] / a[2]
    u1, v1 = ox + f * b[0] / b[2], oy - f * b[1] / b[2]
    u2, v2 = ox + f * c[0] / c[2], oy - f * c[1] / c[2]
    area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    if not abs(area) > 1e-12:  # seen edge-on (or not finite): covers no pixel centre
        return
    inv = 1.0 / area
    iz0, iz1, iz2 = 1.0 / a[2], 1.0 / b[2], 1.0 / c[2]
    i_lo = max(int(np.ceil(min(u0, min(u1, u2)) - 0.5)), 0)
    i_hi = min(int(np.floor(max(u0, max(u1, u2)) - 0.5)), W - 1)
    j_lo = max(int(np.ceil(min(v0, min(v1, v2)) - 0.5)), 0)
    j_hi = min(int(np.floor(max(v0, max(v1, v2)) - 0.5)), H - 1)
    for j in range(j_lo, j_hi + 1):
        y = j + 0.5
        for i in range(i_lo, i_hi + 1):
            x = i + 0.5
            w0 = ((u2 - u1) * (y - v1) - (v2 - v1) * (x - u1)) * inv
            w1 = ((u0 - u2) * (y - v2) - (v0 - v2) * (x - u2)) * inv
            w2 = 1.0 - w0 - w1
            if w0 < -EDGE_EPS or w1 < -EDGE_EPS or w2 < -EDGE_EPS:
                continue
            d = 1.0 / (w0 * iz0 + w1 * iz1 + w2 * iz2)  # 1/z is linear in screen space
            if d < depth[j, i] and d <= far:
                depth[j, i] = d
                mesh_id[j, i] = mid
                face[j, i] = fid


@njit(cache=True)
def _rasterize(cam_x, tris, tri_mesh, tri_face, f, ox, oy, near, far, depth, mesh_id, face):
    """Every triangle (vertex indices into `cam_x`, camera coordinates) clipped at the near plane
    (Sutherland-Hodgman against z = near: a triangle, a quad in two triangles, or nothing), then
    drawn (accumulates into depth, mesh_id, face)."""
    poly = np.empty((4, 3))
    v = np.empty((3, 3))
    for t in range(tris.shape[0]):
        n_in = 0
        for k in range(3):
            for c in range(3):
                v[k, c] = cam_x[tris[t, k], c]
            if v[k, 2] >= near:
                n_in += 1
        if n_in == 3:
            _draw_triangle(v[0], v[1], v[2], f, ox, oy, far, depth, mesh_id, face, tri_mesh[t], tri_face[t])
            continue
        if n_in == 0:
            continue
        m = 0
        for k in range(3):
            p, q = v[k], v[(k + 1) % 3]
            if p[2] >= near:
                poly[m] = p
                m += 1
            if (p[2] >= near) != (q[2] >= near):
                s = (near - p[2]) / (q[2] - p[2])
                for c in range(3):
                    poly[m, c] = p[c] + s * (q[c] - p[c])
                poly[m, 2] = near
                m += 1
        _draw_triangle(poly[0], poly[1], poly[2], f, ox, oy, far, depth, mesh_id, face, tri_mesh[t], tri_face[t])
        if m == 4:
            _draw_triangle(poly[0], poly[2], poly[3], f, ox, oy, far, depth, mesh_id, face, tri_mesh[t], tri_face[t])


def rasterize(camera, meshes, resolution_scale: float = 1.0) -> ScreenImage:
    """Z-buffer image of `meshes` [(vertices (N, 3) m, triangles (F, 3) int, mesh id), ...] seen by
    `camera` (cloth.view.camera.Camera) at `resolution_scale` times its width x height (rounded)."""
    s = float(resolution_scale)
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"resolution_scale must be > 0, got {resolution_scale}")
    W, H = max(int(round(camera.width * s)), 1), max(int(round(camera.height * s)), 1)
    scale = H / camera.height  # exact for the vertical field of view
    f = camera.focal_px * scale
    xs, ts, ms, fs = [], [], [], []
    n = 0
    for x, tri, mid in meshes:
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        tri = np.asarray(tri, dtype=np.int64).reshape(-1, 3)
        if tri.size and (tri.min() < 0 or tri.max() >= x.shape[0]):
            raise ValueError(f"mesh {mid}: a triangle indexes outside its {x.shape[0]} vertices")
        xs.append(x)
        ts.append(tri + n)
        ms.append(np.full(tri.shape[0], mid, dtype=np.int8))
        fs.append(np.arange(tri.shape[0], dtype=np.int32))
        n += x.shape[0]
    depth = np.full((H, W), np.inf)
    mesh_id = np.zeros((H, W), dtype=np.int8)
    face = np.full((H, W), -1, dtype=np.int32)
    if n:
        cam_x = np.ascontiguousarray(camera.to_camera(np.concatenate(xs)))
        _rasterize(cam_x, np.ascontiguousarray(np.concatenate(ts)), np.concatenate(ms), np.concatenate(fs),
                   f, W / 2.0, H / 2.0, float(camera.near), float(camera.far), depth, mesh_id, face)
    return ScreenImage(depth, mesh_id, face, f, scale)


def render_frame(camera, cloth_x, cloth_tris, occluder_x=None, occluder_tris=None,
                 resolution_scale: float = 1.0) -> ScreenImage:
    """The cloth (mesh id CLOTH) and the occluders (OCCLUDER) in one depth test."""
    meshes = []
    if occluder_x is not None and len(occluder_tris):
        meshes.append((occluder_x, occluder_tris, OCCLUDER))
    meshes.append((cloth_x, cloth_tris, CLOTH))
    return rasterize(camera, meshes, resolution_scale)
