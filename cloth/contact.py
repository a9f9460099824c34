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

from .obstacles import ObstacleSet

# A node counts as resolved when within this fraction of the thickness (round-off in phi).
RESOLVED_FRACTION = 1e-9


@njit(cache=True)
def _project(node_x, node_v, active, phi, normal, obs_v, thickness, friction, dt):
    """Project the active nodes with phi < thickness; returns the number moved (modifies x, v)."""
    moved = 0
    for k in range(active.shape[0]):
        i = active[k]
        depth = thickness - phi[k]
        if depth <= 0.0:
            continue
        moved += 1
        n0, n1, n2 = normal[k, 0], normal[k, 1], normal[k, 2]
        node_x[i, 0] += depth * n0
        node_x[i, 1] += depth * n1
        node_x[i, 2] += depth * n2
        r0 = node_v[i, 0] - obs_v[k, 0]
        r1 = node_v[i, 1] - obs_v[k, 1]
        r2 = node_v[i, 2] - obs_v[k, 2]
        rn = r0 * n0 + r1 * n1 + r2 * n2
        dvn = -rn if rn < 0.0 else 0.0  # remove the approaching part of the normal velocity
        t0, t1, t2 = r0 - rn * n0, r1 - rn * n1, r2 - rn * n2
        tn = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        scale = 1.0
        if tn > 0.0:
            scale = max(0.0, 1.0 - friction * dvn / tn)
        rn_new = rn + dvn
        node_v[i, 0] = obs_v[k, 0] + rn_new * n0 + scale * t0
        node_v[i, 1] = obs_v[k, 1] + rn_new * n1 + scale * t1
        node_v[i, 2] = obs_v[k, 2] + rn_new * n2 + scale * t2
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
    for p in range(max_passes):
        phi, normal, vel = obstacles.query(node_x[active])
        inside = phi < thickness * (1.0 - RESOLVED_FRACTION)
        if not inside.any():
            break
        if p == 0:
            stats["contacts"] = int(inside.sum())
            stats["max_depth_m"] = float(np.max(thickness - phi))
        idx = np.flatnonzero(inside)
        active = active[idx]
        _project(node_x, node_v, active, phi[idx], normal[idx], vel[idx], thickness, friction, dt)
        stats["passes"] = p + 1
    else:
        phi, _, _ = obstacles.query(node_x[active])
        stats["remaining"] = int(np.sum(phi < thickness * (1.0 - RESOLVED_FRACTION)))
    return stats
