"""The camera, camera paths and the paper's view-dependent equations (2-8, section 3.3) against
hand-computed cases and their stated properties."""

import numpy as np
import pytest
from scipy.optimize import minimize

from cloth.view.camera import Camera, ViewError
from cloth.view.factors import (
    anticipated_view_factor,
    resample_silhouette,
    scale_sizing,
    screen_space_clamp,
    spatial_view_factor,
)
from cloth.view.paths import CutPath, KeyframePath, OrbitPath, StaticPath, path_from_config

ROUNDOFF = 1e-9
# Rebuilding a 2x2 tensor from its eigen-decomposition (and through S^-1, S) loses ~cond(S)^2 eps.
EIG_ROUNDOFF = 1e-8
# The reference distance comes from an SLSQP projection onto the frustum's six half-spaces,
# converged to ~1e-8 m.
QP_TOL = 1e-5


def _camera(**kw):
    args = dict(position=(0.0, 0.0, 0.0), look_at=(0.0, 1.0, 0.0), up=(0.0, 0.0, 1.0), fov_y_deg=60.0,
                width=800, height=600, near=0.1, far=10.0)
    args.update(kw)
    return Camera(**args)


def test_project_hand_cases():
    cam = _camera()
    ty = np.tan(np.radians(30))
    tx = ty * 800 / 600
    pts = np.array([[0, 2, 0],            # on the axis: image centre
                    [tx * 2, 2, 0],       # right border
                    [0, 2, ty * 2],       # top border (y = 0 at the top)
                    [-tx * 3, 3, -ty * 3]])  # bottom-left corner
    px, depth = cam.project(pts)
    assert np.allclose(px, [[400, 300], [800, 300], [400, 0], [0, 600]])
    assert np.allclose(depth, [2, 2, 2, 3])
    _, d = cam.project(np.array([[5.0, -1.0, 3.0]]))
    assert np.isclose(d[0], -1.0)  # behind the camera: negative depth


def test_frustum_corners_project_to_the_image_corners_at_near_and_far():
    cam = _camera(position=(1, 2, 3), look_at=(2, 3, 3.5), fov_y_deg=45, width=640, height=480)
    c = cam.frustum_corners()
    px, depth = cam.project(c)
    assert np.allclose(depth, [cam.near] * 4 + [cam.far] * 4)
    corners = [[0, 0], [640, 0], [640, 480], [0, 480]] * 2
    assert np.allclose(px, corners, atol=1e-6)


def _qp_distance(cam, p):
    """Reference: minimise |q - p|^2 over the frustum written as 6 half-spaces (camera coordinates)."""
    c = cam.to_camera(p[None])[0]
    tx, ty = cam.tan_half_fov
    cons = [{"type": "ineq", "fun": lambda q: q[2] - cam.near},
            {"type": "ineq", "fun": lambda q: cam.far - q[2]},
            {"type": "ineq", "fun": lambda q: tx * q[2] - q[0]},
            {"type": "ineq", "fun": lambda q: tx * q[2] + q[0]},
            {"type": "ineq", "fun": lambda q: ty * q[2] - q[1]},
            {"type": "ineq", "fun": lambda q: ty * q[2] + q[1]}]
    best = np.inf
    for start in ([0, 0, (cam.near + cam.far) / 2], [0, 0, cam.near * 1.01]):
        r = minimize(lambda q: np.sum((q - c) ** 2), np.array(start, float), constraints=cons, method="SLSQP",
                     options={"ftol": 1e-14, "maxiter": 500})
        best = min(best, np.sqrt(r.fun))
    return best


def test_distance_to_frustum_is_the_exact_euclidean_distance():
    cam = _camera(position=(0.3, -0.2, 1.0), look_at=(0.5, 2.0, 0.8), near=0.2, far=3.0)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-4, 4, (60, 3))
    d = cam.distance_to_frustum(pts)
    ref = np.array([_qp_distance(cam, p) for p in pts])
    assert np.allclose(d, ref, atol=QP_TOL)
    assert np.all(d[cam.inside(pts)] == 0) and np.all(d[~cam.inside(pts)] > 0)


