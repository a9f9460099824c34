"""Triangle-mesh obstacles whose vertices move frame by frame: an OBJ sequence with one topology,
a callable of time, or the mannequin's body as a tessellated, skinned mesh.

`TriangleMeshObstacle` answers the interface of the analytic obstacles (cloth.obstacles):
``query(points) -> (phi, normal, velocity)``, ``set_time(t)``, ``moving``, ``to_mesh()``, ``name``.

* Motion. Keyframe k (positions X_k, (V, 3)) is at time t_k = start_time + k * frame_time;
  between keyframes the positions are linear in t, x(t) = (1 - a) X_k + a X_{k+1}, and the vertex
  velocity is the keyframes' finite difference (X_{k+1} - X_k) / frame_time, the exact derivative
  of that interpolation (right-continuous at a keyframe: the velocity of the segment that starts
  there, which is the one the coming step moves with). Before the first and after the last
  keyframe the mesh is held, at rest. A callable `positions(t) -> (V, 3)` is sampled as given,
  its velocity a central difference over VELOCITY_STEP.
* Closest point. A bounding-volume hierarchy over the triangles' boxes (cloth.bvh's top-down
  median split) is built once and refitted at every set_time (rebuilt when refitting has grown
  the boxes by REBUILD_GROWTH); a branch-and-bound search finds each point's nearest triangle and
  the barycentric coordinates of the closest point on it (cloth.ccd.point_triangle_closest).
* Sign. Negative inside. The sign of (p - c) . n_pseudo, with n_pseudo the angle-weighted
  pseudo-normal of the closest feature (face normal; sum of the two face normals at an edge;
  angle-weighted sum at a vertex; Baerentzen and Aanaes 2005), which is exact for a closed,
  consistently oriented mesh. A mesh of several closed components (a body tessellated capsule by
  capsule, overlapping at the joints) is their union: phi = min over the components of their
  signed distances, so a point inside one component is inside even where another component's
  buried surface is nearer. An open component (a boundary edge) has no inside: its sign is the
  side of its closest feature (for a face, the side of the face), and it takes part only through
  the nearest triangle, never as a containing volume. Closed components wound inwards are flipped
  at construction (`flipped_components` lists them).
* Normal and velocity. The outward normal is sign * (p - c) / |p - c| (the distance's gradient,
  as for the analytic obstacles), or the feature's pseudo-normal for a point on the surface; the
  surface velocity is the barycentric interpolation of the vertex velocities at c.
* Query radius. With `query_radius` r, only triangles within r of a point are searched: a point
  farther than r from every triangle gets phi = r (a lower bound of its distance, as if outside),
  normal (0, 0, 0), velocity 0. This is cheap but wrong for a point more than r deep inside a
  closed mesh; the default r = inf is exact everywhere.
"""

from __future__ import annotations

import glob as _glob
import re
from pathlib import Path

import numpy as np
from numba import njit

from .bvh import _build as _build_box_tree
from .ccd import point_triangle_closest, region_weights
from .obstacles import capsule_tessellation

VELOCITY_STEP = 1e-4  # s, central difference of a callable's positions (error O(h^2 x''') m/s)
REBUILD_GROWTH = 1.5  # rebuild the tree when refitting has grown its boxes' summed extents by this factor
TINY_DISTANCE_REL = 1e-12  # a point closer than this x the mesh's size is on the surface (normal: pseudo-normal)
KEYFRAME_SNAP = 1e-9  # a time within this fraction of a keyframe interval of a keyframe is at it (round-off)


class MeshObstacleError(ValueError):
    """A triangle-mesh obstacle that cannot be built; the message names the file or the problem."""


# --------------------------------------------------------------------------------------------
# kernels
@njit(cache=True)
def _refit(x, faces, nlo, nhi, left, start, count, order):
    """Refit the boxes of a forest of trees to the triangles at positions x (in place).

    Children are stored after their parent (cloth.bvh._build), so one pass in reverse order
    sees every child before its parent. Returns the summed box extents (growth measure)."""
    total = 0.0
    for k in range(nlo.shape[0] - 1, -1, -1):
        for d in range(3):
            nlo[k, d] = np.inf
            nhi[k, d] = -np.inf
        if left[k] < 0:
            for a in range(start[k], start[k] + count[k]):
                f = order[a]
                for j in range(3):
                    v = faces[f, j]
                    for d in range(3):
                        nlo[k, d] = min(nlo[k, d], x[v, d])
                        nhi[k, d] = max(nhi[k, d], x[v, d])
        else:
            for c in range(left[k], left[k] + 2):
                for d in range(3):
                    nlo[k, d] = min(nlo[k, d], nlo[c, d])
                    nhi[k, d] = max(nhi[k, d], nhi[c, d])
        for d in range(3):
            total += nhi[k, d] - nlo[k, d]
    return total


