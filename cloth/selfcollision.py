"""Cloth self-collision over one step: proximity repulsion, continuous collision detection and
rigid impact zones (Bridson, Fedkiw and Anderson 2002; Provot 1997), on node positions.

Given the positions x0 at the start of a step (assumed free of intersections) and the
positions x1 the integrator proposes at its end, `resolve_self_collisions` changes x1 so that

1. **proximity**: vertex-face and edge-edge pairs closer than the thickness at x1 are pushed
   apart to the thickness on the side they were on at x0 (mass-weighted, with the primitives'
   barycentric weights, so a pair that crossed during the step is pushed back), with
   Coulomb friction on their relative tangential motion over the step;
2. **continuous collision detection**: every vertex-face and edge-edge pair that touches
   during the linear motion x0 -> x1 (roots of the coplanarity cubic, `cloth.ccd`) is given a
   correction that leaves it on its starting side by a small separation at the end of the
   step; repeated in Gauss-Seidel passes until a pass finds nothing or the pass limit is hit;
3. **rigid impact zones**: if collisions remain, the nodes of each colliding pair are merged
   into zones (with the zones already found) and each zone moves rigidly with its own linear
   and angular momentum over the step. A rigid motion of a collision-free configuration has no
   internal collisions, and zones only grow, so this terminates: at worst with one zone that
   holds every colliding node. A zone with pinned nodes (infinite mass) takes the rigid motion
   that best fits their displacement (`pinned_fit`). What is left after `max_zone_passes` is
   counted in the record (never aborts).

The caller turns the change of x1 into a change of velocity (dv = dx1 / h). Pairs that share
a node are never tested (adjacent elements touch by construction), nor pairs none of whose
nodes can move (every node pinned: no response can change them).

**Obstacles.** `resolve_collisions_with_obstacles` runs the same three stages between the cloth
and triangle-mesh obstacles (cloth.meshobstacle) moving linearly over the step from their
start to their end positions: the obstacles' triangles are appended to the cloth's as fixed
faces whose nodes are pinned (infinite mass, inv_m = 0), so every correction moves only the
cloth, and face pairs are taken between the cloth and the obstacles (and within the cloth when
asked), never between two obstacle faces. A rigid impact zone holding pinned nodes moves with
the rigid motion that best fits their displacement (least squares, Kabsch): exact for a zone
touching one rigidly moving part (a translating sphere, one skinned capsule), so such a zone
has no collision left inside it and the zone argument above still terminates. A zone touching
parts that move differently (two capsules at a bending joint) is fitted only approximately;
what it leaves after the rounds is counted (`obstacle_collisions_left`).

Broad phase: a bounding-volume hierarchy over face boxes (cloth.bvh) gives the face pairs; each
node and edge is then tested from one face only (`_candidates`), and a slab test along the
face normal or the edges' cross product rejects most pairs before the exact distance or the
CCD cubic (cloth.ccd.vf_separated, ee_separated).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .bvh import cross_overlaps, self_overlaps
from .ccd import ee_ccd, ee_separated, point_triangle_closest, segment_segment_closest, vf_ccd, vf_separated

# CCD counts a touch when two primitives come within this fraction of the thickness: the
# coplanarity roots are exact only up to round-off, and a zero-distance test would miss grazes.
CCD_ETA_FRACTION = 1e-3
# After a CCD correction the pair ends this fraction of the thickness apart on its starting
# side: enough that round-off does not put it back into contact, small enough that the
# correction does not start new collisions (the proximity stage of the next step restores the
# full thickness).
CCD_SEPARATION_FRACTION = 0.1
# A proximity pair closer than this fraction of the thickness has no reliable direction at x1:
# it takes its direction from x0.
DEGENERATE_FRACTION = 1e-6


@dataclass(frozen=True)
class SelfCollisionParams:
    thickness: float  # m, distance kept between cloth surfaces
    friction: float = 0.3  # Coulomb coefficient, cloth against cloth
    proximity_passes: int = 2  # Gauss-Seidel passes of the repulsion
    ccd_passes: int = 3  # Gauss-Seidel CCD passes before rigid impact zones
    max_zone_passes: int = 12  # impact-zone rounds before giving up (the record says what is left)

    def __post_init__(self):
        if not self.thickness > 0:
            raise ValueError(f"self-collision thickness must be > 0, got {self.thickness}")
        if self.friction < 0:
            raise ValueError(f"self-collision friction must be >= 0, got {self.friction}")
        for name in ("proximity_passes", "ccd_passes", "max_zone_passes"):
            if int(getattr(self, name)) < 0:
                raise ValueError(f"self-collision {name} must be >= 0, got {getattr(self, name)}")


# ------------------------------------------------------------------------------------------
# candidate primitive pairs from candidate face pairs


@njit(cache=True)
def _boxes_apart(x0, x1, a0, a1, a2, b0, b1, b2, b3, pad):
    """True when the box swept by nodes a0..a2 (a2 < 0: an edge) over x0 -> x1 and the box swept
    by b0..b3 (b3 < 0: three nodes) are farther apart than `pad` along some axis: then the two
    primitives cannot come within pad of each other during the step (a cheap exact rejection
    before the cubic). x1 may be x0 for a static test."""
    for d in range(3):
        alo = min(x0[a0, d], x1[a0, d], x0[a1, d], x1[a1, d])
        ahi = max(x0[a0, d], x1[a0, d], x0[a1, d], x1[a1, d])
        if a2 >= 0:
            alo = min(alo, x0[a2, d], x1[a2, d])
            ahi = max(ahi, x0[a2, d], x1[a2, d])
        blo = min(x0[b0, d], x1[b0, d], x0[b1, d], x1[b1, d], x0[b2, d], x1[b2, d])
        bhi = max(x0[b0, d], x1[b0, d], x0[b1, d], x1[b1, d], x0[b2, d], x1[b2, d])
        if b3 >= 0:
            blo = min(blo, x0[b3, d], x1[b3, d])
            bhi = max(bhi, x0[b3, d], x1[b3, d])
        if alo > bhi + pad or blo > ahi + pad:
            return True
    return False


@njit(cache=True)
def _kept(i, a, b, c, inv_m, first_fixed, skip):
    """Whether the pair of nodes i, a, b, c is worth testing: some node can move, and, for a
    pair with an obstacle node (index >= first_fixed), no node is flagged in `skip` (cloth
    nodes found inside an obstacle at the step's start: the node contact alone handles them)."""
    if inv_m[i] == 0.0 and inv_m[a] == 0.0 and inv_m[b] == 0.0 and inv_m[c] == 0.0:
        return False
    if i >= first_fixed or a >= first_fixed or b >= first_fixed or c >= first_fixed:
        if skip[i] or skip[a] or skip[b] or skip[c]:
            return False
    return True


@njit(cache=True, inline="always")
def _apart(alo, ahi, a, blo, bhi, b, pad):
    """Box a of (alo, ahi) and box b of (blo, bhi) are farther apart than pad along some axis."""
    for d in range(3):
        if alo[a, d] > bhi[b, d] + pad or blo[b, d] > ahi[a, d] + pad:
            return True
    return False


@njit(cache=True)
def _candidates(face_pairs, face_nodes, face_edges, edge_nodes, n_faces, n_edges, node_lo, node_hi,
                face_lo, face_hi, edge_lo, edge_hi, node_owner, edge_owner, pad, inv_m, first_fixed, skip):
    """Vertex-face keys (node * F + face) and edge-edge keys (e_lo * E + e_hi) of the face
    pairs, skipping pairs that share a node, pairs `_kept` rejects and pairs whose own swept
    boxes are farther apart than pad (node, face and edge boxes over the step, unpadded).

    Each node and each edge is taken from one face only, its owner (node_owner, edge_owner):
    its box lies in its owner's, so a pair whose boxes are within pad comes from the pair of
    owners, which the face pairs hold, and comes once."""
    P = face_pairs.shape[0]
    vf = np.empty(6 * P, dtype=np.int64)
    ee = np.empty(9 * P, dtype=np.int64)
    nv = 0
    ne = 0
    for k in range(P):
        for side in range(2):
            f = face_pairs[k, side]
            g = face_pairs[k, 1 - side]
            for a in range(3):
                i = face_nodes[f, a]
                if node_owner[i] != f:
                    continue
                if i == face_nodes[g, 0] or i == face_nodes[g, 1] or i == face_nodes[g, 2]:
                    continue
                if not _kept(i, face_nodes[g, 0], face_nodes[g, 1], face_nodes[g, 2], inv_m, first_fixed, skip):
                    continue
                if _apart(node_lo, node_hi, i, face_lo, face_hi, g, pad):
                    continue
                vf[nv] = i * n_faces + g
                nv += 1
        f, g = face_pairs[k, 0], face_pairs[k, 1]
        for a in range(3):
            e1 = face_edges[f, a]
            if edge_owner[e1] != f:
                continue
            p, q = edge_nodes[e1, 0], edge_nodes[e1, 1]
            for b in range(3):
                e2 = face_edges[g, b]
                if edge_owner[e2] != g:
                    continue
                P2, Q2 = edge_nodes[e2, 0], edge_nodes[e2, 1]
                if p == P2 or p == Q2 or q == P2 or q == Q2:
                    continue
                if not _kept(p, q, P2, Q2, inv_m, first_fixed, skip):
                    continue
                if _apart(edge_lo, edge_hi, e1, edge_lo, edge_hi, e2, pad):
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


def _boxes(face_nodes, edge_nodes, x0, x1):
    """Unpadded boxes over the step x0 -> x1 (x0 alone if x1 is None) of the nodes, faces and
    edges: (node_lo, node_hi, face_lo, face_hi, edge_lo, edge_hi)."""
    return _box_kernel(face_nodes, edge_nodes, x0, x0 if x1 is None else x1)


def _face_pairs(face_lo, face_hi, pad, n_fixed_faces=0, self_pairs=True):
    """Face pairs (P, 2) whose boxes, inflated by pad, overlap: all of them, or, with
    `n_fixed_faces` obstacle triangles last, those between the cloth and the obstacles (and
    within the cloth if `self_pairs`), never two obstacle faces."""
    lo, hi = face_lo - pad, face_hi + pad
    if not n_fixed_faces:
        return self_overlaps(lo, hi)
    Fc = lo.shape[0] - int(n_fixed_faces)
    # cloth faces whose boxes meet the obstacles' overall box: the others cannot touch them
    olo, ohi = lo[Fc:].min(axis=0), hi[Fc:].max(axis=0)
    near = np.flatnonzero(np.all((lo[:Fc] <= ohi) & (hi[:Fc] >= olo), axis=1))
    cross = cross_overlaps(lo[near], hi[near], lo[Fc:], hi[Fc:])
    parts = [np.column_stack([near[cross[:, 0]], cross[:, 1] + Fc])]
    if self_pairs:
        parts.insert(0, self_overlaps(lo[:Fc], hi[:Fc]))
    return np.ascontiguousarray(np.vstack(parts))


def _owners(face_nodes, face_edges, n_nodes, n_edges):
    """One face of each node and of each edge (-1 for a node in no face): see `_candidates`."""
    owner = np.repeat(np.arange(face_nodes.shape[0], dtype=np.int64), 3)
    node_owner = np.full(n_nodes, -1, dtype=np.int64)
    node_owner[face_nodes.ravel()] = owner
    edge_owner = np.full(n_edges, -1, dtype=np.int64)
    edge_owner[face_edges.ravel()] = owner
    return node_owner, edge_owner


def _primitive_pairs(fp, face_nodes, face_edges, edge_nodes, boxes, owners, pad, inv_m, first_fixed, skip):
    """Vertex-face and edge-edge pairs (see candidate_pairs) of the face pairs fp, whose own boxes
    (`_boxes`) are within pad."""
    F, E = face_nodes.shape[0], edge_nodes.shape[0]
    vf, ee = _candidates(fp, face_nodes, face_edges, edge_nodes, F, E, *boxes, *owners, pad, inv_m, first_fixed, skip)
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
    boxes = _boxes(face_nodes, edge_nodes, x0, x1)
    fp = _face_pairs(boxes[2], boxes[3], pad, n_fixed_faces, self_pairs)
    inv_m = np.ones(N) if inv_m is None else inv_m
    first_fixed = N if first_fixed is None else int(first_fixed)
    skip = np.zeros(N, dtype=np.bool_) if skip is None else skip
    return _primitive_pairs(fp, face_nodes, face_edges, edge_nodes, boxes, _owners(face_nodes, face_edges, N, E),
                            pad, inv_m, first_fixed, skip)


# ------------------------------------------------------------------------------------------
# a constraint on four nodes: n . sum_k w_k x_k >= target


@njit(cache=True)
def _apply(x1, inv_m, idx, w, n, target):
    """Move the four nodes idx (weights w) along n, mass-weighted, so that n . sum w x = target
    if it is below. Returns the correction's size (0 if none or if every node is pinned)."""
    c = 0.0
    denom = 0.0
    for k in range(4):
        i = idx[k]
        c += w[k] * (n[0] * x1[i, 0] + n[1] * x1[i, 1] + n[2] * x1[i, 2])
        denom += w[k] * w[k] * inv_m[i]
    if c >= target or denom == 0.0:
        return 0.0
    lam = (target - c) / denom
    for k in range(4):
        i = idx[k]
        s = lam * w[k] * inv_m[i]
        for d in range(3):
            x1[i, d] += s * n[d]
    return target - c


@njit(cache=True)
def _friction(x0, x1, inv_m, idx, w, n, dn, mu):
    """Coulomb friction: reduce the relative tangential motion over the step of the pair by at
    most mu * dn (the normal correction just applied), stopping at zero relative slip."""
    if mu == 0.0 or dn <= 0.0:
        return
    rel = np.zeros(3)
    denom = 0.0
    for k in range(4):
        i = idx[k]
        for d in range(3):
            rel[d] += w[k] * (x1[i, d] - x0[i, d])
        denom += w[k] * w[k] * inv_m[i]
    if denom == 0.0:
        return
    rn = rel[0] * n[0] + rel[1] * n[1] + rel[2] * n[2]
    t = rel - rn * n
    tn = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
    if tn == 0.0:
        return
    frac = min(1.0, mu * dn / tn)
    lam = -frac / denom
    for k in range(4):
        i = idx[k]
        s = lam * w[k] * inv_m[i]
        for d in range(3):
            x1[i, d] += s * t[d]


@njit(cache=True)
def _normalise(v):
    L = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if L > 0.0:
        for d in range(3):
            v[d] /= L
    return L


@njit(cache=True)
def _vf_geometry(x, i, a, b, c):
    """Distance, weights (1, -w0, -w1, -w2) and unit direction from the face to the node."""
    dist, w0, w1, w2 = point_triangle_closest(x[i], x[a], x[b], x[c])
    n = x[i] - (w0 * x[a] + w1 * x[b] + w2 * x[c])
    _normalise(n)
    w = np.array([1.0, -w0, -w1, -w2])
    return dist, w, n


@njit(cache=True)
def _ee_geometry(x, p, q, P, Q):
    dist, s, t = segment_segment_closest(x[p], x[q], x[P], x[Q])
    n = (x[p] + s * (x[q] - x[p])) - (x[P] + t * (x[Q] - x[P]))
    _normalise(n)
    w = np.array([1.0 - s, s, -(1.0 - t), -t])
    return dist, w, n


@njit(cache=True)
def _proximity(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, h, mu, passes, first_fixed):
    """Repulsion passes; returns the numbers of pairs found closer than h in the first pass:
    (pairs of cloth nodes only, pairs with an obstacle node: index >= first_fixed)."""
    idx = np.empty(4, dtype=np.int64)
    first = 0
    first_obstacle = 0
    for it in range(passes):
        count = 0
        count_obstacle = 0
        for k in range(vf.shape[0]):
            i, f = vf[k, 0], vf[k, 1]
            a, b, c = face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2]
            if _boxes_apart(x1, x1, i, i, -1, a, b, c, -1, h):
                continue
            if vf_separated(x1[i], x1[a], x1[b], x1[c], x1[i], x1[a], x1[b], x1[c], h):
                continue  # farther than h from the face's plane (exact, cheaper than the closest point)
            dist, w, n = _vf_geometry(x1, i, a, b, c)
            if dist >= h:
                continue
            count += 1
            if max(i, a, b, c) >= first_fixed:
                count_obstacle += 1
            if dist < DEGENERATE_FRACTION * h:
                d0, w0_, n = _vf_geometry(x0, i, a, b, c)
                if d0 == 0.0:
                    continue
            idx[0], idx[1], idx[2], idx[3] = i, a, b, c
            if _dot_w(x0, idx, w, n) < 0.0:  # crossed during the step: push back to the starting side
                n = -n
            dn = _apply(x1, inv_m, idx, w, n, h)
            _friction(x0, x1, inv_m, idx, w, n, dn, mu)
        for k in range(ee.shape[0]):
            e1, e2 = ee[k, 0], ee[k, 1]
            p, q, P, Q = edge_nodes[e1, 0], edge_nodes[e1, 1], edge_nodes[e2, 0], edge_nodes[e2, 1]
            if _boxes_apart(x1, x1, p, q, -1, P, Q, P, -1, h):
                continue
            if ee_separated(x1[p], x1[p], x1[q], x1[q], x1[P], x1[P], x1[Q], x1[Q], h):
                continue
            dist, w, n = _ee_geometry(x1, p, q, P, Q)
            if dist >= h:
                continue
            count += 1
            if max(p, q, P, Q) >= first_fixed:
                count_obstacle += 1
            if dist < DEGENERATE_FRACTION * h:
                d0, w0_, n = _ee_geometry(x0, p, q, P, Q)
                if d0 == 0.0:
                    continue
            idx[0], idx[1], idx[2], idx[3] = p, q, P, Q
            if _dot_w(x0, idx, w, n) < 0.0:
                n = -n
            dn = _apply(x1, inv_m, idx, w, n, h)
            _friction(x0, x1, inv_m, idx, w, n, dn, mu)
        if it == 0:
            first = count - count_obstacle
            first_obstacle = count_obstacle
        if count == 0:
            break
    return first, first_obstacle


