"""Discrete-shell bending on the dihedral angle of each interior edge (Grinspun et al. 2003).

A hinge is the stencil (x0, x1, x2, x3): the edge x0 -> x1, face A = (x0, x1, x2) and face
B = (x1, x0, x3), both counter-clockwise. With a = x1 - x0, b = x2 - x0, c = x3 - x0 the
(unnormalised) normals are n_A = a x b and n_B = c x a, and

    |n_A||n_B| sin(theta) = (n_A x n_B) . a/|a| = -|a| det(a, b, c)   =: y
    |n_A||n_B| cos(theta) =  n_A . n_B = (a.c)(a.b) - |a|^2 (b.c)     =: z
    theta = atan2(y, z).

Sign: theta > 0 when x3 lies behind face A (on the side opposite to n_A), i.e. the hinge
folds away from face A's normal; theta = 0 when flat. y and z are polynomials in (a, b, c), so
the exact gradient and Hessian of theta follow from those of y and z by the chain rule for
atan2, with no approximation. The energy of a hinge is

    W = 1/2 w (theta - theta_rest)^2,    w = k_bend * 3 |e|^2 / (A_A + A_B),

with rest edge length |e| and rest face areas A_A, A_B (material space), k_bend in N m.
Its Hessian is w (grad theta grad theta^T + (theta - theta_rest) Hess theta); the second term
is indefinite, so where the element Hessian is indefinite (a Cholesky test fails) it is
projected to positive semi-definite in the (a, b, c) coordinates, whose map to positions is a
fixed congruence, so the projected 12x12 matrix is PSD and equals the exact one wherever that
is PSD already. (Every bent hinge of a dancing skirt is indefinite, so the 9x9 eigen-decomposition,
cloth.physics.eigen, runs for each hinge in every step.)

**Collapsing faces.** d theta / d x2 has length 1 / h_A, h_A = |n_A| / |e| the height of face A
over the hinge edge, so the force of a hinge grows without bound as a face collapses, and theta
jumps by pi when a face passes through its edge. Near collapse the hinge's weight fades:

    W = 1/2 w S (theta - theta_rest)^2,   S = s(r_A) s(r_B),   r_F = (h_F / (q0 |e|))^2,
    s(r) = r (2 - r) for r < 1, 1 beyond (C1 at r = 1),

q0 = HINGE_FADE_HEIGHT. S is 1 for every face higher than q0 |e| (the energy is unchanged there)
and goes as h^2 at a collapse, so the force w S d dtheta + w d^2 dS / 2 goes to 0 with h, the
energy is continuous through the flip (0 on both sides), and the largest force of a hinge is about
w |d| / (q0 |e|). r_F is a polynomial in the positions over |e|^4, so S is differentiated exactly;
in the fade (S < 1) the Hessian is the Gauss-Newton w S dtheta dtheta^T for every `project`:
positive semi-definite and bounded (the exact one has terms in 1 / h).

**The fold at +-pi.** atan2 wraps where the two faces fold flat onto each other. With a flat rest
angle the energy is the same on both sides and only the force's sign turns (it opens the fold
either way); with theta_rest != 0 the energy steps by 2 pi w theta_rest there. The force stays
bounded (at most w (pi + |theta_rest|) |dtheta|) across it, which the tests check; cloth folded
onto itself is held apart by the self-collision thickness.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from cloth.physics.membrane import GAUSS_NEWTON, add_skew, project_psd

# A hinge whose y^2 + z^2 = |n_A|^2 |n_B|^2 falls below this (m^8) has a collapsed face in world
# space: its angle is undefined and it exerts no force.
DEGENERATE_NORMAL2 = 1e-40
# q0: a face whose height over the hinge edge is below q0 |e| has lost its shape, and the hinge's
# weight fades with it (module docstring). ARCSim clamps the height in its bending force at 1e-3
# |e|; a fade from 1e-2 bounds a hinge's force at about 100 times a healthy hinge's (whose faces
# are about |e| / 2 high) and leaves every face of a remeshed mesh (aspect-limited) untouched.
HINGE_FADE_HEIGHT = 1e-2


def hinge_weight(rest_length, area_A, area_B, k_bend):
    """w = k_bend * 3 |e|^2 / (A_A + A_B): the discrete-shell weight of each hinge (N m)."""
    return k_bend * 3.0 * np.asarray(rest_length) ** 2 / (np.asarray(area_A) + np.asarray(area_B))


@njit(cache=True)
def dihedral_angle(x0, x1, x2, x3):
    """Signed bending angle theta of the hinge, in (-pi, pi]; 0 when flat (sign: module docstring)."""
    a = x1 - x0
    b = x2 - x0
    c = x3 - x0
    L = np.sqrt(a @ a)
    y = -L * (a @ np.cross(b, c))
    z = (a @ c) * (a @ b) - (a @ a) * (b @ c)
    return np.arctan2(y, z)


@njit(cache=True)
def _fade(r):
    """(s(r), s'(r)) with s(r) = r (2 - r) on [0, 1) and 1 beyond."""
    if r >= 1.0:
        return 1.0, 0.0
    return r * (2.0 - r), 2.0 - 2.0 * r


@njit(cache=True)
def fade_ratios(a0, a1, a2, b0, b1, b2, c0, c1, c2):
    """(r_A, r_B) = ((h_A / (q0 |e|))^2, (h_B / (q0 |e|))^2) of the hinge (a, b, c), in scalars."""
    L2 = a0 * a0 + a1 * a1 + a2 * a2
    nA0, nA1, nA2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    nB0, nB1, nB2 = c1 * a2 - c2 * a1, c2 * a0 - c0 * a2, c0 * a1 - c1 * a0
    scale = 1.0 / (HINGE_FADE_HEIGHT * HINGE_FADE_HEIGHT * L2 * L2)
    return (nA0 * nA0 + nA1 * nA1 + nA2 * nA2) * scale, (nB0 * nB0 + nB1 * nB1 + nB2 * nB2) * scale


@njit(cache=True)
def hinge_fade(a, b, c, grad):
    """S = s(r_A) s(r_B), the hinge's weight factor near a collapsing face (module docstring);
    writes dS / d(a, b, c) into grad (9,) (zeros where S = 1). With L2 = |a|^2, n_A = a x b,
    n_B = c x a: d|n_A|^2 = 2 (b x n_A, n_A x a, 0), d|n_B|^2 = 2 (n_B x c, 0, a x n_B),
    dr_F = d|n_F|^2 / (q0^2 L2^2) - 2 r_F dL2 / L2 with dL2 = (2 a, 0, 0)."""
    for i in range(9):
        grad[i] = 0.0
    rA, rB = fade_ratios(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2])
    sA, dsA = _fade(rA)
    sB, dsB = _fade(rB)
    if sA == 1.0 and sB == 1.0:
        return 1.0
    L2 = a @ a
    k = 1.0 / (HINGE_FADE_HEIGHT * HINGE_FADE_HEIGHT * L2 * L2)
    nA = np.cross(a, b)
    nB = np.cross(c, a)
    gA = dsA * sB  # dS/dr_A
    gB = sA * dsB  # dS/dr_B
    bxn = np.cross(b, nA)
    nxa = np.cross(nA, a)
    nxc = np.cross(nB, c)
    axn = np.cross(a, nB)
    for i in range(3):
        grad[i] = gA * (2.0 * k * bxn[i] - 4.0 * rA * a[i] / L2) + gB * (2.0 * k * nxc[i] - 4.0 * rB * a[i] / L2)
        grad[3 + i] = gA * 2.0 * k * nxa[i]
        grad[6 + i] = gB * 2.0 * k * axn[i]
    return sA * sB


