"""Eigen-decomposition of small symmetric matrices inside numba kernels, without LAPACK.

The element Hessians of the membrane (9x9) and of bending (9x9 in the hinge's edge coordinates)
are made positive semi-definite by an eigen-decomposition, for most elements of a buckling
garment in every step (all bent hinges and three quarters of the faces of the dancing skirt).
``np.linalg.eigh`` inside a numba kernel pays for LAPACK's general path (a copy, a workspace
query and allocation, a finiteness check) on each call: 16 us for a 9x9 matrix, which made the
projection 90 % of the force evaluation. Here the classical two-phase algorithm runs in place on
the caller's arrays: Householder reduction to tridiagonal form with the orthogonal transform
accumulated, then the implicit QL iteration with Wilkinson's shift on the tridiagonal matrix
(Wilkinson and Reinsch, Handbook for Automatic Computation II, 1971; Golub and Van Loan,
Matrix Computations, sections 8.3 and 8.2). Both are backward stable: the eigenvalues agree with
LAPACK's to round-off of the matrix's norm and the eigenvectors are orthonormal to round-off.
An iteration that does not converge (a matrix with NaN or inf) falls back to ``np.linalg.eigh``,
which raises on non-finite input as before.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# QL sweeps allowed per eigenvalue before the fallback (a finite matrix needs 1-3 on average).
MAX_QL_ITERATIONS = 30


@njit(cache=True)
def _householder_reduce(Q, d, e):
    """Householder reduction of the symmetric Q (n, n) in place (reads its lower triangle): the
    reduced matrix's subdiagonal into e[1:] (e[0] = 0), each reflection's vector u in row i left
    of the diagonal (u / h in column i above it) and its h in d[i] (0: none); the tridiagonal's
    diagonal is then Q's."""
    n = Q.shape[0]
    for i in range(n - 1, 0, -1):
        h = 0.0
        if i > 1:
            scale = 0.0
            for k in range(i):
                scale += abs(Q[i, k])
            if scale == 0.0:
                e[i] = Q[i, i - 1]
            else:
                # the Householder vector u = row i left of the diagonal, scaled, with its last
                # entry shifted so that (I - u u^T / h) zeroes all but the subdiagonal element
                for k in range(i):
                    Q[i, k] /= scale
                    h += Q[i, k] * Q[i, k]
                f = Q[i, i - 1]
                g = -np.sqrt(h) if f >= 0.0 else np.sqrt(h)
                e[i] = scale * g
                h -= f * g
                Q[i, i - 1] = f - g
                # p = A u / h (into e[:i]), K = u^T p / 2h, q = p - K u; A <- A - u q^T - q u^T
                f = 0.0
                for j in range(i):
                    Q[j, i] = Q[i, j] / h  # kept for the accumulation below
                    g = 0.0
                    for k in range(j + 1):
                        g += Q[j, k] * Q[i, k]
                    for k in range(j + 1, i):
                        g += Q[k, j] * Q[i, k]
                    e[j] = g / h
                    f += e[j] * Q[i, j]
                half = f / (h + h)
                for j in range(i):
                    f = Q[i, j]
                    g = e[j] - half * f
                    e[j] = g
                    for k in range(j + 1):
                        Q[j, k] -= f * e[k] + g * Q[i, k]
        else:
            e[i] = Q[i, i - 1]
        d[i] = h
    d[0] = 0.0
    e[0] = 0.0


@njit(cache=True)
def _householder_tridiagonal(Q, d, e):
    """Reduce the symmetric Q (n, n) in place: on return Q is orthogonal with Q^T A Q tridiagonal,
    d its diagonal and e[1:] its subdiagonal (e[0] = 0). Reads only the lower triangle of A."""
    n = Q.shape[0]
    _householder_reduce(Q, d, e)
    # accumulate the product of the reflections (stored in the rows and columns above)
    for i in range(n):
        if d[i] != 0.0:
            for j in range(i):
                g = 0.0
                for k in range(i):
                    g += Q[i, k] * Q[k, j]
                for k in range(i):
                    Q[k, j] -= g * Q[k, i]
        d[i] = Q[i, i]
        Q[i, i] = 1.0
        for j in range(i):
            Q[j, i] = 0.0
            Q[i, j] = 0.0


@njit(cache=True)
def _tridiagonal_ql(d, e, Q):
    """Eigenvalues of the tridiagonal (d, e[1:]) into d (e overwritten), its rotations applied to
    the columns of Q (which then hold the eigenvectors). Returns False if an eigenvalue did not
    converge."""
    n = d.shape[0]
    for i in range(1, n):
        e[i - 1] = e[i]
    e[n - 1] = 0.0
    eps = np.finfo(np.float64).eps
    for l in range(n):
        iterations = 0
        while True:
            # the first negligible subdiagonal element at or after l splits the matrix there
            m = l
            while m < n - 1:
                if abs(e[m]) <= eps * (abs(d[m]) + abs(d[m + 1])):
                    break
                m += 1
            if m == l:
                break
            iterations += 1
            if iterations > MAX_QL_ITERATIONS:
                return False
            # Wilkinson's shift from the leading 2x2 block, then chase the bulge from m up to l
            g = (d[l + 1] - d[l]) / (2.0 * e[l])
            r = np.hypot(g, 1.0)
            g = d[m] - d[l] + e[l] / (g + (r if g >= 0.0 else -r))
            s = 1.0
            c = 1.0
            p = 0.0
            i = m - 1
            deflated = False
            while i >= l:
                f = s * e[i]
                b = c * e[i]
                r = np.hypot(f, g)
                e[i + 1] = r
                if r == 0.0:  # underflow: the matrix splits at i + 1; start this l again
                    d[i + 1] -= p
                    e[m] = 0.0
                    deflated = True
                    break
                s = f / r
                c = g / r
                g = d[i + 1] - p
                r = (d[i] - g) * s + 2.0 * c * b
                p = s * r
                d[i + 1] = g + p
                g = c * r - b
                for k in range(n):
                    f = Q[k, i + 1]
                    Q[k, i + 1] = s * Q[k, i] + c * f
                    Q[k, i] = c * Q[k, i] - s * f
                i -= 1
            if deflated:
                continue
            d[l] -= p
            e[l] = g
            e[m] = 0.0
    return True


@njit(cache=True)
def symmetric_eig(A, w, V):
    """Eigenvalues w (n,) and orthonormal eigenvectors V (n, n, columns) of the symmetric A.

    A is read (its lower triangle), not modified; w and V are written. Unordered eigenvalues.
    """
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            V[i, j] = A[i, j]
    e = np.empty(n)
    _householder_tridiagonal(V, w, e)
    if not _tridiagonal_ql(w, e, V):
        w2, V2 = np.linalg.eigh(A)  # non-finite input: LAPACK's error, or its answer
        for i in range(n):
            w[i] = w2[i]
            for j in range(n):
                V[i, j] = V2[i, j]