@njit(cache=True)
def _dot_w(x, idx, w, n):
    c = 0.0
    for k in range(4):
        i = idx[k]
        c += w[k] * (n[0] * x[i, 0] + n[1] * x[i, 1] + n[2] * x[i, 2])
    return c


@njit(cache=True)
def _lerp(x0, x1, i, t):
    return x0[i] + t * (x1[i] - x0[i])


@njit(cache=True)
def _ccd_pass(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, eta, sep, respond, hits, moved):
    """One Gauss-Seidel pass of CCD over the candidate pairs. Each hit (re-tested against the
    current x1, so pairs an earlier correction fixed are skipped) is written to `hits` as four
    node indices; with `respond` it is also corrected. `moved` (N + 1,) bool: on entry, when its
    last entry is set, pairs none of whose nodes is flagged are skipped (their motion is
    unchanged since the previous pass found them free); on return it flags the nodes this
    pass corrected (last entry cleared). Returns the number of hits."""
    idx = np.empty(4, dtype=np.int64)
    nh = 0
    only_moved = moved[moved.shape[0] - 1]
    was = moved.copy()
    moved[:] = False
    for k in range(vf.shape[0]):
        i, f = vf[k, 0], vf[k, 1]
        a, b, c = face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2]
        if only_moved and not (was[i] or was[a] or was[b] or was[c]):
            continue
        if _boxes_apart(x0, x1, i, i, -1, a, b, c, -1, eta):
            continue
        if vf_separated(x0[i], x0[a], x0[b], x0[c], x1[i], x1[a], x1[b], x1[c], eta):
            continue  # (vf_ccd would reject it too; inlined here, this skips the call)
        t = vf_ccd(x0[i], x0[a], x0[b], x0[c], x1[i], x1[a], x1[b], x1[c], eta)
        if t < 0.0:
            continue
        idx[0], idx[1], idx[2], idx[3] = i, a, b, c
        hits[nh] = idx
        nh += 1
        if not respond:
            continue
        xi, xa, xb, xc = _lerp(x0, x1, i, t), _lerp(x0, x1, a, t), _lerp(x0, x1, b, t), _lerp(x0, x1, c, t)
        dist, w0, w1, w2 = point_triangle_closest(xi, xa, xb, xc)
        n = np.cross(xb - xa, xc - xa)
        if _normalise(n) == 0.0:  # degenerate face at the touch: use the direction at x0
            n = x0[i] - (w0 * x0[a] + w1 * x0[b] + w2 * x0[c])
            if _normalise(n) == 0.0:
                continue
        w = np.array([1.0, -w0, -w1, -w2])
        if _dot_w(x0, idx, w, n) < 0.0:  # keep the node on the side of the face it started on
            n = -n
        if _apply(x1, inv_m, idx, w, n, sep) > 0.0:
            moved[i] = moved[a] = moved[b] = moved[c] = True
    for k in range(ee.shape[0]):
        e1, e2 = ee[k, 0], ee[k, 1]
        p, q, P, Q = edge_nodes[e1, 0], edge_nodes[e1, 1], edge_nodes[e2, 0], edge_nodes[e2, 1]
        if only_moved and not (was[p] or was[q] or was[P] or was[Q]):
            continue
        if _boxes_apart(x0, x1, p, q, -1, P, Q, P, -1, eta):
            continue
        if ee_separated(x0[p], x1[p], x0[q], x1[q], x0[P], x1[P], x0[Q], x1[Q], eta):
            continue
        t = ee_ccd(x0[p], x1[p], x0[q], x1[q], x0[P], x1[P], x0[Q], x1[Q], eta)
        if t < 0.0:
            continue
        idx[0], idx[1], idx[2], idx[3] = p, q, P, Q
        hits[nh] = idx
        nh += 1
        if not respond:
            continue
        xp, xq, xP, xQ = _lerp(x0, x1, p, t), _lerp(x0, x1, q, t), _lerp(x0, x1, P, t), _lerp(x0, x1, Q, t)
        dist, s, u = segment_segment_closest(xp, xq, xP, xQ)
        n = np.cross(xq - xp, xQ - xP)
        w = np.array([1.0 - s, s, -(1.0 - u), -u])
        if _normalise(n) == 0.0:  # parallel edges: the direction between the closest points at x0
            n = np.zeros(3)
            for kk in range(4):
                n += w[kk] * x0[idx[kk]]
            if _normalise(n) == 0.0:
                continue
        if _dot_w(x0, idx, w, n) < 0.0:
            n = -n
        if _apply(x1, inv_m, idx, w, n, sep) > 0.0:
            moved[p] = moved[q] = moved[P] = moved[Q] = True
    return nh


