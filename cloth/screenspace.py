"""Screen-space accuracy of a run against a fine reference of the same scene and camera.

Three parts, all numpy/numba and independent of Hydra:

* **Per-frame states** (:func:`save_state`, :func:`load_state`): what the evaluation needs of a
  frame, written by the runner into ``states/frame_NNNNN.npz``.
* **A z-buffer rasteriser** (:func:`rasterize`, :func:`render_frame`): triangle meshes through a
  :class:`cloth.view.Camera`, sampled at pixel centres (pixel (i, j) covers [i, i+1] x [j, j+1]
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

``offscreen_distance_m`` (ballooning of coarse out-of-view cloth, what buckling compensation is
for): the mean, over the run's cloth nodes outside the camera frustum (distance to the frustum
> 0), of their distance to the closest point of the reference cloth surface at the same frame.
NaN when no node is outside.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from .bvh import _build as _bvh_build
from .ccd import point_triangle_closest

DEFINITION_VERSION = "screenspace-v1"
STATE_FORMAT = 1  # version of the states/frame_NNNNN.npz layout

EMPTY, CLOTH, OCCLUDER = 0, 1, 2  # values of ScreenImage.mesh_id
OCCLUDER_RESOLUTION = 24  # segments around a capsule of the body: facet sag below 1% of its radius
# A pixel centre on a shared edge belongs to both triangles: barycentric weights down to -EDGE_EPS
# count as inside, so round-off on an edge never leaves a one-pixel hole between two faces.
EDGE_EPS = 1e-9


class StateError(ValueError):
    """A missing or malformed per-frame state file; the message names the file."""


# ---- per-frame states --------------------------------------------------------------------------

def save_state(path, mesh, frame: int, time: float, obstacles=()) -> Path:
    """Write ``states/frame_NNNNN.npz`` atomically (compressed npz) and return its path.

    Keys: ``format`` (STATE_FORMAT), ``frame`` (int), ``time`` (s), ``node_x`` (N, 3) float32 world
    positions (m), ``face_nodes`` (F, 3) int32 triangles as node indices, ``capsule_ends`` (K, 2, 3)
    float32 and ``capsule_radii`` (K,) float32 of every capsule of every capsule-union obstacle (the
    body, spheres, capsules: exact and a few hundred bytes), ``obstacle_x`` (M, 3) float32 and
    ``obstacle_faces`` (L, 3) int32, the display tessellation of every other obstacle (a ground
    plane: two triangles).
    """
    from .obstacles import CapsuleUnion

    path = Path(path)
    ends, radii, ox, of = [], [], [], []
    n_ox = 0
    for ob in obstacles:
        if isinstance(ob, CapsuleUnion):
            ends.append(np.asarray(ob.ends, dtype=np.float32).reshape(-1, 2, 3))
            radii.append(np.asarray(ob.radii, dtype=np.float32).reshape(-1))
        else:
            v, f = ob.to_mesh()
            ox.append(np.asarray(v, dtype=np.float32).reshape(-1, 3))
            of.append(np.asarray(f, dtype=np.int32).reshape(-1, 3) + n_ox)
            n_ox += ox[-1].shape[0]
    arrays = {
        "format": np.int32(STATE_FORMAT),
        "frame": np.int64(frame),
        "time": np.float64(time),
        "node_x": np.asarray(mesh.node_x, dtype=np.float32),
        "face_nodes": np.asarray(mesh.vert_node[mesh.face_verts], dtype=np.int32),
        "capsule_ends": np.concatenate(ends) if ends else np.zeros((0, 2, 3), np.float32),
        "capsule_radii": np.concatenate(radii) if radii else np.zeros(0, np.float32),
        "obstacle_x": np.concatenate(ox) if ox else np.zeros((0, 3), np.float32),
        "obstacle_faces": np.concatenate(of) if of else np.zeros((0, 3), np.int32),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


STATE_KEYS = ("format", "frame", "time", "node_x", "face_nodes", "capsule_ends", "capsule_radii",
              "obstacle_x", "obstacle_faces")


def load_state(path) -> dict:
    """The arrays of a state file (see :func:`save_state`), positions as float64; StateError names a bad file."""
    path = Path(path)
    try:
        with np.load(path) as z:
            missing = [k for k in STATE_KEYS if k not in z.files]
            if missing:
                raise StateError(f"state file {path} lacks {missing}")
            out = {k: z[k] for k in STATE_KEYS}
    except (OSError, ValueError, EOFError) as exc:
        if isinstance(exc, StateError):
            raise
        raise StateError(f"cannot read state file {path}: {exc}") from None
    if int(out["format"]) != STATE_FORMAT:
        raise StateError(f"state file {path} has format {int(out['format'])}, this code reads {STATE_FORMAT}")
    out["frame"], out["time"] = int(out["frame"]), float(out["time"])
    for k in ("node_x", "capsule_ends", "capsule_radii", "obstacle_x"):
        out[k] = out[k].astype(np.float64)
    for k in ("face_nodes", "obstacle_faces"):
        out[k] = out[k].astype(np.int64)
    n = out["node_x"].shape[0]
    if out["face_nodes"].size and (out["face_nodes"].min() < 0 or out["face_nodes"].max() >= n):
        raise StateError(f"state file {path}: face_nodes index outside its {n} nodes")
    return out


def merge_states(states: list) -> dict:
    """One state from several (the characters of a crowd under one camera): meshes concatenated."""
    if len(states) == 1:
        return states[0]
    out = dict(states[0])
    for xk, fk in (("node_x", "face_nodes"), ("obstacle_x", "obstacle_faces")):
        offs = np.cumsum([0] + [s[xk].shape[0] for s in states[:-1]])
        out[xk] = np.concatenate([s[xk] for s in states])
        out[fk] = np.concatenate([s[fk] + o for s, o in zip(states, offs)])
    out["capsule_ends"] = np.concatenate([s["capsule_ends"] for s in states])
    out["capsule_radii"] = np.concatenate([s["capsule_radii"] for s in states])
    return out


def occluder_mesh(state: dict, resolution: int = OCCLUDER_RESOLUTION):
    """(vertices (M, 3), triangles (L, 3)) of every obstacle of a state: the capsules tessellated
    with `resolution` segments around, plus the stored tessellations of the other obstacles."""
    from .obstacles import capsule_tessellation

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
    `camera` (cloth.view.Camera) at `resolution_scale` times its width x height (rounded)."""
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
    from scipy.ndimage import distance_transform_edt

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


