"""An error measure people see (beyond the paper, which names perceptual error as future work):
FLIP (Andersson et al. 2020, the ``flip-evaluator`` package) between shaded renders of the cloth.

A state is rendered by the project's z-buffer (cloth.view.zbuffer, the same pixels as the geometric
measures) and shaded flat with one fixed light: every pixel of a face takes its albedo times
AMBIENT + DIFFUSE |n . l| (two-sided: the cloth is thin, and a face seen from behind is lit as from
the front), the cloth in CLOTH_RGB, the obstacles in OCCLUDER_RGB, the background black. The light
comes from the camera's upper left (LIGHT_IN_CAMERA, in the camera's right, up, backward axes), so
that a render depends on the camera and the geometry only. FLIP compares the reference's render
with the run's, both low dynamic range sRGB images in [0, 1], at PIXELS_PER_DEGREE (FLIP's default
observer: a 0.7 m viewing distance on a 4K 0.7 m wide display); its mean over the pixels is the
window's perceptual error, 0 for identical images and near 1 for black against white.
"""

from __future__ import annotations

import numpy as np

from cloth.eval.screenspace import occluder_mesh
from cloth.view.zbuffer import CLOTH, OCCLUDER, ScreenImage, render_frame

CLOTH_RGB = np.array([0.75, 0.32, 0.26])  # a red cloth: FLIP weighs colour as well as luminance
OCCLUDER_RGB = np.array([0.55, 0.55, 0.55])
AMBIENT, DIFFUSE = 0.15, 0.85  # the shaded value runs from AMBIENT (edge-on to the light) to 1 (facing it)
LIGHT_IN_CAMERA = np.array([-0.4, 0.6, 0.7])  # from the upper left, in front of the image (right, up, back)
PIXELS_PER_DEGREE = 67.0  # FLIP's default observer


def face_normals(x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of triangles (zero for a degenerate one)."""
    t = np.asarray(tris, dtype=np.int64)
    n = np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]])
    length = np.linalg.norm(n, axis=1)
    return np.where(length[:, None] > 0, n / np.maximum(length, 1e-300)[:, None], 0.0)


def light_direction(camera) -> np.ndarray:
    """(3,) unit world direction towards the light (LIGHT_IN_CAMERA in the camera's axes)."""
    right = camera.rotation()[:, 0]
    up = -camera.rotation()[:, 1]
    back = -camera.forward
    d = LIGHT_IN_CAMERA[0] * right + LIGHT_IN_CAMERA[1] * up + LIGHT_IN_CAMERA[2] * back
    return d / np.linalg.norm(d)


def shade(image: ScreenImage, cloth_normals: np.ndarray, occluder_normals: np.ndarray | None, light) -> np.ndarray:
    """(H, W, 3) float in [0, 1]: the z-buffer `image` shaded flat (module docstring)."""
    rgb = np.zeros((*image.depth.shape, 3))
    for mesh, normals, albedo in ((CLOTH, cloth_normals, CLOTH_RGB), (OCCLUDER, occluder_normals, OCCLUDER_RGB)):
        pix = image.mesh_id == mesh
        if normals is None or not pix.any():
            continue
        lit = AMBIENT + DIFFUSE * np.abs(np.asarray(normals)[image.face[pix]] @ np.asarray(light))
        rgb[pix] = lit[:, None] * albedo
    return np.clip(rgb, 0.0, 1.0)


def render_shaded(camera, state: dict, resolution_scale: float = 1.0) -> np.ndarray:
    """The shaded render of a state (cloth.io.states: node_x, face_nodes and its obstacles)."""
    ox, of = occluder_mesh(state)
    image = render_frame(camera, state["node_x"], state["face_nodes"], ox, of, resolution_scale)
    occ = face_normals(ox, of) if len(of) else None
    return shade(image, face_normals(state["node_x"], state["face_nodes"]), occ, light_direction(camera))


def flip_error(reference: np.ndarray, test: np.ndarray, ppd: float = PIXELS_PER_DEGREE) -> float:
    """The mean FLIP error of two LDR images (H, W, 3) in [0, 1] (needs the flip-evaluator package)."""
    import flip_evaluator  # noqa: PLC0415 - optional (the perceptual extra), only when asked for

    a = np.ascontiguousarray(reference, dtype=np.float32)
    b = np.ascontiguousarray(test, dtype=np.float32)
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"flip_error: two (H, W, 3) images of one size, got {a.shape} and {b.shape}")
    return float(flip_evaluator.evaluate(a, b, "LDR", applyMagma=False, parameters={"ppd": float(ppd)})[1])
