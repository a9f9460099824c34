"""Interpenetration recovery by intersection contour minimisation (Volino and Magnenat-Thalmann
2006), as the paper's section 3.4 uses it after each remesh.

Remeshing moves the surface under the collision handling (a collapse moves a node onto its
neighbour), so two layers of cloth that were apart before a remesh can cross after it, and
continuous collision detection, which assumes an intersection-free start, cannot see them.

For every pair of faces that cross (sharing no node), the crossing is a segment whose two ends
are points where an edge of one face passes through the other face. Its length l is the
pair's share of the intersection contours. Moving either face changes l: at an end point P,
where the edge e (unit) of face A crosses face B (unit normal n_B), and r is the unit vector
from P along the segment towards its other end,

    dl/d(translation of A) = -r + (e.r / e.n_B) n_B,      dl/d(translation of B) = -(e.r / e.n_B) n_B,

(P slides along e to stay in B's plane), which the faces' nodes share by the barycentric
coordinates of P. The nodes of crossing faces form connected components (nodes joined within
each crossing face, not across a crossing pair); each component c moves rigidly by
y_c = -s g_c / m_c, with g_c its summed gradient and m_c its mass, and the step s chosen so
that the linearised total length falls by all of it plus the thickness,
sum_c g_c . y_c = -(L + thickness): the smallest mass-weighted move that would undo every
crossing to first order (capped at the deepest crossing plus the thickness per iteration).
Repeated until no pair crosses or the iteration bound is reached; the record then says how many
crossing pairs remain and how deep they are.

Against triangle-mesh obstacles (cloth.collision.meshobstacle), `untangle(..., obstacles=[(x, faces)])`
tests cloth-obstacle face pairs too and moves only the cloth: the obstacle's nodes are appended
as pinned nodes, so their components never move.

Limitation (as in the method): a contour that is not closed, such as a hem that passes through
another layer along its whole length, has a length that translations do not change (its
gradient vanishes), so such a crossing is not removed; it is counted in the record.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cloth.collision.bvh import cross_overlaps, face_boxes, self_overlaps
from cloth.collision.ccd import edge_triangle_crossing
from cloth.core.records import UNTANGLE_RECORD

# Bound of any node's total displacement in one untangling, in thicknesses: crossings made by a
# remesh are shallow (a collapse or flip moves the surface by a fraction of an edge near the
# layers' gap); moving a node farther than a few thicknesses stretches the cloth more than
# the crossing is worth.
MAX_MOVE_THICKNESSES = 4.0
# Faces whose normals are closer to parallel than this (|n_A x n_B|^2) are treated as coplanar:
# their crossing has no direction and is left to the next iteration (the other pairs move them).
COPLANAR_SIN2 = 1e-12


@njit(cache=True)
def _unit_normal(x, a, b, c):
    n = np.cross(x[b] - x[a], x[c] - x[a])
    L = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    if L > 0.0:
        n /= L
    return n


@njit(cache=True)
def _bary(x, a, b, c, p):
    """Barycentric coordinates of p (in the plane of abc), clamped to >= 0 and normalised."""
    n = np.cross(x[b] - x[a], x[c] - x[a])
    w = np.empty(3)
    w[0] = np.dot(n, np.cross(x[b] - p, x[c] - p))
    w[1] = np.dot(n, np.cross(x[c] - p, x[a] - p))
    w[2] = np.dot(n, np.cross(x[a] - p, x[b] - p))
    s = 0.0
    for k in range(3):
        w[k] = max(w[k], 0.0)
        s += w[k]
    if s == 0.0:
        w[:] = 1.0 / 3.0
    else:
        w /= s
    return w


@njit(cache=True)
def _depth(x, fa, fb):
    """How far face A must move along B's normal to clear B's plane (the smaller way), and the
    same with the roles swapped: the smaller of the two."""
    best = np.inf
    for side in range(2):
        f = fa if side == 0 else fb
        g = fb if side == 0 else fa
        n = _unit_normal(x, g[0], g[1], g[2])
        up, down = 0.0, 0.0
        for k in range(3):
            s = np.dot(n, x[f[k]] - x[g[0]])
            up = max(up, -s)
            down = max(down, s)
        best = min(best, min(up, down))
    return best


@njit(cache=True)
def _crossings(pairs, face_nodes, x, node_g, want_gradient):
    """For each candidate face pair: whether it crosses, the crossing's length and depth; with
    `want_gradient` the length gradient is added to node_g. Returns (crosses, length, depth)."""
    P = pairs.shape[0]
    crosses = np.zeros(P, dtype=np.bool_)
    length = np.zeros(P)
    depth = np.zeros(P)
    pts = np.empty((4, 3))
    src = np.empty((4, 3), dtype=np.int64)  # (face index within pair, edge's local index, unused)
    for k in range(P):
        f = face_nodes[pairs[k, 0]]
        g = face_nodes[pairs[k, 1]]
        shared = False
        for a in range(3):
            for b in range(3):
                if f[a] == g[b]:
                    shared = True
        if shared:
            continue
        m = 0
        for side in range(2):
            A = f if side == 0 else g
            B = g if side == 0 else f
            for e in range(3):
                i, j = A[e], A[(e + 1) % 3]
                hit, s = edge_triangle_crossing(x[i], x[j], x[B[0]], x[B[1]], x[B[2]])
                if hit and m < 4:
                    pts[m] = x[i] + s * (x[j] - x[i])
                    src[m, 0], src[m, 1] = side, e
                    m += 1
        if m < 2:
            continue
        crosses[k] = True
        depth[k] = _depth(x, f, g)
        # the crossing segment's ends: the two crossing points farthest apart
        ia, ib, best = 0, 1, -1.0
        for a in range(m):
            for b in range(a + 1, m):
                d = np.sum((pts[a] - pts[b]) ** 2)
                if d > best:
                    best, ia, ib = d, a, b
        length[k] = np.sqrt(best)
        if not want_gradient or length[k] == 0.0:
            continue
        for end in range(2):
            a = ia if end == 0 else ib
            o = ib if end == 0 else ia
            side, e = src[a, 0], src[a, 1]
            A = f if side == 0 else g
            B = g if side == 0 else f
            i, j = A[e], A[(e + 1) % 3]
            ev = x[j] - x[i]
            ev /= np.sqrt(np.sum(ev * ev))
            nB = _unit_normal(x, B[0], B[1], B[2])
            en = np.dot(ev, nB)
            if en * en < COPLANAR_SIN2:
                continue
            r = (pts[o] - pts[a]) / length[k]
            gB = -(np.dot(ev, r) / en) * nB
            gA = -r - gB
            wA = _bary(x, A[0], A[1], A[2], pts[a])
            wB = _bary(x, B[0], B[1], B[2], pts[a])
            for v in range(3):
                node_g[A[v]] += wA[v] * gA
                node_g[B[v]] += wB[v] * gB
    return crosses, length, depth


def find_intersections(face_nodes: np.ndarray, x: np.ndarray, node_g: np.ndarray | None = None,
                       n_fixed_faces: int = 0):
    """Crossing face pairs (K, 2) of the mesh at positions x, their crossing lengths and depths
    (m); with node_g (N, 3) the gradient of the total crossing length is added to it.
    The last `n_fixed_faces` faces are obstacle triangles: tested against the others only."""
    lo, hi = face_boxes(face_nodes, x)
    if n_fixed_faces:
        F = face_nodes.shape[0] - int(n_fixed_faces)
        cross = cross_overlaps(lo[:F], hi[:F], lo[F:], hi[F:]) + np.array([0, F])
        pairs = np.vstack([self_overlaps(lo[:F], hi[:F]), cross])
    else:
        pairs = self_overlaps(lo, hi)
    g = node_g if node_g is not None else np.zeros((0, 3))
    crosses, length, depth = _crossings(pairs, face_nodes, x, g, node_g is not None)
    return pairs[crosses], length[crosses], depth[crosses]


def with_obstacles(face_nodes: np.ndarray, x: np.ndarray, obstacles):
    """(faces, positions, obstacle face count): the cloth's faces and nodes with the triangles of
    `obstacles` ([(positions, faces), ...]) appended after them, renumbered onto the appended nodes."""
    parts_f, parts_x, n = [face_nodes], [x], x.shape[0]
    for ox, of in obstacles:
        parts_f.append(np.asarray(of, dtype=face_nodes.dtype) + n)
        parts_x.append(np.asarray(ox, dtype=np.float64))
        n += parts_x[-1].shape[0]
    return np.vstack(parts_f), np.vstack(parts_x), sum(f.shape[0] for f in parts_f[1:])


def obstacle_crossings(face_nodes: np.ndarray, x: np.ndarray, obstacles, faces: np.ndarray | None = None) -> np.ndarray:
    """(K, 2) pairs (cloth face, obstacle triangle) that cross: `faces` of the cloth (all if None)
    against the triangles of `obstacles` ([(positions, faces), ...], numbered in that order)."""
    faces = np.arange(face_nodes.shape[0]) if faces is None else np.asarray(faces, dtype=np.int64)
    if not len(obstacles) or faces.size == 0:
        return np.empty((0, 2), dtype=np.int64)
    fn, xa, _ = with_obstacles(np.asarray(face_nodes[faces], dtype=np.int64), x, obstacles)
    lo, hi = face_boxes(fn, xa)
    F = faces.size
    cand = cross_overlaps(lo[:F], hi[:F], lo[F:], hi[F:]) + np.array([0, F])
    crosses = _crossings(cand, fn, xa, np.zeros((0, 3)), False)[0]
    hit = cand[crosses]
    return np.column_stack([faces[hit[:, 0]], hit[:, 1] - F])


def _components(face_nodes, pairs, n_nodes):
    """Components of the nodes of crossing faces, joined within each crossing face; returns the
    list of node arrays and each node's component index (-1 outside)."""
    parent = np.arange(n_nodes)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    faces = np.unique(pairs.ravel())
    for f in faces:
        a, b, c = face_nodes[f]
        ra = find(a)
        for j in (b, c):
            rj = find(j)
            if rj != ra:
                parent[rj] = ra
    members = np.unique(face_nodes[faces].ravel())
    roots = np.array([find(i) for i in members])
    order = np.argsort(roots, kind="stable")
    members, roots = members[order], roots[order]
    comps = np.split(members, np.flatnonzero(np.diff(roots)) + 1)
    label = np.full(n_nodes, -1, dtype=np.int64)
    for c, comp in enumerate(comps):
        label[comp] = c
    return comps, label


