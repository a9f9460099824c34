"""Screen-space accuracy of a run against a fine reference of the same scene and camera.

Two parts, all numpy/numba and independent of Hydra, over the per-frame states the runner
writes into ``states/frame_NNNNN.npz`` (:func:`cloth.io.states.save_state`, read back by
:func:`cloth.io.states.load_state`):

* **A z-buffer rasteriser** (:func:`rasterize`, :func:`render_frame`, from
  :mod:`cloth.view.zbuffer`): triangle meshes through a :class:`cloth.view.camera.Camera`,
  sampled at pixel centres (pixel (i, j) covers [i, i+1] x [j, j+1] with the origin at the
  image's top-left corner, as :meth:`Camera.project`), two-sided, clipped at the near plane,
  with perspective-correct depth. Every pixel keeps the nearest surface: its depth (distance
  along the viewing direction, metres), which mesh it belongs to (``CLOTH`` or ``OCCLUDER``;
  ``EMPTY`` where nothing is seen) and the face index within that mesh. :func:`render_state`
  renders a saved state with its obstacles.
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

import numpy as np
from scipy.ndimage import distance_transform_edt

from cloth.collision.nearest import point_mesh_distance
from cloth.collision.obstacles import capsule_tessellation

# The rasteriser lives in cloth.view.zbuffer (the view-dependent sizing's occlusion test uses it
# too); its names are re-exported here, where the accuracy measures and their tests find them.
from cloth.view.zbuffer import CLOTH as CLOTH
from cloth.view.zbuffer import EMPTY as EMPTY
from cloth.view.zbuffer import OCCLUDER as OCCLUDER
from cloth.view.zbuffer import ScreenImage as ScreenImage
from cloth.view.zbuffer import rasterize as rasterize
from cloth.view.zbuffer import render_frame as render_frame

DEFINITION_VERSION = "screenspace-v2"  # v2: popping_px

OCCLUDER_RESOLUTION = 24  # segments around a capsule of the body: facet sag below 1% of its radius


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
