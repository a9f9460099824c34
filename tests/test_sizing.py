"""The sizing field of adaptive remeshing (cloth.remeshing.sizing): the tensor maximum, the
clamp, and the velocity, compression, curvature and obstacle criteria on hand-computed cases."""


import numpy as np
import pytest

from cloth.core.mesh import grid_mesh
from cloth.remeshing.sizing import (
    clamp_sizing,
    compression_sizing,
    curvature_sizing,
    face_to_vert_sizing,
    obstacle_sizing,
    tensor_max,
    velocity_sizing,
)


def test_tensor_max_dominates_and_is_tight():
    A = np.diag([1.0, 0.0])
    B = np.diag([0.0, 1.0])
    np.testing.assert_allclose(tensor_max(np.stack([A, B])[:, None]), [np.eye(2)], atol=1e-12)
    C = np.array([[4.0, 1.0], [1.0, 2.0]])
    D = np.array([[1.0, 0.0], [0.0, 1.0]])  # C >= D
    np.testing.assert_allclose(tensor_max(np.stack([C, D])[:, None]), [C], atol=1e-12)
    rng = np.random.default_rng(0)
    for _ in range(50):
        Ms = []
        for _ in range(4):
            q = rng.normal(size=(2, 2))
            Ms.append(q @ q.T)
        T = tensor_max(np.stack(Ms)[:, None])[0]
        for M in Ms:
            assert np.linalg.eigvalsh(T - M).min() >= -1e-9 * np.trace(T)
        # tight: some tensor touches T in some direction (T - M_k singular for some k)
        assert min(abs(np.linalg.eigvalsh(T - M)).min() for M in Ms) <= 1e-7 * np.trace(T)


def test_clamp_sizing_limits_sizes_and_aspect():
    M = np.array([np.diag([1e6, 1e-6]), np.diag([4.0, 100.0])])
    out = clamp_sizing(M, size_min=0.01, size_max=0.2, aspect_min=0.2)
    np.testing.assert_allclose(out[0], np.diag([1e4, 0.04 * 1e4]), rtol=1e-12)
    np.testing.assert_allclose(out[1], np.diag([25.0, 100.0]), rtol=1e-12)


def _sheet(nx=8, ny=8, w=1.0):
    return grid_mesh(w, w, nx, ny)


def test_velocity_sizing_of_a_shear_flow():
    mesh = _sheet()
    omega = 2.0
    mesh.node_v[:, 0] = omega * mesh.node_x[:, 1]
    M = velocity_sizing(mesh, refine_velocity=0.5)
    np.testing.assert_allclose(M, np.tile(np.diag([0.0, omega**2 / 0.25]), (mesh.n_faces, 1, 1)), atol=1e-12)


def test_compression_sizing_of_uniform_compression():
    mesh = _sheet()
    s = 0.9  # stretch along x
    mesh.node_x[:, 0] *= s
    c = 0.005
    M = compression_sizing(mesh, refine_compression=c)
    expected = np.diag([(1 - s**2) / c**2, 0.0])
    np.testing.assert_allclose(M, np.tile(expected, (mesh.n_faces, 1, 1)), rtol=1e-9, atol=1e-6)
    mesh.node_x[:, 0] /= s * s  # stretched: nothing to resolve
    assert np.abs(compression_sizing(mesh, refine_compression=c)).max() < 1e-6


def test_curvature_sizing_of_a_cylinder():
    r = 0.5
    n = 40
    mesh = grid_mesh(np.pi * r, 0.5, n, 4)  # half a cylinder around the y axis
    u = mesh.vert_u
    mesh.node_x[:, 0] = r * np.sin(u[:, 0] / r)
    mesh.node_x[:, 2] = r * np.cos(u[:, 0] / r)
    mesh.node_x[:, 1] = u[:, 1]
    M = curvature_sizing(mesh, refine_angle=0.3)
    interior = np.flatnonzero((mesh.face_nodes.min(axis=1) > 0) & ~mesh.node_boundary[mesh.face_nodes].any(axis=1))
    # curvature 1/r across x, none along y: M = diag(1/r^2, 0) / refine_angle^2
    np.testing.assert_allclose(M[interior, 0, 0], 1 / r**2 / 0.09, rtol=0.02)
    assert np.abs(M[interior, 1, 1]).max() < 1e-3 * M[interior, 0, 0].min()


