"""Screen-space accuracy of a run against a fine reference of the same scene and camera.

Two parts, all numpy/numba and independent of Hydra, over the per-frame states the runner
writes into ``states/frame_NNNNN.npz`` (:func:`cloth.io.states.save_state`, read back by
:func:`cloth.io.states.load_state`):

* **A z-buffer rasteriser** (:func:`rasterize`, :func:`render_frame`): triangle meshes through a
  :class:`cloth.view.camera.Camera`, sampled at pixel centres (pixel (i, j) covers [i, i+1] x [j, j+1]
  with the origin at the image's top-left corner, as :meth:`Camera.project`), two-sided, clipped
  at the near plane, with perspective-correct depth. Every pixel keeps the nearest surface: its
  depth (distance along the viewing direction, metres), which mesh it belongs to (``CLOTH`` or
  ``OCCLUDER``; ``EMPTY`` where nothing is seen) and the face index within that mesh.
* **Error measures** (:func:`frame_errors`, :func:`offscreen_distance`), defined below.

Definitions (version :data:`DEFINITION_VERSION`)
------------------------------------------------
Both images are rendered with the camera of the frame (the run's camera path at the frame's
time), at ``resolution_scale`` times the camera's own width x height, with the scene's obstacles
(the body) drawn into the same depth test, so cloth behind the body is not seen. R and G are
the sets of pixels whose nearest surface is cloth in the run and in the reference (the
*visible-cloth masks*); I = R & G, U = R | G. All distances are in pixels of the camera's own
image: distances measured in the rendered image are divided by ``resolution_scale``.

* ``surface_px``: mean over I of  |z_run - z_ref| * f / z_ref,  z the depth of the pixel in each
  image and f the camera's focal length in pixels: how many pixels the depth difference would
  span on screen if it were turned sideways. NaN where I is empty.
* ``silhouette_px``: average symmetric distance between the boundaries of R and G: the boundary
  of a mask is its pixels with a 4-neighbour inside the image that is not in the mask (the image
  border is not a silhouette); every boundary pixel of either mask contributes its distance to
  the nearest boundary pixel of the other mask (Euclidean distance transform between pixel
  centres), and the mean is taken over both sets together. 0 when neither mask has a boundary.
* ``error_px`` (the headline): mean over U of e(p), with e(p) = the surface error of p for p in
  I, and for p in only one mask its distance to the nearest pixel of the other mask. 0 when U is
  empty. A sideways shift of a large cloth by s pixels gives about s (s + 1) / (width + s) per
  row, not s: it is an area-weighted error (every visible cloth pixel counts once), which mixes
  how much cloth is wrong with how wrong it is.
* ``cloth_px_run``, ``cloth_px_ref``: |R| and |G|, counted in pixels of the rendered image.
* ``iou``: |I| / |U|, 1 when U is empty.
* Where one of the masks (or boundaries) is empty and the other is not, the distance to it is
  capped at the image diagonal.

Limits: depth differences are converted with the reference depth and count fully even when the
displacement is along the viewing ray (then nothing moves on screen): ``surface_px`` is an upper
bound of the lateral motion it stands for. Pixels sample the surfaces at their centres, so
distances are resolved to about one rendered pixel (``resolution_scale`` < 1 is coarser); thin
features below a pixel can disappear. The occluders are the obstacles' display tessellations
(capsules with 24 segments around, OCCLUDER_RESOLUTION) whose facets lie inside the true surface.
Both sides of the cloth count alike (no back-face culling), shading and texture are ignored,
and the two images share the camera, so a camera error is not measured.

``popping_px`` (a run against itself: popping, the sudden jumps a remesh can put on screen), at
frame t from the run's images at t - 1, t and t + 1, each under its own frame's camera and only
when no camera cut falls between t - 1 and t + 1: the mean, over the pixels that show cloth in all
three, of |z(t+1) - 2 z(t) + z(t-1)| * f / z(t), the temporal second difference of the visible
depth as pixels at the depth of frame t. Smooth motion (the cloth's and the camera's) gives a
small value that the modes share; a jump that lasts one frame gives its full size. NaN where the
three images share no cloth pixel or the triple straddles a cut.

``offscreen_distance_m`` (ballooning of coarse out-of-view cloth, what buckling compensation is
for): the mean, over the run's cloth nodes outside the camera frustum (distance to the frustum
> 0), of their distance to the closest point of the reference cloth surface at the same frame.
NaN when no node is outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.ndimage import distance_transform_edt

from cloth.collision.nearest import point_mesh_distance
from cloth.collision.obstacles import capsule_tessellation

DEFINITION_VERSION = "screenspace-v2"  # v2: popping_px

EMPTY, CLOTH, OCCLUDER = 0, 1, 2  # values of ScreenImage.mesh_id
OCCLUDER_RESOLUTION = 24  # segments around a capsule of the body: facet sag below 1% of its radius
# A pixel centre on a shared edge belongs to both triangles: barycentric weights down to -EDGE_EPS
# count as inside, so round-off on an edge never leaves a one-pixel hole between two faces.
EDGE_EPS = 1e-9


# ---- per-frame states --------------------------------------------------------------------------


def occluder_mesh(state: dict, resolution: int = OCCLUDER_RESOLUTION):
    """(vertices (M, 3), triangles (L, 3)) of every obstacle of a state: the capsules tessellated
    with `resolution` segments around, plus the stored tessellations of the other obstacles."""
    xs, fs, n = [state["obstacle_x"]], [state["obstacle_faces"]], state["obstacle_x"].shape[0]
    for (a, b), r in zip(state["capsule_ends"], state["capsule_radii"]):
        v, f = capsule_tessellation(a, b, float(r), resolution)
        xs.append(v)
        fs.append(np.asarray(f, dtype=np.int64) + n)
        n += v.shape[0]
    return np.concatenate(xs).reshape(-1, 3), np.concatenate(fs).reshape(-1, 3).astype(np.int64)


# ---- the rasteriser ----------------------------------------------------------------------------

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


def render_state(camera, state: dict, resolution_scale: float = 1.0) -> ScreenImage:
    """:func:`render_frame` of a state (see :func:`load_state`) with its obstacles as occluders."""
    ox, of = occluder_mesh(state)
    return render_frame(camera, state["node_x"], state["face_nodes"], ox, of, resolution_scale)


# ---- error measures ----------------------------------------------------------------------------

def _boundary(mask: np.ndarray) -> np.ndarray:
    """Pixels of `mask` with a 4-neighbour inside the image that is not in the mask."""
    pad = np.pad(mask, 1, constant_values=True)  # outside the image counts as inside the mask
    interior = pad[:-2, 1:-1] & pad[2:, 1:-1] & pad[1:-1, :-2] & pad[1:-1, 2:]
    return mask & ~interior


def _distance_to(mask: np.ndarray, cap: float) -> np.ndarray:
    """Per pixel, the distance (pixels, between centres) to the nearest pixel of `mask`; `cap`
    everywhere when the mask is empty."""
    if not mask.any():
        return np.full(mask.shape, cap)
    return distance_transform_edt(~mask)


def frame_errors(run: ScreenImage, ref: ScreenImage) -> dict:
    """error_px, silhouette_px, surface_px, cloth_px_run, cloth_px_ref, iou of a run image against
    the reference image of the same camera and resolution (definitions in the module docstring)."""
    if run.depth.shape != ref.depth.shape or run.scale != ref.scale:
        raise ValueError(f"images differ in size: run {run.resolution}, reference {ref.resolution}")
    R, G = run.cloth, ref.cloth
    U = R | G
    n_run, n_ref, n_union = int(R.sum()), int(G.sum()), int(U.sum())
    out = {"cloth_px_run": n_run, "cloth_px_ref": n_ref}
    if n_union == 0:
        out.update(error_px=0.0, silhouette_px=0.0, surface_px=float("nan"), iou=1.0)
        return out
    # everything below happens inside the bounding box of U: every distance is to a pixel of
    # a mask (or its boundary), which lies in the box, so the crop changes no distance
    rows, cols = np.flatnonzero(U.any(axis=1)), np.flatnonzero(U.any(axis=0))
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    H, W = R.shape
    cap = float(np.hypot(H, W))  # the image diagonal: the largest distance on screen
    bR, bG = _boundary(R)[box], _boundary(G)[box]  # boundaries on the whole image, then cropped
    R, G, U = R[box], G[box], U[box]
    I = R & G
    s = run.scale
    # (b) surface: depth difference as pixels at the reference depth (camera pixels: f / scale)
    zr, zg = run.depth[box][I], ref.depth[box][I]
    surf = np.abs(zr - zg) * (ref.focal_px / s) / zg
    # (c) pixels in one mask only: distance to the nearest pixel of the other
    only_r, only_g = R & ~G, G & ~R
    d_only = np.concatenate([_distance_to(G, cap)[only_r], _distance_to(R, cap)[only_g]]) / s
    out["error_px"] = float((surf.sum() + d_only.sum()) / n_union)
    out["surface_px"] = float(surf.mean()) if surf.size else float("nan")
    # (a) silhouettes: symmetric mean boundary distance
    nb = int(bR.sum()) + int(bG.sum())
    if nb == 0:
        out["silhouette_px"] = 0.0
    else:
        d = np.concatenate([_distance_to(bG, cap)[bR], _distance_to(bR, cap)[bG]]) / s
        out["silhouette_px"] = float(d.mean())
    out["iou"] = float(I.sum() / n_union)
    return out


def popping(prev: ScreenImage, now: ScreenImage, nxt: ScreenImage) -> float:
    """popping_px at the middle frame of three consecutive images of a run (module docstring)."""
    if not (prev.depth.shape == now.depth.shape == nxt.depth.shape):
        raise ValueError("popping: the three images differ in size")
    common = prev.cloth & now.cloth & nxt.cloth
    if not common.any():
        return float("nan")
    z0, z1, z2 = prev.depth[common], now.depth[common], nxt.depth[common]
    return float(np.mean(np.abs(z2 - 2.0 * z1 + z0) * (now.focal_px / now.scale) / z1))


# ---- cloth out of view ------------------------------------------------------------------------

def offscreen_distance(camera, run_x, ref_x, ref_tris) -> tuple[float, int]:
    """(offscreen_distance_m, number of nodes outside): the mean distance from the run's nodes
    outside the camera frustum to the reference cloth surface; NaN when no node is outside."""
    run_x = np.asarray(run_x, dtype=np.float64).reshape(-1, 3)
    outside = camera.distance_to_frustum(run_x) > 0.0
    n = int(outside.sum())
    if n == 0:
        return float("nan"), 0
    return float(point_mesh_distance(run_x[outside], ref_x, ref_tris).mean()), n
