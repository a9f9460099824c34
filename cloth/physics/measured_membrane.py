"""Membrane of a measured material: ARCSim's anisotropic, strain-dependent stretching energy
(src/physics.cpp, ``stretching_force``), with the paper's buckling compensation (eq 10).

For a face of rest area A with deformation gradient F (cloth.physics.membrane.deformation_gradient)
and Green strain E = 1/2 (F^T F - I) (eq 9), written e = (E00, E11, E01),

    W = A psi(e^),   psi(e^) = 1/2 (k0 e^_0^2 + 2 k1 e^_0 e^_1 + k2 e^_1^2 + 2 k3 e^_2^2),

with k = (k0, k1, k2, k3) in N/m the material's stiffness at the strain e^
(cloth.physics.dde.stretching_stiffness) and e^ the compensated strain below (e^ = e without
compensation, as in ARCSim; with it, the material sees e^ in place of e in its stiffness as in
its energy: a face whose compression is compensated away is as stiff as an unstrained one).

The factor 2 on k3 makes this the potential of ARCSim's force (its ``stretching_force`` has
2 k3 G01 grad G01); ARCSim's ``stretching_energy``, used only for its diagnostics, writes
k3 G01^2 and so disagrees with its own force on shear.

Stiffness held fixed within a step. ARCSim evaluates k at the step's start and differentiates
W with k held constant: the force is f = -dW/dx |_k and its Jacobian ignores dk/dx. So the
force is not the gradient of one fixed energy (the energy W(x, k(x)) has another gradient
wherever k varies with the strain); it is the gradient of the quadratic energy of the step's
stiffness, and the step is an implicit step of that energy. The Hessian below is that energy's
exact Hessian, made positive semi-definite where it is not.

Buckling compensation (eq 10) in matrix form: with g(l) = l for l >= 0, alpha l for l < 0 on
the eigenvalues l of E, E^ = Q g(L) Q^T = b E + c |E|, b = (1 + alpha) / 2, c = (1 - alpha) / 2,
|E| the matrix absolute value. In the coordinates m = (E00 + E11)/2, p = (E00 - E11)/2, q = E01,
r = sqrt(p^2 + q^2) (eigenvalues m +- r), |E| is E where both eigenvalues are >= 0, -E where both
are < 0, and in between (l1 = m + r >= 0 > l2 = m - r, so r > 0)

    |E| = r I + (m / r) P,    P = [[p, q], [q, -p]],
    i.e. a(e) = (r + m s, r - m s, m t),   s = p / r, t = q / r.

With J = de/dx (3 x 9; rows grad E00, grad E11, grad E01), Phi = de^/de (3 x 3),
psi' = dpsi/de^ = (k0 e^_0 + k1 e^_1, k1 e^_0 + k2 e^_1, 2 k3 e^_2) and C = d2psi/de^2 =
[[k0, k1, 0], [k1, k2, 0], [0, 0, 2 k3]]:

    sigma = Phi^T psi',         S = [[sigma_0, sigma_2 / 2], [sigma_2 / 2, sigma_1]],
    dW/dx_a = A F S g_a,
    d2W/dx2 = A ( J^T M J + (g_a^T S g_b) I_3 ),   M = Phi^T C Phi + sum_c psi'_c d2e^_c/de2,

(g_a as in cloth.physics.membrane). Phi = I, alpha I, or b I + c da/de, and d2e^_c/de2 = c
d2a_c/de2 in the mixed case, 0 otherwise (derivatives of a in :func:`abs_strain_derivatives`).
The Hessian is positive semi-definite when S and M are (the second term is S's Gram matrix
times I_3, the first a congruence of M); otherwise it is projected (cloth.physics.membrane.
project_psd, with absolute values where E is strongly compressed, as the isotropic membrane).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from cloth.physics.dde import stretching_stiffness
from cloth.physics.membrane import ABSOLUTE_STRAIN, deformation_gradient, green_strain, project_psd_face_planar


@njit(cache=True)
def abs_strain_derivatives(m, p, q, da, d2a):
    """a = |E| in the mixed case (r = sqrt(p^2 + q^2) > 0), its Jacobian da (3, 3) and Hessians
    d2a (3, 3, 3), all with respect to (m, p, q); returns a (3,) = (|E|00, |E|11, |E|01).

    With s = p/r, t = q/r: grad r = (0, s, t), grad (m s) = (s, t^2 m/r, -s t m/r),
    grad (m t) = (t, -s t m/r, s^2 m/r); Hess r = [[0, 0, 0], [0, t^2, -s t], [0, -s t, s^2]] / r,
    Hess (m s) = [[0, t^2/r, -s t/r], [., -3 m s t^2/r^2, m t (2 s^2 - t^2)/r^2], [., ., m s (2 t^2 - s^2)/r^2]],
    Hess (m t) = [[0, -s t/r, s^2/r], [., m t (2 s^2 - t^2)/r^2, m s (2 t^2 - s^2)/r^2], [., ., -3 m s^2 t/r^2]].
    """
    r = math.sqrt(p * p + q * q)
    s, t = p / r, q / r
    ir, ir2 = 1.0 / r, 1.0 / (r * r)
    a = np.empty(3)
    a[0] = r + m * s
    a[1] = r - m * s
    a[2] = m * t
    # gradients of r, m s, m t over (m, p, q)
    gr = (0.0, s, t)
    gms = (s, m * t * t * ir, -m * s * t * ir)
    gmt = (t, -m * s * t * ir, m * s * s * ir)
    for j in range(3):
        da[0, j] = gr[j] + gms[j]
        da[1, j] = gr[j] - gms[j]
        da[2, j] = gmt[j]
    Hr = np.zeros((3, 3))
    Hr[1, 1], Hr[1, 2], Hr[2, 2] = t * t * ir, -s * t * ir, s * s * ir
    Hms = np.zeros((3, 3))
    Hms[0, 1], Hms[0, 2] = t * t * ir, -s * t * ir
    Hms[1, 1] = -3.0 * m * s * t * t * ir2
    Hms[1, 2] = m * t * (2.0 * s * s - t * t) * ir2
    Hms[2, 2] = m * s * (2.0 * t * t - s * s) * ir2
    Hmt = np.zeros((3, 3))
    Hmt[0, 1], Hmt[0, 2] = -s * t * ir, s * s * ir
    Hmt[1, 1] = m * t * (2.0 * s * s - t * t) * ir2
    Hmt[1, 2] = m * s * (2.0 * t * t - s * s) * ir2
    Hmt[2, 2] = -3.0 * m * s * s * t * ir2
    for i in range(3):
        for j in range(i, 3):
            d2a[0, i, j] = d2a[0, j, i] = Hr[i, j] + Hms[i, j]
            d2a[1, i, j] = d2a[1, j, i] = Hr[i, j] - Hms[i, j]
            d2a[2, i, j] = d2a[2, j, i] = Hmt[i, j]
    return a


@njit(cache=True)
def compensated_strain(E00, E01, E11, alpha, Phi, d2e):
    """e^ = (E^00, E^11, E^01) of eq 10 (module docstring), with Phi = de^/de (3, 3) and
    d2e (3, 3, 3) = d2e^_c/de2 written into the arguments; e = (E00, E11, E01)."""
    m = 0.5 * (E00 + E11)
    p = 0.5 * (E00 - E11)
    r = math.sqrt(p * p + E01 * E01)
    e = np.empty(3)
    e[0], e[1], e[2] = E00, E11, E01
    for c in range(3):
        for i in range(3):
            Phi[c, i] = 0.0
            for j in range(3):
                d2e[c, i, j] = 0.0
    if alpha >= 1.0 or m - r >= 0.0:  # no compressed direction, or no compensation
        for c in range(3):
            Phi[c, c] = 1.0
        return e
    if m + r < 0.0:  # both directions compressed: E^ = alpha E
        for c in range(3):
            Phi[c, c] = alpha
            e[c] *= alpha
        return e
    b, c_ = 0.5 * (1.0 + alpha), 0.5 * (1.0 - alpha)
    da = np.empty((3, 3))
    d2a = np.empty((3, 3, 3))
    a = abs_strain_derivatives(m, p, E01, da, d2a)
    # (m, p, q) = L e with L = [[1/2, 1/2, 0], [1/2, -1/2, 0], [0, 0, 1]]
    L = np.zeros((3, 3))
    L[0, 0] = L[0, 1] = L[1, 0] = 0.5
    L[1, 1] = -0.5
    L[2, 2] = 1.0
    for c in range(3):
        e[c] = b * e[c] + c_ * a[c]
        for j in range(3):
            s = 0.0
            for k in range(3):
                s += da[c, k] * L[k, j]
            Phi[c, j] = c_ * s + (b if c == j else 0.0)
        for i in range(3):
            for j in range(3):
                s = 0.0
                for k in range(3):
                    for l in range(3):
                        s += L[k, i] * d2a[c, k, l] * L[l, j]
                d2e[c, i, j] = c_ * s
    return e


@njit(cache=True)
def _psd3(M):
    """True if the symmetric 3x3 M is positive semi-definite (all principal minors >= 0)."""
    if M[0, 0] < 0.0 or M[1, 1] < 0.0 or M[2, 2] < 0.0:
        return False
    if (M[0, 0] * M[1, 1] - M[0, 1] * M[0, 1] < 0.0 or M[0, 0] * M[2, 2] - M[0, 2] * M[0, 2] < 0.0
            or M[1, 1] * M[2, 2] - M[1, 2] * M[1, 2] < 0.0):
        return False
    det = (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[1, 2]) - M[0, 1] * (M[0, 1] * M[2, 2] - M[1, 2] * M[0, 2])
           + M[0, 2] * (M[0, 1] * M[1, 2] - M[1, 1] * M[0, 2]))
    return det >= 0.0


@njit(cache=True)
def measured_element_into(x0, x1, x2, Dm_inv, area, samples, alpha, project, grad, hess, k, lookup=True):
    """Energy of one face (module docstring); writes the gradient (9,) and the Hessian (9, 9),
    returns the energy (J).

    `samples` (30, 30, 30, 4) N/m is the material's table; `alpha` in [0, 1] the face's
    compression factor (1: no compensation); `project`: make the Hessian positive semi-definite.
    `k` (4,) N/m: with `lookup`, the stiffness at the face's strain is written into it (ARCSim);
    without, it is read as given (the energy at a fixed stiffness, for tests).
    """
    F = deformation_gradient(x0, x1, x2, Dm_inv)
    E = green_strain(F)
    Phi = np.empty((3, 3))
    d2e = np.empty((3, 3, 3))
    eh = compensated_strain(E[0, 0], E[0, 1], E[1, 1], alpha, Phi, d2e)
    if lookup:
        stretching_stiffness(eh[0], eh[2], eh[1], samples, k)
    k0, k1, k2, k3 = k[0], k[1], k[2], k[3]
    energy = 0.5 * area * (k0 * eh[0] * eh[0] + 2.0 * k1 * eh[0] * eh[1] + k2 * eh[1] * eh[1]
                           + 2.0 * k3 * eh[2] * eh[2])
    dpsi = np.empty(3)
    dpsi[0] = k0 * eh[0] + k1 * eh[1]
    dpsi[1] = k1 * eh[0] + k2 * eh[1]
    dpsi[2] = 2.0 * k3 * eh[2]
    C = np.zeros((3, 3))
    C[0, 0], C[0, 1], C[1, 0], C[1, 1], C[2, 2] = k0, k1, k1, k2, 2.0 * k3
    sigma = np.zeros(3)
    for d in range(3):
        for c in range(3):
            sigma[d] += Phi[c, d] * dpsi[c]
    CPhi = C @ Phi
    M = Phi.T @ CPhi
    for c in range(3):
        for i in range(3):
            for j in range(3):
                M[i, j] += dpsi[c] * d2e[c, i, j]
    S00, S11, S01 = sigma[0], sigma[1], 0.5 * sigma[2]
    g = np.empty((3, 2))
    g[1, 0], g[1, 1] = Dm_inv[0, 0], Dm_inv[0, 1]
    g[2, 0], g[2, 1] = Dm_inv[1, 0], Dm_inv[1, 1]
    g[0, 0], g[0, 1] = -g[1, 0] - g[2, 0], -g[1, 1] - g[2, 1]
    J = np.empty((3, 9))  # rows: grad E00, grad E11, grad E01
    for a in range(3):
        for i in range(3):
            J[0, 3 * a + i] = g[a, 0] * F[i, 0]
            J[1, 3 * a + i] = g[a, 1] * F[i, 1]
            J[2, 3 * a + i] = 0.5 * (g[a, 0] * F[i, 1] + g[a, 1] * F[i, 0])
    for r in range(9):
        grad[r] = area * (sigma[0] * J[0, r] + sigma[1] * J[1, r] + sigma[2] * J[2, r])
    MJ = M @ J
    for a in range(3):
        for b in range(3):
            gSg = (g[a, 0] * (S00 * g[b, 0] + S01 * g[b, 1]) + g[a, 1] * (S01 * g[b, 0] + S11 * g[b, 1]))
            for i in range(3):
                for j in range(3):
                    r, c = 3 * a + i, 3 * b + j
                    h = J[0, r] * MJ[0, c] + J[1, r] * MJ[1, c] + J[2, r] * MJ[2, c]
                    if i == j:
                        h += gSg
                    hess[r, c] = area * h
    for r in range(9):  # exactly symmetric, as the element Hessians are assembled
        for c in range(r + 1, 9):
            v = 0.5 * (hess[r, c] + hess[c, r])
            hess[r, c] = v
            hess[c, r] = v
    if project and not (S00 + S11 >= 0.0 and S00 * S11 - S01 * S01 >= 0.0 and _psd3(M)):
        m_, p_ = 0.5 * (E[0, 0] + E[1, 1]), 0.5 * (E[0, 0] - E[1, 1])
        project_psd_face_planar(hess, g, F, m_ - math.sqrt(p_ * p_ + E[0, 1] * E[0, 1]) < ABSOLUTE_STRAIN)
    return energy


@njit(cache=True)
def measured_element(x0, x1, x2, Dm_inv, area, samples, alpha, project, k, lookup=True):
    """(energy, gradient (9,), Hessian (9, 9)) of one face; `k` (4,) as measured_element_into."""
    grad = np.empty(9)
    hess = np.empty((9, 9))
    energy = measured_element_into(x0, x1, x2, Dm_inv, area, samples, alpha, project, grad, hess, k, lookup)
    return energy, grad, hess


@njit(cache=True, parallel=True)
def measured_membrane_elements(node_x, face_nodes, face_Dm_inv, face_area, samples, project, out_energy, out_grad,
                               out_hess, face_alpha, out_k):
    """Energy (F,), gradient (F, 9), Hessian (F, 9, 9) and stiffness (F, 4) of every face (each
    writes its own slot); `face_alpha` (F,) the compression factors (1: none)."""
    for f in prange(face_nodes.shape[0]):
        out_energy[f] = measured_element_into(
            node_x[face_nodes[f, 0]], node_x[face_nodes[f, 1]], node_x[face_nodes[f, 2]], face_Dm_inv[f],
            face_area[f], samples, face_alpha[f], project, out_grad[f], out_hess[f], out_k[f])


@njit(cache=True)
def measured_compressive_energy(node_x, face_nodes, face_Dm_inv, face_area, samples, faces):
    """J: the energy of the compressive part E- = (E - |E|)/2 of each face's Green strain, sum
    over `faces`, with the stiffness at the face's strain: what buckling compensation removes
    (the measured counterpart of cloth.physics.buckling.compressive_energy)."""
    total = 0.0
    k = np.empty(4)
    Phi = np.empty((3, 3))
    d2e = np.empty((3, 3, 3))
    for n in range(faces.shape[0]):
        f = faces[n]
        F = deformation_gradient(node_x[face_nodes[f, 0]], node_x[face_nodes[f, 1]], node_x[face_nodes[f, 2]],
                                 face_Dm_inv[f])
        E = green_strain(F)
        stretching_stiffness(E[0, 0], E[0, 1], E[1, 1], samples, k)
        ep = compensated_strain(E[0, 0], E[0, 1], E[1, 1], 0.0, Phi, d2e)  # E+ (alpha = 0 drops E-)
        e0, e1, e2 = E[0, 0] - ep[0], E[1, 1] - ep[1], E[0, 1] - ep[2]
        total += 0.5 * face_area[f] * (k[0] * e0 * e0 + 2.0 * k[1] * e0 * e1 + k[2] * e1 * e1 + 2.0 * k[3] * e2 * e2)
    return total
