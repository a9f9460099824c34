"""Analytic obstacles against closed forms and finite differences; contact projection and friction."""

import numpy as np
import pytest

from cloth.collision.contact import resolve_obstacle_contacts
from cloth.collision.obstacles import Capsule, CapsuleUnion, Linear, ObstacleSet, Oscillate, Plane, Sphere, Spin, Static

# Distances are sums and square roots of O(1) numbers.
ROUNDOFF = 1e-12
# Central differences (step 1e-6) of a smooth distance or trajectory: truncation ~1e-12,
# cancellation ~1e-10.
FD_STEP = 1e-6
FD_TOL = 1e-7
rng = np.random.default_rng(5)
POINTS = rng.uniform(-1.5, 1.5, (200, 3))


def _segment_distance(p, a, b):
    t = np.clip(((p - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    return np.linalg.norm(p - (a + t[:, None] * (b - a)), axis=1)


def test_signed_distances_match_closed_forms():
    phi, n, _ = Plane((0, 0, 0.2), (0, 0, 2.0)).query(POINTS)
    assert np.allclose(phi, POINTS[:, 2] - 0.2, atol=ROUNDOFF) and np.allclose(n, [0, 0, 1])
    c = np.array([0.1, -0.2, 0.3])
    phi, n, _ = Sphere(c, 0.5).query(POINTS)
    assert np.allclose(phi, np.linalg.norm(POINTS - c, axis=1) - 0.5, atol=ROUNDOFF)
    a, b = np.array([-0.5, 0, 0]), np.array([0.5, 0.3, 0.2])
    phi, _, _ = Capsule(a, b, 0.25).query(POINTS)
    assert np.allclose(phi, _segment_distance(POINTS, a, b) - 0.25, atol=ROUNDOFF)
    ends = np.array([[a, b], [[0, 0, -1], [0, 0, 1]]], float)
    phi, _, _ = CapsuleUnion(ends, [0.25, 0.1]).query(POINTS)
    ref = np.minimum(_segment_distance(POINTS, a, b) - 0.25, _segment_distance(POINTS, *ends[1]) - 0.1)
    assert np.allclose(phi, ref, atol=ROUNDOFF)


@pytest.mark.parametrize("obstacle", [Sphere((0.1, 0, 0), 0.4), Capsule((0, 0, -0.5), (0.2, 0.1, 0.5), 0.3),
                                      Plane((0, 0, 0), (1, 1, 1))])
def test_normals_are_unit_gradients_of_phi(obstacle):
    pts = POINTS[np.abs(obstacle.query(POINTS)[0]) > 0.05][:40]  # away from the medial axis
    phi, n, _ = obstacle.query(pts)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=ROUNDOFF)
    grad = np.empty_like(pts)
    for k in range(3):
        e = np.zeros(3)
        e[k] = FD_STEP
        grad[:, k] = (obstacle.query(pts + e)[0] - obstacle.query(pts - e)[0]) / (2 * FD_STEP)
    assert np.abs(grad - n).max() < FD_TOL


@pytest.mark.parametrize("motion", [Static(), Linear((0.3, -0.2, 0.1)), Oscillate((0.1, 0, 0.2), 1.5, 0.3),
                                    Spin((0.2, 0.3, 1.0), 2.0, (0.5, 0, 0))])
def test_surface_velocity_is_the_time_derivative_of_the_moving_surface(motion):
    t = 0.37
    R, p = motion.pose(t)
    assert np.allclose(R @ R.T, np.eye(3), atol=ROUNDOFF)
    sphere = Sphere((0.2, 0.1, 0.0), 0.3, motion=motion)
    sphere.set_time(t)
    _, n, v = sphere.query(POINTS[:20])
    # the material point of the sphere at the closest point, moved by the motion over +-dt
    closest = POINTS[:20] - sphere.query(POINTS[:20])[0][:, None] * n
    local = (closest - p) @ R
    Rp, pp = motion.pose(t + FD_STEP)
    Rm, pm = motion.pose(t - FD_STEP)
    v_fd = ((local @ Rp.T + pp) - (local @ Rm.T + pm)) / (2 * FD_STEP)
    assert np.abs(v - v_fd).max() < FD_TOL


def test_driven_capsules_interpolate_endpoint_velocities():
    u = CapsuleUnion(np.zeros((1, 2, 3)), [0.1])
    u.set_capsules(np.array([[[0, 0, 0], [1, 0, 0]]], float), np.array([[[0, 0, 1], [0, 0, 3]]], float))
    phi, n, v = u.query(np.array([[0.25, 0, 0.5]]))
    assert phi[0] == pytest.approx(0.4) and np.allclose(n, [[0, 0, 1]]) and np.allclose(v, [[0, 0, 1.5]])
    assert u.moving


def _nodes(x, v=None, pinned=None):
    x = np.array(x, float)
    v = np.zeros_like(x) if v is None else np.array(v, float)
    pinned = np.zeros(len(x), bool) if pinned is None else np.array(pinned)
    return x, v, pinned


def test_nodes_inside_end_at_the_thickness_and_pinned_nodes_stay():
    obs = ObstacleSet([Plane(), Sphere((0, 0, 0.5), 0.5), Capsule((2, 0, 0.3), (3, 0, 0.3), 0.2)])
    x, v, pinned = _nodes([[0, 0, 0.7], [1, 1, -0.2], [2.5, 0, 0.35], [5, 5, -1], [0, 0.1, 0.6]],
                          pinned=[False, False, False, True, False])
    before = x.copy()
    stats = resolve_obstacle_contacts(x, v, pinned, obs, 0.01, 0.3, 0.01)
    phi = obs.query(x)[0]
    assert np.all(phi[~pinned] >= 0.01 * (1 - 1e-9))
    assert np.allclose(phi[[0, 1, 2, 4]], 0.01, atol=1e-12)
    assert np.array_equal(x[3], before[3])
    assert stats["contacts"] == 4 and stats["remaining"] == 0


def test_node_in_the_corner_between_sphere_and_ground_ends_outside_both():
    obs = ObstacleSet([Plane(), Sphere((0, 0, 0.5), 0.5)])
    # near where the sphere meets the ground: projecting out of one pushes into the other
    x, v, pinned = _nodes([[0.12, 0.0, 0.005], [0.05, 0.02, 0.001]])
    stats = resolve_obstacle_contacts(x, v, pinned, obs, 0.02, 0.0, 0.01)
    assert np.all(obs.query(x)[0] >= 0.02 * (1 - 1e-9))
    # both constraints are solved together, so the wedge does not need many passes
    assert stats["contacts"] == 2 and stats["remaining"] == 0 and stats["passes"] <= 2


@pytest.mark.parametrize("friction, expected_speed", [(0.0, 2.0), (0.5, 2.0 - 0.5 * 1.0), (10.0, 0.0)])
def test_coulomb_friction_on_the_ground(friction, expected_speed):
    # sliding at 2 m/s along x while approaching at 1 m/s: normal change 1 m/s
    x, v, pinned = _nodes([[0, 0, -0.001]], [[2.0, 0, -1.0]])
    resolve_obstacle_contacts(x, v, pinned, ObstacleSet([Plane()]), 0.0, friction, 0.01)
    assert v[0, 2] == pytest.approx(0.0, abs=ROUNDOFF)
    assert v[0, 0] == pytest.approx(expected_speed, abs=ROUNDOFF)


def test_node_on_a_rising_plane_takes_its_normal_velocity():
    plane = Plane(motion=Linear((0.5, 0, 1.0)))
    plane.set_time(0.1)
    x, v, pinned = _nodes([[0, 0, 0.05]])
    resolve_obstacle_contacts(x, v, pinned, ObstacleSet([plane]), 0.0, 0.0, 0.01)
    assert x[0, 2] == pytest.approx(0.1) and v[0, 2] == pytest.approx(1.0) and v[0, 0] == pytest.approx(0.0)


def test_display_meshes_are_valid():
    for ob in (Plane(), Sphere((0, 0, 0), 1), Capsule((0, 0, 0), (1, 0, 0), 0.2),
               CapsuleUnion([[[0, 0, 0], [0, 0, 1]], [[2, 0, 0], [3, 0, 0]]], [0.1, 0.2])):
        v, f = ob.to_mesh(12)
        assert np.all(np.isfinite(v)) and f.min() >= 0 and f.max() < len(v)
        if not isinstance(ob, Plane):  # every vertex lies on the surface
            assert np.abs(ob.query(v)[0]).max() < 1e-9


def test_distance_alone_is_the_querys_phi():
    """ObstacleSet.distance (the view-dependent contact floor's test) is query's phi, bit for bit:
    capsules, a sphere and a plane, one of them spinning, and an empty set is inf."""
    rng = np.random.default_rng(3)
    obstacles = [Sphere((0.2, 0.0, 0.5), 0.3), Plane((0.0, 0.0, -0.2)),
                 Capsule((0.0, 0.0, 0.0), (0.5, 0.2, 0.3), 0.1, motion=Spin((0.0, 0.0, 1.0), 2.0))]
    bodies = ObstacleSet(obstacles)
    bodies.set_time(0.3)
    points = rng.normal(scale=0.6, size=(500, 3))
    assert np.array_equal(bodies.distance(points), bodies.query(points)[0])
    for ob in obstacles:
        assert np.array_equal(ob.distance(points), ob.query(points)[0])
    assert np.all(ObstacleSet([]).distance(points) == np.inf)
