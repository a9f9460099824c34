"""Geometric primitives of collision handling, as numba functions called inside other kernels.

Points are 1-D float64 arrays of length 3 (usually row views x[i] of an (N, 3) array).

- `point_triangle_closest(p, a, b, c) -> (dist, w0, w1, w2)`: closest point on a triangle.
- `segment_segment_closest(p0, p1, q0, q1) -> (dist, s, t)`: closest points of two segments.
- `vf_ccd(...)`, `ee_ccd(...) -> t`: continuous collision detection over a step of linear
  motion, the earliest time in [0, 1] at which a vertex and a triangle (two edges) come within
  `eta` of each other, or -1. The candidate times are the roots in [0, 1] of the cubic
  coplanarity condition (a tetrahedron's signed volume), found by splitting [0, 1] at the
  roots of its derivative into monotone pieces and bisecting each sign change; the critical
  points and the ends of the step are candidates too, so that grazing contacts (double roots)
  are not missed. A candidate counts when the distance there is at most eta.
  Before the cubic, `vf_separated` / `ee_separated` reject (exactly) a pair that a slab wider
  than eta separates throughout the step (axis: the face normal, or the edges' cross product,
  at either end of the step): most pairs of a resting contact.
- `edge_triangle_crossing(e0, e1, a, b, c) -> (hit, s)`: a segment passing through a triangle.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Bisection stops when the bracket is this short (in units of the step).
ROOT_TOL = 1e-12
# A motion whose coplanarity polynomial is below this (relative to the size of its terms) is
# coplanar all along: the distance is then checked at COPLANAR_SAMPLES evenly spaced times.
COPLANAR_REL = 1e-14
COPLANAR_SAMPLES = 17
# Two directions whose cross product is below this (|u x v|^2 / (|u|^2 |v|^2)) are parallel: they
# give no separating axis (a degenerate face, parallel edges), and the slab rejection skips them.
AXIS_PARALLEL_SIN2 = 1e-12


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def region_weights(d1, d2, d3, d4, d5, d6):
    """Barycentric weights of the closest point on a triangle (a, b, c) to p, from Ericson's
    dot products d1 = ab.ap, d2 = ac.ap, d3 = ab.bp, d4 = ac.bp, d5 = ab.cp, d6 = ac.cp, when
    p is not in vertex a's region (d1 > 0 or d2 > 0); the triangle must not be degenerate."""
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w
    den = 1.0 / (va + vb + vc)
    w1 = vb * den
    w2 = vc * den
    return 1.0 - w1 - w2, w1, w2


