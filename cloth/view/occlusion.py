"""Occlusion of cloth faces under a camera (not in the paper; ``view.occlusion``).

The paper's view factor treats a face as visible when it lies in the frustum and faces the camera
(eq 3's nu_front), so cloth hidden behind the body, or behind other cloth, is refined as if it
were seen. With ``view.occlusion`` on, such a face counts as back-facing (nu_back) instead. What
hides it is read from a z-buffer (:mod:`cloth.view.zbuffer`, the rasteriser of the accuracy
measures) of the obstacles and the cloth itself under that camera, at ``view.occlusion_scale``
times the camera's image size (0.25: 320 x 180 pixels for a 1280 x 720 camera).

The test, per face that is in frame and front-facing (:func:`occluded_faces`):

* Samples: the face's three corners and its centroid (SAMPLE_WEIGHTS). A face is occluded when
  every sample is hidden, so a face that peeks out anywhere stays visible. The corners matter
  for cloth lying on the body: contact keeps the nodes a thickness h outside the obstacles,
  while a coarse face spanning a curved limb cuts into it (a chord: its centroid can lie
  centimetres inside the body, where the body's surface is in front of it); the corners of such
  a face are outside the body and seen, so the body never hides the cloth that lies on it.
* Own depth: the sample's pixel of the z-buffer holds the depth of whatever surface covers the
  pixel's centre, not the sample's point; a sample is compared with its face's plane at that
  centre (the ray through the pixel centre meets the plane at z_plane), and with its own depth z
  where that is nearer: z_own = min(z, z_plane). Then a flat surface never hides itself at any
  inclination, and where the face's plane and the sample disagree (a grazing face) the nearer
  of the two can only hide less.
* Hidden: the z-buffer depth D at the pixel is nearer than z_own by more than the tolerance
  tau = OCCLUSION_THICKNESS_FACTOR h + OCCLUSION_PIXEL_FACTOR z_own / f, with h the scene's
  contact thickness and f the z-buffer's focal length in pixels (z / f: one pixel of the buffer
  at that depth). A sample outside the image (or behind the near plane) is not hidden.

Limits: the occluders are the obstacles of the character's own simulation. A crowd
(``multiple_dancers``) simulates every dancer in its own process (experiments/run.py), and its
scene holds only that dancer's body (cloth.scenes.crowd.multiple_dancers): the other dancers'
cloth is not there at all, and their bodies, though prescribed, are not built in the process, so
neither hides anything. Occluders are drawn with the current geometry; nothing predicts where
the cloth or the body will be at a future camera sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cloth.view.camera import Camera
from cloth.view.zbuffer import ScreenImage, render_frame

# Segments around a capsule in the occluders' tessellation (cloth.collision.obstacles
# .capsule_tessellation): its facets lie inside the capsule by at most r (1 - cos(pi / 12)) =
# 3.4 % of the radius, so the body is drawn slightly thin and can only hide less than it should.
OCCLUDER_SEGMENTS = 12
# Depth tolerance, part 1, in thicknesses h: surfaces in contact are about h apart (contact leaves
# cloth nodes h off the obstacles, self-collision keeps layers h apart, and the facets of a
# tessellated obstacle lie inside it); twice that keeps cloth lying on other cloth, whose faces
# sag a little past h between their nodes, from counting as hidden by it.
OCCLUSION_THICKNESS_FACTOR = 2.0
# Depth tolerance, part 2, in z-buffer pixels at the sample's depth: the buffer holds the nearest
# surface at pixel centres; at a bend of the cloth a neighbouring face, not the sample's own
# plane, covers the centre, up to about one pixel away, and departs from the plane by that
# distance times the tangent of the bend; one pixel allows bends up to 45 degrees between faces.
OCCLUSION_PIXEL_FACTOR = 1.0
# Barycentric weights of a face's samples (4, 3): its three corners and its centroid.
SAMPLE_WEIGHTS = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]]) / [[1], [1], [1], [3]]


@dataclass(frozen=True)
class Occluders:
    """What can hide cloth besides the cloth itself: the obstacles' triangles at one instant."""

    obstacle_x: np.ndarray  # (M, 3) float64, metres, world space
    obstacle_tris: np.ndarray  # (L, 3) int64, indices into obstacle_x
    thickness: float  # metres, the scene's contact thickness h (the depth tolerance's unit)