def test_beyond_a_corner_the_distance_exceeds_the_largest_plane_distance():
    cam = _camera()
    c = cam.frustum_corners()
    fwd, right, up = cam._forward, cam._right, np.cross(cam._right, cam._forward)
    tx, ty = cam.tan_half_fov
    # outward unit normals of the far, right and top planes, which meet at the far top-right corner c[5]
    normals = [fwd, right - tx * fwd, up - ty * fwd]
    normals = [n / np.linalg.norm(n) for n in normals]
    u = sum(normals)
    u /= np.linalg.norm(u)  # inside the corner's normal cone: the nearest point is the corner
    p = c[5] + 0.5 * u
    d = cam.distance_to_frustum(p[None])[0]
    assert np.isclose(d, 0.5, atol=1e-9)
    assert max(n @ (p - c[5]) for n in normals) < 0.5 - 0.05  # a plane-distance shortcut would be wrong
    q = np.array([[0.0, 12.0, 0.0]])  # beyond the far plane on the axis: the plane distance
    assert np.isclose(cam.distance_to_frustum(q)[0], 2.0)


def test_bad_cameras_are_named():
    with pytest.raises(ViewError, match="fov_y_deg"):
        _camera(fov_y_deg=180)
    with pytest.raises(ViewError, match="parallel"):
        _camera(up=(0, 1, 0))
    with pytest.raises(ViewError, match="near < far"):
        _camera(near=2, far=1)


# ---- eq 3 --------------------------------------------------------------------------------

def test_spatial_view_factor_hand_cases_and_continuity():
    m = 0.4
    d = np.array([0.0, 0.0, 0.1, 0.2, 0.4, 1.0])
    front = np.array([True, False, True, False, True, False])
    nu = spatial_view_factor(d, front, 1.0, 0.2, 0.01, m)
    assert np.allclose(nu, [1.0, 0.2, 1.0 - 0.25 * 0.99, 0.2 - 0.5 * 0.19, 0.01, 0.01])
    # continuous in d: nu_fb at 0+, nu_out at m-
    eps = 1e-9
    for f in (True, False):
        lo = spatial_view_factor(np.array([0.0, eps]), np.array([f, f]), 1.0, 0.2, 0.01, m)
        hi = spatial_view_factor(np.array([m - eps, m, m + eps]), np.array([f] * 3), 1.0, 0.2, 0.01, m)
        assert abs(lo[1] - lo[0]) < 1e-6 and np.ptp(hi) < 1e-6
    with pytest.raises(ViewError, match="margin"):
        spatial_view_factor(d, front, 1.0, 0.2, 0.01, -1.0)


# ---- eq 4 --------------------------------------------------------------------------------

def test_anticipated_view_factor_hand_case_and_properties():
    T = 5.0
    taus = np.arange(6.0)
    # face 0 visible now; face 1 becomes visible at tau = 2; face 2 never; face 3 at tau = 5
    nu = np.full((6, 4), 0.01)
    nu[:, 0] = 1.0
    nu[2:, 1] = 1.0
    nu[5, 3] = 1.0
    out = anticipated_view_factor(nu, taus, T)
    assert np.allclose(out, [1.0, 0.6, 0.01, 0.01])  # w(2) = 0.6; w(5) = 0
    rng = np.random.default_rng(1)
    r = rng.uniform(0.01, 1, (6, 50))
    a = anticipated_view_factor(r, taus, T)
    assert np.all(a >= r[0]) and np.all(a <= r.max(axis=0))
    assert np.allclose(anticipated_view_factor(r[:1], taus[:1], 0.0), r[0])
    with pytest.raises(ViewError, match="taus"):
        anticipated_view_factor(r, taus + 1, T)


def test_anticipated_view_factor_accepts_taus_built_from_the_frame_time():
    # taus = k * dt with T = 3 dt: 3 * 0.1 overshoots 0.3 by a rounding error, which is no bad input
    dt = 0.1
    taus = np.arange(4) * dt
    assert taus[-1] > 0.3  # the overshoot this test is about
    nu = np.full((4, 2), 0.01)
    nu[1, 1] = 1.0  # face 1 becomes visible one frame ahead: w = 1 - 1/3
    out = anticipated_view_factor(nu, taus, 0.3)
    assert np.allclose(out, [0.01, 2.0 / 3.0])
    assert np.all(out >= 0)


