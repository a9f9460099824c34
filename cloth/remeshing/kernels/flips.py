"""Flip kernels of the remesher: the anisotropic Delaunay test (Bossen and Heckbert 1996) under the
mean metric of a quad's four verts, the flip itself with its world-strain and frozen-node guards,
and Lawson flipping from a stack of half-edges (:func:`flip_pass`) or from every edge
(:func:`flip_all`)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from cloth.remeshing.kernels.geometry import aspect, cross2, world_strain
from cloth.remeshing.kernels.halfedge import link, retwin

# A flip whose new faces have (twice) the area below this fraction of the squared diagonals is
# refused: the quad is not strictly convex (a collinear corner would give a degenerate face).
FLIP_MIN_AREA = 1e-9


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
    sin_c = sq * cross2(pcx, pcy, qcx, qcy)
    cos_c = pcx * qcx * m00 + (pcx * qcy + pcy * qcx) * m01 + pcy * qcy * m11
    sin_d = sq * cross2(pdx, pdy, qdx, qdy)
    cos_d = pdx * qdx * m00 + (pdx * qdy + pdy * qdx) * m01 + pdy * qdy * m11
    if sin_c <= 0.0 or sin_d <= 0.0:
        return False  # already inverted: not a Delaunay question
    nc = math.sqrt(sin_c * sin_c + cos_c * cos_c)
    nd = math.sqrt(sin_d * sin_d + cos_d * cos_d)
    s = (sin_c * cos_d + cos_c * sin_d) / (nc * nd)  # sin(alpha + beta)
    return s < -threshold


@nb.njit(cache=True)
def flip(fv, fadj, vu, vface, h):
    """Flip interior half-edge h (faces (a,b,c), (b,a,d) -> (a,d,c), (d,b,c)); False if that inverts a face."""
    f, k = h // 3, h % 3
    g_h = fadj[f, k]
    g, l = g_h // 3, g_h % 3
    a, b, c = fv[f, k], fv[f, (k + 1) % 3], fv[f, (k + 2) % 3]
    d = fv[g, (l + 2) % 3]
    if c == d:
        return False
    a1 = cross2(vu[d, 0] - vu[a, 0], vu[d, 1] - vu[a, 1], vu[c, 0] - vu[a, 0], vu[c, 1] - vu[a, 1])
    a2 = cross2(vu[b, 0] - vu[d, 0], vu[b, 1] - vu[d, 1], vu[c, 0] - vu[d, 0], vu[c, 1] - vu[d, 1])
    scale = ((vu[c, 0] - vu[d, 0]) ** 2 + (vu[c, 1] - vu[d, 1]) ** 2
             + (vu[b, 0] - vu[a, 0]) ** 2 + (vu[b, 1] - vu[a, 1]) ** 2)
    if a1 <= FLIP_MIN_AREA * scale or a2 <= FLIP_MIN_AREA * scale:
        return False  # the quad is not strictly convex: a new face would be inverted or degenerate
    n_bc = fadj[f, (k + 1) % 3]
    n_ca = fadj[f, (k + 2) % 3]
    n_ad = fadj[g, (l + 1) % 3]
    n_db = fadj[g, (l + 2) % 3]
    fv[f, 0], fv[f, 1], fv[f, 2] = a, d, c
    fv[g, 0], fv[g, 1], fv[g, 2] = d, b, c
    link(fadj, 3 * f + 0, n_ad)
    link(fadj, 3 * f + 1, 3 * g + 2)
    link(fadj, 3 * f + 2, n_ca)
    link(fadj, 3 * g + 0, n_db)
    link(fadj, 3 * g + 1, n_bc)
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
    old = max(world_strain(vu, vnode, nd, a, b, c), world_strain(vu, vnode, nd, b, a, d))
    new = max(world_strain(vu, vnode, nd, a, d, c), world_strain(vu, vnode, nd, d, b, c))
    return new <= max(max_strain, old)


@nb.njit(cache=True)
def _flip_keeps_aspect(fv, vu, f, k, g, l, aspect_min):
    """A flip may not make a face of material aspect below min(aspect_min, the worse of the two
    faces it replaces). The Delaunay test is taken in the metric; where the metric is strongly
    anisotropic, or beside a seam whose nodes are never collapsed, its diagonal can be a sliver in
    material space (aspect 0.073 in karate_no_floor, seed 1, frame 1), which no collapse removes."""
    a, b, c = fv[f, k], fv[f, (k + 1) % 3], fv[f, (k + 2) % 3]
    d = fv[g, (l + 2) % 3]
    new = min(aspect(vu, a, d, c), aspect(vu, d, b, c))
    if new >= aspect_min:
        return True
    return new >= min(aspect(vu, a, b, c), aspect(vu, b, a, d))


@nb.njit(cache=True)
def _touches_frozen(fv, vnode, nd, fz, f, g):
    """True when a vert of face f or g has a frozen node (node data column fz > 0)."""
    for s in range(3):
        if nd[vnode[fv[f, s]], fz] > 0.0 or nd[vnode[fv[g, s]], fz] > 0.0:
            return True
    return False


@nb.njit(cache=True)
def flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n_stack, threshold, max_flips,
               fdirty, fz, aspect_min):
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
        if not _flip_keeps_aspect(fv, vu, f, k, g, fadj[f, k] % 3, aspect_min):
            continue
        # boundary sides of f and g may be seam sides whose twin codes change with the flip
        tw_f = (ftw[f, 0], ftw[f, 1], ftw[f, 2])
        tw_g = (ftw[g, 0], ftw[g, 1], ftw[g, 2])
        old = (fv[f, 0], fv[f, 1], fv[f, 2], fv[g, 0], fv[g, 1], fv[g, 2])
        if not flip(fv, fadj, vu, vface, h):
            continue
        retwin(fv, ftw, f, g, old, tw_f, tw_g)
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
def flip_all(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, cnt, fdirty, threshold, fz, aspect_min):
    """Lawson flipping from every edge (bounded); returns the number of flips."""
    nf = cnt[0]
    stack = np.empty(3 * nf + 4096, dtype=np.int64)
    n = 0
    for f in range(nf - 1, -1, -1):
        if falive[f]:
            for k in range(2, -1, -1):
                stack[n] = 3 * f + k
                n += 1
    return flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n, threshold,
                      3 * nf + 64, fdirty, fz, aspect_min)


@nb.njit(cache=True)
def flip_slivers(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, cnt, fdirty, threshold, fz,
                 aspect_min):
    """Lawson flipping from the sides of the faces of material aspect below aspect_min, after the
    collapses: a split beside a thin face can leave a sliver whose repairing flip the passes
    around the split did not reach (karate, view-dependent, scale=paper, seed 0, frame 37: aspect
    0.042, its longest side's opposite angles summing to 1.29 pi in the metric). Returns the flips."""
    nf = cnt[0]
    stack = np.empty(3 * nf + 4096, dtype=np.int64)
    n = 0
    for f in range(nf):
        if falive[f] and aspect(vu, fv[f, 0], fv[f, 1], fv[f, 2]) < aspect_min:
            for k in range(3):
                stack[n] = 3 * f + k
                n += 1
    if n == 0:
        return 0
    return flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n, threshold,
                     3 * nf + 64, fdirty, fz, aspect_min)