def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


# A zone's pinned nodes give it their rigid motion only when they span a plane: when the second
# singular value of their centred start positions is below this fraction of the first they are
# (nearly) collinear, the rotation about their line is undetermined, and the zone takes their
# mean displacement (a translation).
COLLINEAR_FRACTION = 1e-6


def pinned_fit(p0, p1):
    """The rigid motion that best fits the displacement of points p0 -> p1 (K, 3) in least
    squares (Kabsch): (R (3, 3), c0, c1) with p1 ~ c1 + R (p0 - c0); exact for a rigid
    displacement of three or more non-collinear points. Fewer, or collinear, points give the
    mean translation (R = I)."""
    c0, c1 = p0.mean(axis=0), p1.mean(axis=0)
    if p0.shape[0] < 3:
        return np.eye(3), c0, c1
    a = p0 - c0
    sv = np.linalg.svd(a, compute_uv=False)
    if not sv[1] > COLLINEAR_FRACTION * sv[0]:
        return np.eye(3), c0, c1
    U, _, Vt = np.linalg.svd(a.T @ (p1 - c1))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d if d != 0 else 1.0]) @ U.T
    return R, c0, c1


def _rigid_motion(x0, x1, m, pinned, nodes):
    """Replace the end positions of `nodes` by the rigid motion with their linear and angular
    momentum over the step (or, with pinned nodes, by the rigid motion that best fits the
    pinned nodes' displacement, `pinned_fit`)."""
    if pinned[nodes].any():
        free = nodes[~pinned[nodes]]
        fixed = nodes[pinned[nodes]]
        R, c0, c1 = pinned_fit(x0[fixed], x1[fixed])
        x1[free] = c1 + (x0[free] - c0) @ R.T
        return
    mm = m[nodes]
    d = x1[nodes] - x0[nodes]
    M = mm.sum()
    c0 = (mm @ x0[nodes]) / M
    dc = (mm @ d) / M
    r = x0[nodes] - c0
    L = np.sum(mm[:, None] * np.cross(r, d - dc), axis=0)  # angular momentum x step length
    inertia = (mm * np.einsum("ij,ij->i", r, r)).sum() * np.eye(3) - (mm[:, None] * r).T @ r
    try:
        theta = np.linalg.solve(inertia, L)  # rotation vector over the step
    except np.linalg.LinAlgError:
        theta = np.linalg.lstsq(inertia, L, rcond=None)[0]
    angle = float(np.linalg.norm(theta))
    if angle > 0:
        k = theta / angle
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    else:
        R = np.eye(3)
    x1[nodes] = c0 + dc + r @ R.T


