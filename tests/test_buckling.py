"""Buckling compensation (paper eqs 9-11): hand cases of eqs 10 and 11, and the filtered membrane's
energy, gradient and Hessian against the public filter and finite differences."""

import numpy as np
import pytest
from helpers import random_rest_triangle

from cloth.physics.buckling import (
    ALPHA_MIN,
    BucklingError,
    BucklingParams,
    compression_factor,
    face_alpha,
    filter_strain,
)
from cloth.physics.membrane import deformation_gradient, green_strain, stvk_element

# Central differences with step 1e-6 on O(1) coordinates: truncation ~1e-12, round-off ~1e-10
# relative. The filtered energy has a kink where a principal strain crosses 0; the random cases
# below stay away from it by construction (|principal strains| > 0.02).
FD_STEP = 1e-6
FD_REL_TOL = 1e-5
ROUNDOFF = 1e-12
MU, LAM = 3.0, 2.0


def test_compression_factor_hand_cases():
    area = np.array([1.0, 2.0, 3.0, 5.0])
    # ((5 - A) / 4)^k: 1, (3/4)^k, (1/2)^k, 0
    assert np.allclose(compression_factor(area, 1), [1.0, 0.75, 0.5, 0.0])
    assert np.allclose(compression_factor(area, 10), [1.0, 0.75 ** 10, 0.5 ** 10, 0.0])
    assert np.allclose(compression_factor(np.full(7, 0.3), 10), 1.0)  # all equal: no compensation
    assert compression_factor(np.zeros(0), 10).size == 0
    with pytest.raises(BucklingError, match="k must be >= 1"):
        compression_factor(area, 0.5)


def test_compression_factor_is_monotone_and_in_unit_interval():
    area = np.random.default_rng(0).uniform(1e-4, 1e-1, 50)
    a = compression_factor(area, 10)
    assert np.all((a >= 0) & (a <= 1))
    order = np.argsort(area)
    assert np.all(np.diff(a[order]) <= 0)  # bigger faces are more compressible


def test_filter_strain_hand_cases():
    E = np.array([[[0.1, 0.0], [0.0, -0.2]],   # principal axes: only the compressive one scales
                  [[-0.1, 0.0], [0.0, -0.3]],  # both compressive
                  [[0.2, 0.0], [0.0, 0.05]]])  # no compression: unchanged
    out = filter_strain(E, np.array([0.5, 0.25, 0.0]))
    assert np.allclose(out[0], [[0.1, 0.0], [0.0, -0.1]])
    assert np.allclose(out[1], [[-0.025, 0.0], [0.0, -0.075]])
    assert np.allclose(out[2], E[2])
    # rotated principal axes: E = R diag(0.1, -0.2) R^T -> R diag(0.1, -0.2 alpha) R^T
    c, s = np.cos(0.4), np.sin(0.4)
    R = np.array([[c, -s], [s, c]])
    Er = R @ np.diag([0.1, -0.2]) @ R.T
    assert np.allclose(filter_strain(Er[None], 0.3)[0], R @ np.diag([0.1, -0.06]) @ R.T)
    # alpha = 1 is the identity, alpha = 0 keeps only the tensile part
    assert np.allclose(filter_strain(Er[None], 1.0)[0], Er)
    assert np.allclose(filter_strain(Er[None], 0.0)[0], R @ np.diag([0.1, 0.0]) @ R.T)


def test_face_alpha_only_touches_out_of_frustum_faces():
    area = np.array([1.0, 2.0, 3.0, 4.0])
    out = np.array([False, True, True, False])
    a = face_alpha(area, out, BucklingParams(k=1, alpha_min=0.0))
    assert np.allclose(a, [1.0, 1.0, 0.0, 1.0])  # eq 11 over the two out-of-frustum faces only
    assert np.allclose(face_alpha(area, out, BucklingParams(mode="uniform", alpha_min=0.0)), [1, 0, 0, 1])


