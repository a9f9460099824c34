"""Small helpers on stacks of symmetric tensors (sizing metrics and the like).

Imports numpy only.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def eig_apply(M: np.ndarray, fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Apply `fn` to the eigenvalues of a stack of symmetric matrices: Q fn(Lambda) Q^T.

    `M` (F, n, n) symmetric (only its lower triangle is read, as by ``numpy.linalg.eigh``);
    `fn` maps the (F, n) eigenvalues, ascending per row, to (F, n) new ones. Returns (F, n, n).
    Used for the sizing tensors, n = 2 (clamping, square roots, eqs 7-8 of the view clamp).
    """
    w, Q = np.linalg.eigh(M)
    return np.einsum("fik,fk,fjk->fij", Q, fn(w), Q)
