"""Material-space correspondence between two meshes of the same garment.

Two meshes of one garment (a fixed mesh and a finer reference, or an adaptive mesh after any
number of remeshes) share its material space: every vert has material coordinates ``vert_u``
(metres, the flat pattern), and remeshing never moves a material point. A material point is
therefore the same piece of cloth in both meshes, and values given at one mesh's nodes
(positions, velocities) can be carried to the other's by locating each point in a face of the
first and interpolating with its barycentric weights.

A garment of several pieces (karate's skirt and overskirt) has one connected component of
faces per piece, and the pieces' patterns may overlap in material space: points are located
only in the matching component. Components are matched by their material bounding boxes (the
pieces' patterns differ in size); two meshes whose components do not match within
COMPONENT_MATCH_TOL are refused (MaterialTransferError).

A point outside every face of its component (a coarse polygon's vertex on a curved border lies
outside the finer polygon by the sagitta of its chord) takes the nearest face's values at the
closest point of that face: weights clamped to the triangle and renormalised.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

# Two components are the same piece when their material bounding boxes agree to this fraction of
# the larger box's diagonal (meshes of one pattern at different resolutions differ by the sagitta
# of the border's chords, about 1% of the radius at 20 segments around).
COMPONENT_MATCH_TOL = 0.05
# Candidate faces per point, nearest centroids first: enough that an interior point of a graded
# or anisotropic mesh finds the face holding it; points that do not are searched exhaustively.
CANDIDATES = 16
# Barycentric weights down to -INSIDE_EPS count as inside (round-off on an edge).
INSIDE_EPS = 1e-10
# Points located at once (bounds the candidate index array: CHUNK x CANDIDATES int64, 2.6 MB).
CHUNK = 20_000


class MaterialTransferError(ValueError):
    """Two meshes whose material spaces do not correspond; the message says how they differ."""


def face_components(vert_u: np.ndarray, face_verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(component of each face (F,), bounding box of each component (C, 4): u_min, v_min, u_max,
    v_max). Components are numbered by their first face; faces are connected through shared verts."""
    face_verts = np.asarray(face_verts, dtype=np.int64)
    n_f, n_v = face_verts.shape[0], vert_u.shape[0]
    rows = np.repeat(np.arange(n_f), 3)
    graph = coo_matrix((np.ones(3 * n_f), (rows, n_f + face_verts.reshape(-1))), shape=(n_f + n_v, n_f + n_v))
    _, labels = connected_components(graph, directed=False)
    face_label = labels[:n_f]
    _, first, comp = np.unique(face_label, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))  # renumber by first face
    comp = order[comp]
    n_c = first.size
    bounds = np.empty((n_c, 4))
    for c in range(n_c):
        u = vert_u[face_verts[comp == c].reshape(-1)]
        bounds[c] = [*u.min(axis=0), *u.max(axis=0)]
    return comp, bounds


def match_components(dst_bounds: np.ndarray, src_bounds: np.ndarray) -> np.ndarray:
    """For each destination component, the source component of the same piece (by bounding box)."""
    out = np.empty(dst_bounds.shape[0], dtype=np.int64)
    for c, b in enumerate(dst_bounds):
        d = np.abs(src_bounds - b).max(axis=1)
        k = int(np.argmin(d))
        scale = max(np.hypot(b[2] - b[0], b[3] - b[1]), np.hypot(*(src_bounds[k, 2:] - src_bounds[k, :2])))
        if not d[k] <= COMPONENT_MATCH_TOL * scale:
            raise MaterialTransferError(
                f"piece {c} of the mesh (material box {np.round(b, 4).tolist()} m) matches no piece of the other "
                f"(closest {np.round(src_bounds[k], 4).tolist()} m): not meshes of the same garment")
        out[c] = k
    return out


@njit(cache=True)
def _tri_closest(t, p, w):
    """Weights (into w) of the point of triangle t (3, 2) closest to p; returns the distance (0 inside)."""
    a, b, c = t[0], t[1], t[2]
    e1x, e1y, e2x, e2y = b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]
    dx, dy = p[0] - a[0], p[1] - a[1]
    det = e1x * e2y - e1y * e2x
    if det != 0.0:
        w1 = (dx * e2y - dy * e2x) / det
        w2 = (e1x * dy - e1y * dx) / det
        w0 = 1.0 - w1 - w2
        if w0 >= -INSIDE_EPS and w1 >= -INSIDE_EPS and w2 >= -INSIDE_EPS:
            w[0], w[1], w[2] = w0, w1, w2
            return 0.0
    best = np.inf
    for k in range(3):  # outside (or degenerate): the closest point of the three sides
        q0, q1 = t[k], t[(k + 1) % 3]
        ux, uy = q1[0] - q0[0], q1[1] - q0[1]
        L2 = ux * ux + uy * uy
        s = 0.0
        if L2 > 0.0:
            s = min(max(((p[0] - q0[0]) * ux + (p[1] - q0[1]) * uy) / L2, 0.0), 1.0)
        ex, ey = p[0] - (q0[0] + s * ux), p[1] - (q0[1] + s * uy)
        d = np.sqrt(ex * ex + ey * ey)
        if d < best:
            best = d
            w[0], w[1], w[2] = 0.0, 0.0, 0.0
            w[k] = 1.0 - s
            w[(k + 1) % 3] = s
    return best


