"""Split kernels of the remesher: split an edge at its midpoint (one new node, one new vert per
panel of a seam) and the split pass that splits every invalid edge (s > 1, eq 1) worst first,
flipping around each split."""

from __future__ import annotations

import numba as nb
import numpy as np

from cloth.remeshing.kernels.flips import flip_pass
from cloth.remeshing.kernels.geometry import he_s2
from cloth.remeshing.kernels.halfedge import RING_MAX, canonical, find_he, link, new_face, twin

# status codes of a pass
OUT_OF_CAPACITY = 1  # the working arrays are full: the driver grows them and calls the pass again
RING_OVERFLOW = 2


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
    f2 = new_face(falive, cnt)
    fv[f, 0], fv[f, 1], fv[f, 2] = a, m, c
    fv[f2, 0], fv[f2, 1], fv[f2, 2] = m, b, c
    for s in range(3):
        ftw[f, s] = -1
        ftw[f2, s] = -1
    link(fadj, 3 * f + 1, 3 * f2 + 2)
    link(fadj, 3 * f + 2, n_ca)
    twin(ftw, 3 * f + 2, t_ca)
    link(fadj, 3 * f2 + 1, n_bc)
    twin(ftw, 3 * f2 + 1, t_bc)
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
    g2 = new_face(falive, cnt)
    fv[g, 0], fv[g, 1], fv[g, 2] = b, m, d
    fv[g2, 0], fv[g2, 1], fv[g2, 2] = m, a, d
    for s in range(3):
        ftw[g, s] = -1
        ftw[g2, s] = -1
    link(fadj, 3 * g + 0, 3 * f2 + 0)
    link(fadj, 3 * g + 1, 3 * g2 + 2)
    link(fadj, 3 * g + 2, n_db)
    twin(ftw, 3 * g + 2, t_db)
    link(fadj, 3 * g2 + 0, 3 * f + 0)
    link(fadj, 3 * g2 + 1, n_ad)
    twin(ftw, 3 * g2 + 1, t_ad)
    vface[d] = g
    fdirty[g] = True
    fdirty[g2] = True
    return m, 3 * f + 0, 3 * f2 + 0


@nb.njit(cache=True)
def split(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, nd, npin, nnv, nalive, h, cnt, fdirty,
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
                    twin(ftw, x, y)
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
def split_pass(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, nd, npin, nnv, nalive, cnt, fdirty,
               threshold, max_rounds, max_strain, fz, aspect_min):
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
                if not canonical(fadj, ftw, h):
                    continue
                s = he_s2(fv, ftw, vu, vM, h)
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
            h = find_he(fv, fadj, vface, valive, va[j], vb[j], buf)
            if h < 0:
                continue
            if he_s2(fv, ftw, vu, vM, h) <= 1.0:
                continue
            n_stack = split(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, nd, npin, nnv, nalive,
                             h, cnt, fdirty, stack)
            splits += 1
            flips += flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n_stack,
                                threshold, 64, fdirty, fz, aspect_min)
    return 0, splits, flips