def test_scale_sizing_and_filter_strain_take_a_scalar_and_a_single_tensor():
    from cloth.physics.buckling import filter_strain
    M = _random_spd(np.random.default_rng(3), 4)
    assert np.allclose(scale_sizing(M, 0.5), 0.25 * M)
    E = np.array([[0.1, 0.0], [0.0, -0.2]])
    assert np.allclose(filter_strain(E, 0.5), [[0.1, 0.0], [0.0, -0.1]])


# ---- eqs 2, 5-8 ----------------------------------------------------------------------------

def _random_spd(rng, n):
    A = rng.standard_normal((n, 2, 2))
    return np.einsum("fij,fkj->fik", A, A) + 0.1 * np.eye(2)


def test_scale_sizing_multiplies_by_nu_squared():
    M = _random_spd(np.random.default_rng(2), 3)
    out = scale_sizing(M, np.array([1.0, 0.5, 0.1]))
    assert np.allclose(out, M * np.array([1.0, 0.25, 0.01])[:, None, None])


def test_screen_space_clamp_hand_case():
    # S = s I (an isotropic projection of s pixels per metre); M = diag(a, b) asks edges 1/sqrt(a), 1/sqrt(b) m
    s, l_min = 100.0, 4.0
    M = np.array([[[2500.0, 0.0], [0.0, 100.0]]])  # 2 cm and 10 cm edges: 2 px and 10 px on screen
    out = screen_space_clamp(M, np.array([s * np.eye(2)]), l_min)
    # the 2 px direction is coarsened to l_min = 4 px = 4 cm: eigenvalue (s / l_min)^2 = 625
    assert np.allclose(out[0], [[625.0, 0.0], [0.0, 100.0]])


def test_screen_space_clamp_never_refines_and_keeps_large_edges():
    rng = np.random.default_rng(3)
    M = _random_spd(rng, 200) * 100
    S = rng.standard_normal((200, 2, 2)) * 50
    out = screen_space_clamp(M, S, 5.0)
    diff = M - out
    assert np.all(np.linalg.eigvalsh(diff) > -1e-9 * np.abs(M).max())  # out <= M (PSD order)
    # where every screen-space edge is already >= l_min, M is unchanged
    Si = np.linalg.inv(S)
    M2 = M * 1e-6  # coarse sizings: most faces' screen edges are long enough
    long_enough = np.linalg.eigvalsh(np.einsum("fki,fkl,flj->fij", Si, M2, Si)).max(axis=1) <= 5.0 ** -2
    assert long_enough.sum() > 100 and (~long_enough).sum() > 0
    out2 = screen_space_clamp(M2, S, 5.0)
    rel = np.linalg.norm(out2 - M2, axis=(1, 2)) / np.linalg.norm(M2, axis=(1, 2))
    assert rel[long_enough].max() < EIG_ROUNDOFF and rel[~long_enough].min() > EIG_ROUNDOFF


# ---- section 3.3 ---------------------------------------------------------------------------

def test_resample_silhouette_hand_case():
    nu = np.array([1.0, 0.2, 0.2, 0.95, 0.2])
    visible = np.array([True, False, False, True, False])
    edges = np.array([[0, 1],    # silhouette: face 1 -> 0.6
                      [1, 2],    # two hidden faces: no change
                      [3, 4],    # face 4 -> 0.575
                      [0, 4],    # face 4 also sees 0.6: it takes the larger
                      [2, -1],   # boundary edge
                      [0, 3]])   # both visible
    out = resample_silhouette(nu, visible, edges, 0.3)
    assert np.allclose(out, [1.0, 0.6, 0.2, 0.95, 0.6])
    assert np.allclose(resample_silhouette(nu, visible, edges, 0.9), nu)  # below the threshold: unchanged


# ---- camera paths ----------------------------------------------------------------------------

