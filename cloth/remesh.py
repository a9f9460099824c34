"""Anisotropic remeshing in material space (Narain, Samii and O'Brien 2012), as numba kernels.

Given a sizing tensor M per vert (2x2, material space, 1/m^2), the remesher makes every edge
satisfy the size criterion of the paper's eq 1,

    s^2(i, j) = u_ij^T ((M_i + M_j) / 2) u_ij <= 1,

with as few faces as it can:

1. flip every edge that is not anisotropically Delaunay (Bossen and Heckbert 1996) under the
   mean metric of its four verts;
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

Working representation (capacity-sized arrays, grown by the Python driver):

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

import numba as nb
import numpy as np

from .mesh import Mesh

RING_MAX = 512  # largest vert valence the kernels handle (a ring buffer size, not a quality bound)
# A flip whose new faces have (twice) the area below this fraction of the squared diagonals is
# refused: the quad is not strictly convex (a collinear corner would give a degenerate face).
FLIP_MIN_AREA = 1e-9
OUT_OF_CAPACITY = 1
RING_OVERFLOW = 2


@dataclass(frozen=True)
class RemeshParams:
    aspect_min: float = 0.2  # smallest allowed aspect 12*sqrt(3)*A/P^2 (1 = equilateral) of a collapse's faces
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


# ---------------------------------------------------------------------------------------
# geometry helpers
@nb.njit(cache=True, inline="always")
def _cross2(ax, ay, bx, by):
    return ax * by - ay * bx


@nb.njit(cache=True)
def _edge_s2(vu, vM, a, b):
    """Squared edge size of eq 1 between verts a and b."""
    dx = vu[b, 0] - vu[a, 0]
    dy = vu[b, 1] - vu[a, 1]
    m00 = 0.5 * (vM[a, 0, 0] + vM[b, 0, 0])
    m01 = 0.5 * (vM[a, 0, 1] + vM[b, 0, 1])
    m11 = 0.5 * (vM[a, 1, 1] + vM[b, 1, 1])
    return dx * dx * m00 + 2.0 * dx * dy * m01 + dy * dy * m11


@nb.njit(cache=True)
def _aspect(vu, a, b, c):
    """12*sqrt(3)*A / P^2 of the material triangle (a, b, c): 1 equilateral, <= 0 when inverted."""
    ex, ey = vu[b, 0] - vu[a, 0], vu[b, 1] - vu[a, 1]
    fx, fy = vu[c, 0] - vu[a, 0], vu[c, 1] - vu[a, 1]
    area = 0.5 * _cross2(ex, ey, fx, fy)
    p = (math.sqrt(ex * ex + ey * ey) + math.sqrt(fx * fx + fy * fy)
         + math.sqrt((vu[c, 0] - vu[b, 0]) ** 2 + (vu[c, 1] - vu[b, 1]) ** 2))
    if p <= 0.0:
        return 0.0
    return 12.0 * math.sqrt(3.0) * area / (p * p)


@nb.njit(cache=True)
def _world_strain(vu, vnode, nd, p0, p1, p2):
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
def _he_s2(fv, ftw, vu, vM, h):
    """Edge size s^2 of half-edge h; on a seam, the larger of the two panels' sizes."""
    f, k = h // 3, h % 3
    s2 = _edge_s2(vu, vM, fv[f, k], fv[f, (k + 1) % 3])
    t = ftw[f, k]
    if t >= 0:
        g, l = t // 3, t % 3
        s2 = max(s2, _edge_s2(vu, vM, fv[g, l], fv[g, (l + 1) % 3]))
    return s2


# ---------------------------------------------------------------------------------------
# adjacency helpers
@nb.njit(cache=True, inline="always")
def _local(fv, f, a):
    if fv[f, 0] == a:
        return 0
    if fv[f, 1] == a:
        return 1
    return 2


