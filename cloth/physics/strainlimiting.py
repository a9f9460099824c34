"""Strain limiting: keep the principal stretches of every face within [s_min, s_max].

ARCSim (Narain et al. 2012; src/strainlimiting.cpp, src/auglag.cpp, src/simulation.cpp) limits
strain after the implicit step and before collisions. It moves the nodes as little as possible
in the mass-weighted sense,

    min_y  1/2 sum_a w_a |y_a - x_a|^2,   w_a = m_a mean(1/m)                              (1)
    s.t.   c+_fj = sqrt(A_f) (sigma_fj(y) - s_max) <= 0,  c-_fj = sqrt(A_f) (sigma_fj(y) - s_min) >= 0,

with sigma_f1 >= sigma_f2 the singular values of face f's 3x2 deformation gradient F and A_f
its rest area (handles are equality constraints: pinned nodes stay), then adds the displacement
to the velocities, v += (y - x) / h. It solves (1) by the augmented-Lagrangian method: with
multipliers lambda (lambda+ >= 0, lambda- <= 0) and penalty mu it minimises

    L(y) = 1/2 sum_a w_a |y_a - x_a|^2
           + mu/2 sum_fj ( max(c+_fj + lambda+_fj / mu, 0)^2 + min(c-_fj + lambda-_fj / mu, 0)^2 )   (2)

(nonlinear conjugate gradients, mu = 1e3) and updates lambda <- clamp(lambda + mu c) in turn.

Here (2) is minimised by Newton steps instead (ARCSim's method with a second-order inner
solver), each a sparse solve (a factorisation: the matrix is ill-conditioned as mu grows) of

    (W + mu sum_fj [ grad c grad c^T + z sqrt(A_f) H+(sigma_fj) ]) dy = -grad L,             (3)

z = the clamped term of (2), with, for F = U diag(sigma) V^T (u_3 = u_1 x u_2 the normal),
P = U^T dF V, grad sigma_j . dx = P_jj, dF = sum_a dx_a g_a^T (g_a as in cloth.physics.membrane),
and the second derivatives of the singular values (differentiating the SVD; s1, s2 = sigma_1, sigma_2)

    d2 sigma_1 = P_31^2 / sigma_1 + (P_12 + P_21)^2 / (2 (s1 - s2)) + (P_12 - P_21)^2 / (2 (s1 + s2))
    d2 sigma_2 = P_32^2 / sigma_2 - (P_12 + P_21)^2 / (2 (s1 - s2)) + (P_12 - P_21)^2 / (2 (s1 + s2))

H+ keeps the terms whose product with z is >= 0 (the gap sigma_1 - sigma_2 floored at
SINGULAR_GAP), so the matrix is positive definite on the free nodes and exact where only
sigma_1 <= s_max binds. The out-of-plane term P_3j^2 / sigma_j matters: without it a stretched,
nearly flat sheet has no curvature against moving out of its plane, and the steps overshoot.
A bound inactive but within ACTIVE_BAND of its limit keeps its grad c grad c^T in (3): without
it, a face that the last step brought just inside its limit had no say in the next step, which
undid the last. A backtracking line search on L accepts each step; INNER_STEPS steps per
multiplier update. mu starts at ARCSim's MU_START and grows by MU_GROWTH (to at most MU_MAX)
whenever an update fails to cut the largest violation by VIOLATION_DECREASE. The iteration
stops as soon as every face is within its limits up to STRAIN_TOLERANCE,

    violation_f = max(sigma_f1 - s_max, s_min - sigma_f2, 0)   (a stretch, dimensionless),

or after MAX_OUTER updates, or STALL_UPDATES updates in a row that found no smaller largest
violation; the nodes then take the iterate with the smallest one, and that violation is the
stage's record. (ARCSim stops after a fixed budget of 100 conjugate-gradient iterations and keeps
the last iterate.) Lower limits can stall: a flat face compressed below s_min can gain stretch by
buckling out of its plane only at second order, a direction no descent method sees from flat
(nor does ARCSim's). A face whose
lower stretch has collapsed (sigma_2 < COLLAPSED_STRETCH: its second singular vector is
undefined) has no lower constraint on it. Faces that pinned nodes alone over-stretch (two
handles further apart than s_max allows) cannot be satisfied and stay in the record, as in
ARCSim, whose handle constraints conflict the same way.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cloth.core.mesh import Mesh
from cloth.physics.assembly import SparsityPattern, apply_dirichlet, scatter_blocks, scatter_forces
from cloth.physics.linsolve import SolverOptions, cholesky_available, solve

# The iteration stops once no face is beyond its limits by more than this (a principal stretch,
# i.e. 0.1 % strain: a fiftieth of ARCSim's usual band of 5 %).
STRAIN_TOLERANCE = 1e-3
# ARCSim's penalty of the augmented Lagrangian (dimensionless: the objective and the squared
# constraints are both m^2), its growth when a multiplier update does too little, and its cap.
MU_START = 1e3
MU_GROWTH = 4.0
MU_MAX = 1e7
# A multiplier update that leaves more than this fraction of the largest violation grows mu.
VIOLATION_DECREASE = 0.25
# Newton steps per multiplier update, multiplier updates allowed per stage, and updates in a row
# without a new smallest violation after which the stage gives up (and keeps its best iterate).
INNER_STEPS = 3
MAX_OUTER = 30
STALL_UPDATES = 4
# A bound within this stretch of being active keeps its Gauss-Newton term mu grad c grad c^T in
# the step's matrix (not in L itself): otherwise a face that the last step brought just inside
# its limit has no say in the model, whose step then undoes the last one (the line search would
# cut it to nothing).
ACTIVE_BAND = 0.01
# The gap sigma_1 - sigma_2 below which the curvature of the singular values across it is
# capped (it grows as 1 / gap: sigma_1 = sigma_2 is a kink).
SINGULAR_GAP = 1e-3
# Backtracking line search: sufficient decrease (Armijo) and halvings allowed.
ARMIJO = 1e-4
LINE_SEARCH_HALVINGS = 12
# The Gauss-Newton systems: a factorisation (positive definite, but ill-conditioned as mu grows,
# where block-Jacobi CG would crawl), to this relative residual.
SOLVE_TOLERANCE = 1e-9
# A principal stretch below this is a collapsed direction: its singular vector is undefined, so
# the face's lower limit is left alone (the next step's elasticity restores it).
COLLAPSED_STRETCH = 1e-8


@njit(cache=True)
def principal_stretches(F):
    """(sigma_1 >= sigma_2, V (2, 2)): singular values and right singular vectors of F (3, 2),
    from the eigen-decomposition of C = F^T F (columns of V: the eigenvectors)."""
    c00 = F[0, 0] * F[0, 0] + F[1, 0] * F[1, 0] + F[2, 0] * F[2, 0]
    c01 = F[0, 0] * F[0, 1] + F[1, 0] * F[1, 1] + F[2, 0] * F[2, 1]
    c11 = F[0, 1] * F[0, 1] + F[1, 1] * F[1, 1] + F[2, 1] * F[2, 1]
    m = 0.5 * (c00 + c11)
    r = math.sqrt(0.25 * (c00 - c11) * (c00 - c11) + c01 * c01)
    l1, l2 = m + r, max(m - r, 0.0)
    V = np.empty((2, 2))
    if r == 0.0:
        V[0, 0], V[1, 0] = 1.0, 0.0
    elif c00 >= c11:
        V[0, 0], V[1, 0] = c00 - l2, c01
    else:
        V[0, 0], V[1, 0] = c01, c11 - l2
    n = math.sqrt(V[0, 0] * V[0, 0] + V[1, 0] * V[1, 0])
    V[0, 0] /= n
    V[1, 0] /= n
    V[0, 1], V[1, 1] = -V[1, 0], V[0, 0]
    return math.sqrt(l1), math.sqrt(l2), V


@njit(cache=True)
def _face_F(node_x, i0, i1, i2, B):
    F = np.empty((3, 2))
    for i in range(3):
        d1 = node_x[i1, i] - node_x[i0, i]
        d2 = node_x[i2, i] - node_x[i0, i]
        F[i, 0] = d1 * B[0, 0] + d2 * B[1, 0]
        F[i, 1] = d1 * B[0, 1] + d2 * B[1, 1]
    return F


@njit(cache=True)
def face_violation(node_x, face_nodes, face_Dm_inv, s_min, s_max, out):
    """(F,) max(sigma_1 - s_max, s_min - sigma_2, 0) of every face now (into out); returns the max."""
    worst = 0.0
    for f in range(face_nodes.shape[0]):
        F = _face_F(node_x, face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2], face_Dm_inv[f])
        s1, s2, _ = principal_stretches(F)
        v = max(s1 - s_max, s_min - s2, 0.0)
        out[f] = v
        worst = max(worst, v)
    return worst



@njit(cache=True)
def strain_penalty_elements(node_x, face_nodes, face_Dm_inv, face_area, s_min, s_max, face_lambda, mu,
                            out_value, out_grad, out_hess):
    """The penalty of (2) per face (F,), its gradient (F, 9) and Gauss-Newton Hessian (F, 9, 9)
    (each face writes its own slot; m^2, m, dimensionless). `face_lambda` (F, 4): multipliers of
    (sigma_1 <= s_max, sigma_2 <= s_max, sigma_1 >= s_min, sigma_2 >= s_min), m."""
    for f in range(face_nodes.shape[0]):
        B = face_Dm_inv[f]
        F = _face_F(node_x, face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2], B)
        s1, s2, V = principal_stretches(F)
        w = math.sqrt(face_area[f])
        out_value[f] = 0.0
        for r in range(9):
            out_grad[f, r] = 0.0
            for c in range(9):
                out_hess[f, r, c] = 0.0
        g = np.empty((3, 2))
        g[1, 0], g[1, 1] = B[0, 0], B[0, 1]
        g[2, 0], g[2, 1] = B[1, 0], B[1, 1]
        g[0, 0], g[0, 1] = -g[1, 0] - g[2, 0], -g[1, 1] - g[2, 1]
        ds = np.empty(9)
        p3 = np.empty(9)
        pa = np.empty(9)
        pb = np.empty(9)
        # left singular vectors u_1, u_2 = F v_j / sigma_j and the normal u_3 = u_1 x u_2
        U = np.zeros((3, 3))
        for j in range(2):
            sj = s1 if j == 0 else s2
            if sj >= COLLAPSED_STRETCH:
                for i in range(3):
                    U[i, j] = (F[i, 0] * V[0, j] + F[i, 1] * V[1, j]) / sj
        U[0, 2] = U[1, 0] * U[2, 1] - U[2, 0] * U[1, 1]
        U[1, 2] = U[2, 0] * U[0, 1] - U[0, 0] * U[2, 1]
        U[2, 2] = U[0, 0] * U[1, 1] - U[1, 0] * U[0, 1]
        for k in range(4):
            j = k % 2
            sj = s1 if j == 0 else s2
            if k < 2:  # upper bound, lambda >= 0
                zr = w * (sj - s_max) + face_lambda[f, k] / mu
                z = max(zr, 0.0)
                near = zr > -ACTIVE_BAND * w
            else:  # lower bound, lambda <= 0
                if sj < COLLAPSED_STRETCH:
                    continue
                zr = w * (sj - s_min) + face_lambda[f, k] / mu
                z = min(zr, 0.0)
                near = zr < ACTIVE_BAND * w
            if not near:
                continue
            # d sigma_j / d x_a = u_j (g_a . v_j), u_j = F v_j / sigma_j
            for a in range(3):
                gv = g[a, 0] * V[0, j] + g[a, 1] * V[1, j]
                for i in range(3):
                    ds[3 * a + i] = w * U[i, j] * gv
            out_value[f] += 0.5 * mu * z * z
            for r in range(9):
                out_grad[f, r] += mu * z * ds[r]
                for c in range(9):
                    out_hess[f, r, c] += mu * ds[r] * ds[c]
            if z == 0.0 or s2 < COLLAPSED_STRETCH:
                continue
            # mu z w Hess sigma_j, its positive semi-definite part (module docstring, eq 3)
            for a in range(3):
                ga0 = g[a, 0] * V[0, 0] + g[a, 1] * V[1, 0]
                ga1 = g[a, 0] * V[0, 1] + g[a, 1] * V[1, 1]
                for i in range(3):
                    p3[3 * a + i] = U[i, 2] * (ga0 if j == 0 else ga1)
                    pa[3 * a + i] = U[i, 0] * ga1 + U[i, 1] * ga0
                    pb[3 * a + i] = U[i, 0] * ga1 - U[i, 1] * ga0
            c3 = cb = ca = 0.0
            spread = 2.0 * max(s1 - s2, SINGULAR_GAP)
            if z > 0.0:  # mu z w > 0 times the convex terms of Hess sigma_j
                c3 = mu * z * w / sj
                cb = mu * z * w / (2.0 * (s1 + s2))
                if j == 0:
                    ca = mu * z * w / spread
            elif j == 1:  # mu z w < 0 times the concave term of Hess sigma_2
                ca = -mu * z * w / spread
            for r in range(9):
                for c in range(9):
                    out_hess[f, r, c] += c3 * p3[r] * p3[c] + cb * pb[r] * pb[c] + ca * pa[r] * pa[c]


@njit(cache=True)
def update_multipliers(node_x, face_nodes, face_Dm_inv, face_area, s_min, s_max, face_lambda, mu):
    """lambda <- clamp(lambda + mu c): max(., 0) for the upper bounds, min(., 0) for the lower."""
    for f in range(face_nodes.shape[0]):
        F = _face_F(node_x, face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2], face_Dm_inv[f])
        s1, s2, _ = principal_stretches(F)
        w = math.sqrt(face_area[f])
        for k in range(4):
            sj = s1 if k % 2 == 0 else s2
            if k < 2:
                face_lambda[f, k] = max(face_lambda[f, k] + mu * w * (sj - s_max), 0.0)
            else:
                collapsed = sj < COLLAPSED_STRETCH
                face_lambda[f, k] = 0.0 if collapsed else min(face_lambda[f, k] + mu * w * (sj - s_min), 0.0)


def solver_options() -> SolverOptions:
    """The Newton systems' solver: PARDISO's Cholesky where it loads, SuperLU otherwise (measured
    on a 12 x 12 sheet's 14 steps: 11 ms against SuperLU's 33 ms and block-Jacobi CG's 30 ms)."""
    return SolverOptions(method="cholesky" if cholesky_available() is None else "direct", tolerance=SOLVE_TOLERANCE)


def _objective(y, x, weight, mesh, s_min, s_max, lam, mu, value, grad, hess):
    """L(y) of (2); fills the per-face penalty arrays (value, grad, hess)."""
    strain_penalty_elements(y, mesh.face_nodes, mesh.face_Dm_inv, mesh.face_area, s_min, s_max, lam, mu,
                            value, grad, hess)
    d = y - x
    return 0.5 * float(np.sum(weight[:, None] * d * d)) + float(value.sum())


def limit_strain(mesh: Mesh, pattern: SparsityPattern, s_min: float, s_max: float,
                 tolerance: float = STRAIN_TOLERANCE, solver: SolverOptions | None = None) -> dict:
    """Move the free nodes of `mesh` (mesh.node_x, in place) so that every face's principal
    stretches lie in [s_min, s_max] up to `tolerance` (module docstring). `pattern` must hold the
    "faces" family (the simulation's does); `solver` defaults to :func:`solver_options`.
    Returns {'strain_limit_iterations': Newton steps, 'strain_violation_max': the largest
    violation left}; a mesh already within its limits is left untouched (0 steps)."""
    n_faces = mesh.n_faces
    violation = np.empty(n_faces)
    worst = face_violation(mesh.node_x, mesh.face_nodes, mesh.face_Dm_inv, s_min, s_max, violation)
    out = {"strain_limit_iterations": 0, "strain_violation_max": worst}
    free = ~mesh.node_pinned
    if worst <= tolerance or not free.any():
        return out
    solver = solver or solver_options()
    x = mesh.node_x.copy()
    y = x.copy()
    weight = mesh.node_m * float(np.mean(1.0 / mesh.node_m))  # ARCSim's normalised masses
    lam = np.zeros((n_faces, 4))
    mu = MU_START
    value, grad, hess = np.empty(n_faces), np.empty((n_faces, 9)), np.empty((n_faces, 9, 9))
    slots = pattern.slots["faces"]
    zero = np.zeros_like(x)
    steps = 0
    best_y, best = y, worst  # the iterate with the smallest largest violation so far
    current = previous = worst
    stalled = 0
    for _ in range(MAX_OUTER):
        improved = False
        for _ in range(INNER_STEPS):
            L = _objective(y, x, weight, mesh, s_min, s_max, lam, mu, value, grad, hess)
            g = weight[:, None] * (y - x)
            scatter_forces(g, mesh.face_nodes, grad, 1.0)
            g[~free] = 0.0
            if not np.any(g):
                break
            A = pattern.zeros()
            A[pattern.diag] += weight[:, None, None] * np.eye(3)
            scatter_blocks(A, slots, hess, 1.0)
            rhs = -g
            apply_dirichlet(pattern.indptr, pattern.indices, A, rhs, mesh.node_pinned, zero)
            dy, _, _ = solve(pattern, A, rhs, solver)
            slope = float(np.sum(g * dy))
            if not slope < 0.0:
                break
            step = 1.0
            for _ in range(LINE_SEARCH_HALVINGS):
                y_new = y + step * dy
                L_new = _objective(y_new, x, weight, mesh, s_min, s_max, lam, mu, value, grad, hess)
                if L_new <= L + ARMIJO * step * slope:
                    break
                step *= 0.5
            else:
                break
            y = y_new  # a new array: best_y may keep the old one
            steps += 1
            current = face_violation(y, mesh.face_nodes, mesh.face_Dm_inv, s_min, s_max, violation)
            if current < best:
                best_y, best, improved = y, current, True
            if current <= tolerance:
                break
        if best <= tolerance:
            break
        stalled = 0 if improved else stalled + 1
        if stalled >= STALL_UPDATES:
            break
        update_multipliers(y, mesh.face_nodes, mesh.face_Dm_inv, mesh.face_area, s_min, s_max, lam, mu)
        if current > VIOLATION_DECREASE * previous:
            mu = min(mu * MU_GROWTH, MU_MAX)
        previous = current
    mesh.node_x[free] = best_y[free]
    out.update(strain_limit_iterations=steps, strain_violation_max=best)
    return out
