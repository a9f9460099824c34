"""Rigid impact zones, the last stage of the self-collision pass (cloth.collision.selfcollision;
Provot 1997, Bridson, Fedkiw and Anderson 2002).

The nodes of the pairs still colliding are merged into zones, together with the zones already
found (a union-find forest, `merge_zones`), and each zone moves rigidly over the step with its
linear and angular momentum (`rigid_motion`); a zone holding pinned nodes (infinite mass) takes
the rigid motion that best fits their displacement instead (`pinned_fit`, Kabsch). A zone
holding the nodes of an obstacle, which may deform within the step, is separated by inelastic
projection instead (`inelastic_projection`; cloth.collision.selfcollision decides which).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# A zone's pinned nodes give it their rigid motion only when they span a plane: when the second
# singular value of their centred start positions is below this fraction of the first they are
# (nearly) collinear, the rotation about their line is undetermined, and the zone takes their
# mean displacement (a translation).
COLLINEAR_FRACTION = 1e-6
# Inelastic projection of a zone that holds obstacle nodes (`inelastic_projection`): sweeps over
# its impacts at most, and the largest violation (a fraction of the separation) it may leave.
PROJECTION_SWEEPS = 200
PROJECTION_TOLERANCE = 1e-3


def _find(parent, i):
    """Root of node i in the union-find forest `parent`, halving the path on the way (in place)."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def merge_zones(parent, in_zone, hits):
    """Merge the four nodes of every hit (n, 4) into one zone, with the zones already found:
    `parent` (N,) is the union-find forest and `in_zone` (N,) bool flags the nodes of a zone
    (both updated in place). Returns the zones: arrays of node indices, ordered by root."""
    for a, b, c, d in hits:
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
    return np.split(members, splits)


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


def rigid_motion(x0, x1, m, pinned, nodes):
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


@njit(cache=True)
def inelastic_projection(x1, inv_m, hits, impacts, chosen, sep, max_sweeps, tolerance):
    """Move the free nodes of x1 (in place) the least, in the mass-weighted norm, so that each
    chosen impact k ends at least `sep` on its starting side: n_k . sum_j w_kj x1[hits[k, j]] >= sep
    (Harmon, Vouga, Tamstorf and Grinspun 2008, as ARCSim's impact zones; the weights and normal
    of `impacts` as cloth.collision.response.ccd_pass writes them). Pinned nodes (inv_m = 0) do
    not move. Hildreth's dual coordinate ascent: each impact's multiplier in turn, kept >= 0,
    until no constraint is violated by more than tolerance x sep or max_sweeps. Returns the
    largest violation left (m; <= 0 when every impact is separated)."""
    lam = np.zeros(chosen.shape[0])
    worst = 0.0
    for _ in range(max_sweeps):
        worst = -np.inf
        for jj in range(chosen.shape[0]):
            k = chosen[jj]
            n0, n1, n2 = impacts[k, 4], impacts[k, 5], impacts[k, 6]
            if n0 == 0.0 and n1 == 0.0 and n2 == 0.0:
                continue  # a degenerate touch: no direction to separate along
            gap, denom = -sep, 0.0
            for j in range(4):
                v, w = hits[k, j], impacts[k, j]
                gap += w * (n0 * x1[v, 0] + n1 * x1[v, 1] + n2 * x1[v, 2])
                denom += w * w * inv_m[v]
            worst = max(worst, -gap)
            if denom == 0.0:
                continue
            step = max(-gap / denom, -lam[jj])
            if step == 0.0:
                continue
            lam[jj] += step
            for j in range(4):
                v = hits[k, j]
                s = step * impacts[k, j] * inv_m[v]
                x1[v, 0] += s * n0
                x1[v, 1] += s * n1
                x1[v, 2] += s * n2
        if worst <= tolerance * sep:
            break
    return worst
