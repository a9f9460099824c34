"""Shape difference of two triangle meshes of the same cloth (a run of this project against
ARCSim's output, experiments.compare_arcsim): the two-sided surface distance and the difference
of the axis-aligned bounding boxes. Definition version SURFACE_DEFINITION.

**Sampling.** A surface is sampled at its vertices (those of its triangles) and inside each
triangle: the triangle is cut into n^2 equal triangles (each edge into n equal parts), n =
ceil(longest edge / h), at most MAX_SUBDIVISION, and each small triangle gives its centroid, with
its area (the triangle's over n^2) as weight; vertices have weight 0 (they count in the maximum
only). The centroid rule integrates a function that is linear on each small triangle exactly, so
the weighted mean is the surface integral of the distance over the area, resolved to h. The
spacing h defaults to the smaller of the two meshes' median edge lengths (DEFAULT_SPACING_RULE):
the finer mesh is sampled about once to four times per face, the coarser one as finely.

**Distances.** Each sample's distance is the exact distance to the nearest point of the other
triangle mesh (point to triangle, over a box tree: cloth.collision.nearest.point_mesh_distance).
One-sided, from A to B: d_mean(A, B) = sum_s w_s d(s, B) / sum_s w_s over A's samples, and
d_max(A, B) = max_s d(s, B). Two-sided:

    mean = (d_mean(A, B) + d_mean(B, A)) / 2,    max = max(d_max(A, B), d_max(B, A))

(`max` is the sampled Hausdorff distance: a lower bound of the true one, exact where it is
reached at a vertex or a sample). Both are 0 for a mesh against itself and d for a flat sheet
against its copy moved by d along its normal.

**Bounding boxes.** Per axis, the differences of the boxes' lower and upper corners, B minus A,
and the largest of the six in magnitude.
"""

from __future__ import annotations

import numpy as np

from cloth.collision.nearest import point_mesh_distance

SURFACE_DEFINITION = "surface-v1"  # the version of the definitions above
MAX_SUBDIVISION = 64  # at most 64^2 samples per triangle: a huge face against a fine spacing stays affordable
DEFAULT_SPACING_RULE = "the smaller of the two meshes' median edge lengths"
AXES = ("x", "y", "z")


def median_edge_length(x: np.ndarray, tris: np.ndarray) -> float:
    """Median length (m) of the triangles' edges, each edge once per triangle that has it."""
    corners = np.asarray(x, dtype=np.float64)[np.asarray(tris, dtype=np.int64)]  # (F, 3, 3)
    edges = corners[:, [1, 2, 0]] - corners  # (F, 3, 3): edge k runs from corner k to corner k+1
    return float(np.median(np.linalg.norm(edges, axis=2)))


def centroid_pattern(n: int) -> np.ndarray:
    """(n^2, 3) barycentric coordinates of the centroids of the n^2 equal triangles a triangle is
    cut into when each edge is cut into n parts (n(n+1)/2 upright and n(n-1)/2 inverted)."""
    out = []
    for i in range(n):
        for j in range(n - i):
            out.append((3 * i + 1, 3 * j + 1, 3 * (n - i - j) - 2))  # upright: corners (i,j), (i+1,j), (i,j+1)
            if i + j < n - 1:
                out.append((3 * i + 2, 3 * j + 2, 3 * (n - i - j) - 4))  # inverted: (i+1,j), (i,j+1), (i+1,j+1)
    return np.asarray(out, dtype=np.float64) / (3.0 * n)


def surface_samples(x: np.ndarray, tris: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(points (S, 3) m, weights (S,) m^2) of a triangle mesh (vertices x (N, 3), triangles (F, 3)):
    its triangles' vertices with weight 0, then the centroids of each triangle's n^2 equal parts
    with n = ceil(longest edge / spacing) (1 .. MAX_SUBDIVISION), each weighing 1/n^2 of its area.
    The weights sum to the mesh's area."""
    if not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"surface sampling: the spacing must be a number > 0 (m), got {spacing}")
    x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    corners = x[tris]  # (F, 3, 3)
    edges = corners[:, [1, 2, 0]] - corners
    longest = np.linalg.norm(edges, axis=2).max(axis=1) if len(tris) else np.zeros(0)
    area = 0.5 * np.linalg.norm(np.cross(edges[:, 0], -edges[:, 2]), axis=1)  # (F,) m^2
    n_parts = np.clip(np.ceil(longest / spacing), 1, MAX_SUBDIVISION).astype(np.int64)
    used = np.unique(tris)  # the vertices of the triangles (an OBJ may list others)
    points, weights = [x[used]], [np.zeros(used.size)]
    for n in np.unique(n_parts):
        faces = np.flatnonzero(n_parts == n)
        pattern = centroid_pattern(int(n))  # (n^2, 3)
        points.append(np.einsum("pk,fkd->fpd", pattern, corners[faces]).reshape(-1, 3))
        weights.append(np.repeat(area[faces] / n**2, pattern.shape[0]))
    return np.concatenate(points), np.concatenate(weights)


