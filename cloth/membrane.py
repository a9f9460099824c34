"""StVK membrane elasticity on the Green strain of each triangle (paper eq 9).

For a face with world positions x0, x1, x2 and inverse rest matrix B = Dm^-1 (Dm's columns
are the material edges u1 - u0, u2 - u0), the deformation gradient is

    F = [x1 - x0, x2 - x0] B = sum_a x_a g_a^T      (3x2),
    g_0 = -(B[0] + B[1]),  g_1 = B[0],  g_2 = B[1]  (rows of B),

the Green strain E = 1/2 (F^T F - I) (2x2, :func:`green_strain`, filtered by the buckling
compensation of a later stage), and the StVK energy

    W = A (mu E:E + lam/2 tr(E)^2),     S = 2 mu E + lam tr(E) I  (second Piola-Kirchhoff),

with A the material area and (mu, lam) the 2D Lamé parameters in N/m. Gradient and Hessian:

    dW/dx_a       = A F S g_a
    d2W/dx_a dx_b = A [ (g_a^T S g_b) I + mu (F g_b)(F g_a)^T + mu (g_a.g_b) F F^T + lam (F g_a)(F g_b)^T ].

The last three terms are A (dE/dx)^T C (dE/dx), positive semi-definite; the first is a
Kronecker product of the Gram matrix (g_a^T S g_b) with I, PSD whenever S is. So the Hessian
can be indefinite only under compression (S with a negative eigenvalue), and only then is it
eigen-decomposed and clamped.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


def lame_parameters(youngs_modulus: float, poisson: float) -> tuple[float, float]:
    """2D plane-stress Lamé parameters: mu = Y / (2 (1 + nu)), lam = Y nu / (1 - nu^2), in N/m."""
    return youngs_modulus / (2.0 * (1.0 + poisson)), youngs_modulus * poisson / (1.0 - poisson * poisson)


@njit(cache=True)
def deformation_gradient(x0, x1, x2, Dm_inv):
    """F = [x1 - x0, x2 - x0] Dm^-1, (3, 2)."""
    F = np.empty((3, 2))
    for i in range(3):
        d1 = x1[i] - x0[i]
        d2 = x2[i] - x0[i]
        F[i, 0] = d1 * Dm_inv[0, 0] + d2 * Dm_inv[1, 0]
        F[i, 1] = d1 * Dm_inv[0, 1] + d2 * Dm_inv[1, 1]
    return F


@njit(cache=True)
def green_strain(F):
    """Green strain E = 1/2 (F^T F - I) of a (3, 2) deformation gradient (paper eq 9), (2, 2)."""
    E = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            s = F[0, a] * F[0, b] + F[1, a] * F[1, b] + F[2, a] * F[2, b]
            E[a, b] = 0.5 * (s - (1.0 if a == b else 0.0))
    return E


@njit(cache=True)
def project_psd(H):
    """Clamp the negative eigenvalues of the symmetric matrix H to zero (in place)."""
    w, V = np.linalg.eigh(H)
    n = H.shape[0]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                if w[k] > 0.0:
                    s += V[i, k] * w[k] * V[j, k]
            H[i, j] = s


@njit(cache=True)
def stvk_element_into(x0, x1, x2, Dm_inv, area, mu, lam, project, grad, hess):
    """StVK energy of one face; writes the gradient (9,) and Hessian (9, 9), returns the energy."""
    F = deformation_gradient(x0, x1, x2, Dm_inv)
    E = green_strain(F)
    trE = E[0, 0] + E[1, 1]
    energy = area * (mu * (E[0, 0] ** 2 + 2.0 * E[0, 1] ** 2 + E[1, 1] ** 2) + 0.5 * lam * trE * trE)
    S00 = 2.0 * mu * E[0, 0] + lam * trE
    S11 = 2.0 * mu * E[1, 1] + lam * trE
    S01 = 2.0 * mu * E[0, 1]
    g = np.empty((3, 2))
    g[1, 0], g[1, 1] = Dm_inv[0, 0], Dm_inv[0, 1]
    g[2, 0], g[2, 1] = Dm_inv[1, 0], Dm_inv[1, 1]
    g[0, 0], g[0, 1] = -g[1, 0] - g[2, 0], -g[1, 1] - g[2, 1]
    Fg = np.empty((3, 3))  # Fg[a] = F g_a
    Sg = np.empty((3, 2))  # Sg[a] = S g_a
    for a in range(3):
        Sg[a, 0] = S00 * g[a, 0] + S01 * g[a, 1]
        Sg[a, 1] = S01 * g[a, 0] + S11 * g[a, 1]
        for i in range(3):
            Fg[a, i] = F[i, 0] * g[a, 0] + F[i, 1] * g[a, 1]
            grad[3 * a + i] = area * (F[i, 0] * Sg[a, 0] + F[i, 1] * Sg[a, 1])
    FFt = F @ F.T
    for a in range(3):
        for b in range(3):
            gSg = g[a, 0] * Sg[b, 0] + g[a, 1] * Sg[b, 1]
            gg = g[a, 0] * g[b, 0] + g[a, 1] * g[b, 1]
            for i in range(3):
                for j in range(3):
                    h = mu * Fg[b, i] * Fg[a, j] + mu * gg * FFt[i, j] + lam * Fg[a, i] * Fg[b, j]
                    if i == j:
                        h += gSg
                    hess[3 * a + i, 3 * b + j] = area * h
    # S is PSD iff its trace and determinant are >= 0; then so is the Hessian
    if project and not (S00 + S11 >= 0.0 and S00 * S11 - S01 * S01 >= 0.0):
        project_psd(hess)
    return energy


@njit(cache=True)
def stvk_element(x0, x1, x2, Dm_inv, area, mu, lam, project):
    """(energy, gradient (9,), Hessian (9, 9)) of the StVK membrane energy of one face."""
    grad = np.empty(9)
    hess = np.empty((9, 9))
    energy = stvk_element_into(x0, x1, x2, Dm_inv, area, mu, lam, project, grad, hess)
    return energy, grad, hess


@njit(cache=True, parallel=True)
def membrane_elements(node_x, face_nodes, face_Dm_inv, face_area, mu, lam, project,
                      out_energy, out_grad, out_hess):
    """Energy (F,), gradient (F, 9) and Hessian (F, 9, 9) of every face (each writes its own slot)."""
    for f in prange(face_nodes.shape[0]):
        out_energy[f] = stvk_element_into(
            node_x[face_nodes[f, 0]], node_x[face_nodes[f, 1]], node_x[face_nodes[f, 2]],
            face_Dm_inv[f], face_area[f], mu, lam, project, out_grad[f], out_hess[f])


@njit(cache=True)
def face_green_strain(node_x, face_nodes, face_Dm_inv):
    """Green strain of every face, (F, 2, 2)."""
    out = np.empty((face_nodes.shape[0], 2, 2))
    for f in range(face_nodes.shape[0]):
        F = deformation_gradient(node_x[face_nodes[f, 0]], node_x[face_nodes[f, 1]],
                                 node_x[face_nodes[f, 2]], face_Dm_inv[f])
        out[f] = green_strain(F)
    return out
