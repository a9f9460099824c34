"""On-screen error of the visible cloth by material correspondence (re-synchronised error).

Two runs of one garment started from the same state (the reference's, see
:meth:`cloth.simulation.Simulation.restart_from`) carry the same material points for a few
frames, whatever their meshes: a point of the pattern (material coordinates, ``vert_u``) is the
same piece of cloth in both. After H frames, the run's error is where it puts the cloth the
viewer sees, measured against where the reference puts it.

Definition (version :data:`DEFINITION_VERSION`)
-----------------------------------------------
The reference is rendered with the frame's camera (cloth.eval.screenspace.render_frame, body
drawn as occluder, at ``resolution_scale`` x the camera's image). Every pixel whose nearest
surface is cloth gives one sample: the material point seen at the pixel centre (the ray's
intersection with the reference face seen there, perspective-correct). That point is located
in the run's mesh (in material space, within the same garment piece: cloth.core.transfer) and
both its positions, the reference's and the run's, are projected with the camera. Its error is
the distance between the two projections, in pixels of the camera's own image (a point behind
the camera counts as the image diagonal).

* ``sync_error_px``: the mean error over the samples (0 when the reference shows no cloth: NaN);
* ``sync_error_p90_px``: their 90th percentile;
* ``sync_error_mm``: the mean error in millimetres on the cloth: each sample's pixels times its
  size at the reference point's depth (depth / focal length), so that a close-up and a wide shot
  weigh the same displacement alike (a pixel is 1 mm of the dancer in the close-up, 4 mm in the
  wide shot); ``sync_error_p90_mm`` its 90th percentile;
* ``sync_error_px1080``: the mean error in pixels of a 1920x1080 image of the same framing (the
  camera's pixels times the ratio of the image diagonals: 1.5 for a 1280x720 camera);
* ``sync_samples``: how many samples (pixels of the rendered image).

A rigid sideways shift of the cloth by k pixels gives k, by k mm at a constant depth gives k mm;
identical states give 0. What is not
measured: motion along the viewing ray (it moves nothing on screen), cloth the run shows where
the reference shows none (the samples are the reference's visible points), and shading.
"""

from __future__ import annotations

import numpy as np

from cloth.core.transfer import face_components, locate, match_components
from cloth.eval.screenspace import CLOTH, ScreenImage

DEFINITION_VERSION = "correspondence-v1"
ERROR_KEYS = ("sync_error_px", "sync_error_p90_px", "sync_error_mm", "sync_error_p90_mm", "sync_error_px1080")


def pixel_points(image: ScreenImage, camera, node_x: np.ndarray, face_nodes: np.ndarray):
    """(face (P,), weights (P, 3)) of every cloth pixel of `image` (row-major order): the face seen
    at the pixel centre and the barycentric weights of the point of it the centre's ray meets.
    `node_x`, `face_nodes`: the cloth mesh the image was rendered from."""
    rows, cols = np.nonzero(image.mesh_id == CLOTH)
    face = image.face[rows, cols].astype(np.int64)
    W, H = image.resolution
    f = image.focal_px
    d = np.column_stack([(cols + 0.5 - W / 2.0) / f, -(rows + 0.5 - H / 2.0) / f, np.ones(rows.size)])
    cam = camera.to_camera(node_x)[np.asarray(face_nodes)[face]]  # (P, 3, 3) camera coordinates
    a, e1, e2 = cam[:, 0], cam[:, 1] - cam[:, 0], cam[:, 2] - cam[:, 0]
    n = np.cross(e1, e2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", n, a) / np.einsum("ij,ij->i", n, d)
        p = t[:, None] * d - a
        d00, d01, d11 = (np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e1, e2), np.einsum("ij,ij->i", e2, e2))
        d20, d21 = np.einsum("ij,ij->i", p, e1), np.einsum("ij,ij->i", p, e2)
        den = d00 * d11 - d01 * d01
        w1 = (d11 * d20 - d01 * d21) / den
        w2 = (d00 * d21 - d01 * d20) / den
    w = np.column_stack([1.0 - w1 - w2, w1, w2])
    # a face seen edge-on (or round-off at a vertex): its centroid
    bad = ~np.all(np.isfinite(w), axis=1)
    w[bad] = 1.0 / 3.0
    w = np.clip(w, 0.0, 1.0)  # pixel centres on an edge may fall a hair outside
    return face, w / w.sum(axis=1, keepdims=True)


def material_points(face: np.ndarray, w: np.ndarray, vert_u: np.ndarray, face_verts: np.ndarray) -> np.ndarray:
    """(P, 2) material coordinates of the points (face, weights) of a mesh."""
    return np.einsum("pk,pkd->pd", w, vert_u[np.asarray(face_verts)[face]])


def correspondence_error(camera, ref_image: ScreenImage, ref: dict, run: dict) -> dict:
    """ERROR_KEYS and sync_samples (module docstring) of `run` against `ref`:
    each a dict with node_x, vert_u, vert_node, face_verts (and ``face_nodes`` for `ref`, the
    triangles `ref_image` was rendered from)."""
    face, w = pixel_points(ref_image, camera, ref["node_x"], ref["face_nodes"])
    if face.size == 0:
        return {**dict.fromkeys(ERROR_KEYS, float("nan")), "sync_samples": 0}
    ref_comp, ref_bounds = face_components(ref["vert_u"], ref["face_verts"])
    run_comp, run_bounds = face_components(run["vert_u"], run["face_verts"])
    to_run = match_components(ref_bounds, run_bounds)
    u = material_points(face, w, ref["vert_u"], ref["face_verts"])
    x_ref = np.einsum("pk,pkd->pd", w, ref["node_x"][np.asarray(ref["face_nodes"])[face]])
    run_face, run_w, _ = locate(run["vert_u"], run["face_verts"], run_comp, u, to_run[ref_comp[face]])
    run_nodes = np.asarray(run["vert_node"])[np.asarray(run["face_verts"])[run_face]]
    x_run = np.einsum("pk,pkd->pd", run_w, run["node_x"][run_nodes])
    p_ref, depth = camera.project(x_ref)  # seen by the camera: depth > 0
    p_run, _ = camera.project(x_run)
    err = np.linalg.norm(p_run - p_ref, axis=1)
    err[~np.isfinite(err)] = float(np.hypot(camera.width, camera.height))
    err_mm = err * depth / camera.focal_px * 1e3
    return {"sync_error_px": float(err.mean()), "sync_error_p90_px": float(np.percentile(err, 90)),
            "sync_error_mm": float(err_mm.mean()), "sync_error_p90_mm": float(np.percentile(err_mm, 90)),
            "sync_error_px1080": float(err.mean()) * px1080_scale(camera), "sync_samples": int(face.size)}


def px1080_scale(camera) -> float:
    """Pixels of a 1920x1080 image per pixel of `camera`'s own (the ratio of the image diagonals)."""
    return float(np.hypot(1920.0, 1080.0) / np.hypot(camera.width, camera.height))