def obstacle_occluders(obstacles, thickness: float, segments: int = OCCLUDER_SEGMENTS) -> Occluders:
    """The `obstacles` (cloth.collision.obstacles.Obstacle or TriangleMeshObstacle, each at the pose
    its caller set with set_time) as one triangle soup: their display meshes (`to_mesh`; capsules
    with `segments` around, triangle meshes as they are, planes as their display square)."""
    if not thickness >= 0:
        raise ValueError(f"occluders: the thickness must be >= 0 m, got {thickness}")
    xs, ts, n = [np.zeros((0, 3))], [np.zeros((0, 3), dtype=np.int64)], 0
    for ob in obstacles:
        v, f = ob.to_mesh(segments)
        v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
        xs.append(v)
        ts.append(np.asarray(f, dtype=np.int64).reshape(-1, 3) + n)
        n += v.shape[0]
    return Occluders(np.concatenate(xs), np.concatenate(ts), float(thickness))


def camera_directions(camera: Camera, vectors: np.ndarray) -> np.ndarray:
    """(N, 3) camera coordinates (right, up, forward) of world direction vectors (N, 3)."""
    rdf = np.asarray(vectors, dtype=np.float64) @ camera.rotation()  # right, down, forward
    return rdf * np.array([1.0, -1.0, 1.0])


def hidden_samples(image: ScreenImage, camera: Camera, points: np.ndarray, normals: np.ndarray,
                   tolerance_m: float, tolerance_px: float) -> np.ndarray:
    """(N,) bool: sample `points` (N, 3) on faces with unit `normals` (N, 3), world space, that the
    z-buffer `image` (rendered by `camera` at image.scale) shows something in front of: its depth
    at the sample's pixel is nearer than z_own - tolerance_m - tolerance_px z_own / f (module
    docstring: z_own the nearer of the sample's depth and its face plane's at the pixel centre)."""
    c = camera.to_camera(points)
    z = c[:, 2]
    W, H = image.resolution
    f = image.focal_px
    with np.errstate(divide="ignore", invalid="ignore"):
        u = W / 2.0 + f * c[:, 0] / z
        v = H / 2.0 - f * c[:, 1] / z
    inside = (z >= camera.near) & (u >= 0.0) & (u < W) & (v >= 0.0) & (v < H)  # False for NaN
    hidden = np.zeros(points.shape[0], dtype=bool)
    if not inside.any():
        return hidden
    c, z = c[inside], z[inside]
    i, j = np.floor(u[inside]).astype(np.int64), np.floor(v[inside]).astype(np.int64)
    ray = np.column_stack([(i + 0.5 - W / 2.0) / f, -(j + 0.5 - H / 2.0) / f, np.ones(len(i))])  # depth 1
    n_c = camera_directions(camera, normals[inside])
    denom = np.einsum("ij,ij->i", n_c, ray)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_plane = np.einsum("ij,ij->i", n_c, c) / denom  # the face's plane along the pixel-centre ray
    valid = np.isfinite(z_plane) & (z_plane >= camera.near)
    z_own = np.where(valid, np.minimum(z, z_plane), z)
    tolerance = tolerance_m + tolerance_px * z_own / f
    hidden[inside] = image.depth[j, i] < z_own - tolerance
    return hidden


def occluded_faces(camera: Camera, node_x: np.ndarray, face_nodes: np.ndarray, face_normals: np.ndarray,
                   faces: np.ndarray, occluders: Occluders, scale: float) -> np.ndarray:
    """(len(faces),) bool: which of `faces` (indices) are hidden under `camera`: every one of their
    samples (SAMPLE_WEIGHTS) lies behind the z-buffer of the occluders and the whole cloth
    (`node_x` (N, 3) m, `face_nodes` (F, 3), unit `face_normals` (F, 3)) rendered at `scale`
    times the camera's image size (module docstring)."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1)
    if faces.size == 0:
        return np.zeros(0, dtype=bool)
    image = render_frame(camera, node_x, face_nodes, occluders.obstacle_x, occluders.obstacle_tris, scale)
    corners = node_x[face_nodes[faces]]  # (C, 3, 3)
    points = np.einsum("sk,ckd->csd", SAMPLE_WEIGHTS, corners).reshape(-1, 3)  # (C * S, 3)
    normals = np.repeat(face_normals[faces], SAMPLE_WEIGHTS.shape[0], axis=0)
    hidden = hidden_samples(image, camera, points, normals, OCCLUSION_THICKNESS_FACTOR * occluders.thickness,
                            OCCLUSION_PIXEL_FACTOR)
    return hidden.reshape(faces.size, SAMPLE_WEIGHTS.shape[0]).all(axis=1)
