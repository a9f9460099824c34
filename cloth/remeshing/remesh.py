"""Anisotropic remeshing in material space (Narain, Samii and O'Brien 2012): the Python driver.

Given a sizing tensor M per vert (2x2, material space, 1/m^2), the remesher makes every edge
satisfy the size criterion of the paper's eq 1,

    s^2(i, j) = u_ij^T ((M_i + M_j) / 2) u_ij <= 1,

with as few faces as it can:

1. flip every edge that is not anisotropically Delaunay (Bossen and Heckbert 1996) under the
   mean metric of its four verts, unless a new face would fall below `aspect_min` in material
   space and below the worse of the two it replaces (the metric's diagonal can be a sliver);
2. split invalid edges (s > 1) worst first, at the midpoint, and flip around each split;
   repeat until no edge is invalid;
3. collapse an edge when every edge the collapse creates has s <= `collapse_max_size` (0.9),
   no new face inverts and none falls below `aspect_min`; flip around each collapse; repeat
   over the faces that changed until nothing collapses.

Boundaries, seams, pinned nodes and corners are kept: a boundary vert is removed only by a
collapse along the boundary and only where the boundary is straight to within
`corner_angle`; seam nodes (nodes with several verts) and pinned nodes are never removed.
A split creates one node (the mean of its edge's two nodes' data: position, velocity,
acceleration, handle anchor, so momentum is unchanged) and one vert per side of the edge (two
on a seam). Everything is deterministic: the same input gives the same mesh.

The operations are numba kernels in :mod:`cloth.remeshing.kernels` (geometry, halfedge,
flips, splits, collapses); this module holds the parameters, the result and the working
arrays, and :func:`remesh` runs the three steps above.

Working representation (capacity-sized arrays, :class:`RemeshWork`, grown by the driver):

* faces: ``fv`` (verts, CCW in material space), ``fadj`` (half-edge code 3*g+l of the face
  across each side, -1 on the boundary; side k goes from fv[k] to fv[k+1]), ``ftw`` (on a
  boundary side, the seam twin half-edge on the other panel, else -1), ``falive``;
* verts: ``vu``, ``vM``, ``vnode``, ``vface`` (one incident face), ``valive``;
* nodes: ``nd`` (per-node data averaged on split), ``npin`` (handle id, -1 free), ``nnv``
  (verts per node), ``nalive``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cloth.core.mesh import Mesh
from cloth.remeshing.kernels.collapses import collapse_pass
from cloth.remeshing.kernels.flips import flip_all, flip_slivers
from cloth.remeshing.kernels.splits import OUT_OF_CAPACITY, split_pass


@dataclass(frozen=True)
class RemeshParams:
    aspect_min: float = 0.2  # smallest aspect 12*sqrt(3)*A/P^2 (1 = equilateral) a collapse or flip may make
    collapse_max_size: float = 0.9  # a collapse may create no edge with s above this
    flip_threshold: float = 1e-2  # flip when sin(alpha + beta) < -threshold in metric space
    corner_angle: float = 0.5  # rad: boundary verts where the boundary turns more than this are kept
    max_split_rounds: int = 64  # bound on split passes (each pass splits every invalid edge once)
    max_collapse_rounds: int = 64  # bound on collapse passes
    # World-space guard (not in ARCSim): a flip or collapse may not leave a face whose principal
    # squared stretch differs from 1 by more than this, unless the faces it replaces already did.
    # Material-space operations in a folded region can otherwise crease the surface and compress
    # a face past the StVK softening point (stretch 1/sqrt(3)), where the implicit step blows up.
    max_world_strain: float = 0.2

    def __post_init__(self):
        if not 0 < self.aspect_min <= 1:
            raise ValueError(f"aspect_min must be in (0, 1], got {self.aspect_min}")
        for key in ("collapse_max_size", "max_world_strain"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key} must be > 0, got {getattr(self, key)}")
        for key in ("flip_threshold", "corner_angle"):
            if not getattr(self, key) >= 0:
                raise ValueError(f"{key} must be >= 0, got {getattr(self, key)}")
        for key in ("max_split_rounds", "max_collapse_rounds"):
            if not getattr(self, key) >= 1:
                raise ValueError(f"{key} must be >= 1 pass, got {getattr(self, key)}")


@dataclass
class RemeshResult:
    mesh: Mesh
    node_data: np.ndarray  # (n_nodes, D) carried per-node data after the remesh
    node_handle: np.ndarray  # (n_nodes,) handle id per node, -1 free
    node_origin: np.ndarray  # (n_nodes,) index of each node in the input mesh, -1 for a new node
    vert_M: np.ndarray  # (n_verts, 2, 2) sizing of the output verts (new verts: mean of their edge's)
    splits: int
    collapses: int
    flips: int
    changed: bool


class RemeshWork:
    """Capacity-sized working arrays of one remesh."""

    def __init__(self, mesh: Mesh, vert_M: np.ndarray, node_data: np.ndarray, node_handle: np.ndarray):
        F, V, N = mesh.n_faces, mesh.n_verts, mesh.n_nodes
        cf, cv, cn = 2 * F + 64, 2 * V + 64, 2 * N + 64
        self.cnt = np.array([F, V, N], dtype=np.int64)
        self.n_input_nodes = N
        self.fv = np.zeros((cf, 3), np.int64)
        self.fv[:F] = mesh.face_verts
        self.fadj = np.full((cf, 3), -1, np.int64)
        self.ftw = np.full((cf, 3), -1, np.int64)
        self.falive = np.zeros(cf, bool)
        self.falive[:F] = True
        self.fdirty = np.zeros(cf, bool)
        self.vu = np.zeros((cv, 2))
        self.vu[:V] = mesh.vert_u
        self.vM = np.zeros((cv, 2, 2))
        self.vM[:V] = vert_M
        self.vnode = np.zeros(cv, np.int64)
        self.vnode[:V] = mesh.vert_node
        self.vface = np.zeros(cv, np.int64)
        self.valive = np.zeros(cv, bool)
        self.valive[:V] = True
        self.nd = np.zeros((cn, node_data.shape[1]))
        self.nd[:N] = node_data
        self.npin = np.full(cn, -1, np.int64)
        self.npin[:N] = node_handle
        self.nnv = np.zeros(cn, np.int64)
        np.add.at(self.nnv, mesh.vert_node, 1)
        self.nalive = np.zeros(cn, bool)
        self.nalive[:N] = True
        self._adjacency(mesh)

    def _adjacency(self, mesh: Mesh) -> None:
        """Face adjacency and seam twins from the mesh's derived edges (vectorised)."""
        fv = mesh.face_verts.astype(np.int64)
        F = fv.shape[0]
        a = fv.reshape(-1)
        b = np.roll(fv, -1, axis=1).reshape(-1)
        V = mesh.n_verts
        key_dir = a * V + b
        key_rev = b * V + a
        order = np.argsort(key_dir)
        pos = np.searchsorted(key_dir[order], key_rev)
        pos = np.minimum(pos, a.size - 1)
        match = key_dir[order][pos] == key_rev
        adj = np.where(match, order[pos], -1)
        self.fadj[:F] = adj.reshape(F, 3)
        self.vface[fv.reshape(-1)] = np.repeat(np.arange(F), 3)
        # seam twins: boundary half-edges whose node pair appears on another boundary half-edge
        bnd = np.flatnonzero(adj < 0)
        if bnd.size:
            na = mesh.vert_node[a[bnd]].astype(np.int64)
            nb_ = mesh.vert_node[b[bnd]].astype(np.int64)
            key = np.minimum(na, nb_) * mesh.n_nodes + np.maximum(na, nb_)
            o = np.argsort(key, kind="stable")
            ks = key[o]
            same = np.flatnonzero(ks[1:] == ks[:-1])
            tw = self.ftw.reshape(-1)
            tw[bnd[o[same]]] = bnd[o[same + 1]]
            tw[bnd[o[same + 1]]] = bnd[o[same]]

    def grow(self) -> None:
        def g(arr, fill):
            out = np.full((2 * arr.shape[0],) + arr.shape[1:], fill, dtype=arr.dtype)
            out[: arr.shape[0]] = arr
            return out
        self.fv, self.fadj, self.ftw = g(self.fv, 0), g(self.fadj, -1), g(self.ftw, -1)
        self.falive, self.fdirty = g(self.falive, False), g(self.fdirty, False)
        self.vu, self.vM, self.vnode = g(self.vu, 0.0), g(self.vM, 0.0), g(self.vnode, 0)
        self.vface, self.valive = g(self.vface, 0), g(self.valive, False)
        self.nd, self.npin = g(self.nd, 0.0), g(self.npin, -1)
        self.nnv, self.nalive = g(self.nnv, 0), g(self.nalive, False)

    def to_mesh(self, density: float, x_cols=slice(0, 3), v_cols=slice(3, 6)):
        """Compact the live elements into a new Mesh; returns (mesh, node_data, node_handle, node_origin, vert_M)."""
        nF, nV, nN = self.cnt
        fl = np.flatnonzero(self.falive[:nF])
        vl = np.flatnonzero(self.valive[:nV])
        nl = np.flatnonzero(self.nalive[:nN])
        vmap = np.full(nV, -1, np.int64)
        vmap[vl] = np.arange(vl.size)
        nmap = np.full(nN, -1, np.int64)
        nmap[nl] = np.arange(nl.size)
        nd = self.nd[nl]
        mesh = Mesh(
            node_x=nd[:, x_cols], node_v=nd[:, v_cols], node_pinned=self.npin[nl] != -1,
            vert_u=self.vu[vl], vert_node=nmap[self.vnode[vl]], face_verts=vmap[self.fv[fl]],
            density=density,
        )
        return mesh, nd, self.npin[nl], np.where(nl < self.n_input_nodes, nl, -1), self.vM[vl]