def test_obstacle_sizing_of_a_tilted_sheet_above_a_plane():
    mesh = _sheet(4, 4)
    slope = 0.1
    mesh.node_x[:, 2] = 0.005 + slope * mesh.node_x[:, 0]
    phi = mesh.node_x[:, 2].copy()
    normal = np.tile([0.0, 0.0, 1.0], (mesh.n_nodes, 1))
    M = obstacle_sizing(mesh, phi, normal, distance=1.0)
    # each corner i adds slope^2 / phi_i^2 along x; mean of the three corners
    inv = (1.0 / phi[mesh.face_nodes] ** 2).mean(axis=1)
    np.testing.assert_allclose(M[:, 0, 0], slope**2 * inv, rtol=1e-9)
    np.testing.assert_allclose(M[:, 1, 1], 0.0, atol=1e-12)
    far = obstacle_sizing(mesh, phi + 1.0, normal, distance=0.5)
    assert not far.any()


def test_face_to_vert_transfer_is_area_weighted():
    mesh = grid_mesh(1.0, 1.0, 1, 1)  # two faces of equal area
    face_M = np.array([np.eye(2), 3 * np.eye(2)])
    vM = face_to_vert_sizing(mesh, face_M)
    shared = np.intersect1d(mesh.face_verts[0], mesh.face_verts[1])
    np.testing.assert_allclose(vM[shared], np.tile(2 * np.eye(2), (2, 1, 1)))


# The fused kernel and the criterion-by-criterion definition sum in other orders (einsum, BLAS,
# numpy's vectorised arccos): round-off of 1e-16 relative, amplified where a criterion is
# ill-conditioned (the arccos of a nearly flat hinge, a signed square root near 0), up to about
# 1e-12 on these meshes; 1e-9 of each face's largest entry still catches any wrong term.
FUSED_SIZING_RTOL = 1e-9


def _crumpled_sheet_over_a_sphere(seed):
    from cloth.collision.obstacles import ObstacleSet, Sphere

    rng = np.random.default_rng(seed)
    mesh = grid_mesh(1.0, 1.0, 12, 12)
    x = mesh.node_x
    x[:, 2] = 0.55 + 0.05 * np.sin(6 * x[:, 0]) * np.cos(5 * x[:, 1])  # bent: curvature everywhere
    x[:, :2] *= 0.95  # compressed: the compression criterion acts
    x += 0.01 * rng.standard_normal(x.shape)
    mesh.node_v[:] = rng.standard_normal(mesh.node_v.shape)
    obstacles = ObstacleSet([Sphere(center=(0.5, 0.5, 0.0), radius=0.548)])  # near a patch of nodes
    obstacles.set_time(0.0)
    return mesh, obstacles


@pytest.mark.parametrize("combine", ["max", "sum"])
@pytest.mark.parametrize("with_obstacles", [False, True])
def test_fused_physics_sizing_equals_the_criteria_combined(combine, with_obstacles):
    from cloth.remeshing.sizing import SizingParams, physics_face_sizing, physics_face_sizing_reference

    mesh, obstacles = _crumpled_sheet_over_a_sphere(1)
    params = SizingParams(combine=combine, obstacle_distance=0.05)
    obs = obstacles if with_obstacles else None
    if with_obstacles:  # the obstacle criterion is exercised: some nodes are within its distance
        phi = obstacles.query(mesh.node_x)[0]
        assert 5 < np.count_nonzero((phi > 0) & (phi < 0.05)) < mesh.n_nodes
    ref = physics_face_sizing_reference(mesh, params, obs)
    fused = physics_face_sizing(mesh, params, obs)
    scale = np.abs(ref).max(axis=(1, 2))
    assert np.all(np.abs(fused - ref).max(axis=(1, 2)) <= FUSED_SIZING_RTOL * scale)
    # the clamp acts (size_min and the aspect bound), so the test covers it too
    w = np.linalg.eigvalsh(ref)
    assert np.isclose(w.max(), 1 / params.size_min**2) and np.isclose((w[:, 0] / w[:, 1]).min(), params.aspect_min**2)
