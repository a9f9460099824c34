"""Collision primitives against brute force: closest points by dense sampling, continuous
collision detection by dense sampling of the motion, edge-triangle crossings by hand cases."""

import numpy as np
import pytest

from cloth.collision.ccd import edge_triangle_crossing, ee_ccd, point_triangle_closest, segment_segment_closest, vf_ccd

# dense sampling of a unit-size triangle with 300 x 300 barycentric steps finds the distance to
# within the sampling step (~1/300 of the size)
SAMPLE_TOL = 5e-3
ETA = 1e-6  # CCD touch distance (m) for unit-size primitives
TIME_STEPS = 4000  # dense time sampling of a motion: 1/4000 of the step


def tri_samples(a, b, c, n=300):
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
    keep = i + j <= n
    u, v = i[keep] / n, j[keep] / n
    return a + u[:, None] * (b - a) + v[:, None] * (c - a)


def test_point_triangle_closest_against_sampling():
    rng = np.random.default_rng(3)
    for k in range(150):
        a, b, c, p = rng.standard_normal((4, 3))
        if k % 10 == 0:
            c = a + 0.5 * (b - a)  # degenerate (collinear) triangle
        d, w0, w1, w2 = point_triangle_closest(p, a, b, c)
        brute = np.min(np.linalg.norm(tri_samples(a, b, c) - p, axis=1))
        assert d <= brute + 1e-12 and brute - d < SAMPLE_TOL, k
        assert min(w0, w1, w2) >= -1e-12 and abs(w0 + w1 + w2 - 1) < 1e-12
        assert abs(np.linalg.norm(p - (w0 * a + w1 * b + w2 * c)) - d) < 1e-12


@pytest.mark.slow
def test_segment_segment_closest_against_sampling():
    rng = np.random.default_rng(4)
    s = np.linspace(0, 1, 801)
    for k in range(150):
        p0, p1, q0, q1 = rng.standard_normal((4, 3))
        if k % 10 == 0:
            q0, q1 = p0 + [0.0, 0.0, 0.3], p1 + [0.0, 0.0, 0.3]  # parallel
        if k % 10 == 1:
            q1 = q0.copy()  # zero length
        d, ss, tt = segment_segment_closest(p0, p1, q0, q1)
        P = p0 + s[:, None] * (p1 - p0)
        Q = q0 + s[:, None] * (q1 - q0)
        brute = np.min(np.linalg.norm(P[:, None] - Q[None], axis=2))
        assert d <= brute + 1e-12 and brute - d < SAMPLE_TOL, k
        assert 0 <= ss <= 1 and 0 <= tt <= 1
        assert abs(np.linalg.norm((p0 + ss * (p1 - p0)) - (q0 + tt * (q1 - q0))) - d) < 1e-12


TRI0 = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def test_vf_ccd_hand_cases():
    a, b, c = TRI0
    # falls through the triangle from z = 1 to z = -1: touches at t = 0.5
    t = vf_ccd(np.array([0.2, 0.2, 1.0]), a, b, c, np.array([0.2, 0.2, -1.0]), a, b, c, ETA)
    assert t == pytest.approx(0.5, abs=1e-9)
    # passes beside it
    assert vf_ccd(np.array([0.8, 0.8, 1.0]), a, b, c, np.array([0.8, 0.8, -1.0]), a, b, c, ETA) == -1.0
    # exactly through an edge
    t = vf_ccd(np.array([0.5, 0.0, 1.0]), a, b, c, np.array([0.5, 0.0, -1.0]), a, b, c, ETA)
    assert t == pytest.approx(0.5, abs=1e-9)
    # the triangle moves up onto a resting point
    t = vf_ccd(np.array([0.1, 0.1, 0.5]), a, b, c, np.array([0.1, 0.1, 0.5]), a + [0, 0, 1], b + [0, 0, 1],
               c + [0, 0, 1], ETA)
    assert t == pytest.approx(0.5, abs=1e-9)


def test_ee_ccd_hand_cases():
    p0, q0 = np.array([0.0, -1.0, 1.0]), np.array([0.0, 1.0, 1.0])
    P, Q = np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    down = np.array([0.0, 0.0, -2.0])
    t = ee_ccd(p0, p0 + down, q0, q0 + down, P, P, Q, Q, ETA)
    assert t == pytest.approx(0.5, abs=1e-9)
    shifted = np.array([3.0, 0.0, 0.0])  # passes beside the other edge's end
    assert ee_ccd(p0 + shifted, p0 + shifted + down, q0 + shifted, q0 + shifted + down, P, P, Q, Q, ETA) == -1.0
    # coplanar all along: parallel edges in the plane z = 0 sliding into each other
    a0, a1 = np.array([0.0, 1.0, 0.0]), np.array([1.0, 1.0, 0.0])
    move = np.array([0.0, -1.0, 0.0])
    t = ee_ccd(a0, a0 + move, a1, a1 + move, np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0]),
               np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), ETA)
    assert 0.9 <= t <= 1.0


def _vf_distance(x0, x1, t):
    x = x0 + t * (x1 - x0)
    return point_triangle_closest(x[0], x[1], x[2], x[3])[0]


def test_vf_ccd_against_time_sampling():
    rng = np.random.default_rng(5)
    ts = np.linspace(0, 1, TIME_STEPS + 1)
    hits = 0
    for k in range(60):
        x0 = rng.standard_normal((4, 3)) * 0.5
        x1 = x0 + rng.standard_normal((4, 3))
        if k % 2:  # the point crosses the triangle's plane near its centre: a likely touch
            x0[0] = x0[1:].mean(axis=0) + np.cross(x0[2] - x0[1], x0[3] - x0[1])
            x1[0] = x1[1:].mean(axis=0) - np.cross(x1[2] - x1[1], x1[3] - x1[1]) + 0.3 * rng.standard_normal(3)
        d = np.array([_vf_distance(x0, x1, t) for t in ts])
        eta = 0.02  # a coarse touch distance so that sampling can see the touches
        t = vf_ccd(x0[0], x0[1], x0[2], x0[3], x1[0], x1[1], x1[2], x1[3], eta)
        if t >= 0:
            hits += 1
            assert _vf_distance(x0, x1, t) <= eta * (1 + 1e-9), k
        if d.min() < eta / 10:  # the sampled motion clearly comes close: CCD must see it
            assert t >= 0, k
    assert hits > 5  # the random motions include touches


def test_edge_triangle_crossing():
    a, b, c = TRI0
    hit, s = edge_triangle_crossing(np.array([0.2, 0.2, -1.0]), np.array([0.2, 0.2, 3.0]), a, b, c)
    assert hit and s == pytest.approx(0.25)
    assert not edge_triangle_crossing(np.array([0.9, 0.9, -1.0]), np.array([0.9, 0.9, 1.0]), a, b, c)[0]
    assert not edge_triangle_crossing(np.array([0.2, 0.2, 0.5]), np.array([0.2, 0.2, 1.0]), a, b, c)[0]
    # an end point in the plane is not a crossing (strictly opposite sides)
    assert not edge_triangle_crossing(np.array([0.2, 0.2, 0.0]), np.array([0.2, 0.2, 1.0]), a, b, c)[0]
