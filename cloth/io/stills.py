"""Still pictures of a frame, as in the paper's Figs. 1, 9 and 10: the camera's view with faces
coloured by view factor (the caller's colours: visible faces blue, hidden ones red, lighter where
the view factor is lower), beside an outside view that shows the camera's frustum in wireframe.

A small painter's-algorithm rasteriser on matplotlib (Agg, no global pyplot state): triangles are
projected by the pinhole camera, sorted far to near by mean depth and drawn with a two-sided
Lambert shade. There is no per-pixel depth test, so interpenetrating triangles may be drawn in
the wrong order; that is enough for a still, not for a measurement.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from cloth.io.manifest import atomic_write
from cloth.view.camera import Camera

OBSTACLE_RGB = (0.72, 0.72, 0.72)  # the body and other obstacles: neutral grey
FRUSTUM_RGB = (0.1, 0.1, 0.1)
AMBIENT = 0.35  # shade = AMBIENT + (1 - AMBIENT) |cos(normal, view)|: back faces are not black
PANEL_WIDTH_IN = 6.0  # inches per panel


def mesh_triangles(mesh) -> np.ndarray:
    """(F, 3, 3) world triangles of a cloth mesh."""
    return mesh.node_x[mesh.vert_node[mesh.face_verts]]


def obstacle_triangles(obstacle, resolution: int = 12) -> np.ndarray:
    """(T, 3, 3) world triangles of an obstacle's display mesh."""
    v, f = obstacle.to_mesh(resolution)
    return np.asarray(v, float)[np.asarray(f)]


def _clip_segment(a, b, camera):
    """The part of segment ab in front of the camera's near plane, or None."""
    da, db = camera.project(np.array([a, b]))[1]
    near = camera.near
    if da < near and db < near:
        return None
    if da < near:
        a = a + (b - a) * (near - da) / (db - da)
    elif db < near:
        b = b + (a - b) * (near - db) / (da - db)
    return a, b


def draw_view(ax, camera, triangles, face_rgb, *, extra=(), shade=True, frustum=None) -> None:
    """Draw what `camera` sees into `ax`: `triangles` (F,3,3) with colours `face_rgb` (F,3) in
    [0, 1], plus `extra` [(triangles (T,3,3), rgb (3,)), ...] (obstacles), far to near. A triangle
    with a corner at or behind the near plane is left out. `frustum`: another Camera whose frustum
    edges are drawn (cut at this camera's near plane), with a marker at its position."""
    from matplotlib.collections import LineCollection, PolyCollection  # noqa: PLC0415 - import cost, see render_still

    tris = [np.asarray(triangles, float).reshape(-1, 3, 3)]
    cols = [np.asarray(face_rgb, float).reshape(-1, 3)]
    for t, rgb in extra:
        t = np.asarray(t, float).reshape(-1, 3, 3)
        tris.append(t)
        cols.append(np.tile(np.asarray(rgb, float), (len(t), 1)))
    tri, col = np.concatenate(tris), np.concatenate(cols)
    if len(tri):
        px, depth = camera.project(tri.reshape(-1, 3))
        px, depth = px.reshape(-1, 3, 2), depth.reshape(-1, 3)
        keep = np.all(depth > camera.near, axis=1)
        tri, col, px, depth = tri[keep], col[keep], px[keep], depth[keep]
        if shade and len(tri):
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            view = tri.mean(axis=1) - np.asarray(camera.position, float)
            cos = np.abs(np.einsum("ij,ij->i", n, view)) / np.maximum(
                np.linalg.norm(n, axis=1) * np.linalg.norm(view, axis=1), 1e-300)
            col = col * (AMBIENT + (1 - AMBIENT) * cos)[:, None]
        order = np.argsort(-depth.mean(axis=1), kind="stable")  # far first
        rgb = np.clip(col[order], 0, 1)  # edges in the face colour close the anti-aliasing seams
        ax.add_collection(PolyCollection(px[order], facecolors=rgb, edgecolors=rgb, linewidths=0.3))
    if frustum is not None:
        c = frustum.frustum_corners()
        segs = [s for s in (_clip_segment(c[i], c[j], camera) for i, j in frustum.FRUSTUM_EDGES) if s is not None]
        if segs:
            p = camera.project(np.array(segs).reshape(-1, 3))[0].reshape(-1, 2, 2)
            ax.add_collection(LineCollection(p, colors=[FRUSTUM_RGB], linewidths=0.8))
        pos = np.asarray(frustum.position, float)[None]
        ppx, pd = camera.project(pos)
        if pd[0] > camera.near:
            ax.plot(ppx[0, 0], ppx[0, 1], marker="o", color=FRUSTUM_RGB, markersize=4)
    ax.set_xlim(0, camera.width)
    ax.set_ylim(camera.height, 0)  # pixel y grows downwards
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_linewidth(0.6)