@njit(cache=True)
def _box_distance2(p, lo, hi):
    d2 = 0.0
    for d in range(3):
        if p[d] < lo[d]:
            d2 += (lo[d] - p[d]) ** 2
        elif p[d] > hi[d]:
            d2 += (p[d] - hi[d]) ** 2
    return d2


@njit(cache=True)
def _closest_on_triangle(p, x, ia, ib, ic):
    """(squared distance, w0, w1, w2) from p to triangle (x[ia], x[ib], x[ic]): Ericson's
    Voronoi-region tests on scalars (no temporaries). A degenerate triangle goes to
    cloth.ccd.point_triangle_closest, which handles it by its edges."""
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
def _nearest(p, root, x, faces, nlo, nhi, left, start, count, order, bound2, stack):
    """Nearest triangle to p in the tree at node `root` among those closer than sqrt(bound2):
    (squared distance, face or -1, w0, w1, w2). Branch and bound, nearer child first."""
    best, best_f, b0, b1, b2 = bound2, -1, 0.0, 0.0, 0.0
    top = 0
    stack[0] = root
    while top >= 0:
        k = stack[top]
        top -= 1
        if _box_distance2(p, nlo[k], nhi[k]) >= best:
            continue
        if left[k] < 0:
            for a in range(start[k], start[k] + count[k]):
                f = order[a]
                d2, w0, w1, w2 = _closest_on_triangle(p, x, faces[f, 0], faces[f, 1], faces[f, 2])
                if d2 < best:
                    best, best_f, b0, b1, b2 = d2, f, w0, w1, w2
            continue
        L = left[k]
        dl = _box_distance2(p, nlo[L], nhi[L])
        dr = _box_distance2(p, nlo[L + 1], nhi[L + 1])
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
def _query(points, x, faces, face_n, vert_pn, face_edge_pn, face_comp, comp_root, comp_closed,
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
        d2, f, w0, w1, w2 = _nearest(p, 0, x, faces, nlo, nhi, left, start, count, order, bound2, stack)
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
            if c == own or not comp_closed[c] or _box_distance2(p, nlo[r], nhi[r]) > 0.0:
                continue
            e2, g, v0, v1, v2 = _nearest(p, r, x, faces, nlo, nhi, left, start, count, order, bound2, stack)
            if g < 0:
                continue
            value = _signed(p, g, v0, v1, v2, np.sqrt(e2), x, faces, face_n, vert_pn, face_edge_pn, tiny, n_c)
            if value < phi[i]:
                phi[i] = value
                face[i] = g
                bary[i, 0], bary[i, 1], bary[i, 2] = v0, v1, v2
                for k in range(3):
                    normal[i, k] = n_c[k]


# --------------------------------------------------------------------------------------------
def _check_faces(faces, n_vertices: int) -> np.ndarray:
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] == 0:
        raise MeshObstacleError(f"faces must be a non-empty (F, 3) array of vertex indices, got shape {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise MeshObstacleError(f"faces must be integer vertex indices, got dtype {faces.dtype}")
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if faces.min() < 0 or faces.max() >= n_vertices:
        raise MeshObstacleError(f"face vertex indices must be in [0, {n_vertices - 1}], "
                                f"got [{faces.min()}, {faces.max()}]")
    bad = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    if bad.any():
        raise MeshObstacleError(f"face {int(np.flatnonzero(bad)[0])} repeats a vertex {faces[bad][0].tolist()}")
    return faces


def _edge_keys(faces: np.ndarray, n_vertices: int):
    """Directed (F, 3) and undirected (F, 3) keys of local edge e = (v_e, v_{e+1})."""
    a, b = faces, np.roll(faces, -1, axis=1)
    return a * n_vertices + b, np.minimum(a, b) * n_vertices + np.maximum(a, b)


def _topology(faces: np.ndarray, x0: np.ndarray):
    """Validate orientation; components, closedness; flip inward closed components.
    Returns (faces, face_edge (F,3) edge ids, n_edges, face_comp, comp_closed, flipped)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V, F = x0.shape[0], faces.shape[0]
    directed, undirected = _edge_keys(faces, V)
    uniq, counts = np.unique(directed.ravel(), return_counts=True)
    if np.any(counts > 1):
        k = int(uniq[np.argmax(counts > 1)])
        raise MeshObstacleError(f"edge ({k // V}, {k % V}) is traversed in the same direction by two faces: "
                                "the faces are not consistently oriented, or the edge has more than two faces")
    graph = coo_matrix((np.ones(3 * F), (faces.ravel(), np.roll(faces, -1, axis=1).ravel())), shape=(V, V))
    _, vert_label = connected_components(graph, directed=False)
    _, face_comp = np.unique(vert_label[faces[:, 0]], return_inverse=True)
    face_comp = face_comp.reshape(-1).astype(np.int64)
    C = int(face_comp.max()) + 1
    edge_ids, inverse, edge_count = np.unique(undirected.ravel(), return_inverse=True, return_counts=True)
    face_edge = inverse.reshape(F, 3).astype(np.int64)
    open_face = np.any(edge_count[face_edge] < 2, axis=1)
    comp_closed = np.ones(C, dtype=np.bool_)
    comp_closed[np.unique(face_comp[open_face])] = False
    t = x0[faces]
    volume = np.bincount(face_comp, np.einsum("fi,fi->f", t[:, 0], np.cross(t[:, 1], t[:, 2])) / 6.0, minlength=C)
    flipped = [int(c) for c in np.flatnonzero(comp_closed & (volume < 0))]
    if flipped:
        faces = faces.copy()
        sel = np.isin(face_comp, flipped)
        faces[sel] = faces[sel][:, [0, 2, 1]]
        _, undirected = _edge_keys(faces, V)
        face_edge = np.searchsorted(edge_ids, undirected).astype(np.int64)
    return faces, face_edge, len(edge_ids), face_comp, comp_closed, flipped


class TriangleMeshObstacle:
    """A triangle mesh moving by keyframes (or a callable of time) as a contact obstacle.

    vertices: (K, V, 3) keyframe positions (metres; K = 1 or (V, 3): static), or a callable
    t -> (V, 3); faces (F, 3) vertex indices, counter-clockwise seen from outside;
    frame_time (s) between keyframes (needed when K > 1); start_time (s) of keyframe 0;
    query_radius (m, None = unlimited): see the module docstring; name: entity name.
    """

    def __init__(self, vertices, faces, frame_time: float | None = None, *, start_time: float = 0.0,
                 query_radius: float | None = None, name: str = "mesh", velocity_step: float = VELOCITY_STEP):
        self.name = str(name)
        self.start_time = float(start_time)
        self.velocity_step = float(velocity_step)
        if callable(vertices):
            self._fn = vertices
            self.keyframes = None
            x0 = self._call(self.start_time)
        else:
            self._fn = None
            X = np.asarray(vertices, dtype=np.float64)
            if X.ndim == 2:
                X = X[None]
            if X.ndim != 3 or X.shape[2] != 3 or X.shape[1] < 3:
                raise MeshObstacleError(f"vertices must be (K, V, 3) keyframes or (V, 3), got shape {X.shape}")
            if not np.all(np.isfinite(X)):
                raise MeshObstacleError("vertex positions must be finite")
            self.keyframes = np.ascontiguousarray(X)
            x0 = self.keyframes[0]
        if self.n_keyframes > 1 and frame_time is None:
            raise MeshObstacleError(f"{self.n_keyframes} keyframes need a frame_time (s between keyframes)")
        self.frame_time = None if frame_time is None else float(frame_time)
        if self.frame_time is not None and not self.frame_time > 0:
            raise MeshObstacleError(f"frame_time must be > 0 s, got {frame_time}")
        if query_radius is not None and not query_radius > 0:
            raise MeshObstacleError(f"query_radius must be > 0 m (or None), got {query_radius}")
        self.query_radius = np.inf if query_radius is None else float(query_radius)
        self._n_v = x0.shape[0]
        faces = _check_faces(faces, x0.shape[0])
        (self.faces, self._face_edge, self._n_edges, self.face_component, self.component_closed,
         self.flipped_components) = _topology(faces, x0)
        self.n_components = int(self.component_closed.size)
        self.edge_nodes = np.empty((self._n_edges, 2), dtype=np.int64)  # (E, 2) vertices of each edge
        self.edge_nodes[self._face_edge.ravel()] = np.column_stack([self.faces.ravel(),
                                                                    np.roll(self.faces, -1, axis=1).ravel()])
        self._comp_faces = [np.flatnonzero(self.face_component == c) for c in range(self.n_components)]
        self._tree = None
        self._t = None
        self.set_time(self.start_time)

    # ---- motion --------------------------------------------------------------------------
    @property
    def n_keyframes(self) -> int:
        return 0 if self.keyframes is None else self.keyframes.shape[0]

    @property
    def n_vertices(self) -> int:
        return self._n_v

    @property
    def moving(self) -> bool:
        return self._fn is not None or self.n_keyframes > 1

    def _call(self, t: float) -> np.ndarray:
        x = np.ascontiguousarray(self._fn(t), dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise MeshObstacleError(f"the positions callable must return (V, 3), got shape {x.shape} at t = {t}")
        return x

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(positions (V, 3), velocities (V, 3)) of the vertices at time t."""
        if self._fn is not None:
            h = self.velocity_step
            return self._call(t), (self._call(t + h) - self._call(t - h)) / (2 * h)
        X = self.keyframes
        if X.shape[0] == 1:
            return X[0].copy(), np.zeros_like(X[0])
        u = (t - self.start_time) / self.frame_time
        if abs(u - round(u)) < KEYFRAME_SNAP:
            u = float(round(u))
        if u < 0.0:
            return X[0].copy(), np.zeros_like(X[0])
        k = int(np.floor(u))
        if k >= X.shape[0] - 1:
            return X[-1].copy(), np.zeros_like(X[0])
        a = u - k
        return (1.0 - a) * X[k] + a * X[k + 1], (X[k + 1] - X[k]) / self.frame_time

    def set_time(self, t: float) -> None:
        """Place the mesh at time t: positions, vertex velocities, pseudo-normals, refitted tree."""
        t = float(t)
        if t == self._t:
            return
        x, v = self.state_at(t)
        if x.shape[0] != self._n_v:
            raise MeshObstacleError(f"the positions at t = {t} have {x.shape[0]} vertices, the mesh has {self._n_v}")
        if not np.all(np.isfinite(x)):
            raise MeshObstacleError(f"non-finite vertex positions at t = {t}")
        self.positions = np.ascontiguousarray(x)  # (V, 3) float64, m
        self.vertex_velocities = np.ascontiguousarray(v)  # (V, 3) float64, m/s
        self._t = t
        self._update_normals()
        self._update_tree()

    # ---- derived geometry (after positions change) ----------------------------------------
    def _update_normals(self) -> None:
        x, faces = self.positions, self.faces
        t = x[faces]  # (F, 3, 3)
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        L = np.linalg.norm(n, axis=1)
        self.face_normals = np.ascontiguousarray(n / np.where(L > 0, L, 1.0)[:, None])  # (F, 3) unit (0 if degenerate)
        vert_pn = np.zeros_like(x)
        for k in range(3):  # angle-weighted vertex pseudo-normals
            e1 = t[:, (k + 1) % 3] - t[:, k]
            e2 = t[:, (k + 2) % 3] - t[:, k]
            angle = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=1), np.einsum("fi,fi->f", e1, e2))
            w = angle[:, None] * self.face_normals
            for d in range(3):
                vert_pn[:, d] += np.bincount(faces[:, k], w[:, d], minlength=x.shape[0])
        edge_pn = np.zeros((self._n_edges, 3))
        for d in range(3):
            edge_pn[:, d] = np.bincount(self._face_edge.ravel(), np.repeat(self.face_normals[:, d], 3),
                                        minlength=self._n_edges)
        self._vert_pn = vert_pn
        self._face_edge_pn = np.ascontiguousarray(edge_pn[self._face_edge])  # (F, 3, 3)
        size = float(np.max(x.max(axis=0) - x.min(axis=0)))
        self._tiny = TINY_DISTANCE_REL * max(size, 1e-300)

    def _build_tree(self) -> None:
        """The forest: tree 0 over all faces, then one tree per component (if several)."""
        corners = self.positions[self.faces]
        lo, hi = corners.min(axis=1), corners.max(axis=1)
        parts = [np.arange(self.faces.shape[0])]
        if self.n_components > 1:
            parts += self._comp_faces
        arrays = [[] for _ in range(6)]
        roots, node_off, order_off = [], 0, 0
        for idx in parts:
            nlo, nhi, left, start, count, order = _build_box_tree(np.ascontiguousarray(lo[idx]),
                                                                  np.ascontiguousarray(hi[idx]))
            roots.append(node_off)
            for a, part in zip(arrays, (nlo, nhi, np.where(left >= 0, left + node_off, -1), start + order_off,
                                        count, idx[order])):
                a.append(part)
            node_off += nlo.shape[0]
            order_off += order.shape[0]
        self._tree = tuple(np.ascontiguousarray(np.concatenate(a)) for a in arrays)
        self._comp_root = np.asarray(roots[1:] if self.n_components > 1 else [0], dtype=np.int64)
        self._tree_extent = _refit(self.positions, self.faces, *self._tree)

    def _update_tree(self) -> None:
        if self._tree is None:
            self._build_tree()
            return
        extent = _refit(self.positions, self.faces, *self._tree)
        if extent > REBUILD_GROWTH * self._tree_extent:
            self._build_tree()

    # ---- the obstacle interface -------------------------------------------------------------
    def closest(self, points: np.ndarray) -> dict:
        """Per point: 'phi' (n,), 'normal' (n, 3), 'velocity' (n, 3), 'face' (n,) (-1 beyond the
        query radius), 'bary' (n, 3) barycentric weights of the closest point, 'point' (n, 3)."""
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        n = p.shape[0]
        phi, normal = np.empty(n), np.empty((n, 3))
        face, bary = np.empty(n, dtype=np.int64), np.empty((n, 3))
        if n:
            _query(p, self.positions, self.faces, self.face_normals, self._vert_pn, self._face_edge_pn,
                   self.face_component, self._comp_root, self.component_closed, *self._tree,
                   self.query_radius ** 2, self._tiny, phi, normal, face, bary)
        hit = face >= 0
        fv = self.faces[np.where(hit, face, 0)]  # (n, 3)
        velocity = np.einsum("nk,nkd->nd", bary, self.vertex_velocities[fv]) * hit[:, None]
        point = np.einsum("nk,nkd->nd", bary, self.positions[fv]) * hit[:, None]
        return {"phi": phi, "normal": normal, "velocity": velocity, "face": face, "bary": bary, "point": point}

    def query(self, points: np.ndarray):
        """(phi (n,), outward normal (n, 3), surface velocity (n, 3)) at the closest points."""
        out = self.closest(points)
        return out["phi"], out["normal"], out["velocity"]

    def to_mesh(self, resolution: int = 16):
        """(vertices (V, 3), faces (F, 3)) at the current time (resolution is ignored)."""
        return self.positions.copy(), self.faces.copy()

    def triangles(self):
        """(positions (V, 3), faces (F, 3)) now: the obstacle side of cloth-obstacle untangling."""
        return self.positions, self.faces

    def collision_topology(self):
        """(faces (F, 3), face_edges (F, 3) edge ids, edge_nodes (E, 2)): the obstacle side of the
        step's cloth-obstacle collision handling (cloth.selfcollision.resolve_collisions_with_obstacles)."""
        return self.faces, self._face_edge, self.edge_nodes


