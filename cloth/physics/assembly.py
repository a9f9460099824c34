"""Sparse assembly of per-element forces and 3x3 stiffness blocks.

The global matrices are block-CSR (BSR) with 3x3 blocks, one block row per node. The sparsity
pattern is the node graph of the elements (faces and bending hinges); it is built once per
topology by :class:`SparsityPattern` and reused every step until the remesher changes the
mesh. Each element carries a precomputed map from its local node pairs to block slots, so the
scatter is a plain loop with no searching.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit


class SparsityPattern:
    """Block-CSR pattern of the node graph of a set of elements.

    Parameters
    ----------
    n_nodes : int
    families : dict of name -> (n_elem, k) int array
        Node stencils of each element family ("faces": k = 3, "hinges": k = 4).

    Attributes
    ----------
    indptr : (n_nodes + 1,) int64, block-row pointers
    indices : (n_blocks,) int64, block-column of each block, sorted within a row
    diag : (n_nodes,) int64, slot of the diagonal block of each row
    slots : dict of name -> (n_elem, k, k) int64, slot of block (node a, node b) per element
    """

    def __init__(self, n_nodes: int, families: dict[str, np.ndarray]):
        self.n_nodes = n_nodes
        stencils = [np.ascontiguousarray(en, dtype=np.int64) for en in families.values()]
        counts = np.zeros(n_nodes, dtype=np.int64)  # upper bound of each row's blocks (with repeats)
        for en in stencils:
            _count_row_entries(en, counts)
        bound = np.zeros(n_nodes + 1, dtype=np.int64)
        np.cumsum(counts + 1, out=bound[1:])  # + 1: the diagonal
        cols = np.empty(bound[-1], dtype=np.int64)
        fill = bound[:-1].copy()
        _seed_diagonal(cols, fill)
        for en in stencils:
            _fill_row_entries(en, cols, fill)
        self.indptr, self.indices = _sorted_unique_rows(bound, fill, cols)
        self.n_blocks = self.indices.size
        self.diag = _find_slots_of_diagonal(self.indptr, self.indices)
        self.slots = {name: _element_slots(np.ascontiguousarray(en, dtype=np.int64), self.indptr, self.indices)
                      for name, en in families.items()}

    def zeros(self) -> np.ndarray:
        """A zero block array (n_blocks, 3, 3) for this pattern."""
        return np.zeros((self.n_blocks, 3, 3))

    def to_scipy(self, data: np.ndarray) -> sp.csr_matrix:
        """Scalar CSR matrix (3n x 3n) of a block array, for direct solvers and inspection."""
        bsr = sp.bsr_matrix((data, self.indices, self.indptr), shape=(3 * self.n_nodes, 3 * self.n_nodes))
        return bsr.tocsr()


@njit(cache=True)
def _count_row_entries(element_nodes, counts):
    """counts[a] += k for each node a of each element (k nodes): a bound on row a's blocks (accumulates)."""
    n_elem, k = element_nodes.shape
    for e in range(n_elem):
        for a in range(k):
            counts[element_nodes[e, a]] += k


@njit(cache=True)
def _seed_diagonal(cols, fill):
    """Every row holds its diagonal block: cols[fill[i]] = i, fill[i] += 1 (edits both)."""
    for i in range(fill.size):
        cols[fill[i]] = i
        fill[i] += 1


@njit(cache=True)
def _fill_row_entries(element_nodes, cols, fill):
    """Append every element's node pairs (a, b) to row a's columns, repeats included (edits both)."""
    n_elem, k = element_nodes.shape
    for e in range(n_elem):
        for a in range(k):
            na = element_nodes[e, a]
            for b in range(k):
                cols[fill[na]] = element_nodes[e, b]
                fill[na] += 1


@njit(cache=True)
def _sorted_unique_rows(bound, fill, cols):
    """(indptr, indices): each row's columns cols[bound[i]:fill[i]] sorted, repeats removed.

    A row lists each neighbour once per shared element (about 60 entries for 13 neighbours):
    repeats are dropped first with a per-column marker, and the few left sorted by insertion."""
    n = bound.size - 1
    indptr = np.zeros(n + 1, dtype=np.int64)
    out = np.empty(cols.size, dtype=np.int64)
    seen = np.full(n, -1, dtype=np.int64)  # seen[c] == i: column c already in row i
    m = 0
    for i in range(n):
        start = m
        for j in range(bound[i], fill[i]):
            c = cols[j]
            if seen[c] == i:
                continue
            seen[c] = i
            k = m  # insert c into the sorted out[start:m]
            while k > start and out[k - 1] > c:
                out[k] = out[k - 1]
                k -= 1
            out[k] = c
            m += 1
        indptr[i + 1] = m
    return indptr, out[:m].copy()


