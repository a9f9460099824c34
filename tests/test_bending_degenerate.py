"""Bending near a collapsing face: bounded forces and Hessians, continuity through a flip and the fold.

The hinge of the issue: a 5 cm edge of cotton (k_bend 5e-6 N m), faces 2.5 cm high at rest, bent
30 degrees; face A's height goes from 1 mm to 1e-12 m and through its edge. Without the fade its
force grew as 1 / h (7.9e4 N at 1e-10 m) and theta jumped from -0.52 to 2.62 rad at the flip.
"""

import numpy as np
import pytest

from cloth.physics.bending import (
    GAUSS_NEWTON,
    HINGE_FADE_HEIGHT,
    bending_element,
    dihedral_angle,
    hinge_fade,
    hinge_weight,
)

# A hinge's force is at most about w |d| / (q0 |e|) from the angle (d theta / dx has length 1 / h,
# and the fade removes the force below h = q0 |e|) plus 0.77 w d^2 / (q0 |e|) from the fade's
# slope; its end nodes x0, x1 take parts of both faces'. Over 3,000 random hinges (edges 1 mm to
# 1 m, heights 1e-13 |e| to |e| on both sides, rest angles in [-1, 1]) the largest ratio of
# |grad|_max to w (|d| + d^2) / (q0 |e|) was 1.24: the bound is twice that.
FORCE_BOUND = 2.5
# The Hessian: w (1 + |d|) / (q0 |e|)^2 (d theta / dx squared, and |d| times theta's Hessian,
# both of order 1 / h^2 with h >= q0 |e| in effect); the sample's largest ratio was 4.04.
HESSIAN_BOUND = 8.0
# Central differences of the energy: step 1e-9 m on a face 5e-4 m high (h / step = 5e5) leaves a
# truncation error of order (step / h)^2 and round-off of 1e-16 / 1e-9 relative.
FD_STEP = 1e-9
FD_REL_TOL = 1e-5
# A Hessian's smallest eigenvalue may be negative by the round-off of its eigenvalues.
PSD_TOL = 1e-10

EDGE = 0.05  # m
REST_HEIGHT = 0.025  # m
K_BEND = 5e-6  # N m, conf/material/cotton.yaml
BENT = np.radians(30.0)
WEIGHT = hinge_weight(EDGE, 0.5 * EDGE * REST_HEIGHT, 0.5 * EDGE * REST_HEIGHT, K_BEND)
HEIGHTS = [1e-3, 5e-4, 2e-4, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-10, 1e-12, 0.0, -1e-12, -1e-7, -1e-4]
PROJECTIONS = [False, True, GAUSS_NEWTON]


def _hinge(h, fold=BENT):
    """(x0, x1, x2, x3): the issue's hinge, face A (x0, x1, x2) h high in the z = 0 plane."""
    return (np.zeros(3), np.array([EDGE, 0.0, 0.0]), np.array([EDGE / 2, h, 0.0]),
            np.array([EDGE / 2, -REST_HEIGHT * np.cos(fold), -REST_HEIGHT * np.sin(fold)]))


def _bounds(x, rest, w):
    d = abs(dihedral_angle(*x) - rest)
    scale = HINGE_FADE_HEIGHT * np.linalg.norm(x[1] - x[0])
    return FORCE_BOUND * w * (d + d * d) / scale, HESSIAN_BOUND * w * (1 + d) / scale ** 2


@pytest.mark.slow
@pytest.mark.parametrize("project", PROJECTIONS)
def test_the_issues_hinge_stays_bounded_as_a_face_collapses_and_flips(project):
    g_bound, H_bound = _bounds(_hinge(1e-3), 0.0, WEIGHT)
    largest = 0.0
    for h in HEIGHTS:
        x = _hinge(h)
        e, g, H = bending_element(*x, 0.0, WEIGHT, project)
        assert np.isfinite(e) and np.all(np.isfinite(g)) and np.all(np.isfinite(H))
        # the flipped side has theta = -2.62: its own, larger, bound
        gb, Hb = (g_bound, H_bound) if h >= 0 else _bounds(x, 0.0, WEIGHT)
        assert np.abs(g).max() <= gb, h
        assert np.abs(H).max() <= Hb, h
        if h >= 0:
            largest = max(largest, np.abs(g).max())
    # without the fade the gradient at 1e-12 m would be 1.6e7 N; with it, below the 1 mm value x 2
    assert largest < 2 * np.abs(bending_element(*_hinge(1e-3), 0.0, WEIGHT, True)[1]).max()


def test_energy_and_force_are_continuous_through_the_flip():
    """theta jumps by pi where face A passes through its edge; the faded energy and force go to 0
    from both sides, so the jump does not show."""
    for project in PROJECTIONS:
        above = bending_element(*_hinge(1e-7), 0.0, WEIGHT, project)
        below = bending_element(*_hinge(-1e-7), 0.0, WEIGHT, project)
        healthy = bending_element(*_hinge(REST_HEIGHT), 0.0, WEIGHT, project)
        peak = bending_element(*_hinge(HINGE_FADE_HEIGHT * EDGE), 0.0, WEIGHT, project)  # where the fade starts
        for h, side in ((1e-7, above), (-1e-7, below)):  # at 1e-7 m = 2e-4 q0 |e|: S = 8e-8
            assert side[0] < 1e-5 * healthy[0]  # d^2 is up to 25 times the healthy side's
            assert np.abs(side[1]).max() < 1e-2 * np.abs(peak[1]).max()
            # and the force goes to 0 as h: 100 times closer, 100 times smaller (to 2x)
            closer = bending_element(*_hinge(h / 100), 0.0, WEIGHT, project)[1]
            assert np.abs(closer).max() < 2e-2 * np.abs(side[1]).max()
    assert dihedral_angle(*_hinge(1e-7)) == pytest.approx(BENT)
    assert dihedral_angle(*_hinge(-1e-7)) == pytest.approx(BENT - np.pi)