def mesh_obstacles(obstacles) -> list:
    """The TriangleMeshObstacle instances among `obstacles` (a list or a cloth.obstacles.ObstacleSet)."""
    obs = getattr(obstacles, "obstacles", obstacles)
    return [ob for ob in obs if isinstance(ob, TriangleMeshObstacle)]


def mesh_obstacle_triangles(obstacles) -> list:
    """[(positions, faces), ...] of the triangle-mesh obstacles among `obstacles` (a list or a
    cloth.obstacles.ObstacleSet), for cloth.untangle.untangle(..., obstacles=...)."""
    return [ob.triangles() for ob in mesh_obstacles(obstacles)]


# --------------------------------------------------------------------------------------------
# OBJ sequences
def read_obj_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """(positions (V, 3), triangles (F, 3)) of an OBJ file: `v` and `f` lines only (texture and
    normal indices ignored, polygons split into fans, negative indices relative). The vertex
    numbering is the file's, so that frames of a sequence compare index by index."""
    path = Path(path)
    if not path.is_file():
        raise MeshObstacleError(f"{path}: no such file")
    verts, tris = [], []
    try:
        with open(path) as fh:
            for line_no, line in enumerate(fh, 1):
                if line.startswith("v "):
                    parts = line.split()
                    if len(parts) < 4:
                        raise ValueError("a vertex needs three coordinates")
                    verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
                elif line.startswith("f "):
                    idx = []
                    for tok in line.split()[1:]:
                        i = int(tok.split("/")[0])
                        idx.append(i - 1 if i > 0 else len(verts) + i)
                    if len(idx) < 3:
                        raise ValueError("a face needs at least three vertices")
                    tris.extend((idx[0], idx[j], idx[j + 1]) for j in range(1, len(idx) - 1))
    except (ValueError, UnicodeDecodeError) as exc:
        raise MeshObstacleError(f"{path}: line {line_no}: cannot be read as OBJ ({exc})") from None
    if not tris:
        raise MeshObstacleError(f"{path}: has no faces")
    x = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(tris, dtype=np.int64)
    if f.min() < 0 or f.max() >= x.shape[0]:
        raise MeshObstacleError(f"{path}: a face refers to vertex {int(f.max() + 1 if f.max() >= x.shape[0] else f.min() + 1)}"
                                f" of {x.shape[0]}")
    return x, f


