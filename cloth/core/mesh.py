"""Cloth mesh: struct-of-arrays with nodes (world space) and verts (material space).

Data is tagged by when it goes stale (STYLE.md habit 2):

* **topology** (`face_verts`, `vert_node` and everything derived from them in
  :func:`Mesh.update_topology`): changes only when the remesher changes the mesh;
* **material space** (`vert_u` and the rest data derived in
  :func:`Mesh.update_rest_data`): changes on remesh;
* **world space** (`node_x`, `node_v`): changes every step.

Derived data has exactly two refresh points, :meth:`Mesh.update_topology` (after
topology changes) and :meth:`Mesh.update_rest_data` (after material coordinates or the
material density change). Nothing else writes derived arrays.

A seam of a garment is a node with two or more verts: faces index verts, and each vert
maps to one node. Edges are *node* edges (an edge between two nodes, shared by the faces on
both sides of a seam), so bending acts across seams.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class MeshError(ValueError):
    """An invalid mesh; the message names the problem and the offending element."""


# A material triangle whose area is below this fraction of the squared mean edge length is
# degenerate: its inverse rest shape matrix would amplify round-off beyond 1e6.
DEGENERATE_AREA_RATIO = 1e-12


@dataclass
class Mesh:
    # --- world space (changes every step) -----------------------------------------------
    node_x: np.ndarray  # (n_nodes, 3) float64, metres: world positions
    node_v: np.ndarray  # (n_nodes, 3) float64, m/s: velocities
    node_pinned: np.ndarray  # (n_nodes,) bool: position prescribed (handle or fixed)
    # --- material space (changes on remesh) ---------------------------------------------
    vert_u: np.ndarray  # (n_verts, 2) float64, metres: material (rest) coordinates
    vert_node: np.ndarray  # (n_verts,) int32: node of each vert
    face_verts: np.ndarray  # (n_faces, 3) int32: counter-clockwise in material space
    # --- derived: topology (update_topology) --------------------------------------------
    face_nodes: np.ndarray = field(init=False)  # (n_faces, 3) int32
    edge_nodes: np.ndarray = field(init=False)  # (n_edges, 2) int32: (n0, n1), n0->n1 CCW in face A
    edge_faces: np.ndarray = field(init=False)  # (n_edges, 2) int32: (face A, face B or -1)
    edge_opp_nodes: np.ndarray = field(init=False)  # (n_edges, 2) int32: node opposite in A, B (-1)
    face_edges: np.ndarray = field(init=False)  # (n_faces, 3) int32: edge of side k = (k, k+1)
    node_boundary: np.ndarray = field(init=False)  # (n_nodes,) bool: on an edge with one face
    # --- derived: material space (update_rest_data) -------------------------------------
    face_area: np.ndarray = field(init=False)  # (n_faces,) float64, m^2: material-space area
    face_Dm_inv: np.ndarray = field(init=False)  # (n_faces, 2, 2) inverse rest edge matrix, 1/m
    edge_rest_length: np.ndarray = field(init=False)  # (n_edges,) float64, m
    edge_rest_theta: np.ndarray = field(init=False)  # (n_edges,) float64, rad: rest dihedral
    node_m: np.ndarray = field(init=False)  # (n_nodes,) float64, kg: lumped mass
    density: float = 0.0  # kg/m^2 used for node_m

    def __post_init__(self) -> None:
        self.node_x = np.ascontiguousarray(self.node_x, dtype=np.float64)
        self.node_v = np.ascontiguousarray(self.node_v, dtype=np.float64)
        self.node_pinned = np.ascontiguousarray(self.node_pinned, dtype=bool)
        self.vert_u = np.ascontiguousarray(self.vert_u, dtype=np.float64)
        self.vert_node = np.ascontiguousarray(self.vert_node, dtype=np.int32)
        self.face_verts = np.ascontiguousarray(self.face_verts, dtype=np.int32)
        validate_arrays(self)
        self.update_topology()
        self.update_rest_data(self.density)

    # ------------------------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return self.node_x.shape[0]

    @property
    def n_verts(self) -> int:
        return self.vert_u.shape[0]

    @property
    def n_faces(self) -> int:
        return self.face_verts.shape[0]

    @property
    def n_edges(self) -> int:
        return self.edge_nodes.shape[0]

    @property
    def bending_edges(self) -> np.ndarray:
        """Indices of interior edges (two faces): the hinges that carry bending energy."""
        return np.flatnonzero(self.edge_faces[:, 1] >= 0)

    def edge_stencil(self) -> np.ndarray:
        """(n_interior, 4) int32 hinge stencils (n0, n1, opposite in A, opposite in B)."""
        idx = self.bending_edges
        return np.ascontiguousarray(
            np.column_stack([self.edge_nodes[idx], self.edge_opp_nodes[idx]]), dtype=np.int32
        )

    # --- refresh point 1: after topology changes --------------------------------------
    def update_topology(self) -> None:
        """Derive edges and adjacency from `face_verts` and `vert_node` (raises MeshError)."""
        fn = self.vert_node[self.face_verts]  # (F, 3)
        self.face_nodes = np.ascontiguousarray(fn, dtype=np.int32)
        n_faces = fn.shape[0]
        if np.any(fn[:, 0] == fn[:, 1]) or np.any(fn[:, 1] == fn[:, 2]) or np.any(fn[:, 0] == fn[:, 2]):
            bad = int(np.flatnonzero((fn[:, 0] == fn[:, 1]) | (fn[:, 1] == fn[:, 2]) | (fn[:, 0] == fn[:, 2]))[0])
            raise MeshError(f"face {bad} uses the same node twice (nodes {fn[bad].tolist()})")
        # half-edges: side k of face f goes from node a = fn[f,k] to b = fn[f,k+1]
        a = fn.reshape(-1)
        b = np.roll(fn, -1, axis=1).reshape(-1)
        c = np.roll(fn, -2, axis=1).reshape(-1)
        he_face = np.repeat(np.arange(n_faces, dtype=np.int64), 3)
        lo = np.minimum(a, b).astype(np.int64)
        hi = np.maximum(a, b).astype(np.int64)
        key = lo * (self.n_nodes + 1) + hi
        order = np.argsort(key, kind="stable")
        uniq, first, counts = np.unique(key[order], return_index=True, return_counts=True)
        if np.any(counts > 2):
            e = int(np.flatnonzero(counts > 2)[0])
            k = order[first[e]]
            raise MeshError(
                f"non-manifold edge between nodes {int(lo[k])} and {int(hi[k])}: "
                f"shared by {int(counts[e])} faces"
            )
        n_edges = uniq.shape[0]
        he_edge = np.empty(a.shape[0], dtype=np.int64)
        he_edge[order] = np.repeat(np.arange(n_edges), counts)
        hA = order[first]  # first half-edge of each edge defines face A and direction
        two = counts == 2
        hB = np.full(n_edges, -1, dtype=np.int64)
        hB[two] = order[first[two] + 1]
        edge_nodes = np.column_stack([a[hA], b[hA]]).astype(np.int32)
        # the second face must traverse the edge the other way (consistent orientation)
        same_dir = two & (a[np.maximum(hB, 0)] == a[hA])
        if np.any(same_dir):
            e = int(np.flatnonzero(same_dir)[0])
            raise MeshError(
                f"faces {int(he_face[hA[e]])} and {int(he_face[hB[e]])} have inconsistent "
                f"orientation across the edge between nodes {edge_nodes[e].tolist()}"
            )
        edge_faces = np.column_stack([he_face[hA], np.where(two, he_face[np.maximum(hB, 0)], -1)])
        edge_opp = np.column_stack([c[hA], np.where(two, c[np.maximum(hB, 0)], -1)])
        self.edge_nodes = edge_nodes
        self.edge_faces = edge_faces.astype(np.int32)
        self.edge_opp_nodes = edge_opp.astype(np.int32)
        self.face_edges = he_edge.reshape(n_faces, 3).astype(np.int32)
        boundary = np.zeros(self.n_nodes, dtype=bool)
        boundary[edge_nodes[~two].reshape(-1)] = True
        self.node_boundary = boundary

    # --- refresh point 2: after material coordinates or density change --------------------
    def update_rest_data(self, density: float) -> None:
        """Material-space areas, inverse rest matrices, hinge rest data and lumped masses.

        `density` is the area density in kg/m^2; each face gives a third of its mass to each
        of its nodes.
        """
        u = self.vert_u[self.face_verts]  # (F, 3, 2)
        Dm = np.stack([u[:, 1] - u[:, 0], u[:, 2] - u[:, 0]], axis=2)  # columns are edges
        det = Dm[:, 0, 0] * Dm[:, 1, 1] - Dm[:, 0, 1] * Dm[:, 1, 0]
        scale = (np.sum((u[:, 1] - u[:, 0]) ** 2, 1) + np.sum((u[:, 2] - u[:, 1]) ** 2, 1)
                 + np.sum((u[:, 0] - u[:, 2]) ** 2, 1)) / 3.0
        degenerate = np.abs(det) <= DEGENERATE_AREA_RATIO * 2.0 * np.maximum(scale, 1e-300)
        if np.any(degenerate):
            f = int(np.flatnonzero(degenerate)[0])
            raise MeshError(f"degenerate material triangle: face {f} has material area {0.5 * det[f]:.3e} m^2")
        if np.any(det < 0):
            f = int(np.flatnonzero(det < 0)[0])
            raise MeshError(
                f"inverted material triangle: face {f} is clockwise in material space "
                f"(area {0.5 * det[f]:.3e} m^2); faces must be counter-clockwise"
            )
        self.face_area = 0.5 * det
        inv = np.empty_like(Dm)
        inv[:, 0, 0] = Dm[:, 1, 1] / det
        inv[:, 1, 1] = Dm[:, 0, 0] / det
        inv[:, 0, 1] = -Dm[:, 0, 1] / det
        inv[:, 1, 0] = -Dm[:, 1, 0] / det
        self.face_Dm_inv = np.ascontiguousarray(inv)
        # rest length of each node edge, measured in face A's material coordinates
        fA = self.edge_faces[:, 0]
        side = np.argmax(self.face_edges[fA] == np.arange(self.n_edges)[:, None], axis=1)
        ua = self.vert_u[self.face_verts[fA, side]]
        ub = self.vert_u[self.face_verts[fA, (side + 1) % 3]]
        self.edge_rest_length = np.linalg.norm(ub - ua, axis=1)
        self.edge_rest_theta = np.zeros(self.n_edges)  # cloth is flat in material space
        self.density = float(density)
        m = np.zeros(self.n_nodes)
        np.add.at(m, self.face_nodes.reshape(-1), np.repeat(self.face_area * density / 3.0, 3))
        self.node_m = m

    # ------------------------------------------------------------------------------------
    def vert_x(self) -> np.ndarray:
        """(n_verts, 3) world position of each vert (its node's)."""
        return self.node_x[self.vert_node]

    def face_quality(self) -> np.ndarray:
        """(n_faces,) material-space triangle quality 4*sqrt(3)*A / (sum of squared edges), 1 = equilateral."""
        u = self.vert_u[self.face_verts]
        l2 = (np.sum((u[:, 1] - u[:, 0]) ** 2, 1) + np.sum((u[:, 2] - u[:, 1]) ** 2, 1)
              + np.sum((u[:, 0] - u[:, 2]) ** 2, 1))
        return 4.0 * np.sqrt(3.0) * self.face_area / l2

    def world_face_normals(self) -> np.ndarray:
        """(n_faces, 3) unit world-space normals (zero for collapsed faces)."""
        x = self.node_x[self.face_nodes]
        n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        ln = np.linalg.norm(n, axis=1, keepdims=True)
        return n / np.where(ln > 0, ln, 1.0)

    def copy(self) -> Mesh:
        out = Mesh(
            node_x=self.node_x.copy(), node_v=self.node_v.copy(), node_pinned=self.node_pinned.copy(),
            vert_u=self.vert_u.copy(), vert_node=self.vert_node.copy(), face_verts=self.face_verts.copy(),
            density=self.density,
        )
        return out


def validate_arrays(mesh: Mesh) -> None:
    """Shape and index checks that must pass before anything is derived (raises MeshError)."""
    n, m = mesh.node_x.shape[0], mesh.vert_u.shape[0]
    if mesh.node_x.ndim != 2 or mesh.node_x.shape[1] != 3:
        raise MeshError(f"node_x must have shape (n_nodes, 3), got {mesh.node_x.shape}")
    if mesh.node_v.shape != mesh.node_x.shape:
        raise MeshError(f"node_v has shape {mesh.node_v.shape}, expected {mesh.node_x.shape}")
    if mesh.node_pinned.shape != (n,):
        raise MeshError(f"node_pinned has shape {mesh.node_pinned.shape}, expected ({n},)")
    if mesh.vert_u.ndim != 2 or mesh.vert_u.shape[1] != 2:
        raise MeshError(f"vert_u must have shape (n_verts, 2), got {mesh.vert_u.shape}")
    if mesh.vert_node.shape != (m,):
        raise MeshError(f"vert_node has shape {mesh.vert_node.shape}, expected ({m},)")
    if mesh.face_verts.ndim != 2 or mesh.face_verts.shape[1] != 3:
        raise MeshError(f"face_verts must have shape (n_faces, 3), got {mesh.face_verts.shape}")
    if mesh.face_verts.shape[0] == 0:
        raise MeshError("mesh has no faces")
    if not (np.all(np.isfinite(mesh.node_x)) and np.all(np.isfinite(mesh.node_v)) and np.all(np.isfinite(mesh.vert_u))):
        raise MeshError("mesh has non-finite node positions, velocities or material coordinates")
    bad = (mesh.face_verts < 0) | (mesh.face_verts >= m)
    if np.any(bad):
        f, k = np.argwhere(bad)[0]
        raise MeshError(f"face {f} has out-of-range vert index {int(mesh.face_verts[f, k])} (n_verts = {m})")
    bad = (mesh.vert_node < 0) | (mesh.vert_node >= n)
    if np.any(bad):
        v = int(np.flatnonzero(bad)[0])
        raise MeshError(f"vert {v} maps to out-of-range node {int(mesh.vert_node[v])} (n_nodes = {n})")


def merge_meshes(meshes: list[Mesh]) -> Mesh:
    """One Mesh holding the given meshes as disjoint components (nodes, verts and faces in order)."""
    if not meshes:
        raise MeshError("merge_meshes needs at least one mesh")
    n_off = np.cumsum([0] + [m.n_nodes for m in meshes])[:-1]
    v_off = np.cumsum([0] + [m.n_verts for m in meshes])[:-1]
    return Mesh(node_x=np.vstack([m.node_x for m in meshes]), node_v=np.vstack([m.node_v for m in meshes]),
                node_pinned=np.concatenate([m.node_pinned for m in meshes]),
                vert_u=np.vstack([m.vert_u for m in meshes]),
                vert_node=np.concatenate([m.vert_node + o for m, o in zip(meshes, n_off)]),
                face_verts=np.vstack([m.face_verts + o for m, o in zip(meshes, v_off)]))


def grid_mesh(
    width: float,
    height: float,
    nx: int,
    ny: int,
    origin=(0.0, 0.0, 0.0),
    axes=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    diagonal: str = "alternate",
) -> Mesh:
    """A regular rectangular sheet of `nx` x `ny` cells (2*nx*ny faces).

    Material coordinates are (i*width/nx, j*height/ny) in metres; the world position is
    origin + u*axes[0] + v*axes[1]. `diagonal` = "alternate" flips the cell diagonal in a
    checkerboard so the mesh has no preferred shear direction.
    """
    if nx < 1 or ny < 1:
        raise MeshError(f"grid resolution must be at least 1x1 cells, got {nx}x{ny}")
    if width <= 0 or height <= 0:
        raise MeshError(f"grid size must be positive, got {width} x {height} m")
    i, j = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="xy")
    u = np.column_stack([i.ravel() * width / nx, j.ravel() * height / ny])
    idx = lambda ii, jj: jj * (nx + 1) + ii  # noqa: E731
    ci, cj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    ci, cj = ci.ravel(), cj.ravel()
    v00, v10, v01, v11 = idx(ci, cj), idx(ci + 1, cj), idx(ci, cj + 1), idx(ci + 1, cj + 1)
    flip = ((ci + cj) % 2 == 1) if diagonal == "alternate" else np.zeros_like(ci, dtype=bool)
    fa = np.where(flip[:, None], np.column_stack([v00, v10, v01]), np.column_stack([v00, v10, v11]))
    fb = np.where(flip[:, None], np.column_stack([v10, v11, v01]), np.column_stack([v00, v11, v01]))
    faces = np.empty((2 * ci.size, 3), dtype=np.int32)
    faces[0::2], faces[1::2] = fa, fb
    ax0, ax1 = np.asarray(axes[0], float), np.asarray(axes[1], float)
    x = np.asarray(origin, float) + u[:, :1] * ax0 + u[:, 1:] * ax1
    n = x.shape[0]
    return Mesh(
        node_x=x, node_v=np.zeros((n, 3)), node_pinned=np.zeros(n, dtype=bool),
        vert_u=u, vert_node=np.arange(n, dtype=np.int32), face_verts=faces,
    )
