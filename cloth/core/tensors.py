"""Small helpers on stacks of symmetric tensors (sizing metrics and the like).

Imports numpy, and numba for the scalar kernel :func:`eig2x2`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numba import njit


def eig_apply(M: np.ndarray, fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Apply `fn` to the eigenvalues of a stack of symmetric matrices: Q fn(Lambda) Q^T.

    `M` (F, n, n) symmetric (only its lower triangle is read, as by ``numpy.linalg.eigh``);
    `fn` maps the (F, n) eigenvalues, ascending per row, to (F, n) new ones. Returns (F, n, n).
    Used for the sizing tensors, n = 2 (clamping, square roots, eqs 7-8 of the view clamp).
    """
    if M.shape[1:] == (2, 2):
        return _eig_apply_2x2(M, fn)
    w, Q = np.linalg.eigh(M)
    return (Q * fn(w)[:, None, :]) @ np.swapaxes(Q, 1, 2)


def _eig_apply_2x2(M: np.ndarray, fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """eig_apply for 2x2 matrices in closed form (5x faster than batched eigh at a few thousand
    faces): eigenvalues m -+ r; the larger one's eigenvector is (w - c, b) or (b, w - a), whichever
    is longer (exact for diagonal matrices), (1, 0) when both vanish (a multiple of I)."""
    a, b, c = M[:, 0, 0], M[:, 1, 0], M[:, 1, 1]
    m = 0.5 * (a + c)
    r = np.hypot(0.5 * (a - c), b)
    f = fn(np.column_stack([m - r, m + r]))
    hi_w = m + r
    v1 = np.column_stack([hi_w - c, b])
    v2 = np.column_stack([b, hi_w - a])
    n1, n2 = np.hypot(v1[:, 0], v1[:, 1]), np.hypot(v2[:, 0], v2[:, 1])
    v = np.where((n1 >= n2)[:, None], v1, v2)
    n = np.maximum(n1, n2)
    zero = n == 0.0
    v[zero] = (1.0, 0.0)
    n[zero] = 1.0
    cs, sn = v[:, 0] / n, v[:, 1] / n  # (cs, sn): eigenvector of m + r; (-sn, cs): of m - r
    lo, hi = f[:, 0], f[:, 1]
    out = np.empty_like(M, dtype=np.float64)
    out[:, 0, 0] = lo * sn * sn + hi * cs * cs
    out[:, 1, 1] = lo * cs * cs + hi * sn * sn
    out[:, 0, 1] = out[:, 1, 0] = (hi - lo) * cs * sn
    return out


@njit(cache=True)
def eig2x2(a, b, c):
    """Closed-form eigen-system of the symmetric [[a, b], [b, c]] in scalars, for kernels (the
    same as _eig_apply_2x2's): (lo, hi, cs, sn), (cs, sn) the unit eigenvector of hi, (-sn, cs) of lo."""
    m = 0.5 * (a + c)
    r = math.hypot(0.5 * (a - c), b)
    hi = m + r
    v1x, v1y = hi - c, b
    v2x, v2y = b, hi - a
    n1, n2 = math.hypot(v1x, v1y), math.hypot(v2x, v2y)
    if n1 >= n2:
        vx, vy, n = v1x, v1y, n1
    else:
        vx, vy, n = v2x, v2y, n2
    if n == 0.0:
        vx, vy, n = 1.0, 0.0, 1.0
    return m - r, hi, vx / n, vy / n
