"""Broad phase of collision handling: a bounding-volume hierarchy of axis-aligned boxes, in numba.

The tree is rebuilt from scratch at every query (a top-down median split on the boxes'
centres), which costs O(F log F) and needs no refit bookkeeping when the remesher changes
the faces between steps. Boxes are given by their corners `lo`, `hi` (F, 3); the caller
inflates them by the contact thickness and, for continuous collision detection, makes them
cover a face's positions at the start and at the end of the step (`face_boxes`).

    pairs = self_overlaps(lo, hi)            # (P, 2), i < j, boxes of one set that overlap, sorted
    pairs = cross_overlaps(lo, hi, lo2, hi2)  # (P, 2), (index in set 1, index in set 2)
    tree = build_tree(lo, hi)                 # the tree itself, for other searches over it

The closest-point search over the same tree is cloth.collision.nearest.
"""

from __future__ import annotations

import numpy as np
from numba import njit

LEAF_SIZE = 4  # boxes per leaf: below this, testing all pairs is cheaper than descending


@njit(cache=True)
def build_tree(lo, hi):
    """Tree over the boxes: node arrays (box lo, box hi, left child, start, count) and the
    permutation `order` of box indices; node k's boxes are order[start[k]:start[k] + count[k]];
    an inner node's children are left[k] and left[k] + 1, stored after it (a refit can run over
    the nodes in reverse order); leaves have left = -1."""
    n = lo.shape[0]
    cap = 2 * n + 1
    nlo = np.empty((cap, 3))
    nhi = np.empty((cap, 3))
    left = -np.ones(cap, dtype=np.int64)
    start = np.zeros(cap, dtype=np.int64)
    count = np.zeros(cap, dtype=np.int64)
    order = np.arange(n)
    centre = 0.5 * (lo + hi)
    stack = np.empty(cap, dtype=np.int64)
    n_nodes = 1
    start[0], count[0] = 0, n
    top = 0
    stack[0] = 0
    while top >= 0:
        k = stack[top]
        top -= 1
        s, c = start[k], count[k]
        for d in range(3):
            nlo[k, d] = np.inf
            nhi[k, d] = -np.inf
        for a in range(s, s + c):
            i = order[a]
            for d in range(3):
                nlo[k, d] = min(nlo[k, d], lo[i, d])
                nhi[k, d] = max(nhi[k, d], hi[i, d])
        if c <= LEAF_SIZE:
            continue
        # split at the median of the centres along the axis where the centres spread most
        axis = 0
        best = -1.0
        for d in range(3):
            cmin, cmax = np.inf, -np.inf
            for a in range(s, s + c):
                v = centre[order[a], d]
                cmin = min(cmin, v)
                cmax = max(cmax, v)
            if cmax - cmin > best:
                best = cmax - cmin
                axis = d
        keys = np.empty(c)
        for a in range(c):
            keys[a] = centre[order[s + a], axis]
        perm = np.argsort(keys, kind="mergesort")  # stable: the tree is deterministic
        seg = order[s:s + c].copy()
        for a in range(c):
            order[s + a] = seg[perm[a]]
        half = c // 2
        L = n_nodes
        n_nodes += 2
        left[k] = L
        start[L], count[L] = s, half
        start[L + 1], count[L + 1] = s + half, c - half
        top += 1
        stack[top] = L
        top += 1
        stack[top] = L + 1
    return nlo[:n_nodes], nhi[:n_nodes], left[:n_nodes], start[:n_nodes], count[:n_nodes], order


@njit(cache=True)
def refit(lo, hi, nlo, nhi, left, start, count, order):
    """Refit a tree's node boxes (in place) to new boxes (lo, hi) of the same items: children are
    stored after their parent, so one pass in reverse order sees every child first. Returns the
    summed extents of the node boxes (a measure of how loose the tree has become)."""
    total = 0.0
    for k in range(nlo.shape[0] - 1, -1, -1):
        for d in range(3):
            nlo[k, d] = np.inf
            nhi[k, d] = -np.inf
        if left[k] < 0:
            for a in range(start[k], start[k] + count[k]):
                i = order[a]
                for d in range(3):
                    nlo[k, d] = min(nlo[k, d], lo[i, d])
                    nhi[k, d] = max(nhi[k, d], hi[i, d])
        else:
            for c in range(left[k], left[k] + 2):
                for d in range(3):
                    nlo[k, d] = min(nlo[k, d], nlo[c, d])
                    nhi[k, d] = max(nhi[k, d], nhi[c, d])
        for d in range(3):
            total += nhi[k, d] - nlo[k, d]
    return total


# The box tests below are written out, not called: a call of a numba function with array arguments
# per tested pair (reference counts of every array) made the searches 3-4x slower, and numba's own
# inlining (inline="always") 3x; so was a helper that grows the output per pair.


