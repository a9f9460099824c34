"""Numba kernels of the triangle-mesh obstacles (cloth.collision.meshobstacle.TriangleMeshObstacle):
the refit of their box forest as the mesh moves, the signed distance of a point from its closest
feature, and the query of every point (nearest triangle by cloth.collision.nearest, sign from the
angle-weighted pseudo-normals, union of the closed components). The method is described in
cloth.collision.meshobstacle's docstring.

Arrays: x (V, 3) vertex positions (m); faces (F, 3) vertex indices; face_n (F, 3) unit face
normals; vert_pn (V, 3) vertex pseudo-normals; face_edge_pn (F, 3, 3) pseudo-normals of each
face's edges (a-b, b-c, c-a); the forest (nlo, nhi, left, start, count, order) as built by
cloth.collision.bvh.build_tree, one tree per root, concatenated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cloth.collision.bvh import refit
from cloth.collision.nearest import box_distance2, nearest_triangle


@njit(cache=True)
def refit_tree(x, faces, nlo, nhi, left, start, count, order):
    """Refit the boxes of a forest of trees to the triangles at positions x (in place): the
    triangles' boxes, then cloth.collision.bvh.refit (children are stored after their parent, in
    every tree of the forest). Returns the summed box extents (growth measure)."""
    lo = np.empty((faces.shape[0], 3))
    hi = np.empty((faces.shape[0], 3))
    for f in range(faces.shape[0]):
        for d in range(3):
            lo[f, d] = min(x[faces[f, 0], d], x[faces[f, 1], d], x[faces[f, 2], d])
            hi[f, d] = max(x[faces[f, 0], d], x[faces[f, 1], d], x[faces[f, 2], d])
    return refit(lo, hi, nlo, nhi, left, start, count, order)


@njit(cache=True)
def _signed(p, f, w0, w1, w2, d, x, faces, face_n, vert_pn, face_edge_pn, tiny, n_out):
    """Signed distance of p whose closest point is (w0, w1, w2) on face f at distance d; writes
    the outward normal into n_out. The sign is that of (p - c) . pseudo-normal of the feature."""
    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
    if w1 == 0.0 and w2 == 0.0:
        pn = vert_pn[a]
    elif w0 == 0.0 and w2 == 0.0:
        pn = vert_pn[b]
    elif w0 == 0.0 and w1 == 0.0:
        pn = vert_pn[c]
    elif w2 == 0.0:
        pn = face_edge_pn[f, 0]  # edge a-b
    elif w0 == 0.0:
        pn = face_edge_pn[f, 1]  # edge b-c
    elif w1 == 0.0:
        pn = face_edge_pn[f, 2]  # edge c-a
    else:
        pn = face_n[f]
    s = 0.0
    r = np.empty(3)
    for k in range(3):
        r[k] = p[k] - (w0 * x[a, k] + w1 * x[b, k] + w2 * x[c, k])
        s += r[k] * pn[k]
    sign = 1.0 if s >= 0.0 else -1.0
    if d > tiny:
        for k in range(3):
            n_out[k] = sign * r[k] / d
    else:  # on the surface: the feature's pseudo-normal (the face's if it vanishes)
        L = np.sqrt(pn[0] * pn[0] + pn[1] * pn[1] + pn[2] * pn[2])
        for k in range(3):
            n_out[k] = pn[k] / L if L > 0.0 else face_n[f, k]
    return sign * d


@njit(cache=True)
def query_closest(points, x, faces, face_n, vert_pn, face_edge_pn, face_comp, comp_root, comp_closed,
                  nlo, nhi, left, start, count, order, bound2, tiny, phi, normal, face, bary):
    """Signed distance, outward normal, closest face and barycentric weights of every point.

    Tree 0 (root 0) holds all faces; with several components, comp_root[c] is the root of the
    tree of component c. The nearest triangle overall gives the distance and (for an outside
    point) the answer; a closed component whose box holds the point is searched on its own,
    and the smallest signed distance wins (the union of the components)."""
    stack = np.empty(nlo.shape[0] + 1, dtype=np.int64)
    n_c = np.empty(3)
    C = comp_root.shape[0]
    for i in range(points.shape[0]):
        p = points[i]
        d2, f, w0, w1, w2 = nearest_triangle(p, 0, x, faces, nlo, nhi, left, start, count, order, bound2, stack)
        face[i] = f
        if f < 0:
            phi[i] = np.sqrt(bound2)
            for k in range(3):
                normal[i, k] = 0.0
                bary[i, k] = 0.0
            continue
        phi[i] = _signed(p, f, w0, w1, w2, np.sqrt(d2), x, faces, face_n, vert_pn, face_edge_pn, tiny, normal[i])
        bary[i, 0], bary[i, 1], bary[i, 2] = w0, w1, w2
        if C < 2:
            continue
        own = face_comp[f]
        for c in range(C):
            r = comp_root[c]
            if c == own or not comp_closed[c] or box_distance2(p, nlo[r], nhi[r]) > 0.0:
                continue
            e2, g, v0, v1, v2 = nearest_triangle(p, r, x, faces, nlo, nhi, left, start, count, order, bound2, stack)
            if g < 0:
                continue
            value = _signed(p, g, v0, v1, v2, np.sqrt(e2), x, faces, face_n, vert_pn, face_edge_pn, tiny, n_c)
            if value < phi[i]:
                phi[i] = value
                face[i] = g
                bary[i, 0], bary[i, 1], bary[i, 2] = v0, v1, v2
                for k in range(3):
                    normal[i, k] = n_c[k]



@njit(cache=True)
def _corner_sides(x, faces, face_n):
    """Unit face normals into face_n (F, 3) (0 for a degenerate face), and per corner k of each
    face the sine and cosine sides (|e1 x e2|, e1 . e2) of its angle, (3, F) each, e1 and e2 the
    edges from the corner to the next two."""
    F = faces.shape[0]
    sin_side, cos_side = np.empty((3, F)), np.empty((3, F))
    for f in range(F):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        u0, u1, u2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        w0, w1, w2 = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        n0, n1, n2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
        L = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if not L > 0.0:
            L = 1.0
        face_n[f, 0], face_n[f, 1], face_n[f, 2] = n0 / L, n1 / L, n2 / L
        for k in range(3):
            p, q, r = faces[f, k], faces[f, (k + 1) % 3], faces[f, (k + 2) % 3]
            e10, e11, e12 = x[q, 0] - x[p, 0], x[q, 1] - x[p, 1], x[q, 2] - x[p, 2]
            e20, e21, e22 = x[r, 0] - x[p, 0], x[r, 1] - x[p, 1], x[r, 2] - x[p, 2]
            c0, c1, c2 = e11 * e22 - e12 * e21, e12 * e20 - e10 * e22, e10 * e21 - e11 * e20
            sin_side[k, f] = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            # summed as numpy's einsum sums three terms, (0 + 2) + 1: the vectorised version's bits
            cos_side[k, f] = (e10 * e20 + e12 * e22) + e11 * e21
    return sin_side, cos_side


@njit(cache=True)
def _accumulate_normals(faces, face_edge, face_n, angle, vert_pn, edge_pn):
    """Angle-weighted vertex pseudo-normals into vert_pn and edge pseudo-normals (the sum of the
    faces' normals) into edge_pn, summed as numpy's bincount sums them (face by face, corner 0 of
    every face, then 1, then 2)."""
    part = np.empty(vert_pn.shape)
    vert_pn[:] = 0.0
    for k in range(3):
        part[:] = 0.0
        for f in range(faces.shape[0]):
            p = faces[f, k]
            for d in range(3):
                part[p, d] += angle[k, f] * face_n[f, d]
        vert_pn += part
    edge_pn[:] = 0.0
    for f in range(faces.shape[0]):
        for j in range(3):
            e = face_edge[f, j]
            for d in range(3):
                edge_pn[e, d] += face_n[f, d]


def pseudo_normals(x, faces, face_edge, face_n, vert_pn, edge_pn):
    """Unit face normals, angle-weighted vertex pseudo-normals and edge pseudo-normals of the mesh
    at positions x, into face_n (F, 3), vert_pn (V, 3) and edge_pn (E, 3). The corner angles use
    numpy's arctan2 (its vectorised one differs from the C library's in the last bit for some
    arguments), so the result is bitwise the earlier numpy version's."""
    sin_side, cos_side = _corner_sides(x, faces, face_n)
    _accumulate_normals(faces, face_edge, face_n, np.arctan2(sin_side, cos_side), vert_pn, edge_pn)