@nb.njit(cache=True, inline="always")
def _link(fadj, h1, h2):
    """Make half-edges h1 and h2 (either may be -1) neighbours."""
    if h1 >= 0:
        fadj[h1 // 3, h1 % 3] = h2
    if h2 >= 0:
        fadj[h2 // 3, h2 % 3] = h1


@nb.njit(cache=True, inline="always")
def _twin(ftw, h1, h2):
    if h1 >= 0:
        ftw[h1 // 3, h1 % 3] = h2
    if h2 >= 0:
        ftw[h2 // 3, h2 % 3] = h1


@nb.njit(cache=True)
def _ring(fv, fadj, vface, a, buf):
    """Faces around vert a into buf; returns (count, boundary, next-on-boundary, prev-on-boundary).

    For a boundary vert, the two verts joined to it by boundary edges are returned (else -1).
    Returns count -1 if the ring exceeds the buffer.
    """
    f0 = vface[a]
    n = 0
    f = f0
    nxt = -1
    prv = -1
    while True:
        if n >= buf.shape[0]:
            return -1, False, -1, -1
        buf[n] = f
        n += 1
        i = _local(fv, f, a)
        h = fadj[f, i]  # side i leaves a
        if h < 0:
            nxt = fv[f, (i + 1) % 3]
            break
        f = h // 3
        if f == f0:
            return n, False, -1, -1
    f = f0
    while True:
        i = _local(fv, f, a)
        h = fadj[f, (i + 2) % 3]  # side i+2 enters a
        if h < 0:
            prv = fv[f, (i + 2) % 3]
            break
        f = h // 3
        if n >= buf.shape[0]:
            return -1, False, -1, -1
        buf[n] = f
        n += 1
    return n, True, nxt, prv


@nb.njit(cache=True)
def _find_he(fv, fadj, vface, valive, a, b, buf):
    """Half-edge from vert a to vert b, or from b to a if a->b has no face; -1 if no edge."""
    if a < 0 or b < 0 or not valive[a] or not valive[b]:
        return -1
    n, bnd, nxt, prv = _ring(fv, fadj, vface, a, buf)
    for j in range(n):
        f = buf[j]
        i = _local(fv, f, a)
        if fv[f, (i + 1) % 3] == b:
            return 3 * f + i
        if fv[f, (i + 2) % 3] == b:
            return 3 * f + (i + 2) % 3
    return -1


# ---------------------------------------------------------------------------------------
# flips
@nb.njit(cache=True)
def _should_flip(fv, fadj, vu, vM, h, threshold):
    """Bossen-Heckbert: flip when the angles opposite the edge sum past pi in the mean metric."""
    f, k = h // 3, h % 3
    g_h = fadj[f, k]
    if g_h < 0:
        return False
    g, l = g_h // 3, g_h % 3
    a, b, c = fv[f, k], fv[f, (k + 1) % 3], fv[f, (k + 2) % 3]
    d = fv[g, (l + 2) % 3]
    m00 = 0.25 * (vM[a, 0, 0] + vM[b, 0, 0] + vM[c, 0, 0] + vM[d, 0, 0])
    m01 = 0.25 * (vM[a, 0, 1] + vM[b, 0, 1] + vM[c, 0, 1] + vM[d, 0, 1])
    m11 = 0.25 * (vM[a, 1, 1] + vM[b, 1, 1] + vM[c, 1, 1] + vM[d, 1, 1])
    det = m00 * m11 - m01 * m01
    if det <= 0.0:
        return False
    sq = math.sqrt(det)
    # angle at c between (a - c) and (b - c); at d between (b - d) and (a - d): both CCW
    pcx, pcy = vu[a, 0] - vu[c, 0], vu[a, 1] - vu[c, 1]
    qcx, qcy = vu[b, 0] - vu[c, 0], vu[b, 1] - vu[c, 1]
    pdx, pdy = vu[b, 0] - vu[d, 0], vu[b, 1] - vu[d, 1]
    qdx, qdy = vu[a, 0] - vu[d, 0], vu[a, 1] - vu[d, 1]
    sin_c = sq * _cross2(pcx, pcy, qcx, qcy)
    cos_c = pcx * qcx * m00 + (pcx * qcy + pcy * qcx) * m01 + pcy * qcy * m11
    sin_d = sq * _cross2(pdx, pdy, qdx, qdy)
    cos_d = pdx * qdx * m00 + (pdx * qdy + pdy * qdx) * m01 + pdy * qdy * m11
    if sin_c <= 0.0 or sin_d <= 0.0:
        return False  # already inverted: not a Delaunay question
    nc = math.sqrt(sin_c * sin_c + cos_c * cos_c)
    nd = math.sqrt(sin_d * sin_d + cos_d * cos_d)
    s = (sin_c * cos_d + cos_c * sin_d) / (nc * nd)  # sin(alpha + beta)
    return s < -threshold


@nb.njit(cache=True)
def _flip(fv, fadj, vu, vface, h):
    """Flip interior half-edge h (faces (a,b,c), (b,a,d) -> (a,d,c), (d,b,c)); False if that inverts a face."""
    f, k = h // 3, h % 3
    g_h = fadj[f, k]
    g, l = g_h // 3, g_h % 3
    a, b, c = fv[f, k], fv[f, (k + 1) % 3], fv[f, (k + 2) % 3]
    d = fv[g, (l + 2) % 3]
    if c == d:
        return False
    a1 = _cross2(vu[d, 0] - vu[a, 0], vu[d, 1] - vu[a, 1], vu[c, 0] - vu[a, 0], vu[c, 1] - vu[a, 1])
    a2 = _cross2(vu[b, 0] - vu[d, 0], vu[b, 1] - vu[d, 1], vu[c, 0] - vu[d, 0], vu[c, 1] - vu[d, 1])
    scale = (vu[c, 0] - vu[d, 0]) ** 2 + (vu[c, 1] - vu[d, 1]) ** 2 + (vu[b, 0] - vu[a, 0]) ** 2 + (vu[b, 1] - vu[a, 1]) ** 2
    if a1 <= FLIP_MIN_AREA * scale or a2 <= FLIP_MIN_AREA * scale:
        return False  # the quad is not strictly convex: a new face would be inverted or degenerate
    n_bc = fadj[f, (k + 1) % 3]
    n_ca = fadj[f, (k + 2) % 3]
    n_ad = fadj[g, (l + 1) % 3]
    n_db = fadj[g, (l + 2) % 3]
    fv[f, 0], fv[f, 1], fv[f, 2] = a, d, c
    fv[g, 0], fv[g, 1], fv[g, 2] = d, b, c
    _link(fadj, 3 * f + 0, n_ad)
    _link(fadj, 3 * f + 1, 3 * g + 2)
    _link(fadj, 3 * f + 2, n_ca)
    _link(fadj, 3 * g + 0, n_db)
    _link(fadj, 3 * g + 1, n_bc)
    vface[a] = f
    vface[b] = g
    vface[c] = f
    vface[d] = g
    return True


@nb.njit(cache=True)
def _flip_keeps_world_strain(fv, vu, vnode, nd, f, k, g, l, max_strain):
    """A flip may not make a face more strained in world space than max(max_strain, the worse of
    the two faces it replaces): in a folded region a material-space flip can crease the surface."""
    a, b, c = fv[f, k], fv[f, (k + 1) % 3], fv[f, (k + 2) % 3]
    d = fv[g, (l + 2) % 3]
    old = max(_world_strain(vu, vnode, nd, a, b, c), _world_strain(vu, vnode, nd, b, a, d))
    new = max(_world_strain(vu, vnode, nd, a, d, c), _world_strain(vu, vnode, nd, d, b, c))
    return new <= max(max_strain, old)


@nb.njit(cache=True)
def _touches_frozen(fv, vnode, nd, fz, f, g):
    """True when a vert of face f or g has a frozen node (node data column fz > 0)."""
    for s in range(3):
        if nd[vnode[fv[f, s]], fz] > 0.0 or nd[vnode[fv[g, s]], fz] > 0.0:
            return True
    return False


@nb.njit(cache=True)
def _flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n_stack, threshold, max_flips,
               fdirty, fz):
    """Lawson flipping from the half-edges on `stack`; returns the number of flips."""
    flips = 0
    while n_stack > 0 and flips < max_flips:
        n_stack -= 1
        h = stack[n_stack]
        f, k = h // 3, h % 3
        if not falive[f] or fadj[f, k] < 0:
            continue
        if not _should_flip(fv, fadj, vu, vM, h, threshold):
            continue
        g = fadj[f, k] // 3
        if fz >= 0 and _touches_frozen(fv, vnode, nd, fz, f, g):
            continue
        if not _flip_keeps_world_strain(fv, vu, vnode, nd, f, k, g, fadj[f, k] % 3, max_strain):
            continue
        # boundary sides of f and g may be seam sides whose twin codes change with the flip
        tw_f = (ftw[f, 0], ftw[f, 1], ftw[f, 2])
        tw_g = (ftw[g, 0], ftw[g, 1], ftw[g, 2])
        old = (fv[f, 0], fv[f, 1], fv[f, 2], fv[g, 0], fv[g, 1], fv[g, 2])
        if not _flip(fv, fadj, vu, vface, h):
            continue
        _retwin(fv, ftw, f, g, old, tw_f, tw_g)
        flips += 1
        fdirty[f] = True
        fdirty[g] = True
        if n_stack + 6 > stack.shape[0]:
            continue
        for s in range(3):
            stack[n_stack] = 3 * f + s
            n_stack += 1
            stack[n_stack] = 3 * g + s
            n_stack += 1
    return flips


@nb.njit(cache=True)
def _retwin(fv, ftw, f, g, old, tw_f, tw_g):
    """After faces f, g were rewritten, re-attach seam twins of their boundary sides by vert pair."""
    for s in range(3):
        ftw[f, s] = -1
        ftw[g, s] = -1
    for which in range(2):
        for s in range(3):
            t = tw_f[s] if which == 0 else tw_g[s]
            if t < 0:
                continue
            base = 0 if which == 0 else 3
            va, vb = old[base + s], old[base + (s + 1) % 3]
            placed = False
            for ff in (f, g):
                for ss in range(3):
                    if fv[ff, ss] == va and fv[ff, (ss + 1) % 3] == vb:
                        _twin(ftw, 3 * ff + ss, t)
                        placed = True
            if not placed:
                ftw[t // 3, t % 3] = -1


# ---------------------------------------------------------------------------------------
# splits
@nb.njit(cache=True)
def _new_face(falive, cnt):
    f = cnt[0]
    cnt[0] += 1
    falive[f] = True
    return f


@nb.njit(cache=True)
def _split_side(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, h, m_node, cnt, fdirty):
    """Split half-edge h of one panel at its midpoint with a new vert on node m_node.

    Returns (new vert, half-edge a->m, half-edge m->b) of the face side of h.
    """
    f, k = h // 3, h % 3
    a, b, c = fv[f, k], fv[f, (k + 1) % 3], fv[f, (k + 2) % 3]
    g_h = fadj[f, k]
    n_bc = fadj[f, (k + 1) % 3]
    n_ca = fadj[f, (k + 2) % 3]
    t_bc = ftw[f, (k + 1) % 3]
    t_ca = ftw[f, (k + 2) % 3]
    m = cnt[1]
    cnt[1] += 1
    valive[m] = True
    vu[m, 0] = 0.5 * (vu[a, 0] + vu[b, 0])
    vu[m, 1] = 0.5 * (vu[a, 1] + vu[b, 1])
    for i in range(2):
        for j in range(2):
            vM[m, i, j] = 0.5 * (vM[a, i, j] + vM[b, i, j])
    vnode[m] = m_node
    f2 = _new_face(falive, cnt)
    fv[f, 0], fv[f, 1], fv[f, 2] = a, m, c
    fv[f2, 0], fv[f2, 1], fv[f2, 2] = m, b, c
    for s in range(3):
        ftw[f, s] = -1
        ftw[f2, s] = -1
    _link(fadj, 3 * f + 1, 3 * f2 + 2)
    _link(fadj, 3 * f + 2, n_ca)
    _twin(ftw, 3 * f + 2, t_ca)
    _link(fadj, 3 * f2 + 1, n_bc)
    _twin(ftw, 3 * f2 + 1, t_bc)
    vface[a] = f
    vface[b] = f2
    vface[c] = f
    vface[m] = f
    fdirty[f] = True
    fdirty[f2] = True
    if g_h < 0:
        fadj[f, 0] = -1
        fadj[f2, 0] = -1
        return m, 3 * f + 0, 3 * f2 + 0
    g, l = g_h // 3, g_h % 3
    d = fv[g, (l + 2) % 3]
    n_ad = fadj[g, (l + 1) % 3]
    n_db = fadj[g, (l + 2) % 3]
    t_ad = ftw[g, (l + 1) % 3]
    t_db = ftw[g, (l + 2) % 3]
    g2 = _new_face(falive, cnt)
    fv[g, 0], fv[g, 1], fv[g, 2] = b, m, d
    fv[g2, 0], fv[g2, 1], fv[g2, 2] = m, a, d
    for s in range(3):
        ftw[g, s] = -1
        ftw[g2, s] = -1
    _link(fadj, 3 * g + 0, 3 * f2 + 0)
    _link(fadj, 3 * g + 1, 3 * g2 + 2)
    _link(fadj, 3 * g + 2, n_db)
    _twin(ftw, 3 * g + 2, t_db)
    _link(fadj, 3 * g2 + 0, 3 * f + 0)
    _link(fadj, 3 * g2 + 1, n_ad)
    _twin(ftw, 3 * g2 + 1, t_ad)
    vface[d] = g
    fdirty[g] = True
    fdirty[g2] = True
    return m, 3 * f + 0, 3 * f2 + 0


@nb.njit(cache=True)
def _split(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, nd, npin, nnv, nalive, h, cnt, fdirty,
           stack):
    """Split the edge of half-edge h (both panels on a seam); push the new faces' sides on stack."""
    f, k = h // 3, h % 3
    a, b = fv[f, k], fv[f, (k + 1) % 3]
    na, nb_ = vnode[a], vnode[b]
    n = cnt[2]
    cnt[2] += 1
    nalive[n] = True
    for j in range(nd.shape[1]):
        nd[n, j] = 0.5 * (nd[na, j] + nd[nb_, j])
    npin[n] = npin[na] if npin[na] == npin[nb_] else -1
    t = ftw[f, k]
    f0_before = cnt[0]
    m, h_am, h_mb = _split_side(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, h, n, cnt, fdirty)
    nnv[n] = 1
    if t >= 0:
        g, l = t // 3, t % 3
        m2, h2_am, h2_mb = _split_side(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, t, n, cnt, fdirty)
        nnv[n] = 2
        # pair the four boundary halves by their node pairs
        for x in (h_am, h_mb):
            xn0 = vnode[fv[x // 3, x % 3]]
            xn1 = vnode[fv[x // 3, (x % 3 + 1) % 3]]
            for y in (h2_am, h2_mb):
                yn0 = vnode[fv[y // 3, y % 3]]
                yn1 = vnode[fv[y // 3, (y % 3 + 1) % 3]]
                if (xn0 == yn0 and xn1 == yn1) or (xn0 == yn1 and xn1 == yn0):
                    _twin(ftw, x, y)
    n_stack = 0
    for ff in range(f0_before, cnt[0]):
        for s in range(3):
            stack[n_stack] = 3 * ff + s
            n_stack += 1
    for s in range(3):
        stack[n_stack] = 3 * f + s
        n_stack += 1
    if fadj[f, 0] >= 0:
        g = fadj[f, 0] // 3
        for s in range(3):
            stack[n_stack] = 3 * g + s
            n_stack += 1
    return n_stack


@nb.njit(cache=True)
def _canonical(fadj, ftw, h):
    o = fadj[h // 3, h % 3]
    if o < 0:
        t = ftw[h // 3, h % 3]
        return t < 0 or h < t
    return h < o


@nb.njit(cache=True)
def split_pass(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, nd, npin, nnv, nalive, cnt, fdirty,
               threshold, max_rounds, max_strain, fz):
    """Split every invalid edge, worst first, flipping around each split; repeat until none is invalid.

    Returns (status, splits, flips); status OUT_OF_CAPACITY asks the driver to grow and call again.
    """
    buf = np.empty(RING_MAX, dtype=np.int64)
    stack = np.empty(4096, dtype=np.int64)
    splits = 0
    flips = 0
    for _ in range(max_rounds):
        nf = cnt[0]
        s2 = np.empty(3 * nf)
        hs = np.empty(3 * nf, dtype=np.int64)
        nbad = 0
        for f in range(nf):
            if not falive[f]:
                continue
            for k in range(3):
                h = 3 * f + k
                if not _canonical(fadj, ftw, h):
                    continue
                s = _he_s2(fv, ftw, vu, vM, h)
                if s > 1.0:
                    s2[nbad] = s
                    hs[nbad] = h
                    nbad += 1
        if nbad == 0:
            return 0, splits, flips
        order = np.argsort(-s2[:nbad], kind="mergesort")  # worst first, stable: deterministic
        # identify edges by vert pairs, since splits renumber half-edges
        va = np.empty(nbad, dtype=np.int64)
        vb = np.empty(nbad, dtype=np.int64)
        for j in range(nbad):
            h = hs[order[j]]
            va[j] = fv[h // 3, h % 3]
            vb[j] = fv[h // 3, (h % 3 + 1) % 3]
        for j in range(nbad):
            if (cnt[0] + 4 > falive.shape[0] or cnt[1] + 2 > valive.shape[0]
                    or cnt[2] + 1 > nalive.shape[0]):
                return OUT_OF_CAPACITY, splits, flips
            h = _find_he(fv, fadj, vface, valive, va[j], vb[j], buf)
            if h < 0:
                continue
            if _he_s2(fv, ftw, vu, vM, h) <= 1.0:
                continue
            n_stack = _split(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, nd, npin, nnv, nalive,
                             h, cnt, fdirty, stack)
            splits += 1
            flips += _flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n_stack,
                                threshold, 64, fdirty, fz)
    return 0, splits, flips


# ---------------------------------------------------------------------------------------
# collapses
@nb.njit(cache=True)
def _try_collapse(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, npin, nnv, nalive, h, a_first,
                  aspect_min, max_s2, cos_corner, buf, buf2, fdirty, nd, max_strain, fz):
    """Collapse the edge of half-edge h, removing its first vert (a_first) or its second; True on success."""
    f, k = h // 3, h % 3
    if a_first:
        a, b = fv[f, k], fv[f, (k + 1) % 3]
    else:
        a, b = fv[f, (k + 1) % 3], fv[f, k]
    na = vnode[a]
    if npin[na] != -1 or nnv[na] != 1:
        return False  # pinned and seam nodes stay
    if fz >= 0 and (nd[na, fz] > 0.0 or nd[vnode[b], fz] > 0.0):
        return False  # frozen: a collapse here would make the cloth cross itself
    edge_boundary = fadj[f, k] < 0
    n, a_bnd, nxt, prv = _ring(fv, fadj, vface, a, buf)
    if n < 0:
        return False
    if a_bnd:
        if not edge_boundary:
            return False
        # a boundary vert goes only along a straight-enough boundary
        other = prv if nxt == b else nxt
        if other < 0:
            return False
        e1x, e1y = vu[a, 0] - vu[other, 0], vu[a, 1] - vu[other, 1]
        e2x, e2y = vu[b, 0] - vu[a, 0], vu[b, 1] - vu[a, 1]
        l1 = math.sqrt(e1x * e1x + e1y * e1y)
        l2 = math.sqrt(e2x * e2x + e2y * e2y)
        if (e1x * e2x + e1y * e2y) < cos_corner * l1 * l2:
            return False
    # link condition: the verts adjacent to both a and b are exactly the edge's opposite verts
    nb2, b_bnd, _, _ = _ring(fv, fadj, vface, b, buf2)
    if nb2 < 0:
        return False
    for i in range(n):
        fa = buf[i]
        for s in range(3):
            x = fv[fa, s]
            if x == a or x == b:
                continue
            found = False
            for j in range(nb2):
                fb = buf2[j]
                if fv[fb, 0] == x or fv[fb, 1] == x or fv[fb, 2] == x:
                    found = True
                    break
            if found:
                # x is joined to both a and b; allowed only when a face (a, b, x) exists
                ok = False
                for j in range(n):
                    fc = buf[j]
                    has_b = fv[fc, 0] == b or fv[fc, 1] == b or fv[fc, 2] == b
                    has_x = fv[fc, 0] == x or fv[fc, 1] == x or fv[fc, 2] == x
                    if has_b and has_x:
                        ok = True
                        break
                if not ok:
                    return False
    # new faces: quality, orientation, world strain and the size of every new edge at b
    old_strain = 0.0
    for i in range(n):
        fa = buf[i]
        old_strain = max(old_strain, _world_strain(vu, vnode, nd, fv[fa, 0], fv[fa, 1], fv[fa, 2]))
    strain_limit = max(max_strain, old_strain)
    n_keep = 0
    for i in range(n):
        fa = buf[i]
        if fv[fa, 0] == b or fv[fa, 1] == b or fv[fa, 2] == b:
            continue
        n_keep += 1
        p0 = b if fv[fa, 0] == a else fv[fa, 0]
        p1 = b if fv[fa, 1] == a else fv[fa, 1]
        p2 = b if fv[fa, 2] == a else fv[fa, 2]
        if _aspect(vu, p0, p1, p2) < aspect_min:
            return False
        if _world_strain(vu, vnode, nd, p0, p1, p2) > strain_limit:
            return False  # the world surface would crease or stretch more than it already is
        for x in (p0, p1, p2):
            if x != b and _edge_s2(vu, vM, b, x) > max_s2:
                return False
    if n_keep == 0 and not a_bnd:
        return False
    # --- apply: the faces holding both a and b die, their outer sides are joined --------------
    for i in range(n):
        fa = buf[i]
        if not (fv[fa, 0] == b or fv[fa, 1] == b or fv[fa, 2] == b):
            continue
        ia = _local(fv, fa, a)
        ib = _local(fv, fa, b)
        ic = 3 - ia - ib
        c = fv[fa, ic]
        # sides touching c: (a, c) and (b, c), whichever direction
        h_ac = -1
        h_bc = -1
        for s in range(3):
            s0, s1 = fv[fa, s], fv[fa, (s + 1) % 3]
            if (s0 == a and s1 == c) or (s0 == c and s1 == a):
                h_ac = s
            if (s0 == b and s1 == c) or (s0 == c and s1 == b):
                h_bc = s
        o_ac = fadj[fa, h_ac]
        o_bc = fadj[fa, h_bc]
        t_ac = ftw[fa, h_ac]
        t_bc = ftw[fa, h_bc]
        if o_ac >= 0 and o_bc >= 0:
            _link(fadj, o_ac, o_bc)
        elif o_ac >= 0:
            _link(fadj, o_ac, -1)
            _twin(ftw, o_ac, t_bc)
        elif o_bc >= 0:
            _link(fadj, o_bc, -1)
            _twin(ftw, o_bc, t_ac)
        else:
            return False  # cannot happen after the link test; refuse rather than corrupt
        falive[fa] = False
        if o_ac >= 0:
            vface[c] = o_ac // 3
        else:
            vface[c] = o_bc // 3
        if o_bc >= 0:
            vface[b] = o_bc // 3
        else:
            vface[b] = o_ac // 3
    for i in range(n):
        fa = buf[i]
        if not falive[fa]:
            continue
        for s in range(3):
            if fv[fa, s] == a:
                fv[fa, s] = b
        fdirty[fa] = True
        vface[b] = fa
    valive[a] = False
    nalive[na] = False
    return True


@nb.njit(cache=True)
def collapse_pass(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, npin, nnv, nalive, cnt, fdirty,
                  aspect_min, max_size, cos_corner, threshold, max_rounds, nd, max_strain, fz):
    """Collapse short edges of dirty faces (shortest first), flipping after each; returns (collapses, flips)."""
    buf = np.empty(RING_MAX, dtype=np.int64)
    buf2 = np.empty(RING_MAX, dtype=np.int64)
    stack = np.empty(4 * RING_MAX, dtype=np.int64)
    max_s2 = max_size * max_size
    collapses = 0
    flips = 0
    for _ in range(max_rounds):
        nf = cnt[0]
        s2 = np.empty(3 * nf)
        va = np.empty(3 * nf, dtype=np.int64)
        vb = np.empty(3 * nf, dtype=np.int64)
        nc = 0
        for f in range(nf):
            if not falive[f] or not fdirty[f]:
                continue
            for k in range(3):
                h = 3 * f + k
                o = fadj[f, k]
                if o >= 0 and fdirty[o // 3] and o < h:
                    continue  # the other side lists it
                s = _he_s2(fv, ftw, vu, vM, h)
                if s < max_s2:
                    s2[nc] = s
                    va[nc] = fv[f, k]
                    vb[nc] = fv[f, (k + 1) % 3]
                    nc += 1
        fdirty[:nf] = False
        if nc == 0:
            break
        order = np.argsort(s2[:nc], kind="mergesort")
        done = 0
        for j in range(nc):
            a = va[order[j]]
            b = vb[order[j]]
            h = _find_he(fv, fadj, vface, valive, a, b, buf)
            if h < 0:
                continue
            first = fv[h // 3, h % 3] == a
            ok = _try_collapse(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, npin, nnv, nalive, h,
                               first, aspect_min, max_s2, cos_corner, buf, buf2, fdirty, nd, max_strain, fz)
            if not ok:
                ok = _try_collapse(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, npin, nnv, nalive,
                                   h, not first, aspect_min, max_s2, cos_corner, buf, buf2, fdirty, nd,
                                   max_strain, fz)
            if not ok:
                continue
            done += 1
            # flip around the surviving vert
            keep = b if not valive[a] else a
            n, _, _, _ = _ring(fv, fadj, vface, keep, buf)
            n_stack = 0
            for i in range(max(n, 0)):
                for s in range(3):
                    if n_stack < stack.shape[0]:
                        stack[n_stack] = 3 * buf[i] + s
                        n_stack += 1
            flips += _flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n_stack,
                                threshold, 256, fdirty, fz)
        collapses += done
        if done == 0:
            break
    return collapses, flips


@nb.njit(cache=True)
def flip_all(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, cnt, fdirty, threshold, fz):
    """Lawson flipping from every edge (bounded); returns the number of flips."""
    nf = cnt[0]
    stack = np.empty(3 * nf + 4096, dtype=np.int64)
    n = 0
    for f in range(nf - 1, -1, -1):
        if falive[f]:
            for k in range(2, -1, -1):
                stack[n] = 3 * f + k
                n += 1
    return _flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n, threshold,
                      3 * nf + 64, fdirty, fz)


# ---------------------------------------------------------------------------------------
# Python driver
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


class _Work:
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
        self.nd, self.npin, self.nnv, self.nalive = g(self.nd, 0.0), g(self.npin, -1), g(self.nnv, 0), g(self.nalive, False)

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
    w = _Work(mesh, vert_M, node_data, np.asarray(node_handle, dtype=np.int64))
    thr = params.flip_threshold
    ms = params.max_world_strain
    flips = flip_all(w.fv, w.fadj, w.ftw, w.falive, w.vu, w.vM, w.vface, w.vnode, w.nd, ms, w.cnt, w.fdirty, thr,
                     fz)
    splits = 0
    while True:
        status, s, fl = split_pass(w.fv, w.fadj, w.ftw, w.falive, w.vu, w.vM, w.vnode, w.vface, w.valive,
                                   w.nd, w.npin, w.nnv, w.nalive, w.cnt, w.fdirty, thr, params.max_split_rounds, ms,
                                   fz)
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
    out, nd, nh, origin, vM = w.to_mesh(mesh.density)
    nd = nd[:, :n_data]
    return RemeshResult(mesh=out, node_data=nd, node_handle=nh, node_origin=origin, vert_M=vM, splits=int(splits),
                        collapses=int(collapses), flips=int(flips),
                        changed=bool(splits or collapses or flips))