def _natural_key(path: str):
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", str(path))]


def obj_sequence_paths(source) -> list[Path]:
    """The files of an OBJ sequence: a glob pattern (e.g. 'walk/frame_*.obj'; sorted by name,
    numbers by value), a directory (its *.obj files), one file, or an explicit list of paths."""
    if isinstance(source, (list, tuple)):
        if not source:
            raise MeshObstacleError("obstacle OBJ sequence: the list of files is empty")
        paths = [Path(p).expanduser() for p in source]
    else:
        s = str(Path(str(source)).expanduser())
        if Path(s).is_dir():
            paths = [Path(p) for p in sorted(_glob.glob(str(Path(s) / "*.obj")), key=_natural_key)]
        elif _glob.has_magic(s):
            paths = [Path(p) for p in sorted(_glob.glob(s), key=_natural_key)]
        else:
            paths = [Path(s)]
        if not paths:
            raise MeshObstacleError(f"obstacle OBJ sequence {str(source)!r}: no file matches")
    for p in paths:
        if not p.is_file():
            raise MeshObstacleError(f"obstacle OBJ sequence: {p}: no such file")
    return paths


def load_obj_sequence(source, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, list[Path]]:
    """Read an OBJ sequence of one topology: (vertices (K, V, 3) in metres = file units x scale,
    faces (F, 3), paths). A file whose vertex count or faces differ from the first's is named."""
    if not (np.isfinite(scale) and scale > 0):
        raise MeshObstacleError(f"obstacle OBJ scale must be > 0, got {scale}")
    paths = obj_sequence_paths(source)
    x0, faces = read_obj_mesh(paths[0])
    frames = [x0]
    for p in paths[1:]:
        x, f = read_obj_mesh(p)
        if x.shape[0] != x0.shape[0]:
            raise MeshObstacleError(f"{p}: has {x.shape[0]} vertices, {paths[0]} has {x0.shape[0]}: "
                                    "an OBJ sequence needs one topology")
        if f.shape != faces.shape or not np.array_equal(f, faces):
            raise MeshObstacleError(f"{p}: its faces differ from those of {paths[0]}: an OBJ sequence needs one topology")
        frames.append(x)
    return np.stack(frames) * float(scale), faces, paths