@njit(cache=True)
def point_triangle_closest(p, a, b, c):
    """Distance from p to the closed triangle abc and the barycentric weights (w0, w1, w2) of
    the closest point w0 a + w1 b + w2 c (the Voronoi-region case analysis of the triangle).
    A degenerate (zero-area) triangle falls back to the closest of its three edges."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    n = np.cross(ab, ac)
    if _dot(n, n) <= 1e-30 * max(_dot(ab, ab), _dot(ac, ac)) ** 2:  # degenerate: nearest edge
        best, w0, w1, w2 = np.inf, 1.0, 0.0, 0.0
        for k in range(3):
            u = a if k == 0 else (b if k == 1 else c)
            v = b if k == 0 else (c if k == 1 else a)
            d, s, _ = segment_segment_closest(u, v, p, p)
            if d < best:
                best = d
                if k == 0:
                    w0, w1, w2 = 1.0 - s, s, 0.0
                elif k == 1:
                    w0, w1, w2 = 0.0, 1.0 - s, s
                else:
                    w0, w1, w2 = s, 0.0, 1.0 - s
        return best, w0, w1, w2
    if d1 <= 0.0 and d2 <= 0.0:
        w0, w1, w2 = 1.0, 0.0, 0.0
    else:
        bp = p - b
        d3, d4 = _dot(ab, bp), _dot(ac, bp)
        cp = p - c
        d5, d6 = _dot(ab, cp), _dot(ac, cp)
        w0, w1, w2 = region_weights(d1, d2, d3, d4, d5, d6)
    q = w0 * a + w1 * b + w2 * c
    d = p - q
    return np.sqrt(_dot(d, d)), w0, w1, w2


@njit(cache=True)
def segment_segment_closest(p0, p1, q0, q1):
    """Distance between the closed segments p0p1 and q0q1 and the parameters s, t in [0, 1] of
    their closest points p0 + s (p1 - p0), q0 + t (q1 - q0); parallel and zero-length segments
    included (then one of the closest pairs)."""
    d1 = p1 - p0
    d2 = q1 - q0
    r = p0 - q0
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    tiny = 1e-30
    if a <= tiny and e <= tiny:
        s, t = 0.0, 0.0
    elif a <= tiny:
        s = 0.0
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = _dot(d1, r)
        if e <= tiny:
            t = 0.0
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = _dot(d1, d2)
            den = a * e - b * b
            s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 1e-14 * a * e else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    d = (p0 + s * d1) - (q0 + t * d2)
    return np.sqrt(_dot(d, d)), s, t


@njit(cache=True)
def _cubic(A0, dA, B0, dB, C0, dC):
    """Coefficients (c0..c3) of (A0 + t dA) . ((B0 + t dB) x (C0 + t dC)) and the size of its terms."""
    BC = np.cross(B0, C0)
    dBC = np.cross(dB, C0) + np.cross(B0, dC)
    dBdC = np.cross(dB, dC)
    c0 = _dot(A0, BC)
    c1 = _dot(dA, BC) + _dot(A0, dBC)
    c2 = _dot(A0, dBdC) + _dot(dA, dBC)
    c3 = _dot(dA, dBdC)
    la = np.sqrt(_dot(A0, A0)) + np.sqrt(_dot(dA, dA))
    lb = np.sqrt(_dot(B0, B0)) + np.sqrt(_dot(dB, dB))
    lc = np.sqrt(_dot(C0, C0)) + np.sqrt(_dot(dC, dC))
    return c0, c1, c2, c3, la * lb * lc


@njit(cache=True, inline="always")
def _poly(c0, c1, c2, c3, t):
    return ((c3 * t + c2) * t + c1) * t + c0


@njit(cache=True)
def _candidate_times(c0, c1, c2, c3, scale):
    """Sorted candidate times in [0, 1]: the cubic's roots, its critical points and 0 and 1;
    or evenly spaced samples when the polynomial vanishes identically (coplanar motion)."""
    out = np.empty(12)
    n = 0
    if max(max(abs(c0), abs(c1)), max(abs(c2), abs(c3))) <= COPLANAR_REL * scale:
        out = np.empty(COPLANAR_SAMPLES)
        for k in range(COPLANAR_SAMPLES):
            out[k] = k / (COPLANAR_SAMPLES - 1)
        return out
    # split points: 0, the derivative's roots in (0, 1), 1
    cuts = np.empty(4)
    m = 0
    cuts[m] = 0.0
    m += 1
    qa, qb, qc = 3.0 * c3, 2.0 * c2, c1
    r1, r2 = -1.0, -1.0
    if abs(qa) > 1e-300:
        disc = qb * qb - 4.0 * qa * qc
        if disc >= 0.0:
            sq = np.sqrt(disc)
            q = -0.5 * (qb + (sq if qb >= 0.0 else -sq))
            r1 = q / qa
            r2 = qc / q if q != 0.0 else -1.0
    elif abs(qb) > 1e-300:
        r1 = -qc / qb
    if r1 > r2:
        r1, r2 = r2, r1
    for r in (r1, r2):
        if 0.0 < r < 1.0:
            cuts[m] = r
            m += 1
    cuts[m] = 1.0
    m += 1
    for k in range(m):
        out[n] = cuts[k]
        n += 1
    for k in range(m - 1):
        lo, hi = cuts[k], cuts[k + 1]
        flo, fhi = _poly(c0, c1, c2, c3, lo), _poly(c0, c1, c2, c3, hi)
        if flo == 0.0 or fhi == 0.0 or (flo < 0.0) == (fhi < 0.0):
            continue
        while hi - lo > ROOT_TOL:
            mid = 0.5 * (lo + hi)
            fm = _poly(c0, c1, c2, c3, mid)
            if (fm < 0.0) == (flo < 0.0):
                lo, flo = mid, fm
            else:
                hi = mid
        out[n] = 0.5 * (lo + hi)
        n += 1
    return np.sort(out[:n])


@njit(cache=True, inline="always")
def _unit_cross(u0, u1, u2, v0, v1, v2):
    """The unit vector along u x v (scalars), and False if u and v are (nearly) parallel."""
    n0, n1, n2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    L = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    scale = (u0 * u0 + u1 * u1 + u2 * u2) * (v0 * v0 + v1 * v1 + v2 * v2)
    if not L * L > AXIS_PARALLEL_SIN2 * scale:
        return 0.0, 0.0, 0.0, False
    return n0 / L, n1 / L, n2 / L, True


@njit(cache=True, inline="always")
def vf_separated(p0, a0, b0, c0, p1, a1, b1, c1, eta):
    """True when a slab wider than eta separates the point from the triangle during the whole
    linear motion, so that they cannot come within eta (an exact, cheap rejection before the
    cubic). The slab's axis is the face normal at the start or at the end of the step. Along a
    fixed axis n, n.p(t) - max_k n.v_k(t) is concave in t (a linear function minus a maximum
    of linear ones), so if it exceeds eta at t = 0 and at t = 1 it does so throughout, and then
    every point of the triangle is farther than eta from p; likewise the other way round."""
    for end in range(2):
        a, b, c = (a0, b0, c0) if end == 0 else (a1, b1, c1)
        n0, n1, n2, ok = _unit_cross(b[0] - a[0], b[1] - a[1], b[2] - a[2], c[0] - a[0], c[1] - a[1], c[2] - a[2])
        if not ok:
            continue
        above, below = True, True
        for t in range(2):
            p, a, b, c = (p0, a0, b0, c0) if t == 0 else (p1, a1, b1, c1)
            dp = n0 * p[0] + n1 * p[1] + n2 * p[2]
            da = n0 * a[0] + n1 * a[1] + n2 * a[2]
            db = n0 * b[0] + n1 * b[1] + n2 * b[2]
            dc = n0 * c[0] + n1 * c[1] + n2 * c[2]
            if not dp - max(da, max(db, dc)) > eta:
                above = False
            if not min(da, min(db, dc)) - dp > eta:
                below = False
        if above or below:
            return True
    return False


@njit(cache=True, inline="always")
def ee_separated(p0, p1, q0, q1, P0, P1, Q0, Q1, eta):
    """True when a slab wider than eta separates edge (p, q) from edge (P, Q) during the whole
    linear motion (the argument of `vf_separated`, with the axis along the two edges' cross
    product at the start or at the end of the step)."""
    for end in range(2):
        p, q, P, Q = (p0, q0, P0, Q0) if end == 0 else (p1, q1, P1, Q1)
        n0, n1, n2, ok = _unit_cross(q[0] - p[0], q[1] - p[1], q[2] - p[2], Q[0] - P[0], Q[1] - P[1], Q[2] - P[2])
        if not ok:
            continue
        above, below = True, True
        for t in range(2):
            p, q, P, Q = (p0, q0, P0, Q0) if t == 0 else (p1, q1, P1, Q1)
            dp = n0 * p[0] + n1 * p[1] + n2 * p[2]
            dq = n0 * q[0] + n1 * q[1] + n2 * q[2]
            dP = n0 * P[0] + n1 * P[1] + n2 * P[2]
            dQ = n0 * Q[0] + n1 * Q[1] + n2 * Q[2]
            if not min(dp, dq) - max(dP, dQ) > eta:
                above = False
            if not min(dP, dQ) - max(dp, dq) > eta:
                below = False
        if above or below:
            return True
    return False


@njit(cache=True)
def vf_ccd(p0, a0, b0, c0, p1, a1, b1, c1, eta):
    """Earliest t in [0, 1] at which the point p and the triangle abc, moving linearly from
    (p0, a0, b0, c0) to (p1, a1, b1, c1), come within `eta`; -1.0 if they do not."""
    if vf_separated(p0, a0, b0, c0, p1, a1, b1, c1, eta):
        return -1.0
    A0, B0, C0 = a0 - p0, b0 - p0, c0 - p0
    dA, dB, dC = (a1 - p1) - A0, (b1 - p1) - B0, (c1 - p1) - C0
    k0, k1, k2, k3, scale = _cubic(A0, dA, B0, dB, C0, dC)
    for t in _candidate_times(k0, k1, k2, k3, scale):
        d = point_triangle_closest(p0 + t * (p1 - p0), a0 + t * (a1 - a0), b0 + t * (b1 - b0),
                                   c0 + t * (c1 - c0))[0]
        if d <= eta:
            return t
    return -1.0


@njit(cache=True)
def ee_ccd(p0, p1, q0, q1, P0, P1, Q0, Q1, eta):
    """Earliest t in [0, 1] at which edge (p, q), moving from (p0, q0) to (p1, q1), and edge
    (P, Q), moving from (P0, Q0) to (P1, Q1), come within `eta`; -1.0 if they do not."""
    if ee_separated(p0, p1, q0, q1, P0, P1, Q0, Q1, eta):
        return -1.0
    A0, B0, C0 = q0 - p0, P0 - p0, Q0 - p0
    dA, dB, dC = (q1 - p1) - A0, (P1 - p1) - B0, (Q1 - p1) - C0
    k0, k1, k2, k3, scale = _cubic(A0, dA, B0, dB, C0, dC)
    for t in _candidate_times(k0, k1, k2, k3, scale):
        d = segment_segment_closest(p0 + t * (p1 - p0), q0 + t * (q1 - q0), P0 + t * (P1 - P0),
                                    Q0 + t * (Q1 - Q0))[0]
        if d <= eta:
            return t
    return -1.0


@njit(cache=True)
def edge_triangle_crossing(e0, e1, a, b, c):
    """Whether the segment e0e1 passes through the triangle abc: its ends strictly on opposite
    sides of the plane and the crossing point inside the closed triangle. Returns (hit, s) with
    the crossing point e0 + s (e1 - e0)."""
    n = np.cross(b - a, c - a)
    d0 = _dot(n, e0 - a)
    d1 = _dot(n, e1 - a)
    if not ((d0 > 0.0 and d1 < 0.0) or (d0 < 0.0 and d1 > 0.0)):
        return False, 0.0
    s = d0 / (d0 - d1)
    x = e0 + s * (e1 - e0)
    if _dot(n, np.cross(b - a, x - a)) < 0.0:
        return False, s
    if _dot(n, np.cross(c - b, x - b)) < 0.0:
        return False, s
    if _dot(n, np.cross(a - c, x - c)) < 0.0:
        return False, s
    return True, s
