"""Linearised implicit (backward) Euler, one solve per step (Baraff and Witkin 1998).

With stiffness K = -df/dx and velocity Jacobian D = -df/dv (drag) plus Rayleigh damping
(alpha M + beta K), one step of length h solves

    (M (1 + h alpha) + h (D + beta K) + h^2 K) dv = h (f - alpha M v - beta K v - h K v)

for the velocity change dv, then v <- v + dv and x <- x + h v. Nodes whose position is
prescribed (pins and handles) get the dv that lands them exactly on their target; their
columns move to the right-hand side so the matrix stays symmetric positive definite.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from .assembly import SparsityPattern, apply_dirichlet, bsr_matvec
from .forces import ForceAccumulator, ForceTerm
from .linsolve import SolverOptions, solve
from .mesh import Mesh


@dataclass
class StepStats:
    iterations: int
    residual: float
    time_physics_s: float  # force and Jacobian evaluation and assembly
    time_solve_s: float  # linear solve
    energy: dict  # J, potential energy per term at the start of the step


@njit(cache=True)
def compose_system(indptr, diag, K, D, node_m, h, alpha, beta, out):
    """out = (h beta + h^2) K + h D, plus m (1 + h alpha) I on the diagonal blocks."""
    ck = h * beta + h * h
    for k in range(K.shape[0]):
        for a in range(3):
            for b in range(3):
                out[k, a, b] = ck * K[k, a, b] + h * D[k, a, b]
    for i in range(diag.shape[0]):
        mi = node_m[i] * (1.0 + h * alpha)
        for a in range(3):
            out[diag[i], a, a] += mi


def implicit_euler_step(
    mesh: Mesh,
    terms: list[ForceTerm],
    pattern: SparsityPattern,
    h: float,
    t: float,
    damping_mass: float,
    damping_stiffness: float,
    fixed_targets: np.ndarray | None,
    options: SolverOptions,
    dv_guess: np.ndarray | None = None,
) -> tuple[StepStats, np.ndarray]:
    """Advance `mesh.node_x`, `mesh.node_v` by one step of length `h` (modifies `mesh` in place).

    `fixed_targets` is (n_nodes, 3) with the positions at t + h of the pinned nodes
    (`mesh.node_pinned`); None when no node is pinned. `dv_guess` warm-starts the iterative
    solver (the previous step's dv: velocity changes vary smoothly in time). Returns the step's
    statistics and dv.
    """
    t0 = time.perf_counter()
    acc = ForceAccumulator.zeros(mesh.n_nodes, pattern)
    for term in terms:
        term.accumulate(mesh, t, acc)
    v = mesh.node_v
    Kv = np.empty_like(v)
    bsr_matvec(pattern.indptr, pattern.indices, acc.K, v, Kv)
    rhs = h * (acc.force - damping_mass * mesh.node_m[:, None] * v - (damping_stiffness + h) * Kv)
    A = np.empty_like(acc.K)
    compose_system(pattern.indptr, pattern.diag, acc.K, acc.D, mesh.node_m, h, damping_mass, damping_stiffness, A)
    pinned = mesh.node_pinned
    any_pinned = bool(pinned.any())
    if any_pinned:
        dv_fixed = np.zeros_like(v)
        dv_fixed[pinned] = (fixed_targets[pinned] - mesh.node_x[pinned]) / h - v[pinned]
        apply_dirichlet(pattern.indptr, pattern.indices, A, rhs, pinned, dv_fixed)
    t1 = time.perf_counter()
    if dv_guess is not None and any_pinned:
        dv_guess = dv_guess.copy()
        dv_guess[pinned] = dv_fixed[pinned]
    dv, iterations, residual = solve(pattern, A, rhs, options, x0=dv_guess)
    t2 = time.perf_counter()
    mesh.node_v += dv
    mesh.node_x += h * mesh.node_v
    if any_pinned:  # land exactly on the targets, free of round-off drift
        mesh.node_x[pinned] = fixed_targets[pinned]
    return StepStats(iterations, residual, t1 - t0, t2 - t1, acc.energy), dv