def write_obj_sequence(directory, vertices_per_frame, faces, stem: str = "frame") -> list[Path]:
    """Write keyframes (K, V, 3) as OBJ files directory/<stem>_0000.obj ... (atomically each)."""
    from .io.manifest import write_text_atomic

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    faces = np.asarray(faces, dtype=np.int64)
    face_text = "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)
    paths = []
    for k, x in enumerate(np.asarray(vertices_per_frame, dtype=np.float64)):
        text = "".join(f"v {a:.17g} {b:.17g} {c:.17g}\n" for a, b, c in x) + face_text
        path = directory / f"{stem}_{k:04d}.obj"
        write_text_atomic(path, text)
        paths.append(path)
    return paths


# --------------------------------------------------------------------------------------------
# procedural meshes
def icosphere(radius: float = 1.0, subdivisions: int = 2, center=(0.0, 0.0, 0.0)):
    """(vertices (V, 3), faces (F, 3)) of a subdivided icosahedron on a sphere, outward wound."""
    import trimesh.creation

    m = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=float(radius))
    return np.asarray(m.vertices, dtype=np.float64) + np.asarray(center, dtype=np.float64), \
        np.asarray(m.faces, dtype=np.int64)


def moving_sphere_keyframes(radius: float, subdivisions: int, centers) -> tuple[np.ndarray, np.ndarray]:
    """Keyframes (K, V, 3) of an icosphere whose centre passes through `centers` (K, 3), and its faces."""
    x0, faces = icosphere(radius, subdivisions)
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    return x0[None] + centers[:, None, :], faces


