"""Candidate pairs of the self-collision pass (cloth.collision.selfcollision): the vertex-face and
edge-edge pairs of a step that the response (cloth.collision.response) has to test.

1. `swept_boxes`: unpadded boxes of the nodes, faces and edges over the step x0 -> x1;
2. `overlapping_face_pairs`: face pairs whose padded boxes overlap (the bounding-volume hierarchy
   of cloth.collision.bvh), or, with obstacle triangles appended, the cloth-obstacle pairs;
3. `primitive_pairs`: the vertex-face and edge-edge pairs of those face pairs. Each node and each
   edge is tested from one face only, its owner (`owner_faces`); pairs that share a node, pairs
   none of whose nodes can move and pairs whose own boxes are farther apart than the pad are
   dropped.

    vf, ee = candidate_pairs(face_nodes, face_edges, edge_nodes, x0, x1, pad)  # the three in one call
    # vf (K, 2) [node, face], ee (L, 2) [edge, edge], each sorted and unique
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cloth.collision.bvh import build_tree, cross_overlaps, refit, self_overlaps

# The kernel's tests are written out, not calls of helpers: a call of a numba function with
# array arguments per pair (reference counts of each array) cost more than the tests themselves,
# and numba's own inlining (inline="always") as much.


@njit(cache=True)
def _candidates(face_pairs, face_nodes, edge_nodes, n_faces, n_edges, node_lo, node_hi,
                face_lo, face_hi, edge_lo, edge_hi, node_start, node_items, edge_start, edge_items, pad, inv_m,
                first_fixed, skip):
    """Vertex-face keys (node * F + face) and edge-edge keys (e_lo * E + e_hi) of the face
    pairs, skipping pairs that share a node, pairs whose own swept boxes are farther apart than
    pad (node, face and edge boxes over the step, unpadded), pairs none of whose nodes can move,
    and pairs of an obstacle node with a node flagged in `skip`.

    Each node and each edge is taken from one face only, its owner (`owner_faces`: the nodes and
    edges face f owns are node_items[node_start[f]:node_start[f + 1]], and likewise for edges):
    its box lies in its owner's, so a pair whose boxes are within pad comes from the pair of
    owners, which the face pairs hold, and comes once."""
    P = face_pairs.shape[0]
    vf = np.empty(6 * P, dtype=np.int64)
    ee = np.empty(9 * P, dtype=np.int64)
    nv = 0
    ne = 0
    for k in range(P):
        f, g = face_pairs[k, 0], face_pairs[k, 1]
        # the faces' own boxes first: every node and edge box lies in its face's, so a pair of
        # primitives within pad comes from faces within pad (the face pairs may be reused ones,
        # found with a wider pad at other positions)
        if (face_lo[f, 0] > face_hi[g, 0] + pad or face_lo[g, 0] > face_hi[f, 0] + pad
                or face_lo[f, 1] > face_hi[g, 1] + pad or face_lo[g, 1] > face_hi[f, 1] + pad
                or face_lo[f, 2] > face_hi[g, 2] + pad or face_lo[g, 2] > face_hi[f, 2] + pad):
            continue
        for side in range(2):
            f = face_pairs[k, side]
            g = face_pairs[k, 1 - side]
            a0, a1, a2 = face_nodes[g, 0], face_nodes[g, 1], face_nodes[g, 2]
            for a in range(node_start[f], node_start[f + 1]):
                i = node_items[a]
                if i == a0 or i == a1 or i == a2:
                    continue
                # some node can move, and a pair with an obstacle node (index >= first_fixed) has no
                # node flagged in `skip` (cloth nodes inside an obstacle at the step's start: the
                # node contact alone handles them)
                if inv_m[i] == 0.0 and inv_m[a0] == 0.0 and inv_m[a1] == 0.0 and inv_m[a2] == 0.0:
                    continue
                if (i >= first_fixed or a0 >= first_fixed or a1 >= first_fixed or a2 >= first_fixed) and \
                        (skip[i] or skip[a0] or skip[a1] or skip[a2]):
                    continue
                # the node's and the face's own boxes within pad
                if (node_lo[i, 0] > face_hi[g, 0] + pad or face_lo[g, 0] > node_hi[i, 0] + pad
                        or node_lo[i, 1] > face_hi[g, 1] + pad or face_lo[g, 1] > node_hi[i, 1] + pad
                        or node_lo[i, 2] > face_hi[g, 2] + pad or face_lo[g, 2] > node_hi[i, 2] + pad):
                    continue
                vf[nv] = i * n_faces + g
                nv += 1
        f, g = face_pairs[k, 0], face_pairs[k, 1]
        for a in range(edge_start[f], edge_start[f + 1]):
            e1 = edge_items[a]
            p, q = edge_nodes[e1, 0], edge_nodes[e1, 1]
            for b in range(edge_start[g], edge_start[g + 1]):
                e2 = edge_items[b]
                P2, Q2 = edge_nodes[e2, 0], edge_nodes[e2, 1]
                if p == P2 or p == Q2 or q == P2 or q == Q2:
                    continue
                if inv_m[p] == 0.0 and inv_m[q] == 0.0 and inv_m[P2] == 0.0 and inv_m[Q2] == 0.0:
                    continue
                if (p >= first_fixed or q >= first_fixed or P2 >= first_fixed or Q2 >= first_fixed) and \
                        (skip[p] or skip[q] or skip[P2] or skip[Q2]):
                    continue
                if (edge_lo[e1, 0] > edge_hi[e2, 0] + pad or edge_lo[e2, 0] > edge_hi[e1, 0] + pad
                        or edge_lo[e1, 1] > edge_hi[e2, 1] + pad or edge_lo[e2, 1] > edge_hi[e1, 1] + pad
                        or edge_lo[e1, 2] > edge_hi[e2, 2] + pad or edge_lo[e2, 2] > edge_hi[e1, 2] + pad):
                    continue
                ee[ne] = min(e1, e2) * n_edges + max(e1, e2)
                ne += 1
    return vf[:nv], ee[:ne]


@njit(cache=True)
def _sorted_unique(keys):
    """The distinct values of `keys`, sorted (np.unique without its Python overhead)."""
    if keys.shape[0] == 0:
        return keys
    k = np.sort(keys)
    out = np.empty_like(k)
    out[0] = k[0]
    n = 1
    for j in range(1, k.shape[0]):
        if k[j] != out[n - 1]:
            out[n] = k[j]
            n += 1
    return out[:n]


@njit(cache=True)
def _box_kernel(face_nodes, edge_nodes, x0, x1):
    N, F, E = x0.shape[0], face_nodes.shape[0], edge_nodes.shape[0]
    node_lo, node_hi = np.empty((N, 3)), np.empty((N, 3))
    face_lo, face_hi = np.empty((F, 3)), np.empty((F, 3))
    edge_lo, edge_hi = np.empty((E, 3)), np.empty((E, 3))
    for i in range(N):
        for d in range(3):
            node_lo[i, d] = min(x0[i, d], x1[i, d])
            node_hi[i, d] = max(x0[i, d], x1[i, d])
    for f in range(F):
        a, b, c = face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2]
        for d in range(3):
            face_lo[f, d] = min(node_lo[a, d], min(node_lo[b, d], node_lo[c, d]))
            face_hi[f, d] = max(node_hi[a, d], max(node_hi[b, d], node_hi[c, d]))
    for e in range(E):
        p, q = edge_nodes[e, 0], edge_nodes[e, 1]
        for d in range(3):
            edge_lo[e, d] = min(node_lo[p, d], node_lo[q, d])
            edge_hi[e, d] = max(node_hi[p, d], node_hi[q, d])
    return node_lo, node_hi, face_lo, face_hi, edge_lo, edge_hi


def swept_boxes(face_nodes, edge_nodes, x0, x1):
    """Unpadded boxes over the step x0 -> x1 (x0 alone if x1 is None) of the nodes, faces and
    edges: (node_lo, node_hi, face_lo, face_hi, edge_lo, edge_hi)."""
    return _box_kernel(face_nodes, edge_nodes, x0, x0 if x1 is None else x1)


# An obstacle's tree kept from pass to pass is refitted to its new boxes (its triangles do not
# change) until its node boxes' summed extents grow past this factor of a fresh build's; then it is
# built again. A body moves coherently, so the refitted tree stays tight for many steps; the pairs
# found are the same either way (a tree only decides how fast they are found).
REFIT_GROWTH = 1.5


def obstacle_tree(lo, hi, trees: dict | None):
    """The tree over the obstacle triangles' boxes (lo, hi): `trees` (kept by the caller from pass
    to pass, or None) holds the last one, refitted when it has as many boxes and has not grown past
    REFIT_GROWTH, built afresh otherwise."""
    kept = None if trees is None else trees.get("tree")
    if kept is not None and kept[0].shape[0] and kept[5].shape[0] == lo.shape[0]:
        nlo, nhi, left, start, count, order = kept
        if refit(lo, hi, nlo, nhi, left, start, count, order) <= REFIT_GROWTH * trees["extent"]:
            return kept
    tree = build_tree(lo, hi)
    if trees is not None:
        trees["tree"] = tree
        trees["extent"] = float(np.sum(tree[1] - tree[0]))
    return tree


def overlapping_face_pairs(face_lo, face_hi, pad, n_fixed_faces=0, self_pairs=True, cache=None, trees=None):
    """Face pairs (P, 2) whose boxes, inflated by pad, overlap: all of them, or, with
    `n_fixed_faces` obstacle triangles last, those between the cloth and the obstacles (and
    within the cloth if `self_pairs`), never two obstacle faces. Any order (the candidates are
    sorted). `cache` (a dict, optional): keeps the obstacle triangles' tree for the next call of the
    same collision pass, whose obstacle boxes and pad are the same (obstacle nodes do not move);
    `trees` (a dict kept from pass to pass, optional): see `obstacle_tree`."""
    lo, hi = face_lo - pad, face_hi + pad
    if not n_fixed_faces:
        return self_overlaps(lo, hi, sort=False)
    Fc = lo.shape[0] - int(n_fixed_faces)
    olo, ohi = np.ascontiguousarray(lo[Fc:]), np.ascontiguousarray(hi[Fc:])
    tree = None if cache is None else cache.get("obstacle_tree")
    if tree is None:
        tree = obstacle_tree(olo, ohi, trees)
        if cache is not None:
            cache["obstacle_tree"] = tree
    # cloth faces whose boxes meet the obstacles' overall box (the tree's root): the others cannot touch them
    near = np.flatnonzero(np.all((lo[:Fc] <= tree[1][0]) & (hi[:Fc] >= tree[0][0]), axis=1))
    cross = cross_overlaps(lo[near], hi[near], olo, ohi, tree2=tree, sort=False)
    parts = [np.column_stack([near[cross[:, 0]], cross[:, 1] + Fc])]
    if self_pairs:
        parts.insert(0, self_overlaps(lo[:Fc], hi[:Fc], sort=False))
    return np.ascontiguousarray(np.vstack(parts))


def _by_face(owner: np.ndarray, n_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """(start (F + 1,), items): the items whose owner is face f are items[start[f]:start[f + 1]]."""
    items = np.flatnonzero(owner >= 0)
    of = owner[items]
    items = items[np.argsort(of, kind="stable")]
    start = np.zeros(n_faces + 1, dtype=np.int64)
    np.cumsum(np.bincount(of, minlength=n_faces), out=start[1:])
    return start, items


def owner_faces(face_nodes, face_edges, n_nodes, n_edges):
    """One face of each node and of each edge (the last face that holds it; a node in no face has
    none), as the nodes and the edges each face owns: (node_start, node_items, edge_start,
    edge_items), see `_candidates`."""
    F = face_nodes.shape[0]
    owner = np.repeat(np.arange(F, dtype=np.int64), 3)
    node_owner = np.full(n_nodes, -1, dtype=np.int64)
    node_owner[face_nodes.ravel()] = owner
    edge_owner = np.full(n_edges, -1, dtype=np.int64)
    edge_owner[face_edges.ravel()] = owner
    return (*_by_face(node_owner, F), *_by_face(edge_owner, F))


def primitive_pairs(fp, face_nodes, face_edges, edge_nodes, boxes, owners, pad, inv_m, first_fixed, skip):
    """Vertex-face and edge-edge pairs (see candidate_pairs) of the face pairs fp, whose own boxes
    (`swept_boxes`) are within pad."""
    F, E = face_nodes.shape[0], edge_nodes.shape[0]
    vf, ee = _candidates(fp, face_nodes, edge_nodes, F, E, *boxes, *owners, pad, inv_m, first_fixed, skip)
    vf, ee = _sorted_unique(vf), _sorted_unique(ee)
    return (np.stack([vf // F, vf % F], axis=1), np.stack([ee // E, ee % E], axis=1))


def candidate_pairs(face_nodes, face_edges, edge_nodes, x0, x1, pad, inv_m=None, n_fixed_faces=0,
                    self_pairs=True, first_fixed=None, skip=None):
    """Vertex-face (K, 2) [node, face] and edge-edge (L, 2) [edge, edge] pairs whose boxes
    (covering x0 -> x1, or x0 alone if x1 is None, inflated by `pad`) overlap.

    With `inv_m`, pairs none of whose nodes can move (inv_m = 0) are left out. The last
    `n_fixed_faces` faces are obstacle triangles (nodes from `first_fixed` on): face pairs are
    then taken between them and the other faces only, and among the other faces only if
    `self_pairs`; `skip` (N,) flags nodes whose pairs with obstacle nodes are left out."""
    N, E = x0.shape[0], edge_nodes.shape[0]
    boxes = swept_boxes(face_nodes, edge_nodes, x0, x1)
    fp = overlapping_face_pairs(boxes[2], boxes[3], pad, n_fixed_faces, self_pairs)
    inv_m = np.ones(N) if inv_m is None else inv_m
    first_fixed = N if first_fixed is None else int(first_fixed)
    skip = np.zeros(N, dtype=np.bool_) if skip is None else skip
    return primitive_pairs(fp, face_nodes, face_edges, edge_nodes, boxes, owner_faces(face_nodes, face_edges, N, E),
                           pad, inv_m, first_fixed, skip)
