"""Connectivity primitives of the remesher's half-edge arrays (see :mod:`cloth.remeshing.remesh`):
local index of a vert in a face, linking neighbours and seam twins, the face ring of a vert,
finding the half-edge between two verts, re-attaching seam twins after a rewrite, allocating a
face and the canonical half-edge of an edge."""

from __future__ import annotations

import numba as nb

RING_MAX = 512  # largest vert valence the kernels handle (a ring buffer size, not a quality bound)


@nb.njit(cache=True, inline="always")
def local_index(fv, f, a):
    if fv[f, 0] == a:
        return 0
    if fv[f, 1] == a:
        return 1
    return 2


@nb.njit(cache=True, inline="always")
def link(fadj, h1, h2):
    """Make half-edges h1 and h2 (either may be -1) neighbours."""
    if h1 >= 0:
        fadj[h1 // 3, h1 % 3] = h2
    if h2 >= 0:
        fadj[h2 // 3, h2 % 3] = h1


@nb.njit(cache=True, inline="always")
def twin(ftw, h1, h2):
    if h1 >= 0:
        ftw[h1 // 3, h1 % 3] = h2
    if h2 >= 0:
        ftw[h2 // 3, h2 % 3] = h1


@nb.njit(cache=True)
def ring(fv, fadj, vface, a, buf):
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
        i = local_index(fv, f, a)
        h = fadj[f, i]  # side i leaves a
        if h < 0:
            nxt = fv[f, (i + 1) % 3]
            break
        f = h // 3
        if f == f0:
            return n, False, -1, -1
    f = f0
    while True:
        i = local_index(fv, f, a)
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
def find_he(fv, fadj, vface, valive, a, b, buf):
    """Half-edge from vert a to vert b, or from b to a if a->b has no face; -1 if no edge."""
    if a < 0 or b < 0 or not valive[a] or not valive[b]:
        return -1
    n, bnd, nxt, prv = ring(fv, fadj, vface, a, buf)
    for j in range(n):
        f = buf[j]
        i = local_index(fv, f, a)
        if fv[f, (i + 1) % 3] == b:
            return 3 * f + i
        if fv[f, (i + 2) % 3] == b:
            return 3 * f + (i + 2) % 3
    return -1


@nb.njit(cache=True)
def retwin(fv, ftw, f, g, old, tw_f, tw_g):
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
                        twin(ftw, 3 * ff + ss, t)
                        placed = True
            if not placed:
                ftw[t // 3, t % 3] = -1


@nb.njit(cache=True)
def new_face(falive, cnt):
    f = cnt[0]
    cnt[0] += 1
    falive[f] = True
    return f


@nb.njit(cache=True)
def canonical(fadj, ftw, h):
    o = fadj[h // 3, h % 3]
    if o < 0:
        t = ftw[h // 3, h % 3]
        return t < 0 or h < t
    return h < o
