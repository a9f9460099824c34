"""Response of the self-collision pass (cloth.collision.selfcollision) to its candidate pairs
(cloth.collision.candidates), in numba.

Every correction enforces a constraint on the four nodes idx of a pair, n . sum_k w_k x_k >= target
(w: the pair's barycentric weights, positive on the node or first edge, negative on the other side),
by a mass-weighted move along n (`_apply`), followed in the proximity stage by Coulomb friction
on the pair's relative tangential motion over the step (`_friction`).

* `proximity_repulsion`: Gauss-Seidel passes that push the pairs closer than their thickness at
  the end positions x1 apart to it, on the side they were on at x0 (cloth-cloth pairs across
  the sheets only, INTERIOR_TOLERANCE; a thickness for them and one for obstacle pairs);
* `ccd_pass`: one Gauss-Seidel pass of continuous collision detection (cloth.collision.ccd) over
  the linear motion x0 -> x1: each pair that touches is listed and, if asked, corrected to end a
  small separation apart on its starting side.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cloth.collision.ccd import (
    ee_ccd,
    ee_separated,
    point_triangle_closest,
    segment_segment_closest,
    vf_ccd,
    vf_separated,
)

# A proximity pair closer than this fraction of the thickness has no reliable direction at x1:
# it takes its direction from x0.
DEGENERATE_FRACTION = 1e-6
# Cloth-cloth proximity acts across the surfaces only, as ARCSim's does: a vertex-face pair
# whose node projects into the face (plane barycentric weights >= -INTERIOR_TOLERANCE, round-off
# on a shared edge), an edge-edge pair whose closest points lie inside both edges. Otherwise the
# closest point is on the face's rim or an edge's end and the push runs along the sheet: on a
# mesh a few thicknesses fine, a node and a face two rings away lie closer than the thickness
# in the sheet's own plane, and pushing them apart stretched the cloth (ARCSim's sphere.json at
# its own sizes: Green strains of 2 to 9 by the pins, against ARCSim's 0.7). For the same reason
# an edge-edge pair of (nearly) parallel edges, sin^2 of their angle below EDGE_PARALLEL_SIN2, is left
# out: their closest points are not unique and may lie side by side in the sheet. Neighbouring
# pairs cover what these leave out, and CCD still sees every crossing. Pairs with an obstacle
# node keep the closest-point distance (a body's tip or ridge must push the cloth).
INTERIOR_TOLERANCE = 1e-6
EDGE_PARALLEL_SIN2 = 1e-6
# A CCD pair already within eta at the step's start (a touch at t = 0) is a hit only if the step
# brings it within this fraction of its starting distance. Its touch at t = 0 is no event the step
# can change: the pair held apart by a rigid impact zone keeps its distance, so it stayed a hit
# round after round (karate, view-dependent, seed 0, frame 113: an edge pair 1.9 um apart at the
# start, eta 5 um, left after 48 rounds and four halvings of the step); a pair that crosses
# passes through distance 0 and is still caught. A pair at distance exactly 0 stays a hit.
START_TOUCH_FRACTION = 0.5


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
def _projects_inside(p, a, b, c):
    """Whether p's projection onto the plane of triangle abc lies in the triangle (to
    INTERIOR_TOLERANCE in barycentric weight); False for a degenerate triangle."""
    n = np.cross(b - a, c - a)
    nn = np.dot(n, n)
    if nn == 0.0:
        return False
    b0 = np.dot(np.cross(b - p, c - p), n) / nn
    b1 = np.dot(np.cross(c - p, a - p), n) / nn
    return min(b0, b1, 1.0 - b0 - b1) >= -INTERIOR_TOLERANCE


@njit(cache=True)
def _across(x, p, q, P, Q, w):
    """Whether the edge-edge pair's closest points lie inside both edges (weights w of
    `_ee_geometry`) and the edges are not parallel (EDGE_PARALLEL_SIN2)."""
    if not (0.0 < w[1] < 1.0 and 0.0 < -w[3] < 1.0):
        return False
    e1 = x[q] - x[p]
    e2 = x[Q] - x[P]
    c = np.cross(e1, e2)
    return np.dot(c, c) >= EDGE_PARALLEL_SIN2 * np.dot(e1, e1) * np.dot(e2, e2)


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


# ------------------------------------------------------------------------------------------
# the two stages


@njit(cache=True)
def proximity_repulsion(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, h_obstacle, h_self, mu, passes, first_fixed):
    """Repulsion passes; returns the numbers of pairs found closer than their thickness in the
    first pass: (pairs of cloth nodes only, kept h_self apart; pairs with an obstacle node, index
    >= first_fixed, kept h_obstacle apart)."""
    idx = np.empty(4, dtype=np.int64)
    first = 0
    first_obstacle = 0
    for it in range(passes):
        count = 0
        count_obstacle = 0
        for k in range(vf.shape[0]):
            i, f = vf[k, 0], vf[k, 1]
            a, b, c = face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2]
            cloth = max(i, a, b, c) < first_fixed
            h = h_self if cloth else h_obstacle
            if _boxes_apart(x1, x1, i, i, -1, a, b, c, -1, h):
                continue
            if vf_separated(x1[i], x1[a], x1[b], x1[c], x1[i], x1[a], x1[b], x1[c], h):
                continue  # farther than h from the face's plane (exact, cheaper than the closest point)
            dist, w, n = _vf_geometry(x1, i, a, b, c)
            if dist >= h:
                continue
            if cloth and not _projects_inside(x1[i], x1[a], x1[b], x1[c]):
                continue  # along the sheet, not across it (INTERIOR_TOLERANCE)
            count += 1
            if not cloth:
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
            cloth = max(p, q, P, Q) < first_fixed
            h = h_self if cloth else h_obstacle
            if _boxes_apart(x1, x1, p, q, -1, P, Q, P, -1, h):
                continue
            if ee_separated(x1[p], x1[p], x1[q], x1[q], x1[P], x1[P], x1[Q], x1[Q], h):
                continue
            dist, w, n = _ee_geometry(x1, p, q, P, Q)
            if dist >= h:
                continue
            if cloth and not _across(x1, p, q, P, Q, w):
                continue  # closest at an edge's end, or parallel edges: the vertex-face pairs cover it
            count += 1
            if not cloth:
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
def _record(impacts, k, w, n):
    """Row k of `impacts` (when it has rows): the hit's weights and normal."""
    if impacts.shape[0] == 0:
        return
    for j in range(4):
        impacts[k, j] = w[j]
    for j in range(3):
        impacts[k, 4 + j] = n[j]