def remesh(mesh: Mesh, vert_M: np.ndarray, node_data: np.ndarray, node_handle: np.ndarray,
           params: RemeshParams = RemeshParams(), frozen: np.ndarray | None = None) -> RemeshResult:
    """Remesh `mesh` to the per-vert sizing `vert_M` (n_verts, 2, 2).

    `node_data` (n_nodes, D) holds everything per node that a split averages; its first six
    columns are position and velocity. `node_handle` (n_nodes,) is the handle id of each pinned
    node (-1 free): a node created between two nodes of one handle joins that handle.
    `frozen` (n_nodes,) bool, optional: no flip or collapse touches these nodes, nor the nodes
    a split makes next to them (splits still refine there: they do not move the surface).
    """
    vert_M = np.ascontiguousarray(vert_M, dtype=np.float64)
    if vert_M.shape != (mesh.n_verts, 2, 2):
        raise ValueError(f"vert_M must have shape ({mesh.n_verts}, 2, 2), got {vert_M.shape}")
    if node_data.shape[0] != mesh.n_nodes or node_data.shape[1] < 6:
        raise ValueError(f"node_data must have shape ({mesh.n_nodes}, >= 6), got {node_data.shape}")
    node_data = np.asarray(node_data, dtype=np.float64)
    n_data = node_data.shape[1]
    fz = -1
    if frozen is not None:
        frozen = np.asarray(frozen, dtype=bool)
        if frozen.shape != (mesh.n_nodes,):
            raise ValueError(f"frozen must have shape ({mesh.n_nodes},), got {frozen.shape}")
        if frozen.any():  # carried as one more column: a split's mean is > 0 next to a frozen node
            node_data = np.hstack([node_data, frozen[:, None].astype(np.float64)])
            fz = n_data
    w = RemeshWork(mesh, vert_M, node_data, np.asarray(node_handle, dtype=np.int64))
    thr = params.flip_threshold
    ms = params.max_world_strain
    am = params.aspect_min
    flips = flip_all(w.fv, w.fadj, w.ftw, w.falive, w.vu, w.vM, w.vface, w.vnode, w.nd, ms, w.cnt, w.fdirty, thr,
                     fz, am)
    splits = 0
    while True:
        status, s, fl = split_pass(w.fv, w.fadj, w.ftw, w.falive, w.vu, w.vM, w.vnode, w.vface, w.valive,
                                   w.nd, w.npin, w.nnv, w.nalive, w.cnt, w.fdirty, thr, params.max_split_rounds, ms,
                                   fz, am)
        splits += s
        flips += fl
        if status == OUT_OF_CAPACITY:
            w.grow()
            continue
        break
    w.fdirty[: w.cnt[0]] = w.falive[: w.cnt[0]]  # every face is a collapse candidate once
    collapses, fl = collapse_pass(w.fv, w.fadj, w.ftw, w.falive, w.vu, w.vM, w.vnode, w.vface, w.valive,
                                  w.npin, w.nnv, w.nalive, w.cnt, w.fdirty, params.aspect_min,
                                  params.collapse_max_size, math.cos(params.corner_angle), thr,
                                  params.max_collapse_rounds, w.nd, ms, fz)
    flips += fl
    flips += flip_slivers(w.fv, w.fadj, w.ftw, w.falive, w.vu, w.vM, w.vface, w.vnode, w.nd, ms, w.cnt, w.fdirty, thr,
                          fz, am)
    out, nd, nh, origin, vM = w.to_mesh(mesh.density)
    nd = nd[:, :n_data]
    return RemeshResult(mesh=out, node_data=nd, node_handle=nh, node_origin=origin, vert_M=vM, splits=int(splits),
                        collapses=int(collapses), flips=int(flips),
                        changed=bool(splits or collapses or flips))