def test_orbit_cut_and_keyframe_paths():
    orbit = OrbitPath(center=(0, 0, 0), radius=2.0, height=1.0, period_s=4.0)
    assert np.allclose(orbit.camera_at(0.0).position, [2, 0, 1])
    assert np.allclose(orbit.camera_at(1.0).position, [0, 2, 1])
    shot = StaticPath(_camera(position=(5, 5, 5), look_at=(0, 0, 0)))
    cut = CutPath(np.array([0.0, 1.5]), [orbit, shot])
    assert cut.cuts == (1.5,)
    assert np.allclose(cut.camera_at(1.4999).position, orbit.camera_at(1.4999).position)
    assert cut.camera_at(1.5) is shot.camera  # an instant switch
    keys = KeyframePath(np.array([0.0, 1.0, 3.0]), np.array([[0, -3, 1], [1, -3, 1], [2, -2, 2.0]]),
                        np.zeros((3, 3)), np.tile([0, 0, 1.0], (3, 1)), np.array([40.0, 30.0, 20.0]))
    for t, p in zip(keys.times, keys.positions):
        assert np.allclose(keys.camera_at(t).position, p)
    # C1: the velocity is continuous across the middle key
    h = 1e-6
    v_left = (np.array(keys.camera_at(1.0).position) - keys.camera_at(1.0 - h).position) / h
    v_right = (np.array(keys.camera_at(1.0 + h).position) - keys.camera_at(1.0).position) / h
    assert np.allclose(v_left, v_right, atol=1e-4)


def test_path_from_config_names_the_problem():
    with pytest.raises(ViewError, match="type"):
        path_from_config({"type": "dolly"})
    with pytest.raises(ViewError, match="look_at"):
        path_from_config({"type": "static", "camera": {"position": [0, 0, 1]}})
    p = path_from_config({"type": "cuts", "shots": [
        {"start": 0, "type": "static", "camera": {"position": [0, -2, 1], "look_at": [0, 0, 0]}},
        {"start": 2, "type": "orbit", "center": [0, 0, 0], "radius": 1, "period_s": 2}]})
    assert p.cuts == (2.0,)


def test_keyframe_path_interpolates_every_channel_smoothly():
    """Position, look-at, up and field of view pass through their keys, stay within a linear
    segment's neighbourhood between them (Catmull-Rom on evenly spaced keys), and have no
    velocity jump at an interior key (C1)."""
    times = [0.0, 1.0, 2.0]
    path = KeyframePath(times=times, positions=np.array([[0.0, -3, 1], [2, -3, 1], [4, -2, 2]]),
                        targets=np.array([[0.0, 0, 1], [0, 0, 1.5], [1, 0, 1]]),
                        ups=np.array([[0.0, 0, 1], [0.1, 0, 1], [0.2, 0, 1]]), fovs=np.array([40.0, 60.0, 30.0]))
    for k, t in enumerate(times):
        cam = path.camera_at(t)
        assert np.allclose(cam.position, path.positions[k]) and np.allclose(cam.look_at, path.targets[k])
        assert np.allclose(cam.up, path.ups[k]) and cam.fov_y_deg == pytest.approx(path.fovs[k])
    mid = path.camera_at(0.5)
    assert 40.0 < mid.fov_y_deg < 60.0 and 0.0 < mid.up[0] < 0.1 and 1.0 < mid.look_at[2] < 1.5
    dt = 1e-6
    def rate(f, t0, t1):
        return (np.asarray(f(t1), float) - np.asarray(f(t0), float)) / (t1 - t0)
    for channel in (lambda t: path.camera_at(t).position, lambda t: path.camera_at(t).up,
                    lambda t: [path.camera_at(t).fov_y_deg]):
        left, right = rate(channel, 1.0 - dt, 1.0), rate(channel, 1.0, 1.0 + dt)
        assert np.allclose(left, right, atol=1e-4), (left, right)
    assert np.allclose(path.camera_at(-1.0).position, path.positions[0])  # held at the ends
    assert np.allclose(path.camera_at(5.0).position, path.positions[-1])


# The kernel computes S^-1 by its adjugate (numpy: LU) and sums in another order; both are within
# about 1e-12 of an extended-precision evaluation at condition numbers below 10 (the error grows
# with cond(S), the same for both), so 1e-11 of each face's largest entry tests the algebra.
CLAMP_KERNEL_RTOL = 1e-11


