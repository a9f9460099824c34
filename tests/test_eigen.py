"""The small symmetric eigensolver of the element Hessians' projection (cloth.physics.eigen)."""

import numpy as np
import pytest

from cloth.physics.eigen import symmetric_eig
from cloth.physics.membrane import project_psd

# Relative to the matrix's largest entry: a backward-stable decomposition of a 12x12 matrix is
# exact to a few hundred ulps; a wrong rotation or reflection shows at order 1.
ROUND_OFF = 1e-12


def _cases(rng):
    for n in (1, 2, 3, 9, 12):
        for _ in range(40):
            a = rng.normal(size=(n, n))
            yield a + a.T
            q, _ = np.linalg.qr(rng.normal(size=(n, n)))
            yield (q * rng.choice([-1.0, -1.0, 0.0, 2.0], size=n)) @ q.T  # repeated eigenvalues
        yield np.zeros((n, n))
        yield -np.eye(n)
        yield np.diag(np.arange(n, dtype=float) - n / 2)
        yield -np.ones((n, n))  # rank one
        yield 1e-200 * np.ones((n, n))
        yield 1e200 * np.eye(n) - 1e190 * np.ones((n, n))


def test_symmetric_eig_against_lapack():
    rng = np.random.default_rng(0)
    for a in _cases(rng):
        n = a.shape[0]
        w, v = np.empty(n), np.empty((n, n))
        symmetric_eig(a, w, v)
        scale = max(np.abs(a).max(), 1e-300)
        assert np.abs(a @ v - v * w).max() <= ROUND_OFF * scale
        assert np.abs(v.T @ v - np.eye(n)).max() <= ROUND_OFF
        assert np.abs(np.sort(w) - np.linalg.eigvalsh(a)).max() <= ROUND_OFF * scale


@pytest.mark.parametrize("absolute", [False, True])
def test_projection_is_the_eigenvalue_clamp(absolute):
    """V max(w, 0) V^T (or V |w| V^T), as LAPACK's decomposition gives it, and the input is kept
    where it is already positive semi-definite."""
    rng = np.random.default_rng(1)
    for a in _cases(rng):
        h = a.copy()
        project_psd(h, absolute)
        w, v = np.linalg.eigh(a)
        expected = (v * (np.abs(w) if absolute else np.maximum(w, 0.0))) @ v.T
        assert np.abs(h - expected).max() <= ROUND_OFF * max(np.abs(a).max(), 1e-300)
        assert np.array_equal(h, h.T)


def test_non_finite_matrix_is_refused():
    a = np.full((3, 3), np.nan)
    with pytest.raises(np.linalg.LinAlgError):
        symmetric_eig(a, np.empty(3), np.empty((3, 3)))