OBSTACLE_RECORD = ("obstacle_proximity", "obstacle_ccd_hits", "obstacle_collisions_left")


def resolve_self_collisions(face_nodes, face_edges, edge_nodes, x0, x1, node_m, pinned,
                            params: SelfCollisionParams, *, n_fixed_faces: int = 0, first_fixed=None,
                            self_pairs: bool = True, skip=None) -> dict:
    """Make the step x0 -> x1 free of cloth self-collisions (modifies x1 in place).

    Returns the record: proximity pairs, CCD collisions found in the first pass, CCD passes,
    impact zones and their rounds, and the collisions left when every bound was reached.

    Obstacles (see `resolve_collisions_with_obstacles`, which builds these arguments): the last
    `n_fixed_faces` faces are obstacle triangles on the pinned nodes from `first_fixed` on;
    pairs are taken between them and the cloth, and within the cloth only if `self_pairs`;
    `skip` (N,) bool: cloth nodes left out of the pairs with obstacle nodes. The record then
    counts the pairs with an obstacle node apart (OBSTACLE_RECORD); the self_ keys count the rest.
    """
    h = params.thickness
    inv_m = np.where(pinned, 0.0, 1.0 / node_m)
    N = x0.shape[0]
    first_fixed = N if first_fixed is None else int(first_fixed)
    skip = np.zeros(N, dtype=np.bool_) if skip is None else np.ascontiguousarray(skip, dtype=np.bool_)
    stats = {"self_proximity": 0, "self_ccd_hits": 0, "self_ccd_passes": 0, "impact_zones": 0,
             "impact_zone_rounds": 0, "self_collisions_left": 0}
    if n_fixed_faces:
        stats.update({k: 0 for k in OBSTACLE_RECORD})
    if face_nodes.shape[0] < 2:
        return stats

    owners = _owners(face_nodes, face_edges, N, edge_nodes.shape[0])

    def pairs(xa, xb, pad, fp=None):
        boxes = _boxes(face_nodes, edge_nodes, xa, xb)
        if fp is None:
            fp = _face_pairs(boxes[2], boxes[3], pad, n_fixed_faces, self_pairs)
        return _primitive_pairs(fp, face_nodes, face_edges, edge_nodes, boxes, owners, pad, inv_m, first_fixed, skip)

    def count(key_self, key_obstacle, hits, n):
        n_obstacle = int(np.count_nonzero((hits[:n] >= first_fixed).any(axis=1))) if n_fixed_faces else 0
        stats[key_self] = int(n) - n_obstacle
        if n_fixed_faces:
            stats[key_obstacle] = n_obstacle

    eta = CCD_ETA_FRACTION * h
    sep = CCD_SEPARATION_FRACTION * h
    # 1. proximity at the proposed end positions. Its face pairs come from boxes over the whole
    # step padded by h, so that the first CCD pass can reuse them: the proximity moves no
    # coordinate by more than delta, its boxes over the step grow by at most delta, and face
    # boxes whose gap is then within 2 eta had a gap within 2 (eta + delta) <= 2 h before.
    fp = None
    if params.proximity_passes > 0:
        boxes = _boxes(face_nodes, edge_nodes, x0, x1)
        fp = _face_pairs(boxes[2], boxes[3], h, n_fixed_faces, self_pairs)
        vf, ee = pairs(x1, None, h, fp)
        x_prox = x1.copy()
        n_self, n_obstacle = _proximity(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, h, params.friction,
                                        int(params.proximity_passes), first_fixed)
        stats["self_proximity"] = int(n_self)
        if n_fixed_faces:
            stats["obstacle_proximity"] = int(n_obstacle)
        delta = float(np.max(np.abs(x1 - x_prox))) if N else 0.0
        if not delta <= h - eta:
            fp = None
    # 2. CCD passes with corrections
    vf, ee = pairs(x0, x1, eta, fp)
    hits = np.empty((vf.shape[0] + ee.shape[0], 4), dtype=np.int64)
    moved = np.zeros(N + 1, dtype=bool)  # first pass: every pair
    for p in range(int(params.ccd_passes)):
        n = _ccd_pass(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, eta, sep, True, hits, moved)
        moved[-1] = True  # later passes: only pairs with a node this pass moved
        if p == 0:
            count("self_ccd_hits", "obstacle_ccd_hits", hits, n)
        if n == 0:
            return stats
        stats["self_ccd_passes"] = p + 1
        vf, ee = pairs(x0, x1, eta)
        hits = np.empty((vf.shape[0] + ee.shape[0], 4), dtype=np.int64)
    # 3. rigid impact zones
    parent = np.arange(N)
    in_zone = np.zeros(N, dtype=bool)
    for r in range(int(params.max_zone_passes) + 1):
        n = _ccd_pass(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, eta, sep, False, hits,
                      np.zeros(N + 1, dtype=bool))  # every pair: zones moved rigidly
        if n == 0:
            break
        if r == int(params.max_zone_passes):
            count("self_collisions_left", "obstacle_collisions_left", hits, n)
            break
        stats["impact_zone_rounds"] = r + 1
        for a, b, c, d in hits[:n]:
            ra = _find(parent, a)
            for j in (b, c, d):
                rj = _find(parent, j)
                if rj != ra:
                    parent[rj] = ra
            in_zone[[a, b, c, d]] = True
        members = np.flatnonzero(in_zone)
        roots = np.array([_find(parent, i) for i in members])
        order = np.argsort(roots, kind="stable")
        members, roots = members[order], roots[order]
        splits = np.flatnonzero(np.diff(roots)) + 1
        zones = np.split(members, splits)
        stats["impact_zones"] = len(zones)
        for zone in zones:
            _rigid_motion(x0, x1, node_m, pinned, zone)
        vf, ee = pairs(x0, x1, eta)
        hits = np.empty((vf.shape[0] + ee.shape[0], 4), dtype=np.int64)
    return stats