@njit(cache=True)
def _self_pairs(lo, hi, tree):
    """All overlapping pairs (min, max) of the boxes of one tree, box by box in the tree's order:
    the box at position p of `order` descends only into nodes that hold boxes after p, so each
    pair is found once, from its earlier box (a third of the work of a dual-tree descent on cloth)."""
    nlo, nhi, left, start, count, order = tree
    n_boxes = lo.shape[0]
    out = np.empty((max(16, 8 * n_boxes), 2), dtype=np.int64)
    n = 0
    stack = np.empty(64 + 2 * left.shape[0], dtype=np.int64)
    for p in range(n_boxes):
        i = order[p]
        top = 0
        stack[0] = 0
        while top >= 0:
            k = stack[top]
            top -= 1
            if start[k] + count[k] <= p + 1:
                continue
            if (nlo[k, 0] > hi[i, 0] or lo[i, 0] > nhi[k, 0] or nlo[k, 1] > hi[i, 1] or lo[i, 1] > nhi[k, 1]
                    or nlo[k, 2] > hi[i, 2] or lo[i, 2] > nhi[k, 2]):
                continue
            if left[k] >= 0:
                stack[top + 1] = left[k]
                stack[top + 2] = left[k] + 1
                top += 2
                continue
            for a in range(max(start[k], p + 1), start[k] + count[k]):
                j = order[a]
                if not (lo[j, 0] > hi[i, 0] or lo[i, 0] > hi[j, 0] or lo[j, 1] > hi[i, 1] or lo[i, 1] > hi[j, 1]
                        or lo[j, 2] > hi[i, 2] or lo[i, 2] > hi[j, 2]):
                    if n == out.shape[0]:
                        grown = np.empty((2 * n, 2), dtype=np.int64)
                        grown[:n] = out[:n]
                        out = grown
                    out[n, 0] = min(i, j)
                    out[n, 1] = max(i, j)
                    n += 1
    return out[:n]


@njit(cache=True)
def _tree_pairs(lo, hi, lo2, hi2, tree2):
    """All overlapping pairs (i, j) of a box i of (lo, hi) and a box j of (lo2, hi2), box by box of
    the first set down the second's tree."""
    nlo, nhi, left, start, count, order = tree2
    out = np.empty((max(16, 4 * lo.shape[0]), 2), dtype=np.int64)
    n = 0
    stack = np.empty(64 + 2 * left.shape[0], dtype=np.int64)
    for i in range(lo.shape[0]):
        top = 0
        stack[0] = 0
        while top >= 0:
            k = stack[top]
            top -= 1
            if (nlo[k, 0] > hi[i, 0] or lo[i, 0] > nhi[k, 0] or nlo[k, 1] > hi[i, 1] or lo[i, 1] > nhi[k, 1]
                    or nlo[k, 2] > hi[i, 2] or lo[i, 2] > nhi[k, 2]):
                continue
            if left[k] >= 0:
                stack[top + 1] = left[k]
                stack[top + 2] = left[k] + 1
                top += 2
                continue
            for a in range(start[k], start[k] + count[k]):
                j = order[a]
                if not (lo2[j, 0] > hi[i, 0] or lo[i, 0] > hi2[j, 0] or lo2[j, 1] > hi[i, 1] or lo[i, 1] > hi2[j, 1]
                        or lo2[j, 2] > hi[i, 2] or lo[i, 2] > hi2[j, 2]):
                    if n == out.shape[0]:
                        grown = np.empty((2 * n, 2), dtype=np.int64)
                        grown[:n] = out[:n]
                        out = grown
                    out[n, 0] = i
                    out[n, 1] = j
                    n += 1
    return out[:n]


def _check_boxes(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape:
        raise ValueError(f"boxes must be two (N, 3) arrays of equal shape, got {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("boxes must be finite")
    return lo, hi


def self_overlaps(lo: np.ndarray, hi: np.ndarray, sort: bool = True) -> np.ndarray:
    """Index pairs (i, j), i < j, of the boxes [lo_i, hi_i] that overlap (closed boxes), (P, 2),
    sorted lexicographically; with sort=False in the search's own order (deterministic too: for
    a caller whose result does not depend on the order, such as the collision candidates, which
    are sorted afterwards)."""
    lo, hi = _check_boxes(lo, hi)
    if lo.shape[0] < 2:
        return np.empty((0, 2), dtype=np.int64)
    pairs = _self_pairs(lo, hi, build_tree(lo, hi))
    if not sort:
        return pairs
    key = np.sort(pairs[:, 0] * lo.shape[0] + pairs[:, 1])  # i < j < n: the key orders as (i, j)
    return np.column_stack([key // lo.shape[0], key % lo.shape[0]])


def cross_overlaps(lo: np.ndarray, hi: np.ndarray, lo2: np.ndarray, hi2: np.ndarray, tree2=None,
                   sort: bool = True) -> np.ndarray:
    """Index pairs (i, j) of a box i of the first set overlapping a box j of the second, (P, 2),
    sorted lexicographically (sort=False: in the search's own order). `tree2`: the second set's
    tree (`build_tree(lo2, hi2)`) when the caller has it already (an obstacle queried again and
    again within a collision pass)."""
    lo, hi = _check_boxes(lo, hi)
    lo2, hi2 = _check_boxes(lo2, hi2)
    if lo.shape[0] == 0 or lo2.shape[0] == 0:
        return np.empty((0, 2), dtype=np.int64)
    pairs = _tree_pairs(lo, hi, lo2, hi2, build_tree(lo2, hi2) if tree2 is None else tree2)
    if not sort:
        return pairs
    key = np.sort(pairs[:, 0] * lo2.shape[0] + pairs[:, 1])  # j < n2: the key orders as (i, j)
    return np.column_stack([key // lo2.shape[0], key % lo2.shape[0]])


def face_boxes(face_nodes: np.ndarray, x0: np.ndarray, x1: np.ndarray | None = None,
               pad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Boxes of the triangles `face_nodes` (F, 3) at positions x0 (and x1: the box then covers
    the linear motion from x0 to x1 over a step), inflated by `pad` on every side."""
    corners = x0[face_nodes]
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    if x1 is not None:
        c1 = x1[face_nodes]
        lo, hi = np.minimum(lo, c1.min(axis=1)), np.maximum(hi, c1.max(axis=1))
    return lo - pad, hi + pad