def test_alpha_floor_keeps_every_compensated_face_some_compression_resistance():
    """alpha >= alpha_min on the out-of-frustum faces (the largest face's eq 11 value is 0), eq 11
    unchanged above the floor, faces in view at 1, uniform compensation at the floor."""
    area = np.linspace(1.0, 2.0, 11)
    out = np.ones(11, dtype=bool)
    out[0] = False
    floor = BucklingParams(k=3).alpha_min
    assert floor == ALPHA_MIN > 0
    a = face_alpha(area, out, BucklingParams(k=3))
    raw = face_alpha(area, out, BucklingParams(k=3, alpha_min=0.0))
    assert a[0] == 1.0 and raw[-1] == 0.0 and a[-1] == ALPHA_MIN
    assert np.all(a[out] >= ALPHA_MIN)
    above = raw >= ALPHA_MIN
    assert above[1:-1].sum() >= 5 and np.array_equal(a[above], raw[above])
    assert np.all(face_alpha(area, out, BucklingParams(mode="uniform"))[out] == ALPHA_MIN)
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(BucklingError, match="alpha_min"):
            BucklingParams(alpha_min=bad)


def _compressed_cases():
    """Random elements with at least one principal strain below -0.02 and none within 0.02 of 0."""
    rng = np.random.default_rng(3)
    found = 0
    for seed in range(400):
        u, B, A = random_rest_triangle(seed)
        x0 = np.column_stack([u, np.zeros(3)])
        x = x0 * [rng.uniform(0.6, 1.2), rng.uniform(0.6, 1.2), 1] + 0.1 * rng.standard_normal((3, 3))
        E = green_strain(deformation_gradient(x[0], x[1], x[2], B))
        lam = np.linalg.eigvalsh(E)
        if lam.min() < -0.02 and np.all(np.abs(lam) > 0.02):
            yield B, A, x.reshape(-1)
            found += 1
            if found == 8:
                return


CASES = [(c, alpha) for c in range(8) for alpha in (0.0, 0.3, 1.0)]


@pytest.mark.parametrize("case, alpha", CASES)
def test_filtered_membrane_matches_the_filter_and_finite_differences(case, alpha):
    B, A, x = list(_compressed_cases())[case]

    def elem(y):
        return stvk_element(y[0:3], y[3:6], y[6:9], B, A, MU, LAM, False, alpha)

    e, g, H = elem(x)
    # energy = StVK of the filtered strain (eq 10 through the public function)
    E = green_strain(deformation_gradient(x[0:3], x[3:6], x[6:9], B))
    Eh = filter_strain(E[None], alpha)[0]
    assert np.isclose(e, A * (MU * np.sum(Eh * Eh) + 0.5 * LAM * np.trace(Eh) ** 2), rtol=1e-12)
    fd_g = np.array([(elem(x + d)[0] - elem(x - d)[0]) / (2 * FD_STEP) for d in np.eye(9) * FD_STEP])
    assert np.linalg.norm(g - fd_g) <= FD_REL_TOL * np.linalg.norm(fd_g) + ROUNDOFF
    fd_H = np.column_stack([(elem(x + d)[1] - elem(x - d)[1]) / (2 * FD_STEP) for d in np.eye(9) * FD_STEP])
    assert np.linalg.norm(H - fd_H) <= FD_REL_TOL * np.linalg.norm(fd_H) + ROUNDOFF
    # the filtered path agrees with plain StVK at alpha = 1
    if alpha == 1.0:
        e0, g0, H0 = stvk_element(x[0:3], x[3:6], x[6:9], B, A, MU, LAM, False)
        assert np.isclose(e, e0) and np.allclose(g, g0) and np.allclose(H, H0)
    # projection makes it PSD
    Hp = stvk_element(x[0:3], x[3:6], x[6:9], B, A, MU, LAM, True, alpha)[2]
    assert np.linalg.eigvalsh(Hp).min() >= -1e-10 * np.abs(Hp).max()


def test_alpha_zero_makes_pure_compression_free():
    u, B, A = random_rest_triangle(1)
    x = (np.column_stack([u, np.zeros(3)]) * [0.8, 0.7, 1]).reshape(-1)  # compressed both ways
    e, g, _ = stvk_element(x[0:3], x[3:6], x[6:9], B, A, MU, LAM, True, 0.0)
    assert abs(e) < ROUNDOFF and np.abs(g).max() < ROUNDOFF
    e1, _, _ = stvk_element(x[0:3], x[3:6], x[6:9], B, A, MU, LAM, True, 1.0)
    assert e1 > 0


