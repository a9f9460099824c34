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
eigen-decomposed (cloth.physics.eigen; by the face's plane, :func:`project_psd_face_planar`) and
made positive semi-definite (:func:`project_psd`): negative eigenvalues are
clamped to zero under mild compression, and replaced by their absolute values (Chen et al.,
"Stabler Neo-Hookean Simulation", 2024) where E's smallest eigenvalue is below
ABSOLUTE_STRAIN = -0.1 (a principal stretch below 0.89). A face compressed that far with
clamped eigenvalues has almost no stiffness along its soft directions while its restoring force
is large, and on light nodes (a fine mesh of light cloth, where m / h^2 is a thousandth of the
stiffness) one linearised step is then a bare Newton step that overshoots by centimetres: a
dense pile of folds (the crushed sheet at 48 cells, whose self-collision response compresses
faces every step) reached Green strains of 3 to 8 and diverged at frame 27, and so did the
solo dancer with self-collision at frame 18; with the threshold at -0.1 both run to the end.
(The threshold was at StVK's softening point, -1/3, before.) Absolute values under mild
compression too would add stiffness against ordinary buckling: a falling sheet over a sphere
then keeps more of its small wrinkles and folds less at the rim (measured at frame 8 of the
adaptive `sheet_on_sphere`: faces per m^2 at the rim 971 against 1,518 with the threshold),
while its first 8 frames with the threshold are those of the softening-point rule exactly.

Buckling compensation (paper eq 10, cloth.physics.buckling) gives each face a compression factor
alpha in [0, 1]: the energy sees E^ = Q diag(g(l_1), g(l_2)) Q^T, with l_j the eigenvalues of
E, q_j its eigenvectors and g(l) = l for l >= 0, alpha l for l < 0. The energy is then a
spectral function of E, W = A psi(l_1, l_2) with psi = mu (g_1^2 + g_2^2) + lam/2 (g_1 + g_2)^2:

    S = dpsi/dE = sum_j psi_j q_j q_j^T,      psi_j = g'_j (2 mu g_j + lam (g_1 + g_2)),
    d2psi/dE2 [D, D'] = sum_jk psi_jk D~_jj D'~_kk + 2 c D~_12 D'~_12,
    psi_jk = g'_j g'_k (2 mu delta_jk + lam),  c = (psi_1 - psi_2) / (l_1 - l_2),

with D~ = Q^T D Q (the derivative of a spectral function, Lewis 1996); for alpha = 1 this is
the StVK formula above. The gradient keeps the form A F S g_a. Faces with alpha = 1 or with no
compressed direction take the StVK path unchanged.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from cloth.physics.eigen import symmetric_eig


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


# Smallest Green strain (1/2 (stretch^2 - 1)) below which the projection takes absolute values
# of negative eigenvalues instead of clamping them (see the module docstring).
ABSOLUTE_STRAIN = -0.1
# `project` value of the element kernels for the Gauss-Newton Hessian: membrane, the stress
# clamped to its positive part in the geometric term (stvk_element_into); bending, the term
# w u u^T only (cloth.physics.bending). Positive semi-definite without a 9x9 or 12x12 eigensolve.
GAUSS_NEWTON = 2


@njit(cache=True)
def _strongly_compressed(E00, E01, E11):
    """True when the smallest eigenvalue of E is below ABSOLUTE_STRAIN."""
    m = 0.5 * (E00 + E11)
    r = np.sqrt(0.25 * (E00 - E11) * (E00 - E11) + E01 * E01)
    return m - r < ABSOLUTE_STRAIN


@njit(cache=True)
def project_psd(H, absolute=False):
    """Make the symmetric matrix H positive semi-definite in place: negative eigenvalues -> 0,
    or -> |w| with `absolute` (absolute-eigenvalue filtering, Chen et al., "Stabler Neo-Hookean
    Simulation", SIGGRAPH 2024). H - c sum_{w_k < 0} w_k v_k v_k^T with c = 1 (clamp) or 2
    (absolute): the same matrix as V max(w, 0) V^T, in the work of the few negative eigenpairs."""
    n = H.shape[0]
    w = np.empty(n)
    V = np.empty((n, n))
    symmetric_eig(H, w, V)
    c = 2.0 if absolute else 1.0
    for k in range(n):
        if w[k] >= 0.0:
            continue
        wk = c * w[k]
        for i in range(n):
            vi = wk * V[i, k]
            for j in range(n):
                H[i, j] -= vi * V[j, k]
    for i in range(n):  # exactly symmetric, as the element Hessians are assembled
        for j in range(i + 1, n):
            m = 0.5 * (H[i, j] + H[j, i])
            H[i, j] = m
            H[j, i] = m


@njit(cache=True)
def _whitened_rows(g):
    """h = g Gm^-1/2 (3, 2; orthonormal columns) with Gm = g^T g, or None for a degenerate rest face
    (Gm not positive definite): the face projections' basis of the deformations."""
    p, q, r = 0.0, 0.0, 0.0
    for a in range(3):
        p += g[a, 0] * g[a, 0]
        q += g[a, 0] * g[a, 1]
        r += g[a, 1] * g[a, 1]
    l1, l2, q1, q2 = _eig_sym2(p, q, r)
    if not l2 > 0.0:
        return None
    s1, s2 = 1.0 / np.sqrt(l1), 1.0 / np.sqrt(l2)
    r00 = s1 * q1[0] * q1[0] + s2 * q2[0] * q2[0]  # Gm^-1/2
    r01 = s1 * q1[0] * q1[1] + s2 * q2[0] * q2[1]
    r11 = s1 * q1[1] * q1[1] + s2 * q2[1] * q2[1]
    h = np.empty((3, 2))
    for a in range(3):
        h[a, 0] = g[a, 0] * r00 + g[a, 1] * r01
        h[a, 1] = g[a, 0] * r01 + g[a, 1] * r11
    return h


@njit(cache=True)
def project_psd_face(hess, g, absolute=False):
    """:func:`project_psd` of a face's Hessian (9, 9), done on a 6x6 matrix: the same result to
    round-off, at a fraction of the eigen-decomposition's work.

    A face's energy depends on its nodes only through F = sum_a x_a g_a^T (g (3, 2): the rows
    g_a of [-1 -1; 1 0; 0 1] Dm^-1), so its Hessian is G^T K G with G (6, 9) the linear map
    x -> F. With Gm = g^T g (2x2, positive definite for a face of positive rest area) and
    h = g Gm^-1/2 (3x2, orthonormal columns), Q = h (x) I_3 (9x6) has orthonormal columns spanning
    the complement of the translations, and the Hessian is Q M Q^T with M = Q^T H Q (6x6). Its
    eigenpairs are M's, mapped by Q, and three zeros (the translations): projecting M and mapping
    back is projecting H."""
    h = _whitened_rows(g)
    if h is None:  # a degenerate rest face: no reduction
        project_psd(hess, absolute)
        return
    # T[3a + i, 2j + l] = sum_b H[3a + i, 3b + j] h[b, l]  (H Q), then M = Q^T T
    T = np.empty((9, 6))
    for row in range(9):
        for j in range(3):
            for l in range(2):
                T[row, 2 * j + l] = (hess[row, j] * h[0, l] + hess[row, 3 + j] * h[1, l]
                                     + hess[row, 6 + j] * h[2, l])
    M = np.empty((6, 6))
    for i in range(3):
        for k in range(2):
            for col in range(6):
                M[2 * i + k, col] = h[0, k] * T[i, col] + h[1, k] * T[3 + i, col] + h[2, k] * T[6 + i, col]
    project_psd(M, absolute)
    # H = Q M Q^T: U = M Q^T (6x9), then H = Q U
    U = np.empty((6, 9))
    for row in range(6):
        for b in range(3):
            for j in range(3):
                U[row, 3 * b + j] = M[row, 2 * j] * h[b, 0] + M[row, 2 * j + 1] * h[b, 1]
    for a in range(3):
        for i in range(3):
            for col in range(9):
                hess[3 * a + i, col] = h[a, 0] * U[2 * i, col] + h[a, 1] * U[2 * i + 1, col]
    for i in range(9):  # exactly symmetric, as the element Hessians are assembled
        for j in range(i + 1, 9):
            m = 0.5 * (hess[i, j] + hess[j, i])
            hess[i, j] = m
            hess[j, i] = m


# Slack of the in-plane block's positive-definiteness test in project_psd_face_planar, relative to
# the block's largest diagonal entry: a block whose Cholesky factorisation of A + slack I
# succeeds has no eigenvalue below -slack, so leaving it unprojected differs from the full
# projection by at most that, round-off of the matrix's norm (the eigensolver's own is 1e-13).
PLANAR_PSD_SLACK = 1e-13


@njit(cache=True)
def _subtract_negative_part(hess, W, vec, w, c):
    """hess -= c w y y^T with y = W vec (9,): one negative eigenpair (w, vec in W's basis) removed
    (c = 1) or reflected (c = 2)."""
    y = np.zeros(9)
    for r in range(9):
        for k in range(W.shape[1]):
            y[r] += W[r, k] * vec[k]
    cw = c * w
    for r in range(9):
        yr = cw * y[r]
        for s in range(9):
            hess[r, s] -= yr * y[s]


@njit(cache=True)
def project_psd_face_planar(hess, g, F, absolute=False):
    """:func:`project_psd_face` for the Hessian of an energy that depends on a face's nodes only
    through C = F^T F (StVK, buckling-compensated or measured): the same matrix to round-off,
    with a 2x2 and a 4x4 eigenproblem instead of a 6x6 one, and most often without the 4x4.

    Rotating the world does not change C, and F's columns lie in the face's plane (unit normal
    n): a displacement along n, x_a += n b_a, changes C only at second order (F^T n = 0), by
    (g^T b)(g^T b)^T, and shares no term with a displacement in the plane.
    In the whitened basis of project_psd_face, taken along (t1, t2, n) with t1, t2 spanning the
    plane, M (6x6) is thus block-diagonal: an in-plane block (4x4: stretch, shear and the
    in-plane rotation) and an out-of-plane block (2x2: the geometric term A g^T S g, whitened),
    which holds the negative eigenvalues of every compressed face. The 2x2 is decomposed in
    closed form; the 4x4 only when a Cholesky factorisation of it plus PLANAR_PSD_SLACK fails
    (about 45 % of the projected faces of a buckling sheet or skirt: where C : S < 0, as under
    compression both ways, the in-plane rotation alone has negative stiffness). A face of no world area, or a degenerate
    rest face, goes to project_psd_face."""
    n0 = F[1, 0] * F[2, 1] - F[2, 0] * F[1, 1]
    n1 = F[2, 0] * F[0, 1] - F[0, 0] * F[2, 1]
    n2 = F[0, 0] * F[1, 1] - F[1, 0] * F[0, 1]
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    h = _whitened_rows(g)
    if h is None or not (nn > 0.0 and np.isfinite(nn)):
        project_psd_face(hess, g, absolute)
        return
    frame = np.empty((3, 3))  # rows t1, t2, n
    frame[2, 0], frame[2, 1], frame[2, 2] = n0 / nn, n1 / nn, n2 / nn
    c0 = np.sqrt(F[0, 0] * F[0, 0] + F[1, 0] * F[1, 0] + F[2, 0] * F[2, 0])
    for i in range(3):
        frame[0, i] = F[i, 0] / c0
    frame[1, 0] = frame[2, 1] * frame[0, 2] - frame[2, 2] * frame[0, 1]
    frame[1, 1] = frame[2, 2] * frame[0, 0] - frame[2, 0] * frame[0, 2]
    frame[1, 2] = frame[2, 0] * frame[0, 1] - frame[2, 1] * frame[0, 0]
    W = np.empty((9, 6))  # orthonormal columns h[:, k] (x) frame[c], column 2c + k
    for a in range(3):
        for i in range(3):
            for c in range(3):
                for k in range(2):
                    W[3 * a + i, 2 * c + k] = h[a, k] * frame[c, i]
    T = np.zeros((9, 6))  # hess W
    for row in range(9):
        for s in range(9):
            hs = hess[row, s]
            for col in range(6):
                T[row, col] += hs * W[s, col]
    M = np.zeros((6, 6))  # W^T hess W
    for i in range(6):
        for j in range(i, 6):
            v = 0.0
            for row in range(9):
                v += W[row, i] * T[row, j]
            M[i, j] = v
            M[j, i] = v
    c = 2.0 if absolute else 1.0
    # out-of-plane block, closed form
    b1, b2, v1, v2 = _eig_sym2(M[4, 4], M[4, 5], M[5, 5])
    vec = np.zeros(6)
    if b1 < 0.0:
        vec[4], vec[5] = v1[0], v1[1]
        _subtract_negative_part(hess, W, vec, b1, c)
    if b2 < 0.0:
        vec[4], vec[5] = v2[0], v2[1]
        _subtract_negative_part(hess, W, vec, b2, c)
    # in-plane block: Cholesky of A + slack I, the 4x4 eigenproblem only if that fails
    A = M[:4, :4].copy()
    slack = 0.0
    for i in range(4):
        slack = max(slack, abs(A[i, i]))
    slack *= PLANAR_PSD_SLACK
    L = A.copy()
    definite = True
    for j in range(4):
        d = L[j, j] + slack
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            definite = False
            break
        d = np.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, 4):
            s = L[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    if not definite:
        w = np.empty(4)
        V = np.empty((4, 4))
        symmetric_eig(A, w, V)
        for k in range(4):
            if w[k] < 0.0:
                for i in range(4):
                    vec[i] = V[i, k]
                vec[4], vec[5] = 0.0, 0.0
                _subtract_negative_part(hess, W, vec, w[k], c)
    for i in range(9):  # exactly symmetric, as the element Hessians are assembled
        for j in range(i + 1, 9):
            m = 0.5 * (hess[i, j] + hess[j, i])
            hess[i, j] = m
            hess[j, i] = m


@njit(cache=True)
def _eig_sym2(a, b, c):
    """Eigen-decomposition of [[a, b], [b, c]]: (l1 >= l2, q1 (2,), q2 (2,))."""
    m = 0.5 * (a + c)
    r = np.sqrt(0.25 * (a - c) * (a - c) + b * b)
    l1, l2 = m + r, m - r
    q1 = np.empty(2)
    if r == 0.0:
        q1[0], q1[1] = 1.0, 0.0
    elif a >= c:  # the better-conditioned of the two equivalent formulas
        q1[0], q1[1] = a - l2, b
    else:
        q1[0], q1[1] = b, c - l2
    n = np.sqrt(q1[0] * q1[0] + q1[1] * q1[1])
    q1[0] /= n
    q1[1] /= n
    q2 = np.empty(2)
    q2[0], q2[1] = -q1[1], q1[0]
    return l1, l2, q1, q2


@njit(cache=True)
def _filtered_element_into(F, E, Dm_inv, area, mu, lam, alpha, project, grad, hess):
    """Membrane energy of one face under eq 10 (see the module docstring); as stvk_element_into."""
    l1, l2, q1, q2 = _eig_sym2(E[0, 0], E[0, 1], E[1, 1])
    d1 = 1.0 if l1 >= 0.0 else alpha
    d2 = 1.0 if l2 >= 0.0 else alpha
    g1, g2 = d1 * l1, d2 * l2
    tr = g1 + g2
    energy = area * (mu * (g1 * g1 + g2 * g2) + 0.5 * lam * tr * tr)
    p1 = d1 * (2.0 * mu * g1 + lam * tr)
    p2 = d2 * (2.0 * mu * g2 + lam * tr)
    p11 = d1 * d1 * (2.0 * mu + lam)
    p22 = d2 * d2 * (2.0 * mu + lam)
    p12 = d1 * d2 * lam
    if l1 - l2 > 1e-12 * (abs(l1) + abs(l2) + 1e-300):
        cc = (p1 - p2) / (l1 - l2)
    else:  # equal eigenvalues (same branch): the limit psi_11 - psi_12
        cc = 2.0 * mu * d1 * d1
    S00 = p1 * q1[0] * q1[0] + p2 * q2[0] * q2[0]
    S01 = p1 * q1[0] * q1[1] + p2 * q2[0] * q2[1]
    S11 = p1 * q1[1] * q1[1] + p2 * q2[1] * q2[1]
    g = np.empty((3, 2))
    g[1, 0], g[1, 1] = Dm_inv[0, 0], Dm_inv[0, 1]
    g[2, 0], g[2, 1] = Dm_inv[1, 0], Dm_inv[1, 1]
    g[0, 0], g[0, 1] = -g[1, 0] - g[2, 0], -g[1, 1] - g[2, 1]
    # eigenbasis components: gh[a] = Q^T g_a, fh[i] = Q^T (row i of F)
    gh = np.empty((3, 2))
    fh = np.empty((3, 2))
    for a in range(3):
        gh[a, 0] = q1[0] * g[a, 0] + q1[1] * g[a, 1]
        gh[a, 1] = q2[0] * g[a, 0] + q2[1] * g[a, 1]
    for i in range(3):
        fh[i, 0] = q1[0] * F[i, 0] + q1[1] * F[i, 1]
        fh[i, 1] = q2[0] * F[i, 0] + q2[1] * F[i, 1]
    # dE/dx_{a,i} in the eigenbasis, as (D~_11, D~_22, sqrt2 D~_12)
    V = np.empty((9, 3))
    r2 = np.sqrt(2.0)
    for a in range(3):
        for i in range(3):
            V[3 * a + i, 0] = gh[a, 0] * fh[i, 0]
            V[3 * a + i, 1] = gh[a, 1] * fh[i, 1]
            V[3 * a + i, 2] = r2 * 0.5 * (gh[a, 0] * fh[i, 1] + gh[a, 1] * fh[i, 0])
    Sg = np.empty((3, 2))
    for a in range(3):
        Sg[a, 0] = S00 * g[a, 0] + S01 * g[a, 1]
        Sg[a, 1] = S01 * g[a, 0] + S11 * g[a, 1]
        for i in range(3):
            grad[3 * a + i] = area * (F[i, 0] * Sg[a, 0] + F[i, 1] * Sg[a, 1])
    for r in range(9):
        a = r // 3
        i = r % 3
        for c in range(9):
            b = c // 3
            j = c % 3
            v, w = V[r], V[c]
            h = (p11 * v[0] * w[0] + p12 * (v[0] * w[1] + v[1] * w[0]) + p22 * v[1] * w[1]
                 + cc * v[2] * w[2])
            if i == j:
                h += g[a, 0] * Sg[b, 0] + g[a, 1] * Sg[b, 1]
            hess[r, c] = area * h
    if project and not (p1 >= 0.0 and p2 >= 0.0 and cc >= 0.0):
        project_psd_face_planar(hess, g, F, l2 < ABSOLUTE_STRAIN)
    return energy


# Area barrier of the compensated faces (alpha < 1). Eq 10 leaves a compensated face almost no
# resistance to compression (alpha^2 of its stiffness: 1e-4 at the floor, cloth.physics.buckling),
# and StVK none near a collapse anyway (its force vanishes as a principal stretch goes to 0), so a
# hanging view-coarsened specimen was seen to fold a face to 0.3 % of its area, its hinges then to
# pull its light nodes at 5e5 m/s^2, and the run to diverge (the drape test at 1.5 cm, k = 10,
# frame 29). Below COLLAPSE_AREA_RATIO of its rest area (J = world area / rest area), a compensated
# face stores W_b = A kappa / 2 (J_c - J)^2 with kappa = 2 mu + lam (the membrane's compression
# stiffness): C1 at J_c, nothing above it, so the compensation of buckling-scale compression (a
# quarter of the area is a principal stretch of 0.5 both ways, or 0.25 one way) is untouched.
COLLAPSE_AREA_RATIO = 0.25


@njit(cache=True)
def add_skew(H, r0, c0, v, s):
    """H[r0:r0+3, c0:c0+3] += s [v]_x (accumulates into H; also the hinge Hessian's, cloth.physics.bending)."""
    H[r0, c0 + 1] -= s * v[2]
    H[r0, c0 + 2] += s * v[1]
    H[r0 + 1, c0] += s * v[2]
    H[r0 + 1, c0 + 2] -= s * v[0]
    H[r0 + 2, c0] -= s * v[1]
    H[r0 + 2, c0 + 1] += s * v[0]


@njit(cache=True)
def area_barrier_into(x0, x1, x2, area, kappa, exact, grad, hess):
    """Adds the collapse barrier of a compensated face (COLLAPSE_AREA_RATIO) to grad (9,) and hess
    (9, 9); returns its energy (0 above the ratio, or for a face of no world area).

    With e1 = x1 - x0, e2 = x2 - x0, n = e1 x e2 and J = |n| / (2 A): dJ/dx1 = (e2 x n^) / 2A,
    dJ/dx2 = (n^ x e1) / 2A, dJ/dx0 = -(both); the Hessian is A kappa (dJ dJ^T - (J_c - J) d2J),
    d2J = (N^T (I - n^ n^T) N / |n| + C) / 2A in (e1, e2) with N = [-[e2]x, [e1]x] and C the
    bilinear form n^ . (de1 x de2' + de1' x de2). `exact` = False keeps the Gauss-Newton part
    A kappa dJ dJ^T only: positive semi-definite and bounded as the face collapses."""
    e1 = x1 - x0
    e2 = x2 - x0
    n = np.cross(e1, e2)
    nn = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    J = nn / (2.0 * area)
    if J >= COLLAPSE_AREA_RATIO or nn == 0.0:
        return 0.0
    nh = n / nn
    r = COLLAPSE_AREA_RATIO - J
    d = np.empty(9)
    d[3:6] = np.cross(e2, nh) / (2.0 * area)
    d[6:9] = np.cross(nh, e1) / (2.0 * area)
    d[0:3] = -(d[3:6] + d[6:9])
    ka = kappa * area
    for i in range(9):
        grad[i] -= ka * r * d[i]
        for j in range(9):
            hess[i, j] += ka * d[i] * d[j]
    if exact:  # - A kappa r d2J, built in (e1, e2) and mapped to (x0, x1, x2)
        N = np.zeros((3, 6))
        add_skew(N, 0, 0, e2, -1.0)
        add_skew(N, 0, 3, e1, 1.0)
        Pn = np.eye(3) - np.outer(nh, nh)
        He = N.T @ Pn @ N / nn
        # C: n^ . (a x b) = a . (b x n^) = -a^T [n^]x b  for a = de1, b = de2'
        add_skew(He, 0, 3, nh, -1.0)
        add_skew(He, 3, 0, nh, 1.0)
        He *= -ka * r / (2.0 * area)
        for a in range(2):
            for b in range(2):
                for i in range(3):
                    for j in range(3):
                        h = He[3 * a + i, 3 * b + j]
                        hess[3 * (a + 1) + i, 3 * (b + 1) + j] += h
                        hess[i, 3 * (b + 1) + j] -= h
                        hess[3 * (a + 1) + i, j] -= h
                        hess[i, j] += h
    return 0.5 * ka * r * r


@njit(cache=True)
def stvk_element_into(x0, x1, x2, Dm_inv, area, mu, lam, project, grad, hess, alpha=1.0):
    """StVK energy of one face; writes the gradient (9,) and Hessian (9, 9), returns the energy.

    `alpha` < 1 filters the compressive principal strains (buckling compensation, eq 10).
    `project`: False, the exact Hessian; True, projected to positive semi-definite where the
    stress is not; GAUSS_NEWTON, the stress's positive part in the geometric term (a filtered
    face, alpha < 1, is projected instead).
    """
    F = deformation_gradient(x0, x1, x2, Dm_inv)
    E = green_strain(F)
    if alpha < 1.0 and (E[0, 0] + E[1, 1] < 0.0 or E[0, 0] * E[1, 1] - E[0, 1] * E[0, 1] < 0.0):
        # (a face below COLLAPSE_AREA_RATIO is compressed, so the barrier is needed on this path only)
        energy = _filtered_element_into(F, E, Dm_inv, area, mu, lam, alpha, project, grad, hess)
        return energy + area_barrier_into(x0, x1, x2, area, 2.0 * mu + lam, not project, grad, hess)
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
    FFt = np.empty((3, 3))  # F F^T, summed in order (as membrane_elements does; BLAS may fuse)
    for i in range(3):
        for j in range(3):
            FFt[i, j] = F[i, 0] * F[j, 0] + F[i, 1] * F[j, 1]
    clamp = project == GAUSS_NEWTON and not (S00 + S11 >= 0.0 and S00 * S11 - S01 * S01 >= 0.0)
    if clamp:  # the geometric term of S's positive part: the material term is PSD, so is their sum
        l1, l2, q1, q2 = _eig_sym2(S00, S01, S11)
        l1, l2 = max(l1, 0.0), max(l2, 0.0)
        P00 = l1 * q1[0] * q1[0] + l2 * q2[0] * q2[0]
        P01 = l1 * q1[0] * q1[1] + l2 * q2[0] * q2[1]
        P11 = l1 * q1[1] * q1[1] + l2 * q2[1] * q2[1]
        for a in range(3):
            Sg[a, 0] = P00 * g[a, 0] + P01 * g[a, 1]
            Sg[a, 1] = P01 * g[a, 0] + P11 * g[a, 1]
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
    if project and not clamp and not (S00 + S11 >= 0.0 and S00 * S11 - S01 * S01 >= 0.0):
        project_psd_face_planar(hess, g, F, _strongly_compressed(E[0, 0], E[0, 1], E[1, 1]))
    return energy


@njit(cache=True)
def stvk_element(x0, x1, x2, Dm_inv, area, mu, lam, project, alpha=1.0):
    """(energy, gradient (9,), Hessian (9, 9)) of the StVK membrane energy of one face."""
    grad = np.empty(9)
    hess = np.empty((9, 9))
    energy = stvk_element_into(x0, x1, x2, Dm_inv, area, mu, lam, project, grad, hess, alpha)
    return energy, grad, hess


@njit(cache=True, parallel=True)
def membrane_elements(node_x, face_nodes, face_Dm_inv, face_area, mu, lam, project,
                      out_energy, out_grad, out_hess, face_alpha):
    """Energy (F,), gradient (F, 9) and Hessian (F, 9, 9) of every face (each writes its own slot).

    `face_alpha` (F,) is each face's compression factor (1: plain StVK; cloth.physics.buckling).
    The plain StVK face (alpha = 1, or no compressed direction), exact or Gauss-Newton, and the
    projected one whose stress is positive semi-definite, are computed here on scalars, with no
    array made per face (the formulas of :func:`stvk_element_into`, term for term: the same to
    round-off); a filtered face, and a projected one whose stress is not PSD, go through
    :func:`stvk_element_into`.
    """
    other = np.zeros(face_nodes.shape[0], dtype=np.bool_)  # faces for stvk_element_into, after the loop
    for f in prange(face_nodes.shape[0]):
        a, b, c = face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2]
        B00, B01 = face_Dm_inv[f, 0, 0], face_Dm_inv[f, 0, 1]
        B10, B11 = face_Dm_inv[f, 1, 0], face_Dm_inv[f, 1, 1]
        # F = [x1 - x0, x2 - x0] Dm^-1 (deformation_gradient), rows i
        d1, d2 = node_x[b, 0] - node_x[a, 0], node_x[c, 0] - node_x[a, 0]
        F00, F01 = d1 * B00 + d2 * B10, d1 * B01 + d2 * B11
        d1, d2 = node_x[b, 1] - node_x[a, 1], node_x[c, 1] - node_x[a, 1]
        F10, F11 = d1 * B00 + d2 * B10, d1 * B01 + d2 * B11
        d1, d2 = node_x[b, 2] - node_x[a, 2], node_x[c, 2] - node_x[a, 2]
        F20, F21 = d1 * B00 + d2 * B10, d1 * B01 + d2 * B11
        # E = 1/2 (F^T F - I) (green_strain)
        E00 = 0.5 * ((F00 * F00 + F10 * F10 + F20 * F20) - 1.0)
        E01 = 0.5 * ((F00 * F01 + F10 * F11 + F20 * F21) - 0.0)
        E11 = 0.5 * ((F01 * F01 + F11 * F11 + F21 * F21) - 1.0)
        area, alpha = face_area[f], face_alpha[f]
        trE = E00 + E11
        S00 = 2.0 * mu * E00 + lam * trE
        S11 = 2.0 * mu * E11 + lam * trE
        S01 = 2.0 * mu * E01
        psd = S00 + S11 >= 0.0 and S00 * S11 - S01 * S01 >= 0.0
        filtered = alpha < 1.0 and (E00 + E11 < 0.0 or E00 * E11 - E01 * E01 < 0.0)
        if filtered or (project and project != GAUSS_NEWTON and not psd):
            other[f] = True  # (a call here, in the loop, would slow every face down)
            continue
        out_energy[f] = area * (mu * (E00 ** 2 + 2.0 * E01 ** 2 + E11 ** 2) + 0.5 * lam * trE * trE)
        g = ((-B00 - B10, -B01 - B11), (B00, B01), (B10, B11))  # rows g_a
        Fm = ((F00, F01), (F10, F11), (F20, F21))
        for k in range(3):
            sg0 = S00 * g[k][0] + S01 * g[k][1]
            sg1 = S01 * g[k][0] + S11 * g[k][1]
            for i in range(3):
                out_grad[f, 3 * k + i] = area * (Fm[i][0] * sg0 + Fm[i][1] * sg1)
        P00, P01, P11 = S00, S01, S11
        if project == GAUSS_NEWTON and not psd:  # the stress's positive part in the geometric term
            m = 0.5 * (S00 + S11)
            r = np.sqrt(0.25 * (S00 - S11) * (S00 - S11) + S01 * S01)
            l1, l2 = max(m + r, 0.0), max(m - r, 0.0)
            if r == 0.0:  # (_eig_sym2's eigenvector, its formulas)
                q0, q1 = 1.0, 0.0
            elif S00 >= S11:
                q0, q1 = S00 - (m - r), S01
            else:
                q0, q1 = S01, S11 - (m - r)
            n = np.sqrt(q0 * q0 + q1 * q1)
            q0, q1 = q0 / n, q1 / n
            p0, p1 = -q1, q0
            P00 = l1 * q0 * q0 + l2 * p0 * p0
            P01 = l1 * q0 * q1 + l2 * p0 * p1
            P11 = l1 * q1 * q1 + l2 * p1 * p1
        for k in range(3):
            for j in range(3):
                gSg = g[k][0] * (P00 * g[j][0] + P01 * g[j][1]) + g[k][1] * (P01 * g[j][0] + P11 * g[j][1])
                gg = g[k][0] * g[j][0] + g[k][1] * g[j][1]
                for i in range(3):
                    Fgk_i = Fm[i][0] * g[k][0] + Fm[i][1] * g[k][1]
                    Fgj_i = Fm[i][0] * g[j][0] + Fm[i][1] * g[j][1]
                    for q in range(3):
                        Fgk_q = Fm[q][0] * g[k][0] + Fm[q][1] * g[k][1]
                        Fgj_q = Fm[q][0] * g[j][0] + Fm[q][1] * g[j][1]
                        FFt = Fm[i][0] * Fm[q][0] + Fm[i][1] * Fm[q][1]
                        h = mu * Fgj_i * Fgk_q + mu * gg * FFt + lam * Fgk_i * Fgj_q
                        if i == q:
                            h += gSg
                        out_hess[f, 3 * k + i, 3 * j + q] = area * h
    rest = np.flatnonzero(other)
    for r in prange(rest.shape[0]):
        f = rest[r]
        a, b, c = face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2]
        out_energy[f] = stvk_element_into(node_x[a], node_x[b], node_x[c], face_Dm_inv[f], face_area[f], mu, lam,
                                          project, out_grad[f], out_hess[f], face_alpha[f])


@njit(cache=True)
def face_green_strain(node_x, face_nodes, face_Dm_inv):
    """Green strain of every face, (F, 2, 2)."""
    out = np.empty((face_nodes.shape[0], 2, 2))
    for f in range(face_nodes.shape[0]):
        F = deformation_gradient(node_x[face_nodes[f, 0]], node_x[face_nodes[f, 1]],
                                 node_x[face_nodes[f, 2]], face_Dm_inv[f])
        out[f] = green_strain(F)
    return out
