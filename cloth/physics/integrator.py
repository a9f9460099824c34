"""Linearised implicit (backward) Euler, one solve per step (Baraff and Witkin 1998).

With stiffness K = -df/dx and velocity Jacobian D = -df/dv (drag) plus Rayleigh damping
(alpha M + beta K), one step of length h solves

    (M (1 + h alpha) + h (D + beta K) + h^2 K) dv = h (f - alpha M v - beta K v - h K v)

for the velocity change dv, then v <- v + dv and x <- x + h v. Nodes whose position is
prescribed (pins and handles) get the dv that lands them exactly on their target; their
columns move to the right-hand side so the matrix stays symmetric positive definite.

Nodes resting on an obstacle (`ContactConstraints`) are constrained in the solve itself:
n . dv = n . (v_obstacle - v), i.e. no approaching normal velocity after the step, imposed
as a stiff term kappa n n^T on the node's diagonal block (kappa = CONSTRAINT_RATIO times
the block's own scale, so the constraint holds to ~1/CONSTRAINT_RATIO whatever the units).
Without it the solve sees a node on the ground as free, and a large internal force on a
light node (a coarse face's corner) sends it through the obstacle; the projection afterwards
restores the position but not the tangential jump. A constraint holds only a node that its
forces push into the obstacle (the right-hand side's normal part), so cloth can lift off.
Its normal impulse, read from the solve's residual, gives Coulomb friction on the node's
tangential velocity relative to the obstacle.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from cloth.core.mesh import Mesh
from cloth.physics.assembly import SparsityPattern, apply_dirichlet, bsr_matvec
from cloth.physics.forces import ForceAccumulator, ForceTerm
from cloth.physics.linsolve import SolverOptions, solve

# kappa / (the diagonal block's scale): the constraint's relative error in n . dv.
CONSTRAINT_RATIO = 1e6


@dataclass
class ContactConstraints:
    """Free nodes in contact with an obstacle at the start of a step."""

    nodes: np.ndarray  # (k,) node indices
    normal: np.ndarray  # (k, 3) unit obstacle normals
    obstacle_velocity: np.ndarray  # (k, 3) velocity of the obstacle surface at the node
    friction: float  # Coulomb coefficient


@njit(cache=True)
def _select_constraints(v, rhs, nodes, normal, obs_v, active, dv_c):
    """Choose the held contact nodes and their constrained velocity change.

    A node is held when its forces push it into its obstacle (rhs . n < 0) and it is not
    already leaving (relative normal velocity rn <= 0). dv_c gets n c with c = -rn: no
    approaching normal velocity after the step.
    """
    for k in range(nodes.shape[0]):
        i = nodes[k]
        n0, n1, n2 = normal[k, 0], normal[k, 1], normal[k, 2]
        push = rhs[i, 0] * n0 + rhs[i, 1] * n1 + rhs[i, 2] * n2
        rn = (v[i, 0] - obs_v[k, 0]) * n0 + (v[i, 1] - obs_v[k, 1]) * n1 + (v[i, 2] - obs_v[k, 2]) * n2
        active[k] = push < 0.0 and rn <= 0.0
        if active[k]:
            for a in range(3):
                dv_c[i, a] = -rn * normal[k, a]


@njit(cache=True)
def _add_constraint_stiffness(diag, A, nodes, normal, active, kappa):
    """kappa n n^T on each held node's diagonal block (kappa relative to the block's scale)."""
    for k in range(nodes.shape[0]):
        if not active[k]:
            continue
        b = diag[nodes[k]]
        kap = CONSTRAINT_RATIO * (A[b, 0, 0] + A[b, 1, 1] + A[b, 2, 2]) / 3.0
        kappa[k] = kap
        for a in range(3):
            for e in range(3):
                A[b, a, e] += kap * normal[k, a] * normal[k, e]


@njit(cache=True)
def _contact_friction(v, dv, node_m, nodes, normal, obs_v, active, kappa, friction):
    """Coulomb friction from each active constraint's normal impulse kappa (n . dv - c).

    Modifies v (after the step's dv) in place; returns the largest normal impulse (N s).
    """
    jmax = 0.0
    for k in range(nodes.shape[0]):
        if not active[k]:
            continue
        i = nodes[k]
        n = normal[k]
        # impulse = kappa * (n . dv - c) with c = n . (obs_v - v_old) = n . (obs_v - v_new + dv)
        rn_new = (v[i, 0] - obs_v[k, 0]) * n[0] + (v[i, 1] - obs_v[k, 1]) * n[1] + (v[i, 2] - obs_v[k, 2]) * n[2]
        j = -kappa[k] * rn_new  # > 0 when the constraint pushed the node out
        if j <= 0.0:
            continue
        jmax = max(jmax, j)
        t0 = v[i, 0] - obs_v[k, 0] - rn_new * n[0]
        t1 = v[i, 1] - obs_v[k, 1] - rn_new * n[1]
        t2 = v[i, 2] - obs_v[k, 2] - rn_new * n[2]
        tn = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        if tn == 0.0:
            continue
        scale = max(0.0, 1.0 - friction * j / (node_m[i] * tn))
        v[i, 0] -= (1.0 - scale) * t0
        v[i, 1] -= (1.0 - scale) * t1
        v[i, 2] -= (1.0 - scale) * t2
    return jmax


@dataclass
class StepStats:
    iterations: int
    residual: float
    time_physics_s: float  # force and Jacobian evaluation and assembly
    time_solve_s: float  # linear solve
    constrained: int  # contact nodes held by a constraint in the solve
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
    contacts: ContactConstraints | None = None,
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
    constrained = 0
    if contacts is not None and contacts.nodes.size:
        # Solve for dv' = dv - dv_c, whose normal part at held nodes kappa n n^T pins to zero.
        # (kappa n c on the right-hand side instead would make |rhs| huge and the solver's
        # relative tolerance meaningless.)
        k = contacts.nodes.size
        active, kappa, dv_c = np.zeros(k, dtype=np.bool_), np.zeros(k), np.zeros_like(v)
        _select_constraints(v, rhs, contacts.nodes, contacts.normal, contacts.obstacle_velocity, active, dv_c)
        constrained = int(active.sum())
    if constrained:
        Adv = np.empty_like(v)
        bsr_matvec(pattern.indptr, pattern.indices, A, dv_c, Adv)
        rhs -= Adv
        _add_constraint_stiffness(pattern.diag, A, contacts.nodes, contacts.normal, active, kappa)
        if dv_guess is not None:
            dv_guess = dv_guess - dv_c
    t1 = time.perf_counter()
    if dv_guess is not None and any_pinned:
        dv_guess = dv_guess.copy()
        dv_guess[pinned] = dv_fixed[pinned]
    dv, iterations, residual = solve(pattern, A, rhs, options, x0=dv_guess)
    t2 = time.perf_counter()
    if constrained:
        dv += dv_c
    mesh.node_v += dv
    if constrained:
        _contact_friction(mesh.node_v, dv, mesh.node_m, contacts.nodes, contacts.normal,
                          contacts.obstacle_velocity, active, kappa, contacts.friction)
    mesh.node_x += h * mesh.node_v
    if any_pinned:  # land exactly on the targets, free of round-off drift
        mesh.node_x[pinned] = fixed_targets[pinned]
    return StepStats(iterations, residual, t1 - t0, t2 - t1, constrained, acc.energy), dv