def test_screen_space_clamp_kernel_equals_eqs_5_to_8_in_numpy():
    from cloth.core.tensors import eig_apply

    rng = np.random.default_rng(5)
    S = rng.standard_normal((4000, 2, 2)) * 50
    S = S[np.linalg.cond(S) < 10]
    M = _random_spd(rng, len(S)) * 100
    l_min = 4.0
    Si = np.linalg.inv(S)
    Ms = np.einsum("fki,fkl,flj->fij", Si, M, Si)  # eq 5: S^-T M S^-1
    Mh = eig_apply(0.5 * (Ms + np.swapaxes(Ms, 1, 2)), lambda lam: np.minimum(lam, l_min**-2))  # eqs 6-8
    Mvd = np.einsum("fki,fkl,flj->fij", S, Mh, S)
    ref = 0.5 * (Mvd + np.swapaxes(Mvd, 1, 2))
    clamped = np.linalg.eigvalsh(Ms)[:, 1] > l_min**-2
    assert 100 < clamped.sum() < len(S) - 100  # both branches of eq 7
    out = screen_space_clamp(M, S, l_min)
    assert np.all(np.abs(out - ref).max(axis=(1, 2)) <= CLAMP_KERNEL_RTOL * np.abs(ref).max(axis=(1, 2)))
    singular = np.zeros((1, 2, 2))  # seen edge-on: M kept
    assert np.array_equal(screen_space_clamp(M[:1], singular, l_min), M[:1])


# The per-face kernels of the view-dependent sizing against their numpy definitions: the same
# arithmetic up to the order of a few sums (BLAS's dot products, LU's inverse against the
# adjugate), so a few ulps of each quantity's scale.
VIEW_KERNEL_RTOL = 1e-12


def test_per_face_view_kernels_equal_their_numpy_definitions():
    """cloth.view.factors: face_geometry, face_view_data (Camera.distance_and_facing) and
    material_to_screen_jacobian in one pass each, against the centroid mean, Mesh.world_face_normals,
    Camera.distance_to_frustum with the facing test, and S = [p1 - p0, p2 - p0] Dm^-1 from
    Camera.project, on a crumpled sheet seen from cameras inside, beside and behind it."""
    from cloth.core.mesh import grid_mesh
    from cloth.view.factors import face_geometry, face_view_data, material_to_screen_jacobian

    rng = np.random.default_rng(7)
    mesh = grid_mesh(1.2, 0.9, 12, 9)
    mesh.node_x = mesh.node_x + rng.normal(scale=0.05, size=mesh.node_x.shape)
    mesh.node_x[mesh.face_nodes[0, 1]] = mesh.node_x[mesh.face_nodes[0, 0]]  # a collapsed face
    c, n = face_geometry(mesh)
    assert np.abs(c - mesh.node_x[mesh.face_nodes].mean(axis=1)).max() <= VIEW_KERNEL_RTOL
    assert np.abs(n - mesh.world_face_normals()).max() <= VIEW_KERNEL_RTOL
    assert np.array_equal(n[0], np.zeros(3))
    x = mesh.vert_x()
    behind = inside = facing = 0
    for position, target in (((0.6, -2.0, 1.0), (0.6, 0.45, 0.0)), ((0.6, 0.45, 0.05), (1.2, 0.45, 0.0)),
                             ((3.0, 0.4, 0.1), (0.6, 0.45, 0.0)), ((0.6, -0.45, -1.5), (0.6, 0.45, 0.0))):
        cam = Camera(position, target, (0.0, 0.0, 1.0), 50.0, 640, 360, near=0.1, far=2.5)
        d, front = face_view_data(cam, c, n)
        ref_d = cam.distance_to_frustum(c)
        assert np.abs(d - ref_d).max() <= VIEW_KERNEL_RTOL * max(ref_d.max(), 1.0)
        assert np.array_equal(front, np.einsum("ij,ij->i", n, cam.center - c) > 0.0)
        inside += np.count_nonzero(d == 0)
        facing += np.count_nonzero(front)
        S = material_to_screen_jacobian(cam, mesh.vert_u, mesh.face_verts, x)
        px, _ = cam.project(x)
        p, u = px[mesh.face_verts], mesh.vert_u[mesh.face_verts]
        ref = (np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], -1)
               @ np.linalg.inv(np.stack([u[:, 1] - u[:, 0], u[:, 2] - u[:, 0]], -1)))
        assert np.array_equal(np.isnan(S), np.isnan(ref))
        ok = ~np.isnan(ref)
        behind += np.count_nonzero(~ok)
        assert np.all(np.abs(S - ref)[ok] <= VIEW_KERNEL_RTOL * np.abs(ref[ok]).max())
    assert behind > 0  # the camera inside the sheet has verts behind it
    assert 0 < inside < 4 * len(c) and 0 < facing < 4 * len(c)  # both sides of both tests
