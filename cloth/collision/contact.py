"""Cloth-obstacle contact: project nodes out to the contact thickness, with Coulomb friction.

Run at the end of every step. A free node closer than `thickness` to an obstacle is moved
along the obstacle's normal to the thickness; its velocity relative to the obstacle surface
loses any approaching normal component, and its tangential relative velocity is reduced by
friction * |normal velocity change| (Coulomb), stopping at zero (stick). Pushing a node out of
one obstacle can push it into another (a sheet corner between a sphere and the ground), so
the projection repeats until no free node is inside or the pass limit is reached.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cloth.collision.obstacles import ObstacleSet

# A node counts as resolved when within this fraction of the thickness (round-off in phi).
RESOLVED_FRACTION = 1e-9


@njit(cache=True)
def _project(node_x, node_v, active, phi, normal, obs_v, thickness, friction):
    """Project each active node out of every obstacle it is inside (modifies x, v in place).

    phi (K, m), normal (K, m, 3), obs_v (K, m, 3) hold the queries of the K obstacles for the m
    active nodes. The position correction is the smallest dx with n_k . dx = thickness - phi_k
    for every violated obstacle k (dx = N^T (N N^T)^-1 depth, solved for the violated set), so a
    node wedged between two obstacles leaves both at once instead of bouncing between them.
    Velocities then lose their approaching normal part against each violated obstacle, with
    Coulomb friction on the tangential part. Returns the number of nodes moved.
    """
    K = phi.shape[0]
    moved = 0
    N = np.empty((K, 3))
    depth = np.empty(K)
    idx = np.empty(K, dtype=np.int64)
    for k in range(active.shape[0]):
        i = active[k]
        m = 0
        for o in range(K):
            if phi[o, k] < thickness:
                N[m] = normal[o, k]
                depth[m] = thickness - phi[o, k]
                idx[m] = o
                m += 1
        if m == 0:
            continue
        moved += 1
        G = N[:m] @ N[:m].T
        for a in range(m):
            G[a, a] += 1e-12
        lam = np.linalg.solve(G, depth[:m])
        for a in range(m):
            if lam[a] < 0.0:  # a constraint the others already satisfy pulls back: drop its pull
                lam[a] = 0.0
        dx = N[:m].T @ lam
        if m > 1:  # make sure every violated obstacle is left (the clamp above can undershoot)
            for a in range(m):
                short = depth[a] - (N[a, 0] * dx[0] + N[a, 1] * dx[1] + N[a, 2] * dx[2])
                if short > 0.0:
                    dx += short * N[a]
        for d in range(3):
            node_x[i, d] += dx[d]
        for a in range(m):
            o = idx[a]
            n0, n1, n2 = N[a, 0], N[a, 1], N[a, 2]
            r0 = node_v[i, 0] - obs_v[o, k, 0]
            r1 = node_v[i, 1] - obs_v[o, k, 1]
            r2 = node_v[i, 2] - obs_v[o, k, 2]
            rn = r0 * n0 + r1 * n1 + r2 * n2
            dvn = -rn if rn < 0.0 else 0.0  # remove the approaching part of the normal velocity
            t0, t1, t2 = r0 - rn * n0, r1 - rn * n1, r2 - rn * n2
            tn = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
            scale = 1.0
            if tn > 0.0:
                scale = max(0.0, 1.0 - friction * dvn / tn)
            rn_new = rn + dvn
            node_v[i, 0] = obs_v[o, k, 0] + rn_new * n0 + scale * t0
            node_v[i, 1] = obs_v[o, k, 1] + rn_new * n1 + scale * t1
            node_v[i, 2] = obs_v[o, k, 2] + rn_new * n2 + scale * t2
    return moved


def resolve_obstacle_contacts(node_x, node_v, node_pinned, obstacles: ObstacleSet, thickness: float,
                              friction: float, dt: float, max_passes: int = 4) -> dict:
    """Push free nodes out of all obstacles (modifies node_x and node_v in place).

    Returns {'contacts': nodes moved in the first pass, 'passes': passes used,
    'max_depth_m': deepest penetration below the thickness before resolution,
    'remaining': free nodes still closer than the thickness after the last pass}.
    """
    free = np.flatnonzero(~node_pinned)
    stats = {"contacts": 0, "passes": 0, "max_depth_m": 0.0, "remaining": 0}
    if not obstacles.obstacles or free.size == 0:
        return stats
    active = free
    limit = thickness * (1.0 - RESOLVED_FRACTION)
    for p in range(max_passes + 1):
        phi, normal, vel = obstacles.query_each(node_x[active])
        inside = np.any(phi < limit, axis=0)
        if not inside.any():
            break
        if p == max_passes:
            stats["remaining"] = int(inside.sum())
            break
        if p == 0:
            stats["contacts"] = int(inside.sum())
            stats["max_depth_m"] = float(np.max(thickness - phi))
        sel = np.flatnonzero(inside)
        active = active[sel]
        _project(node_x, node_v, active, np.ascontiguousarray(phi[:, sel]), np.ascontiguousarray(normal[:, sel]),
                 np.ascontiguousarray(vel[:, sel]), limit + RESOLVED_FRACTION * thickness, friction)
        stats["passes"] = p + 1
    return stats