class SkinnedMannequin:
    """Vertex positions of the mannequin's body as a triangle mesh: each capsule tessellated in
    its joint's frame (`capsule_tessellation`), so every vertex follows its capsule rigidly.
    Callable: t -> (V, 3) world positions, placed as the Mannequin is (position, heading, phase)."""

    def __init__(self, mannequin, segments: int = 12):
        from .character import CAPSULES, JOINTS

        self.motion = mannequin.motion
        self.offset = np.asarray(mannequin.offset, dtype=np.float64)
        self.heading = float(mannequin.place_heading)
        self.phase = float(mannequin.phase)
        local, joint, faces, n = [], [], [], 0
        for joint_name, a, b, r in CAPSULES.values():
            v, f = capsule_tessellation(a, b, r, segments)
            local.append(v)
            joint.append(np.full(len(v), JOINTS.index(joint_name)))
            faces.append(f + n)
            n += len(v)
        self.local = np.vstack(local)  # (V, 3) m, in the frame of the vertex's joint
        self.vert_joint = np.concatenate(joint)  # (V,) index into character.JOINTS
        self.faces = np.vstack(faces)

    def __call__(self, t: float) -> np.ndarray:
        from .character import JOINTS, forward_kinematics, motion_time

        frames = forward_kinematics(self.motion.pose(motion_time(t, self.phase)))
        R = np.stack([frames[j][0] for j in JOINTS])[self.vert_joint]
        p = np.stack([frames[j][1] for j in JOINTS])[self.vert_joint]
        x = np.einsum("vij,vj->vi", R, self.local) + p
        c, s = np.cos(self.heading), np.sin(self.heading)
        place = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return x @ place.T + self.offset


def skinned_mannequin_mesh(mannequin, segments: int = 12, name: str = "mannequin_mesh",
                           query_radius: float | None = None) -> TriangleMeshObstacle:
    """The mannequin's body (a cloth.character.Mannequin) as a moving triangle mesh: one closed
    tessellated capsule per body capsule, moving with its joint; the union of the capsules, as
    the capsule body is, up to the tessellation (facets inside by about r (1 - cos(pi/segments)))."""
    skin = SkinnedMannequin(mannequin, segments)
    return TriangleMeshObstacle(skin, skin.faces, name=name, query_radius=query_radius)


if __name__ == "__main__":  # write an example OBJ sequence: python -m cloth.meshobstacle DIR
    import sys

    out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/obstacle_obj")
    times = np.arange(50) * 0.04
    centers = np.column_stack([0.15 * np.sin(np.pi * times), np.zeros_like(times), 0.25 + 0.0 * times])
    X, F = moving_sphere_keyframes(0.25, 2, centers)
    written = write_obj_sequence(out, X, F)
    print(f"wrote {len(written)} frames: {out}/frame_*.obj")
