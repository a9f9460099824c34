"""Closest points on a triangle mesh: a branch-and-bound search, in numba, over the box tree of
cloth.collision.bvh (`build_tree` over the triangles' boxes) for a point's nearest triangle and
the barycentric coordinates of the closest point on it.

    d2, f, w0, w1, w2 = nearest_triangle(p, root, x, faces, *tree, bound2, stack)  # in a kernel
    dist = point_mesh_distance(points, x, faces)                                    # (P,) from Python

One search for two users: the triangle-mesh obstacles (cloth.collision.meshobstacle, whose
kernels in cloth.collision.meshkernels add the sign, normal and a refit of the tree as the mesh
moves) and the evaluation (cloth.eval.screenspace: distance of off-screen nodes to the
reference cloth).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cloth.collision.bvh import build_tree
from cloth.collision.ccd import point_triangle_closest, region_weights


@njit(cache=True)
def box_distance2(p, lo, hi):
    """Squared distance from point p (3,) to the box [lo, hi] (0 inside)."""
    d2 = 0.0
    for d in range(3):
        if p[d] < lo[d]:
            d2 += (lo[d] - p[d]) ** 2
        elif p[d] > hi[d]:
            d2 += (p[d] - hi[d]) ** 2
    return d2


@njit(cache=True)
def closest_on_triangle(p, x, ia, ib, ic):
    """(squared distance, w0, w1, w2) from p to triangle (x[ia], x[ib], x[ic]): Ericson's
    Voronoi-region tests on scalars (no temporaries). A degenerate triangle goes to
    cloth.collision.ccd.point_triangle_closest, which handles it by its edges."""
    ax, ay, az = x[ia, 0], x[ia, 1], x[ia, 2]
    abx, aby, abz = x[ib, 0] - ax, x[ib, 1] - ay, x[ib, 2] - az
    acx, acy, acz = x[ic, 0] - ax, x[ic, 1] - ay, x[ic, 2] - az
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    ab2, ac2 = abx * abx + aby * aby + abz * abz, acx * acx + acy * acy + acz * acz
    if nx * nx + ny * ny + nz * nz <= 1e-30 * max(ab2, ac2) ** 2:
        d, w0, w1, w2 = point_triangle_closest(p, x[ia], x[ib], x[ic])
        return d * d, w0, w1, w2
    apx, apy, apz = p[0] - ax, p[1] - ay, p[2] - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        w0, w1, w2 = 1.0, 0.0, 0.0
    else:
        bpx, bpy, bpz = apx - abx, apy - aby, apz - abz
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx, cpy, cpz = apx - acx, apy - acy, apz - acz
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        w0, w1, w2 = region_weights(d1, d2, d3, d4, d5, d6)
    rx = apx - w1 * abx - w2 * acx
    ry = apy - w1 * aby - w2 * acy
    rz = apz - w1 * abz - w2 * acz
    return rx * rx + ry * ry + rz * rz, w0, w1, w2


@njit(cache=True)
def nearest_triangle(p, root, x, faces, nlo, nhi, left, start, count, order, bound2, stack):
    """Nearest triangle to p in the tree at node `root` among those closer than sqrt(bound2):
    (squared distance, face or -1, w0, w1, w2). Branch and bound, nearer child first.

    x (V, 3) vertex positions; faces (F, 3) vertex indices; (nlo, nhi, left, start, count,
    order) the tree of cloth.collision.bvh.build_tree over the faces' boxes (possibly a forest:
    several trees concatenated, one per root); stack: int64 scratch of at least n_nodes + 1."""
    best, best_f, b0, b1, b2 = bound2, -1, 0.0, 0.0, 0.0
    top = 0
    stack[0] = root
    while top >= 0:
        k = stack[top]
        top -= 1
        if box_distance2(p, nlo[k], nhi[k]) >= best:
            continue
        if left[k] < 0:
            for a in range(start[k], start[k] + count[k]):
                f = order[a]
                d2, w0, w1, w2 = closest_on_triangle(p, x, faces[f, 0], faces[f, 1], faces[f, 2])
                if d2 < best:
                    best, best_f, b0, b1, b2 = d2, f, w0, w1, w2
            continue
        L = left[k]
        dl = box_distance2(p, nlo[L], nhi[L])
        dr = box_distance2(p, nlo[L + 1], nhi[L + 1])
        near, far, dn, df = L, L + 1, dl, dr
        if dr < dl:
            near, far, dn, df = L + 1, L, dr, dl
        if df < best:
            top += 1
            stack[top] = far
        if dn < best:
            top += 1
            stack[top] = near
    return best, best_f, b0, b1, b2


@njit(cache=True)
def _nearest_distances(points, x, faces, nlo, nhi, left, start, count, order):
    """Distance of each point to its nearest triangle (the tree rooted at node 0)."""
    n = points.shape[0]
    out = np.empty(n)
    stack = np.empty(nlo.shape[0] + 1, dtype=np.int64)
    for i in range(n):
        d2, f, w0, w1, w2 = nearest_triangle(points[i], 0, x, faces, nlo, nhi, left, start, count, order, np.inf, stack)
        out[i] = np.sqrt(d2)
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
    tree = build_tree(np.ascontiguousarray(corners.min(axis=1)), np.ascontiguousarray(corners.max(axis=1)))
    return _nearest_distances(points, x, tris, *tree)
