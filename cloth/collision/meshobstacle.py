"""Triangle-mesh obstacles whose vertices move frame by frame: an OBJ sequence with one topology
(cloth.io.obj.load_obj_sequence), a callable of time, or the mannequin's body as a tessellated,
skinned mesh (cloth.scenes.bodies).

`TriangleMeshObstacle` answers the interface of the analytic obstacles (cloth.collision.obstacles):
``query(points) -> (phi, normal, velocity)``, ``set_time(t)``, ``moving``, ``to_mesh()``, ``name``.

* Motion. Keyframe k (positions X_k, (V, 3)) is at time t_k = start_time + k * frame_time;
  between keyframes the positions are linear in t, x(t) = (1 - a) X_k + a X_{k+1}, and the vertex
  velocity is the keyframes' finite difference (X_{k+1} - X_k) / frame_time, the exact derivative
  of that interpolation (right-continuous at a keyframe: the velocity of the segment that starts
  there, which is the one the coming step moves with). Before the first and after the last
  keyframe the mesh is held, at rest. A callable `positions(t) -> (V, 3)` is sampled as given,
  its velocity a central difference over VELOCITY_STEP.
* Closest point. A bounding-volume hierarchy over the triangles' boxes (cloth.collision.bvh's top-down
  median split) is built once and refitted at every set_time (rebuilt when refitting has grown
  the boxes by REBUILD_GROWTH); a branch-and-bound search (cloth.collision.nearest) finds each
  point's nearest triangle and the barycentric coordinates of the closest point on it.
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

The numba kernels (refit, signed distance, query of every point) are in cloth.collision.meshkernels.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cloth.collision.bvh import build_tree
from cloth.collision.meshkernels import pseudo_normals, query_closest, refit_tree

VELOCITY_STEP = 1e-4  # s, central difference of a callable's positions (error O(h^2 x''') m/s)
REBUILD_GROWTH = 1.5  # rebuild the tree when refitting has grown its boxes' summed extents by this factor
TINY_DISTANCE_REL = 1e-12  # a point closer than this x the mesh's size is on the surface (normal: pseudo-normal)
KEYFRAME_SNAP = 1e-9  # a time within this fraction of a keyframe interval of a keyframe is at it (round-off)


class MeshObstacleError(ValueError):
    """A triangle-mesh obstacle that cannot be built; the message names the file or the problem."""


# ---- topology, checked once at construction ------------------------------------------------
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
        """Unit face normals, angle-weighted vertex pseudo-normals and edge pseudo-normals (numba:
        cloth.collision.meshkernels.pseudo_normals)."""
        x = self.positions
        self.face_normals = np.empty((self.faces.shape[0], 3))  # (F, 3) unit (0 if degenerate)
        self._vert_pn = np.empty_like(x)
        edge_pn = np.empty((self._n_edges, 3))
        pseudo_normals(x, self.faces, self._face_edge, self.face_normals, self._vert_pn, edge_pn)
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
            nlo, nhi, left, start, count, order = build_tree(np.ascontiguousarray(lo[idx]),
                                                             np.ascontiguousarray(hi[idx]))
            roots.append(node_off)
            for a, part in zip(arrays, (nlo, nhi, np.where(left >= 0, left + node_off, -1), start + order_off,
                                        count, idx[order])):
                a.append(part)
            node_off += nlo.shape[0]
            order_off += order.shape[0]
        self._tree = tuple(np.ascontiguousarray(np.concatenate(a)) for a in arrays)
        self._comp_root = np.asarray(roots[1:] if self.n_components > 1 else [0], dtype=np.int64)
        self._tree_extent = refit_tree(self.positions, self.faces, *self._tree)

    def _update_tree(self) -> None:
        if self._tree is None:
            self._build_tree()
            return
        extent = refit_tree(self.positions, self.faces, *self._tree)
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
            query_closest(p, self.positions, self.faces, self.face_normals, self._vert_pn, self._face_edge_pn,
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
        step's cloth-obstacle collision handling (cloth.collision.selfcollision.resolve_collisions_with_obstacles)."""
        return self.faces, self._face_edge, self.edge_nodes


def mesh_obstacles(obstacles) -> list:
    """The TriangleMeshObstacle instances among `obstacles` (a list or a cloth.collision.obstacles.ObstacleSet)."""
    obs = getattr(obstacles, "obstacles", obstacles)
    return [ob for ob in obs if isinstance(ob, TriangleMeshObstacle)]


def mesh_obstacle_triangles(obstacles) -> list:
    """[(positions, faces), ...] of the triangle-mesh obstacles among `obstacles` (a list or a
    cloth.collision.obstacles.ObstacleSet), for cloth.collision.untangle.untangle(..., obstacles=...)."""
    return [ob.triangles() for ob in mesh_obstacles(obstacles)]