@njit(cache=True)
def _is_psd(H):
    """True if H + eps I admits a Cholesky factorisation (H positive semi-definite up to eps)."""
    n = H.shape[0]
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(H[i, i]))
    eps = 1e-12 * scale + 1e-300
    L = np.zeros((n, n))
    for j in range(n):
        s = H[j, j] + eps
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if s <= 0.0:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            t = H[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    return True


@njit(cache=True)
def angle_derivatives(a, b, c):
    """theta, gradient (9,) and Hessian (9, 9) with respect to (a, b, c); ok = False if degenerate.

    Hess theta = (z Hy - y Hz + gz gy^T - gy gz^T) / r2 - u (2 y gy + 2 z gz)^T / r2, with
    u = grad theta = (z gy - y gz) / r2 and r2 = y^2 + z^2; symmetrised against round-off.
    """
    L2 = a[0] * a[0] + a[1] * a[1] + a[2] * a[2]
    L = np.sqrt(L2)
    bxc = np.cross(b, c)
    cxa = np.cross(c, a)
    axb = np.cross(a, b)
    p = a[0] * bxc[0] + a[1] * bxc[1] + a[2] * bxc[2]
    ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    ac = a[0] * c[0] + a[1] * c[1] + a[2] * c[2]
    bc = b[0] * c[0] + b[1] * c[1] + b[2] * c[2]
    y = -L * p
    z = ac * ab - L2 * bc
    r2 = y * y + z * z
    u = np.zeros(9)
    H = np.zeros((9, 9))
    if r2 < DEGENERATE_NORMAL2 or L == 0.0:
        return 0.0, u, H, False
    gy = np.empty(9)
    gz = np.empty(9)
    for i in range(3):
        ah = a[i] / L
        # y = -L p: dL/da = a/|a|, dp/d(a, b, c) = (b x c, c x a, a x b)
        gy[i] = -(p * ah + L * bxc[i])
        gy[3 + i] = -L * cxa[i]
        gy[6 + i] = -L * axb[i]
        # z = (a.c)(a.b) - |a|^2 (b.c)
        gz[i] = c[i] * ab + b[i] * ac - 2.0 * a[i] * bc
        gz[3 + i] = a[i] * ac - c[i] * L2
        gz[6 + i] = a[i] * ab - b[i] * L2
    inv = 1.0 / r2
    for i in range(9):
        u[i] = (z * gy[i] - y * gz[i]) * inv
    # z Hy with Hy = -(gL gp^T + gp gL^T + p HL + L Hp); gL = (a/|a|, 0, 0), HL = (I - a a^T/|a|^2)/|a|
    zL = z * L
    add_skew(H, 0, 3, c, zL)   # -L Hp blocks: Hp[a,b] = -[c]x, Hp[b,c] = -[a]x, Hp[c,a] = -[b]x
    add_skew(H, 3, 0, c, -zL)
    add_skew(H, 3, 6, a, zL)
    add_skew(H, 6, 3, a, -zL)
    add_skew(H, 6, 0, b, zL)
    add_skew(H, 0, 6, b, -zL)
    for i in range(3):
        ahi = a[i] / L
        for j in range(3):
            ahj = a[j] / L
            # -z (gL gp^T + gp gL^T) restricted to the a-rows/columns, and -z p HL
            H[i, j] -= z * (ahi * bxc[j] + bxc[i] * ahj + p * ((1.0 if i == j else 0.0) - ahi * ahj) / L)
            H[i, 3 + j] -= z * ahi * cxa[j]
            H[3 + j, i] -= z * ahi * cxa[j]
            H[i, 6 + j] -= z * ahi * axb[j]
            H[6 + j, i] -= z * ahi * axb[j]
            # -y Hz
            d = 1.0 if i == j else 0.0
            H[i, j] -= y * (c[i] * b[j] + b[i] * c[j] - 2.0 * bc * d)
            hab = c[i] * a[j] + ac * d - 2.0 * a[i] * c[j]
            H[i, 3 + j] -= y * hab
            H[3 + j, i] -= y * hab
            hac = ab * d + b[i] * a[j] - 2.0 * a[i] * b[j]
            H[i, 6 + j] -= y * hac
            H[6 + j, i] -= y * hac
            hbc = a[i] * a[j] - L2 * d
            H[3 + i, 6 + j] -= y * hbc
            H[6 + j, 3 + i] -= y * hbc
    for i in range(9):
        for j in range(9):
            H[i, j] = (H[i, j] + gz[i] * gy[j] - gy[i] * gz[j] - u[i] * 2.0 * (y * gy[j] + z * gz[j])) * inv
    for i in range(9):
        for j in range(i + 1, 9):
            m = 0.5 * (H[i, j] + H[j, i])
            H[i, j] = m
            H[j, i] = m
    theta = np.arctan2(y, z)
    return theta, u, H, True


@njit(cache=True)
def _gauss_newton_hinge_into(x0, x1, x2, x3, rest_theta, weight, grad, hess):
    """bending_element_into's GAUSS_NEWTON case in scalars, without temporary arrays (the pop
    filter evaluates it on thousands of hinges per Newton step): grad = w d U, hess = w U U^T,
    U = d theta / d(x0..x3) from angle_derivatives' gradient formulas."""
    a0, a1, a2 = x1[0] - x0[0], x1[1] - x0[1], x1[2] - x0[2]
    b0, b1, b2 = x2[0] - x0[0], x2[1] - x0[1], x2[2] - x0[2]
    c0, c1, c2 = x3[0] - x0[0], x3[1] - x0[1], x3[2] - x0[2]
    L2 = a0 * a0 + a1 * a1 + a2 * a2
    L = np.sqrt(L2)
    bxc = (b1 * c2 - b2 * c1, b2 * c0 - b0 * c2, b0 * c1 - b1 * c0)
    cxa = (c1 * a2 - c2 * a1, c2 * a0 - c0 * a2, c0 * a1 - c1 * a0)
    axb = (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)
    a, b, c = (a0, a1, a2), (b0, b1, b2), (c0, c1, c2)
    p = a0 * bxc[0] + a1 * bxc[1] + a2 * bxc[2]
    ab = a0 * b0 + a1 * b1 + a2 * b2
    ac = a0 * c0 + a1 * c1 + a2 * c2
    bc = b0 * c0 + b1 * c1 + b2 * c2
    y = -L * p
    z = ac * ab - L2 * bc
    r2 = y * y + z * z
    for i in range(12):
        grad[i] = 0.0
    if r2 < DEGENERATE_NORMAL2 or L == 0.0:
        for i in range(12):
            for j in range(12):
                hess[i, j] = 0.0
        return 0.0
    inv = 1.0 / r2
    for i in range(3):  # grad holds U here: U_{k+1} = u_k, U_0 = -(u_0 + u_1 + u_2)
        gy = -(p * a[i] / L + L * bxc[i])
        gz = c[i] * ab + b[i] * ac - 2.0 * a[i] * bc
        grad[3 + i] = (z * gy - y * gz) * inv
        gy = -L * cxa[i]
        gz = a[i] * ac - c[i] * L2
        grad[6 + i] = (z * gy - y * gz) * inv
        gy = -L * axb[i]
        gz = a[i] * ab - b[i] * L2
        grad[9 + i] = (z * gy - y * gz) * inv
        grad[i] = -(grad[3 + i] + grad[6 + i] + grad[9 + i])
    S = 1.0
    rA, rB = fade_ratios(a0, a1, a2, b0, b1, b2, c0, c1, c2)
    fading = rA < 1.0 or rB < 1.0
    if fading:  # a collapsing face (rare): the fade's gradient in 12 coordinates, as U's
        g9 = np.empty(9)
        S = hinge_fade(np.array((a0, a1, a2)), np.array((b0, b1, b2)), np.array((c0, c1, c2)), g9)
    ws = weight * S
    for i in range(12):
        wi = ws * grad[i]
        for j in range(12):
            hess[i, j] = wi * grad[j]
    d = np.arctan2(y, z) - rest_theta
    for i in range(12):
        grad[i] *= ws * d
    if fading:
        h = 0.5 * weight * d * d
        for i in range(3):
            grad[3 + i] += h * g9[i]
            grad[6 + i] += h * g9[3 + i]
            grad[9 + i] += h * g9[6 + i]
            grad[i] -= h * (g9[i] + g9[3 + i] + g9[6 + i])
    return 0.5 * ws * d * d


@njit(cache=True)
def bending_element_into(x0, x1, x2, x3, rest_theta, weight, project, grad, hess):
    """Hinge energy; writes the gradient (12,) and Hessian (12, 12) w.r.t. (x0..x3), returns W.

    `project`: False, the exact Hessian; True, projected to positive semi-definite where it is
    not; GAUSS_NEWTON (2), only the term w u u^T (u = d theta / dx), positive semi-definite by
    construction and about 8x cheaper than the projection (ARCSim's bending Hessian).
    """
    if project == GAUSS_NEWTON:
        return _gauss_newton_hinge_into(x0, x1, x2, x3, rest_theta, weight, grad, hess)
    a, b, c = x1 - x0, x2 - x0, x3 - x0
    theta, u, H, ok = angle_derivatives(a, b, c)
    for i in range(12):
        grad[i] = 0.0
        for j in range(12):
            hess[i, j] = 0.0
    if not ok:
        return 0.0
    d = theta - rest_theta
    gS = np.empty(9)
    S = hinge_fade(a, b, c, gS)
    if S < 1.0:  # a collapsing face: the faded energy's gradient, the Gauss-Newton Hessian
        g9 = weight * (S * d * u + 0.5 * d * d * gS)
        H9 = weight * S * np.outer(u, u)
    else:
        g9 = weight * d * u
        H9 = weight * (np.outer(u, u) + d * H)
        if project and d != 0.0 and not _is_psd(H9):
            project_psd(H9)
    # (a, b, c) = (x1 - x0, x2 - x0, x3 - x0): x0 gets minus the sum, x1..x3 the blocks
    for k in range(3):
        for i in range(3):
            grad[3 * (k + 1) + i] = g9[3 * k + i]
            grad[i] -= g9[3 * k + i]
    for k in range(3):
        for l in range(3):
            for i in range(3):
                for j in range(3):
                    h = H9[3 * k + i, 3 * l + j]
                    hess[3 * (k + 1) + i, 3 * (l + 1) + j] = h
                    hess[i, 3 * (l + 1) + j] -= h
                    hess[3 * (k + 1) + i, j] -= h
                    hess[i, j] += h
    return 0.5 * weight * S * d * d


@njit(cache=True)
def bending_element(x0, x1, x2, x3, rest_theta, weight, project):
    """(energy, gradient (12,), Hessian (12, 12)) of one hinge."""
    grad = np.empty(12)
    hess = np.empty((12, 12))
    energy = bending_element_into(x0, x1, x2, x3, rest_theta, weight, project, grad, hess)
    return energy, grad, hess


@njit(cache=True, parallel=True)
def bending_elements(node_x, edge_stencil, edge_rest_theta, edge_weight, project, out_energy, out_grad, out_hess):
    """Energy (E,), gradient (E, 12), Hessian (E, 12, 12) of every hinge (each writes its own slot)."""
    for e in prange(edge_stencil.shape[0]):
        s = edge_stencil[e]
        out_energy[e] = bending_element_into(node_x[s[0]], node_x[s[1]], node_x[s[2]], node_x[s[3]],
                                             edge_rest_theta[e], edge_weight[e], project, out_grad[e], out_hess[e])
