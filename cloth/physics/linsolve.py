"""Linear solvers for the implicit step: block-Jacobi preconditioned CG, or a direct solve."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla
from numba import njit

from cloth.physics.assembly import SparsityPattern, bsr_matvec


@dataclass(frozen=True)
class SolverOptions:
    method: str = "pcg"  # "pcg" (block-Jacobi preconditioned conjugate gradient) or "direct"
    tolerance: float = 1e-6  # relative residual |b - A x| / |b| at which PCG stops
    max_iterations: int = 1000  # PCG iteration cap; the record says when it is hit

    def __post_init__(self) -> None:
        if self.method not in ("pcg", "direct"):
            raise ValueError(f"solver.method must be 'pcg' or 'direct', got {self.method!r}")
        if not self.tolerance > 0:
            raise ValueError(f"solver.tolerance must be > 0, got {self.tolerance}")
        if self.max_iterations < 1:
            raise ValueError(f"solver.max_iterations must be >= 1, got {self.max_iterations}")


@njit(cache=True)
def _block_jacobi(indptr, diag, data):
    """Inverse of each 3x3 diagonal block (identity where singular)."""
    n = diag.shape[0]
    inv = np.empty((n, 3, 3))
    for i in range(n):
        a = data[diag[i]]
        det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
               - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
               + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
        if det == 0.0:
            for r in range(3):
                for c in range(3):
                    inv[i, r, c] = 1.0 if r == c else 0.0
            continue
        inv[i, 0, 0] = (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) / det
        inv[i, 0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
        inv[i, 0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
        inv[i, 1, 0] = (a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]) / det
        inv[i, 1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
        inv[i, 1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
        inv[i, 2, 0] = (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]) / det
        inv[i, 2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
        inv[i, 2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det
    return inv


@njit(cache=True)
def _apply_precond(inv, r, z):
    for i in range(r.shape[0]):
        for a in range(3):
            z[i, a] = inv[i, a, 0] * r[i, 0] + inv[i, a, 1] * r[i, 1] + inv[i, a, 2] * r[i, 2]


@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i, 0] * b[i, 0] + a[i, 1] * b[i, 1] + a[i, 2] * b[i, 2]
    return s


@njit(cache=True)
def pcg(indptr, indices, diag, data, b, x, tol, max_iter):
    """Solve A x = b (A symmetric positive definite, block-CSR) by preconditioned CG.

    `x` holds the initial guess and is overwritten with the solution. Returns
    (iterations, relative residual |b - A x| / |b|).
    """
    inv = _block_jacobi(indptr, diag, data)
    n = b.shape[0]
    r = np.empty((n, 3))
    bsr_matvec(indptr, indices, data, x, r)
    for i in range(n):
        for a in range(3):
            r[i, a] = b[i, a] - r[i, a]
    bnorm = np.sqrt(_dot(b, b))
    if bnorm == 0.0:
        for i in range(n):
            for a in range(3):
                x[i, a] = 0.0
        return 0, 0.0
    z = np.empty((n, 3))
    _apply_precond(inv, r, z)
    p = z.copy()
    q = np.empty((n, 3))
    rz = _dot(r, z)
    rnorm = np.sqrt(_dot(r, r))
    it = 0
    while it < max_iter and rnorm > tol * bnorm:
        bsr_matvec(indptr, indices, data, p, q)
        pq = _dot(p, q)
        if pq <= 0.0:  # loss of positive definiteness: stop with the best iterate so far
            break
        alpha = rz / pq
        for i in range(n):
            for a in range(3):
                x[i, a] += alpha * p[i, a]
                r[i, a] -= alpha * q[i, a]
        _apply_precond(inv, r, z)
        rz_new = _dot(r, z)
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            for a in range(3):
                p[i, a] = z[i, a] + beta * p[i, a]
        rnorm = np.sqrt(_dot(r, r))
        it += 1
    return it, rnorm / bnorm


def solve_capped(options: SolverOptions, iterations: int, residual: float) -> bool:
    """True for an iterative solve that stopped at its iteration cap with its residual still above
    the tolerance: an inexact step, which the frame's record counts (solves_capped)."""
    return options.method == "pcg" and iterations >= options.max_iterations and residual > options.tolerance


def solve(pattern: SparsityPattern, data: np.ndarray, b: np.ndarray, options: SolverOptions,
          x0: np.ndarray | None = None) -> tuple[np.ndarray, int, float]:
    """Solve the block system; returns (x (n,3), iterations, relative residual)."""
    if options.method == "direct":
        A = pattern.to_scipy(data)
        x = spla.spsolve(A.tocsc(), b.reshape(-1)).reshape(-1, 3)
        r = b.reshape(-1) - A @ x.reshape(-1)
        bn = np.linalg.norm(b)
        return x, 1, float(np.linalg.norm(r) / bn) if bn > 0 else 0.0
    x = np.zeros_like(b) if x0 is None else x0.copy()
    it, res = pcg(pattern.indptr, pattern.indices, pattern.diag, data, b, x,
                  options.tolerance, options.max_iterations)
    return x, int(it), float(res)
