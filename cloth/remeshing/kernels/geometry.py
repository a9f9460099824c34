"""Geometry kernels of the remesher: edge size of eq 1, triangle aspect ratio and world-space
strain, on the remesher's working arrays (see :mod:`cloth.remeshing.remesh`)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
def cross2(ax, ay, bx, by):
    return ax * by - ay * bx


@nb.njit(cache=True)
def edge_s2(vu, vM, a, b):
    """Squared edge size of eq 1 between verts a and b."""
    dx = vu[b, 0] - vu[a, 0]
    dy = vu[b, 1] - vu[a, 1]
    m00 = 0.5 * (vM[a, 0, 0] + vM[b, 0, 0])
    m01 = 0.5 * (vM[a, 0, 1] + vM[b, 0, 1])
    m11 = 0.5 * (vM[a, 1, 1] + vM[b, 1, 1])
    return dx * dx * m00 + 2.0 * dx * dy * m01 + dy * dy * m11


@nb.njit(cache=True)
def aspect(vu, a, b, c):
    """12*sqrt(3)*A / P^2 of the material triangle (a, b, c): 1 equilateral, <= 0 when inverted."""
    ex, ey = vu[b, 0] - vu[a, 0], vu[b, 1] - vu[a, 1]
    fx, fy = vu[c, 0] - vu[a, 0], vu[c, 1] - vu[a, 1]
    area = 0.5 * cross2(ex, ey, fx, fy)
    p = (math.sqrt(ex * ex + ey * ey) + math.sqrt(fx * fx + fy * fy)
         + math.sqrt((vu[c, 0] - vu[b, 0]) ** 2 + (vu[c, 1] - vu[b, 1]) ** 2))
    if p <= 0.0:
        return 0.0
    return 12.0 * math.sqrt(3.0) * area / (p * p)


@nb.njit(cache=True)
def world_strain(vu, vnode, nd, p0, p1, p2):
    """Largest |lambda - 1| of the right Cauchy-Green tensor C = F^T F of the triangle (p0, p1, p2)
    with world positions from node data columns 0:3 (1 for a face with no world area)."""
    u1x, u1y = vu[p1, 0] - vu[p0, 0], vu[p1, 1] - vu[p0, 1]
    u2x, u2y = vu[p2, 0] - vu[p0, 0], vu[p2, 1] - vu[p0, 1]
    det = u1x * u2y - u1y * u2x
    if det <= 0.0:
        return np.inf
    n0, n1, n2 = vnode[p0], vnode[p1], vnode[p2]
    c00 = 0.0
    c01 = 0.0
    c11 = 0.0
    for k in range(3):
        x1 = nd[n1, k] - nd[n0, k]
        x2 = nd[n2, k] - nd[n0, k]
        f0 = (x1 * u2y - x2 * u1y) / det
        f1 = (x2 * u1x - x1 * u2x) / det
        c00 += f0 * f0
        c01 += f0 * f1
        c11 += f1 * f1
    mid = 0.5 * (c00 + c11)
    rad = math.sqrt(0.25 * (c00 - c11) ** 2 + c01 * c01)
    return max(abs(mid + rad - 1.0), abs(mid - rad - 1.0))


@nb.njit(cache=True)
def he_s2(fv, ftw, vu, vM, h):
    """Edge size s^2 of half-edge h; on a seam, the larger of the two panels' sizes."""
    f, k = h // 3, h % 3
    s2 = edge_s2(vu, vM, fv[f, k], fv[f, (k + 1) % 3])
    t = ftw[f, k]
    if t >= 0:
        g, l = t // 3, t % 3
        s2 = max(s2, edge_s2(vu, vM, fv[g, l], fv[g, (l + 1) % 3]))
    return s2