def outside_camera(camera, points, *, distance_factor: float = 2.5, fov_y_deg: float = 40.0):
    """A third-person camera (z up) that sees the scene `points` (N,3) and `camera`'s position:
    it looks at the centre of their bounding box from behind the camera, above and to its side,
    far enough for the bounding sphere to fit the field of view."""
    pts = np.vstack([np.asarray(points, float).reshape(-1, 3), np.asarray(camera.position, float)[None]])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2
    radius = max(0.5 * np.linalg.norm(hi - lo), 0.1)
    back = centre - np.asarray(camera.look_at, float) + (np.asarray(camera.position, float) - centre)
    back[2] = 0.0
    if np.linalg.norm(back) < 1e-9:
        back = np.array([0.0, -1.0, 0.0])
    back /= np.linalg.norm(back)
    side = np.cross([0.0, 0.0, 1.0], back)
    direction = back + 0.6 * side + np.array([0.0, 0.0, 0.7])
    direction /= np.linalg.norm(direction)
    aspect = camera.width / camera.height
    half = np.radians(fov_y_deg) / 2
    fit = radius / np.sin(min(half, np.arctan(aspect * np.tan(half))))  # bounding sphere in the view
    dist = max(fit, distance_factor * radius)
    return Camera(tuple(centre + dist * direction), tuple(centre), (0.0, 0.0, 1.0), fov_y_deg,
                  camera.width, camera.height, near=min(0.05, dist / 100), far=dist + 4 * radius)


def render_still(path, camera, triangles, face_rgb, *, extra=(), title=None, dpi=100) -> Path:
    """One PNG: the camera's view (left) and an outside view with the frustum (right). The
    frustum is drawn out to the scene's far extent, not to the far plane. Written atomically."""
    # matplotlib costs ~1.4 s to import (python -X importtime): paid only by runs that write stills
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415 - import cost, above
    from matplotlib.figure import Figure  # noqa: PLC0415 - import cost, above

    path = Path(path)
    pts = [np.asarray(triangles, float).reshape(-1, 3)] + [np.asarray(t, float).reshape(-1, 3) for t, _ in extra]
    pts = np.concatenate(pts)
    depth = camera.project(pts)[1] if len(pts) else np.array([camera.near])
    far = float(np.clip(depth.max() * 1.1, camera.near * 2, camera.far))
    aspect = camera.height / camera.width
    fig = Figure(figsize=(2 * PANEL_WIDTH_IN, PANEL_WIDTH_IN * aspect + (0.6 if title else 0.35)), dpi=dpi)
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)
    draw_view(left, camera, triangles, face_rgb, extra=extra)
    left.set_title("camera view", fontsize=9)
    outside = outside_camera(camera, pts if len(pts) else np.zeros((1, 3)))
    draw_view(right, outside, triangles, face_rgb, extra=extra, frustum=replace(camera, far=far))
    right.set_title("outside view", fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_write(path, durable=False) as tmp:  # one per frame or so: no fsync
        fig.savefig(tmp, dpi=dpi, format="png")
    return path