def untangle(face_nodes: np.ndarray, x: np.ndarray, node_m: np.ndarray, pinned: np.ndarray,
             thickness: float, max_iterations: int = 30, obstacles=(), n_fixed_faces: int = 0) -> dict:
    """Remove crossings of the mesh with itself by contour minimisation (modifies x in place).

    `obstacles`: [(positions (V, 3), faces (F, 3)), ...] triangle meshes the cloth must not cross
    either (cloth.collision.meshobstacle.mesh_obstacle_triangles); only the cloth moves. `n_fixed_faces`
    (internal): the last faces are such obstacle triangles, their nodes pinned.
    Returns {'intersections_found', 'untangle_iterations', 'intersections_left',
    'intersection_depth_m' (deepest remaining), 'intersection_length_m' (remaining contour)}.
    """
    if max_iterations < 0:
        raise ValueError(f"max_iterations must be >= 0, got {max_iterations}")
    if len(obstacles):  # append the obstacles as pinned nodes and fixed faces, untangle, copy the cloth back
        n = x.shape[0]
        faces_all, x_all, n_fixed = with_obstacles(face_nodes, x, obstacles)
        fixed = np.ones(x_all.shape[0] - n, dtype=bool)
        stats = untangle(faces_all, x_all, np.concatenate([node_m, fixed.astype(float)]),
                         np.concatenate([pinned, fixed]), thickness, max_iterations, n_fixed_faces=n_fixed)
        x[:] = x_all[:n]
        return stats
    stats = dict(UNTANGLE_RECORD)
    best = None  # (crossings, contour length, positions) of the best state seen
    x_init = x.copy()
    max_move = MAX_MOVE_THICKNESSES * thickness
    for it in range(max_iterations + 1):
        g = np.zeros_like(x)
        pairs, length, depth = find_intersections(face_nodes, x, g, n_fixed_faces)
        if it == 0:
            stats["intersections_found"] = len(pairs)
        if len(pairs) == 0:
            return stats
        key = (len(pairs), float(length.sum()))
        if best is None or key < best[:2]:
            best = (*key, x.copy(), depth)
        if it == max_iterations:
            break
        comps, _ = _components(face_nodes, pairs, x.shape[0])
        free = [c[~pinned[c]] for c in comps]
        ok = np.array([f.size > 0 for f in free])
        mass = np.array([node_m[f].sum() if f.size else np.inf for f in free])
        gc = np.array([g[f].sum(axis=0) for f in free])
        denom = float(np.sum(np.einsum("ij,ij->i", gc[ok], gc[ok]) / mass[ok]))
        if denom == 0.0:  # every gradient cancels, or every crossing node is pinned: stuck
            break
        stats["untangle_iterations"] = it + 1
        moves = np.zeros((len(comps), 3))
        moves[ok] = -(float(length.sum()) + thickness) / denom * gc[ok] / mass[ok, None]
        # a nearly cancelling gradient asks for a huge linearised step: no component moves
        # farther than the deepest crossing plus the thickness in one iteration
        cap = float(depth.max()) + thickness
        size = np.linalg.norm(moves, axis=1)
        moves *= np.minimum(1.0, cap / np.maximum(size, 1e-300))[:, None]
        for f, d in zip(free, moves):
            x[f] += d
        # no node goes farther than max_move from where the untangling found it: a tangle that
        # needs more is left (and counted) rather than torn apart, which would store more
        # elastic energy than any crossing costs (a tangled garment was seen to blow up so)
        disp = x - x_init
        dist = np.sqrt(np.einsum("ij,ij->i", disp, disp))
        far = dist > max_move
        if far.any():
            x[far] = x_init[far] + disp[far] * (max_move / dist[far])[:, None]
    # not converged: go on from the best state seen (fewest crossings, then shortest contour),
    # never from one that the iterations made worse than they found it
    n_best, length_best, x_best, depth_best = best
    x[:] = x_best
    stats["intersections_left"] = n_best
    stats["intersection_depth_m"] = float(depth_best.max())
    stats["intersection_length_m"] = length_best
    return stats
