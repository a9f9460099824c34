"""cloth.core.tensors.eig_apply: Q f(Lambda) Q^T of stacks of symmetric matrices."""

from __future__ import annotations

import numpy as np
import pytest

from cloth.core.tensors import eig_apply

# The closed form and LAPACK agree to round-off, relative to the largest entry.
ROUNDOFF = 1e-13


def _reference(M, fn):
    w, Q = np.linalg.eigh(M)
    return np.einsum("fik,fk,fjk->fij", Q, fn(w), Q)


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("fn", [lambda w: np.sign(w) * np.sqrt(np.abs(w)), lambda w: np.maximum(w, 0.3),
                                lambda w: w**3 - w])
def test_eig_apply_matches_lapack_and_the_2x2_closed_form_keeps_diagonals_diagonal(n, fn):
    rng = np.random.default_rng(3)
    A = rng.standard_normal((500, n, n))
    M = A + np.swapaxes(A, 1, 2)
    M[:5] = 2.0 * np.eye(n)  # a multiple of the identity
    M[5:10] = np.diag(np.arange(1.0, n + 1))  # diagonal, ascending
    M[10:15] = np.diag(np.arange(n, 0.0, -1))  # diagonal, descending
    M[15:20] = 0.0
    M[20] = np.eye(n) + 1e-9 * (np.ones((n, n)) - np.eye(n))  # nearly equal eigenvalues
    out = eig_apply(M, fn)
    ref = _reference(M, fn)
    assert np.abs(out - ref).max() < ROUNDOFF * np.abs(ref).max()
    assert n != 2 or np.array_equal(out, np.swapaxes(out, 1, 2))  # the 2x2 closed form: exactly symmetric
    for k in range(5, 15) if n == 2 else ():  # the closed form of 2x2: nothing off a diagonal's diagonal
        assert np.count_nonzero(out[k] - np.diag(np.diag(out[k]))) == 0