def _collapsed_cases():
    """Random compensated faces squeezed to 2-24 % of their rest area (below COLLAPSE_AREA_RATIO),
    tilted out of plane, away from the strain kink at 0 (|principal strains| > 0.02)."""
    from cloth.physics.membrane import COLLAPSE_AREA_RATIO
    rng = np.random.default_rng(5)
    for seed in range(2000):
        u, B, A = random_rest_triangle(seed)
        x = np.column_stack([u, np.zeros(3)]) * [rng.uniform(0.05, 1.3), rng.uniform(0.05, 0.5), 1]
        x = x @ np.linalg.qr(rng.standard_normal((3, 3)))[0] + 0.002 * rng.standard_normal((3, 3))
        n = np.cross(x[1] - x[0], x[2] - x[0])
        J = 0.5 * np.linalg.norm(n) / A
        lam = np.linalg.eigvalsh(green_strain(deformation_gradient(x[0], x[1], x[2], B)))
        if 0.02 < J < 0.96 * COLLAPSE_AREA_RATIO and np.all(np.abs(lam) > 0.02):
            yield B, A, x.reshape(-1), J


@pytest.mark.parametrize("case", range(6))
def test_the_collapse_barrier_matches_finite_differences_and_keeps_the_projection_psd(case):
    """A compensated face below COLLAPSE_AREA_RATIO of its area stores A kappa / 2 (J_c - J)^2 on top of
    eq 10's energy: the exact gradient and Hessian (project=False) against central differences, the
    projected Hessian positive semi-definite, and the energy eq 10's plus the barrier's by hand."""
    from cloth.physics.membrane import COLLAPSE_AREA_RATIO
    B, A, x, J = list(_collapsed_cases())[case]
    alpha = 0.3

    def elem(y, project=False):
        return stvk_element(y[0:3], y[3:6], y[6:9], B, A, MU, LAM, project, alpha)

    e, g, H = elem(x)
    E = green_strain(deformation_gradient(x[0:3], x[3:6], x[6:9], B))
    Eh = filter_strain(E[None], alpha)[0]
    barrier = 0.5 * A * (2 * MU + LAM) * (COLLAPSE_AREA_RATIO - J) ** 2
    assert barrier > 0 and np.isclose(e, A * (MU * np.sum(Eh * Eh) + 0.5 * LAM * np.trace(Eh) ** 2) + barrier,
                                      rtol=1e-12)
    fd_g = np.array([(elem(x + d)[0] - elem(x - d)[0]) / (2 * FD_STEP) for d in np.eye(9) * FD_STEP])
    assert np.linalg.norm(g - fd_g) <= FD_REL_TOL * np.linalg.norm(fd_g) + ROUNDOFF
    fd_H = np.column_stack([(elem(x + d)[1] - elem(x - d)[1]) / (2 * FD_STEP) for d in np.eye(9) * FD_STEP])
    assert np.linalg.norm(H - fd_H) <= FD_REL_TOL * np.linalg.norm(fd_H) + ROUNDOFF
    for project in (True, 2):  # projected and Gauss-Newton
        Hp = elem(x, project)[2]
        assert np.linalg.eigvalsh(Hp).min() >= -1e-10 * np.abs(Hp).max()


def test_the_collapse_barrier_acts_only_on_compensated_faces_below_the_ratio():
    """No barrier at alpha = 1 (plain StVK), none at or above COLLAPSE_AREA_RATIO, and its force
    opens the face: it pushes the area up (the gradient's descent raises J)."""
    from cloth.physics.membrane import COLLAPSE_AREA_RATIO, area_barrier_into
    u, B, A = random_rest_triangle(2)
    flat = np.column_stack([u, np.zeros(3)])
    for s, expect in ((1.0, False), (np.sqrt(COLLAPSE_AREA_RATIO) * 1.001, False), (0.3, True)):
        x = flat * [s, s, 1]
        g, H = np.zeros(9), np.zeros((9, 9))
        e = area_barrier_into(x[0], x[1], x[2], A, 1.0, True, g, H)
        assert (e > 0) == expect and (np.abs(g).max() > 0) == expect
        if expect:
            y = x.reshape(-1) - 1e-4 * g / np.linalg.norm(g)
            n0 = np.linalg.norm(np.cross(x[1] - x[0], x[2] - x[0]))
            n1 = np.linalg.norm(np.cross(y[3:6] - y[0:3], y[6:9] - y[0:3]))
            assert n1 > n0
    x = (flat * [0.3, 0.3, 1]).reshape(-1)
    plain = stvk_element(x[0:3], x[3:6], x[6:9], B, A, MU, LAM, False, 1.0)[0]
    E = green_strain(deformation_gradient(x[0:3], x[3:6], x[6:9], B))
    assert np.isclose(plain, A * (MU * np.sum(E * E) + 0.5 * LAM * np.trace(E) ** 2), rtol=1e-12)