def one_sided_distance(points: np.ndarray, weights: np.ndarray, x: np.ndarray, tris: np.ndarray) -> tuple[float, float]:
    """(weighted mean, max) of the distance (m) from the samples to the triangle mesh (x, tris)."""
    d = point_mesh_distance(points, x, tris)
    total = np.sum(weights)
    mean = np.sum(weights * d) / total if total > 0 else np.mean(d)  # a surface of zero area: its samples alike
    return float(mean), float(d.max())


def surface_distance(xa: np.ndarray, tris_a: np.ndarray, xb: np.ndarray, tris_b: np.ndarray,
                     spacing: float | None = None) -> dict:
    """The two-sided surface distance of meshes A (xa, tris_a) and B (see the module docstring).

    Keys (metres): ``mean_m``, ``max_m`` (two-sided), ``mean_a_to_b_m``, ``mean_b_to_a_m``,
    ``max_a_to_b_m``, ``max_b_to_a_m``; ``spacing_m`` (h: `spacing`, or by DEFAULT_SPACING_RULE when
    None), ``samples_a``, ``samples_b``. ValueError for a mesh without triangles.
    """
    tris_a = np.asarray(tris_a, dtype=np.int64).reshape(-1, 3)
    tris_b = np.asarray(tris_b, dtype=np.int64).reshape(-1, 3)
    if len(tris_a) == 0 or len(tris_b) == 0:
        raise ValueError("surface distance: a mesh has no triangles")
    if spacing is None:
        spacing = min(median_edge_length(xa, tris_a), median_edge_length(xb, tris_b))
    pa, wa = surface_samples(xa, tris_a, spacing)
    pb, wb = surface_samples(xb, tris_b, spacing)
    mean_ab, max_ab = one_sided_distance(pa, wa, xb, tris_b)
    mean_ba, max_ba = one_sided_distance(pb, wb, xa, tris_a)
    return {"mean_m": 0.5 * (mean_ab + mean_ba), "max_m": max(max_ab, max_ba),
            "mean_a_to_b_m": mean_ab, "mean_b_to_a_m": mean_ba, "max_a_to_b_m": max_ab, "max_b_to_a_m": max_ba,
            "spacing_m": float(spacing), "samples_a": int(len(pa)), "samples_b": int(len(pb))}


def bounding_box_difference(xa: np.ndarray, xb: np.ndarray) -> dict:
    """The difference (m) of the axis-aligned bounding boxes of the points xa (N, 3) and xb (M, 3),
    B minus A: ``min_dx_m``, ``min_dy_m``, ``min_dz_m`` (lower corners), ``max_dx_m`` ... (upper
    corners) and ``largest_m``, the largest of the six in magnitude (>= 0)."""
    xa = np.asarray(xa, dtype=np.float64).reshape(-1, 3)
    xb = np.asarray(xb, dtype=np.float64).reshape(-1, 3)
    d_min = xb.min(axis=0) - xa.min(axis=0)
    d_max = xb.max(axis=0) - xa.max(axis=0)
    out = {f"min_d{a}_m": float(v) for a, v in zip(AXES, d_min)}
    out.update({f"max_d{a}_m": float(v) for a, v in zip(AXES, d_max)})
    out["largest_m"] = float(np.abs(np.concatenate([d_min, d_max])).max())
    return out


def material_area(vert_u: np.ndarray, face_verts: np.ndarray) -> float:
    """Total area (m^2) of the triangles in material space (vert_u (V, 2), face_verts (F, 3)):
    what remeshing keeps, so two meshes of the same cloth agree on it."""
    u = np.asarray(vert_u, dtype=np.float64)[np.asarray(face_verts, dtype=np.int64)]  # (F, 3, 2)
    e1, e2 = u[:, 1] - u[:, 0], u[:, 2] - u[:, 0]
    return float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())
