"""Collapse kernels of the remesher: the tests and the topology change of one edge collapse
(:func:`try_collapse`) and the collapse pass over the edges of dirty faces, shortest first,
flipping around each collapse."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from cloth.remeshing.kernels.flips import flip_pass
from cloth.remeshing.kernels.geometry import aspect, edge_s2, he_s2, world_strain
from cloth.remeshing.kernels.halfedge import RING_MAX, find_he, link, local_index, ring, twin


@nb.njit(cache=True)
def try_collapse(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, npin, nnv, nalive, h, a_first,
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
    n, a_bnd, nxt, prv = ring(fv, fadj, vface, a, buf)
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
    # the size of every new edge at b first: the cheapest test, and the one most candidates fail
    for i in range(n):
        fa = buf[i]
        if fv[fa, 0] == b or fv[fa, 1] == b or fv[fa, 2] == b:
            continue
        for s in range(3):
            x = fv[fa, s]
            if x != a and edge_s2(vu, vM, b, x) > max_s2:
                return False
    # link condition: the verts adjacent to both a and b are exactly the edge's opposite verts
    nb2, b_bnd, _, _ = ring(fv, fadj, vface, b, buf2)
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
    # new faces: quality, orientation and world strain
    old_strain = 0.0
    for i in range(n):
        fa = buf[i]
        old_strain = max(old_strain, world_strain(vu, vnode, nd, fv[fa, 0], fv[fa, 1], fv[fa, 2]))
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
        if aspect(vu, p0, p1, p2) < aspect_min:
            return False
        if world_strain(vu, vnode, nd, p0, p1, p2) > strain_limit:
            return False  # the world surface would crease or stretch more than it already is
    if n_keep == 0 and not a_bnd:
        return False
    # --- apply: the faces holding both a and b die, their outer sides are joined --------------
    for i in range(n):
        fa = buf[i]
        if not (fv[fa, 0] == b or fv[fa, 1] == b or fv[fa, 2] == b):
            continue
        ia = local_index(fv, fa, a)
        ib = local_index(fv, fa, b)
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
            link(fadj, o_ac, o_bc)
        elif o_ac >= 0:
            link(fadj, o_ac, -1)
            twin(ftw, o_ac, t_bc)
        elif o_bc >= 0:
            link(fadj, o_bc, -1)
            twin(ftw, o_bc, t_ac)
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
                s = he_s2(fv, ftw, vu, vM, h)
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
            h = find_he(fv, fadj, vface, valive, a, b, buf)
            if h < 0:
                continue
            first = fv[h // 3, h % 3] == a
            ok = try_collapse(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, npin, nnv, nalive, h,
                               first, aspect_min, max_s2, cos_corner, buf, buf2, fdirty, nd, max_strain, fz)
            if not ok:
                ok = try_collapse(fv, fadj, ftw, falive, vu, vM, vnode, vface, valive, npin, nnv, nalive,
                                   h, not first, aspect_min, max_s2, cos_corner, buf, buf2, fdirty, nd,
                                   max_strain, fz)
            if not ok:
                continue
            done += 1
            # flip around the surviving vert
            keep = b if not valive[a] else a
            n, _, _, _ = ring(fv, fadj, vface, keep, buf)
            n_stack = 0
            for i in range(max(n, 0)):
                for s in range(3):
                    if n_stack < stack.shape[0]:
                        stack[n_stack] = 3 * buf[i] + s
                        n_stack += 1
            flips += flip_pass(fv, fadj, ftw, falive, vu, vM, vface, vnode, nd, max_strain, stack, n_stack,
                                threshold, 256, fdirty, fz, aspect_min)
        collapses += done
        if done == 0:
            break
    return collapses, flips