# ---- distance to a triangle mesh ---------------------------------------------------------------

@njit(cache=True)
def _closest_distances(points, x, tris, nlo, nhi, left, start, count, order):
    """Distance of each point to the closest triangle: depth-first over the box tree, nearer child
    first, skipping every box farther than the best distance found so far."""
    n = points.shape[0]
    out = np.empty(n)
    stack = np.empty(left.shape[0] + 2, dtype=np.int64)
    for i in range(n):
        p = points[i]
        best = np.inf
        top = 0
        stack[0] = 0
        while top >= 0:
            k = stack[top]
            top -= 1
            d2 = 0.0
            for c in range(3):
                g = max(nlo[k, c] - p[c], 0.0, p[c] - nhi[k, c])
                d2 += g * g
            if d2 >= best * best:
                continue
            if left[k] < 0:
                for a in range(start[k], start[k] + count[k]):
                    t = order[a]
                    d, _, _, _ = point_triangle_closest(p, x[tris[t, 0]], x[tris[t, 1]], x[tris[t, 2]])
                    if d < best:
                        best = d
                continue
            L = left[k]
            dl = 0.0
            dr = 0.0
            for c in range(3):
                gl = max(nlo[L, c] - p[c], 0.0, p[c] - nhi[L, c])
                gr = max(nlo[L + 1, c] - p[c], 0.0, p[c] - nhi[L + 1, c])
                dl += gl * gl
                dr += gr * gr
            # push the farther child first so that the nearer one is searched first
            if dl <= dr:
                stack[top + 1] = L + 1
                stack[top + 2] = L
            else:
                stack[top + 1] = L
                stack[top + 2] = L + 1
            top += 2
        out[i] = best
    return out


def point_mesh_distance(points, x, tris) -> np.ndarray:
    """(P,) exact distance (m) from each point to the closest point of the triangle mesh
    (vertices x (N, 3), triangles (F, 3)); inf for a mesh without triangles."""
    points = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    x = np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(-1, 3))
    tris = np.ascontiguousarray(np.asarray(tris, dtype=np.int64).reshape(-1, 3))
    if tris.shape[0] == 0:
        return np.full(points.shape[0], np.inf)
    corners = x[tris]
    nlo, nhi, left, start, count, order = _bvh_build(np.ascontiguousarray(corners.min(axis=1)),
                                                     np.ascontiguousarray(corners.max(axis=1)))
    return _closest_distances(points, x, tris, nlo, nhi, left, start, count, order)


def offscreen_distance(camera, run_x, ref_x, ref_tris) -> tuple[float, int]:
    """(offscreen_distance_m, number of nodes outside): the mean distance from the run's nodes
    outside the camera frustum to the reference cloth surface; NaN when no node is outside."""
    run_x = np.asarray(run_x, dtype=np.float64).reshape(-1, 3)
    outside = camera.distance_to_frustum(run_x) > 0.0
    n = int(outside.sum())
    if n == 0:
        return float("nan"), 0
    return float(point_mesh_distance(run_x[outside], ref_x, ref_tris).mean()), n