@njit(cache=True)
def _find_slots_of_diagonal(indptr, indices):
    diag = np.empty(indptr.size - 1, dtype=np.int64)
    for i in range(diag.size):
        diag[i] = indptr[i] + np.searchsorted(indices[indptr[i]:indptr[i + 1]], i)
    return diag


@njit(cache=True)
def _element_slots(element_nodes, indptr, indices):
    """(n_elem, k, k) slot of block (node a, node b) of every element: a search in row a."""
    n_elem, k = element_nodes.shape
    slots = np.empty((n_elem, k, k), dtype=np.int64)
    for e in range(n_elem):
        for a in range(k):
            na = element_nodes[e, a]
            lo, hi = indptr[na], indptr[na + 1]
            for b in range(k):
                nb = element_nodes[e, b]
                j = lo  # rows are short (a node's neighbours): a scan beats a bisection's overhead
                while j < hi and indices[j] != nb:
                    j += 1
                slots[e, a, b] = j
    return slots


@njit(cache=True)
def scatter_forces(force, element_nodes, element_grad, sign):
    """force[node] += sign * element_grad for every element (accumulates into `force`).

    element_grad is (n_elem, 3k) with the k nodes' 3-vectors stacked; sign = -1 turns energy
    gradients into forces.
    """
    n_elem, k = element_nodes.shape
    for e in range(n_elem):
        for a in range(k):
            na = element_nodes[e, a]
            for d in range(3):
                force[na, d] += sign * element_grad[e, 3 * a + d]


@njit(cache=True)
def scatter_blocks(data, element_slots, element_hess, scale):
    """data[slot] += scale * 3x3 block (a, b) of each element Hessian (accumulates into `data`)."""
    n_elem, k, _ = element_slots.shape
    for e in range(n_elem):
        for a in range(k):
            for b in range(k):
                s = element_slots[e, a, b]
                for i in range(3):
                    for j in range(3):
                        data[s, i, j] += scale * element_hess[e, 3 * a + i, 3 * b + j]


@njit(cache=True)
def bsr_matvec(indptr, indices, data, x, out):
    """out = A @ x for a block-CSR matrix with 3x3 blocks; x, out are (n, 3)."""
    n = indptr.shape[0] - 1
    for i in range(n):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            x0, x1, x2 = x[j, 0], x[j, 1], x[j, 2]
            s0 += data[k, 0, 0] * x0 + data[k, 0, 1] * x1 + data[k, 0, 2] * x2
            s1 += data[k, 1, 0] * x0 + data[k, 1, 1] * x1 + data[k, 1, 2] * x2
            s2 += data[k, 2, 0] * x0 + data[k, 2, 1] * x1 + data[k, 2, 2] * x2
        out[i, 0] = s0
        out[i, 1] = s1
        out[i, 2] = s2


@njit(cache=True)
def apply_dirichlet(indptr, indices, data, rhs, fixed, value):
    """Impose x[i] = value[i] for nodes with fixed[i], keeping the matrix symmetric.

    Free rows move the known columns to the right-hand side (rhs[i] -= A_ij value[j]) and zero
    them; fixed rows become identity rows with rhs = value. Modifies `data` and `rhs` in place.
    """
    n = indptr.shape[0] - 1
    for i in range(n):
        if fixed[i]:
            for k in range(indptr[i], indptr[i + 1]):
                j = indices[k]
                for a in range(3):
                    for b in range(3):
                        data[k, a, b] = 1.0 if (j == i and a == b) else 0.0
            for a in range(3):
                rhs[i, a] = value[i, a]
        else:
            for k in range(indptr[i], indptr[i + 1]):
                j = indices[k]
                if fixed[j]:
                    for a in range(3):
                        acc = 0.0
                        for b in range(3):
                            acc += data[k, a, b] * value[j, b]
                            data[k, a, b] = 0.0
                        rhs[i, a] -= acc