def resolve_collisions_with_obstacles(face_nodes, face_edges, edge_nodes, x0, x1, node_m, pinned,
                                      params: SelfCollisionParams, obstacles, *, self_pairs: bool = True,
                                      skip=None) -> dict:
    """Make the step x0 -> x1 of the cloth free of collisions with triangle-mesh obstacles (and,
    with `self_pairs`, with itself, in the same pass), modifying x1 in place; the obstacles
    do not move.

    obstacles: [(y0 (V, 3), y1 (V, 3), faces (G, 3), face_edges (G, 3), edge_nodes (E, 2)), ...],
    each obstacle's vertex positions at the step's start and end (linear in between) and its
    topology (cloth.meshobstacle.TriangleMeshObstacle.collision_topology). skip (n,) bool:
    cloth nodes to leave out of the cloth-obstacle pairs (e.g. found inside an obstacle at the
    step's start, where keeping them on their starting side would hold them in). Returns the
    record of `resolve_self_collisions` with OBSTACLE_RECORD.
    """
    if not len(obstacles) and not self_pairs:
        return {"self_proximity": 0, "self_ccd_hits": 0, "self_ccd_passes": 0, "impact_zones": 0,
                "impact_zone_rounds": 0, "self_collisions_left": 0, **{k: 0 for k in OBSTACLE_RECORD}}
    n, E = x0.shape[0], edge_nodes.shape[0]
    fn, fe = [np.asarray(face_nodes, np.int64)], [np.asarray(face_edges, np.int64)]
    en = [np.asarray(edge_nodes, np.int64)]
    X0, X1 = [x0], [x1]
    node_off, edge_off, n_fixed = n, E, 0
    for y0, y1, faces, f_edges, e_nodes in obstacles:
        fn.append(np.asarray(faces, np.int64) + node_off)
        fe.append(np.asarray(f_edges, np.int64) + edge_off)
        en.append(np.asarray(e_nodes, np.int64) + node_off)
        X0.append(np.asarray(y0, np.float64))
        X1.append(np.asarray(y1, np.float64))
        node_off += X0[-1].shape[0]
        edge_off += en[-1].shape[0]
        n_fixed += fn[-1].shape[0]
    extra = node_off - n
    x0_all, x1_all = np.ascontiguousarray(np.vstack(X0)), np.ascontiguousarray(np.vstack(X1))
    stats = resolve_self_collisions(
        np.ascontiguousarray(np.vstack(fn)), np.ascontiguousarray(np.vstack(fe)), np.ascontiguousarray(np.vstack(en)),
        x0_all, x1_all, np.concatenate([node_m, np.ones(extra)]), np.concatenate([pinned, np.ones(extra, dtype=bool)]),
        params, n_fixed_faces=n_fixed, first_fixed=n, self_pairs=self_pairs,
        skip=None if skip is None else np.concatenate([np.asarray(skip, dtype=bool), np.zeros(extra, dtype=bool)]))
    x1[:] = x1_all[:n]
    return stats