@njit(cache=True)
def ccd_pass(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, eta, sep, respond, hits, moved, impacts):
    """One Gauss-Seidel pass of CCD over the candidate pairs. Each hit (re-tested against the
    current x1, so pairs an earlier correction fixed are skipped) is written to `hits` as four
    node indices; with `respond` it is also corrected. `moved` (N + 1,) bool: on entry, when its
    last entry is set, pairs none of whose nodes is flagged are skipped (their motion is
    unchanged since the previous pass found them free); on return it flags the nodes this
    pass corrected (last entry cleared). `impacts`: (len(hits), 7) to also write each hit's
    four weights w and unit normal n at the touch (n . sum_k w_k x_k > 0 on the starting side;
    n = 0 for a degenerate touch), or (0, 7) not to. Returns the number of hits."""
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
        if t == 0.0:  # within eta at the start: a hit if the step closes it (START_TOUCH_FRACTION)
            d0 = point_triangle_closest(x0[i], x0[a], x0[b], x0[c])[0]
            if d0 > 0.0:
                t = vf_ccd(x0[i], x0[a], x0[b], x0[c], x1[i], x1[a], x1[b], x1[c], START_TOUCH_FRACTION * d0)
        if t < 0.0:
            continue
        idx[0], idx[1], idx[2], idx[3] = i, a, b, c
        hits[nh] = idx
        nh += 1
        if not respond and impacts.shape[0] == 0:
            continue
        xi, xa, xb, xc = _lerp(x0, x1, i, t), _lerp(x0, x1, a, t), _lerp(x0, x1, b, t), _lerp(x0, x1, c, t)
        dist, w0, w1, w2 = point_triangle_closest(xi, xa, xb, xc)
        n = np.cross(xb - xa, xc - xa)
        if _normalise(n) == 0.0:  # degenerate face at the touch: use the direction at x0
            n = x0[i] - (w0 * x0[a] + w1 * x0[b] + w2 * x0[c])
            if _normalise(n) == 0.0:
                _record(impacts, nh - 1, np.array([1.0, -w0, -w1, -w2]), n)
                continue
        w = np.array([1.0, -w0, -w1, -w2])
        if _dot_w(x0, idx, w, n) < 0.0:  # keep the node on the side of the face it started on
            n = -n
        _record(impacts, nh - 1, w, n)
        if not respond:
            continue
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
        if t == 0.0:  # within eta at the start: a hit if the step closes it (START_TOUCH_FRACTION)
            d0 = segment_segment_closest(x0[p], x0[q], x0[P], x0[Q])[0]
            if d0 > 0.0:
                t = ee_ccd(x0[p], x1[p], x0[q], x1[q], x0[P], x1[P], x0[Q], x1[Q], START_TOUCH_FRACTION * d0)
        if t < 0.0:
            continue
        idx[0], idx[1], idx[2], idx[3] = p, q, P, Q
        hits[nh] = idx
        nh += 1
        if not respond and impacts.shape[0] == 0:
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
                _record(impacts, nh - 1, w, n)
                continue
        if _dot_w(x0, idx, w, n) < 0.0:
            n = -n
        _record(impacts, nh - 1, w, n)
        if not respond:
            continue
        if _apply(x1, inv_m, idx, w, n, sep) > 0.0:
            moved[p] = moved[q] = moved[P] = moved[Q] = True
    return nh