@pytest.mark.parametrize("h", [4e-4, 2e-4, 5e-5, 1e-5])
def test_faded_gradient_matches_finite_differences(h):
    """In the fade (h < q0 |e| = 5e-4 m) the gradient is the faded energy's, exactly."""
    rng = np.random.default_rng(3)
    x = np.concatenate(_hinge(h)) + 1e-3 * h * rng.standard_normal(12)
    for project in PROJECTIONS:
        def energy(y, project=project):
            return bending_element(y[0:3], y[3:6], y[6:9], y[9:12], 0.2, WEIGHT, project)[0]

        g = bending_element(x[0:3], x[3:6], x[6:9], x[9:12], 0.2, WEIGHT, project)[1]
        fd = np.array([(energy(x + FD_STEP * e) - energy(x - FD_STEP * e)) / (2 * FD_STEP) for e in np.eye(12)])
        assert np.linalg.norm(g - fd) < FD_REL_TOL * np.linalg.norm(fd)


def test_fade_gradient_matches_finite_differences():
    rng = np.random.default_rng(5)
    for _ in range(10):
        a = rng.standard_normal(3)
        b = 0.6 * a + 0.004 * rng.standard_normal(3)  # face A nearly collinear with the edge
        c = rng.standard_normal(3)
        g = np.empty(9)
        S = hinge_fade(a, b, c, g)
        assert 0.0 < S < 1.0
        v = np.concatenate([a, b, c])
        step = 1e-8
        fd = np.empty(9)
        for i in range(9):
            e = np.zeros(9)
            e[i] = step
            p, m = v + e, v - e
            fd[i] = (hinge_fade(p[:3], p[3:6], p[6:], np.empty(9)) - hinge_fade(m[:3], m[3:6], m[6:], np.empty(9))) / (
                2 * step)
        assert np.linalg.norm(g - fd) < FD_REL_TOL * np.linalg.norm(fd)


def test_hessian_is_psd_in_the_fade():
    for h in (4e-4, 1e-5, 1e-9):
        for project in PROJECTIONS:
            H = bending_element(*_hinge(h), 0.3, WEIGHT, project)[2]
            assert np.linalg.eigvalsh(H).min() >= -PSD_TOL * np.abs(H).max()


def test_healthy_hinges_are_untouched_by_the_fade():
    g = np.empty(9)
    x = _hinge(REST_HEIGHT)
    assert hinge_fade(x[1] - x[0], x[2] - x[0], x[3] - x[0], g) == 1.0 and not g.any()
    x = _hinge(1.01 * HINGE_FADE_HEIGHT * EDGE)
    assert hinge_fade(x[1] - x[0], x[2] - x[0], x[3] - x[0], g) == 1.0


@pytest.mark.parametrize("rest", [0.0, 0.4])
def test_force_stays_bounded_across_the_fold_at_pi(rest):
    """x3 swung around the edge through theta = +-pi (face B folded onto face A): atan2 wraps, the
    energy is the same on both sides with a flat rest angle, and the force is bounded throughout."""
    folds = np.linspace(np.pi - 0.2, np.pi + 0.2, 41)
    energies = []
    for fold in folds:
        x = _hinge(REST_HEIGHT, fold)
        for project in PROJECTIONS:
            e, g, H = bending_element(*x, rest, WEIGHT, project)
            g_bound, H_bound = _bounds(x, rest, WEIGHT)
            assert np.abs(g).max() <= g_bound and np.abs(H).max() <= H_bound
        energies.append(bending_element(*x, rest, WEIGHT, True)[0])
    jumps = np.abs(np.diff(energies))
    smooth = np.median(jumps)
    if rest == 0.0:
        assert jumps.max() < 10 * smooth
    else:  # the step of 2 pi w theta_rest where atan2 wraps, and nowhere else
        assert jumps.max() == pytest.approx(2 * np.pi * WEIGHT * rest, rel=0.05)
        assert np.sort(jumps)[-2] < 10 * smooth


def test_random_hinges_stay_within_the_bounds():
    rng = np.random.default_rng(11)
    for _ in range(400):
        L = 10 ** rng.uniform(-3, 0)
        hB, fold = L * rng.uniform(0.05, 1.5), rng.uniform(-3.1, 3.1)
        h = L * 10 ** rng.uniform(-13, 0) * rng.choice([-1, 1])
        x = [np.zeros(3), np.array([L, 0, 0]), np.array([rng.uniform(-0.5, 1.5) * L, h, 0]),
             np.array([rng.uniform(-0.5, 1.5) * L, -hB * np.cos(fold), -hB * np.sin(fold)])]
        R, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        x = [R @ p for p in x]
        rest, w = rng.uniform(-1, 1), 10 ** rng.uniform(-8, -3)
        g_bound, H_bound = _bounds(x, rest, w)
        for project in PROJECTIONS:
            _, g, H = bending_element(*x, rest, w, project)
            assert np.abs(g).max() <= g_bound and np.abs(H).max() <= H_bound