@njit(cache=True)
def _locate_candidates(tri, cand, face_comp, points, point_comp, face, weights, dist):
    """For each point, the best of its candidate faces of its component (into face, weights, dist)."""
    w = np.empty(3)
    for i in range(points.shape[0]):
        for j in range(cand.shape[1]):
            f = cand[i, j]
            if face_comp[f] != point_comp[i]:
                continue
            d = _tri_closest(tri[f], points[i], w)
            if d < dist[i]:
                dist[i] = d
                face[i] = f
                weights[i, :] = w
                if d == 0.0:
                    break


def locate(vert_u: np.ndarray, face_verts: np.ndarray, face_comp: np.ndarray, points: np.ndarray,
           point_comp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(face (M,), weights (M, 3), distance (M,) m) of material points (M, 2) of the given
    components in a mesh (vert_u, face_verts, face_comp): the face holding each point (distance 0),
    or the closest point of the closest face of its component (weights clamped)."""
    points = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
    point_comp = np.ascontiguousarray(np.asarray(point_comp, dtype=np.int64).reshape(-1))
    face_comp = np.ascontiguousarray(face_comp, dtype=np.int64)
    m = points.shape[0]
    face = np.full(m, -1, dtype=np.int64)
    weights = np.zeros((m, 3))
    dist = np.full(m, np.inf)
    if m == 0:
        return face, weights, dist
    tri = np.ascontiguousarray(np.asarray(vert_u, dtype=np.float64)[face_verts])  # (F, 3, 2)
    centroid = tri.mean(axis=1)
    extent = float(np.ptp(vert_u, axis=0).max()) + 1.0
    lift = 10.0 * extent  # components far apart in a third coordinate: neighbours stay in one piece
    tree = cKDTree(np.column_stack([centroid, lift * face_comp]))
    k = min(CANDIDATES, tri.shape[0])
    for lo in range(0, m, CHUNK):
        sl = slice(lo, min(lo + CHUNK, m))
        _, cand = tree.query(np.column_stack([points[sl], lift * point_comp[sl]]), k=k)
        cand = np.ascontiguousarray(np.asarray(cand, dtype=np.int64).reshape(-1, k))
        _locate_candidates(tri, cand, face_comp, points[sl], point_comp[sl], face[sl], weights[sl], dist[sl])
    # not inside any candidate: search the whole component (boundary points, long thin faces)
    out = np.flatnonzero(dist > 0)
    if out.size:
        for c in np.unique(point_comp[out]):
            pts = out[point_comp[out] == c]
            every = np.flatnonzero(face_comp == c)[None, :]  # every face of the piece is a candidate
            for i in pts:
                _locate_candidates(tri, every, face_comp, points[i:i + 1], point_comp[i:i + 1], face[i:i + 1],
                                   weights[i:i + 1], dist[i:i + 1])
    return face, weights, dist


def transfer_node_values(src: dict, dst_vert_u: np.ndarray, dst_vert_node: np.ndarray, dst_face_verts: np.ndarray,
                         values: tuple = ("node_x", "node_v")) -> tuple[dict, np.ndarray]:
    """Node values of mesh `src` (a dict with vert_u, vert_node, face_verts and the named (N, 3)
    arrays) carried to the nodes of another mesh of the same garment by material-space
    interpolation. Returns ({name: (n_dst_nodes, 3)}, distance (n_dst_nodes,) m of each node's
    material point from the source mesh: 0 inside it)."""
    src_comp, src_bounds = face_components(src["vert_u"], src["face_verts"])
    dst_comp, dst_bounds = face_components(dst_vert_u, dst_face_verts)
    to_src = match_components(dst_bounds, src_bounds)
    # one vert per node (a seam node's verts are the same piece of cloth) and its component
    n_nodes = int(dst_vert_node.max()) + 1 if dst_vert_node.size else 0
    vert_comp = np.zeros(dst_vert_u.shape[0], dtype=np.int64)
    vert_comp[np.asarray(dst_face_verts).reshape(-1)] = np.repeat(dst_comp, 3)
    node_vert = np.full(n_nodes, -1, dtype=np.int64)
    node_vert[dst_vert_node[::-1]] = np.arange(dst_vert_u.shape[0])[::-1]
    if np.any(node_vert < 0):
        raise MaterialTransferError(f"{int(np.sum(node_vert < 0))} node(s) of the mesh have no vert")
    face, w, dist = locate(src["vert_u"], src["face_verts"], src_comp, dst_vert_u[node_vert],
                           to_src[vert_comp[node_vert]])
    src_nodes = np.asarray(src["vert_node"])[np.asarray(src["face_verts"])[face]]  # (n, 3)
    out = {name: np.einsum("nk,nkd->nd", w, np.asarray(src[name])[src_nodes]) for name in values}
    return out, dist
