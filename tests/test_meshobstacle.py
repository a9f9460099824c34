"""Triangle-mesh obstacles: closest point, sign and normal against closed forms and brute force,
keyframe interpolation and velocities, OBJ sequences, the skinned mannequin, the mesh_obstacle
scene and untangling cloth from a mesh obstacle. The collisions within each step are in
tests/test_meshobstacle_collisions.py."""

import numpy as np
import pytest
import trimesh.creation
from helpers import COTTON, build_sim

from cloth.collision.ccd import point_triangle_closest
from cloth.collision.meshobstacle import (
    MeshObstacleError,
    TriangleMeshObstacle,
    mesh_obstacle_triangles,
)
from cloth.collision.obstacles import Capsule, Sphere, capsule_tessellation
from cloth.collision.untangle import find_intersections, untangle
from cloth.core.mesh import grid_mesh
from cloth.core.scene import SceneError
from cloth.io.obj import ObjError, load_obj_sequence, write_obj_sequence
from cloth.scenes.bodies import icosphere, moving_sphere_keyframes, skinned_mannequin_mesh
from cloth.scenes.character import Dance, Mannequin
from cloth.scenes.registry import build_scene
from experiments.build import ConfigError

# Distances are sums and square roots of O(1) numbers.
ROUNDOFF = 1e-12
# Positions written with 17 significant digits and scaled once: a few ulps.
OBJ_ROUNDTRIP = 1e-14
# Central difference of a callable over cloth.collision.meshobstacle.VELOCITY_STEP = 1e-4 s of a rotation
# at 2 rad/s and 0.5 m: truncation h^2 w^3 r / 6 ~ 7e-9 m/s.
CALLABLE_VELOCITY_TOL = 1e-7
# Points of the sphere test lie between 0.8 R and 1.5 R from the centre; inside at depth d the
# mesh normal can lean by up to the facets' angular radius alpha enlarged by R / (R - d) <= 1.25.
SHELL_INNER, SHELL_OUTER = 0.8, 1.5
NORMAL_LEAN = 1.0 / SHELL_INNER
# The deepest point of a facet below the analytic capsule is found by sampling each facet on a
# barycentric grid; the sampled maximum is below the true one by a second-order amount.
FACET_SAMPLES = 12
FACET_SAMPLING_MARGIN = 0.1
# A free node ends every step at the contact thickness (the projection's fixed point); half the
# thickness is margin for what the last projection pass leaves.
CONTACT_MARGIN = 0.5


@pytest.fixture
def rng():
    """The random numbers of one test: the same whichever tests run before it."""
    return np.random.default_rng(11)


def _shell_points(rng, center, radius, n):
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return center + d * rng.uniform(SHELL_INNER * radius, SHELL_OUTER * radius, n)[:, None]


def _winding_number(P, X, F):
    """Generalised winding number (sum of signed solid angles / 4 pi): 1 inside a closed mesh, 0 outside."""
    a, b, c = (X[F[:, k]][None] - P[:, None] for k in range(3))
    la, lb, lc = (np.linalg.norm(q, axis=2) for q in (a, b, c))
    det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    dot = lambda u, v: np.einsum("pfi,pfi->pf", u, v)  # noqa: E731
    den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb
    return (2 * np.arctan2(det, den)).sum(axis=1) / (4 * np.pi)


def _brute_distance(P, X, F):
    return np.array([min(point_triangle_closest(p, X[f[0]], X[f[1]], X[f[2]])[0] for f in F) for p in P])


# ---- geometry ------------------------------------------------------------------------------

def test_sphere_mesh_matches_the_analytic_sphere_within_its_tessellation(rng):
    R, c = 0.5, np.array([0.1, -0.2, 0.3])
    X, F = icosphere(R, 3, c)
    mesh = TriangleMeshObstacle(X, F)
    n_f = mesh.face_normals
    sagitta = R - np.min(np.einsum("fi,fi->f", n_f, X[F[:, 0]] - c))  # deepest facet below the sphere
    alpha = np.arccos(np.clip(np.einsum("fi,fki->fk", n_f, (X[F] - c) / R), -1, 1)).max()  # facets' angular radius
    P = _shell_points(rng, c, R, 5000)
    phi, normal, velocity = mesh.query(P)
    phi_s, normal_s, _ = Sphere(c, R).query(P)
    assert np.all(phi - phi_s >= -ROUNDOFF)  # the mesh is inscribed: its signed distance is never smaller
    assert np.all(phi - phi_s <= sagitta + ROUNDOFF)
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0, atol=ROUNDOFF)
    lean = np.arccos(np.clip(np.einsum("ij,ij->i", normal, normal_s), -1, 1))
    assert lean.max() <= NORMAL_LEAN * alpha
    assert np.all(velocity == 0.0) and not mesh.moving


def test_signs_and_distances_on_a_nonconvex_closed_mesh_match_brute_force(rng):
    tm = trimesh.creation.torus(major_radius=0.4, minor_radius=0.15, major_sections=20, minor_sections=10)
    X, F = np.asarray(tm.vertices), np.asarray(tm.faces)
    mesh = TriangleMeshObstacle(X, F)
    P = rng.uniform(-0.6, 0.6, (1500, 3)) * [1.0, 1.0, 0.4]
    phi, normal, _ = mesh.query(P)
    inside = _winding_number(P, X, F) > 0.5
    assert 0 < inside.sum() < len(P)  # both kinds of point are tested
    assert np.array_equal(phi < 0, inside)
    assert np.allclose(np.abs(phi[:200]), _brute_distance(P[:200], X, F), atol=ROUNDOFF)
    # the outward normal points from the closest point to an outside point, away from an inside one
    closest = mesh.closest(P)["point"]
    assert np.allclose((P - closest), phi[:, None] * normal, atol=1e-10)


def test_query_radius_cuts_off_far_points(rng):
    X, F = icosphere(0.3, 2)
    exact = TriangleMeshObstacle(X, F)
    near = TriangleMeshObstacle(X, F, query_radius=0.1)
    P = _shell_points(rng, np.zeros(3), 0.3, 2000)
    phi, _, _ = exact.query(P)
    out = near.closest(P)
    far = np.abs(phi) >= 0.1
    assert far.any() and (~far).any()
    assert np.allclose(out["phi"][~far], phi[~far], atol=ROUNDOFF)
    assert np.all(out["phi"][far] == 0.1) and np.all(out["face"][far] == -1) and np.all(out["normal"][far] == 0)


def test_overlapping_closed_components_are_a_union(rng):
    XA, FA = icosphere(0.3, 2)
    XB, FB = icosphere(0.2, 2, center=(0.35, 0.0, 0.0))
    union = TriangleMeshObstacle(np.vstack([XA, XB]), np.vstack([FA, FB + len(XA)]))
    assert union.n_components == 2 and union.component_closed.all()
    P = rng.uniform(-0.4, 0.6, (3000, 3)) * [1.0, 0.6, 0.6]
    phi = union.query(P)[0]
    ref = np.minimum(TriangleMeshObstacle(XA, FA).query(P)[0], TriangleMeshObstacle(XB, FB).query(P)[0])
    assert np.allclose(phi, ref, atol=ROUNDOFF)
    # inside A, nearer to B's buried surface than to A's own: still inside
    p = np.array([[0.1, 0.0, 0.0]])
    assert union.query(p)[0][0] < 0 and TriangleMeshObstacle(XB, FB).query(p)[0][0] > 0


def test_open_mesh_sign_is_the_side_of_the_face_and_inward_closed_meshes_are_flipped(rng):
    square = TriangleMeshObstacle([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    assert not square.component_closed[0]
    P = np.column_stack([rng.uniform(0, 1, (50, 2)), rng.uniform(-0.5, 0.5, 50)])
    phi, normal, _ = square.query(P)
    assert np.allclose(phi, P[:, 2], atol=ROUNDOFF) and np.allclose(normal[:, 2], 1.0)
    X, F = icosphere(0.3, 2)
    inward = TriangleMeshObstacle(X, F[:, ::-1])
    assert inward.flipped_components == [0]
    Q = _shell_points(rng, np.zeros(3), 0.3, 200)
    assert np.allclose(inward.query(Q)[0], TriangleMeshObstacle(X, F).query(Q)[0], atol=ROUNDOFF)


@pytest.mark.parametrize("faces, match", [
    ("one_flipped", "consistently oriented"), ("out_of_range", "vertex indices"), ("repeated", "repeats a vertex")])
def test_bad_meshes_raise_one_clear_error(faces, match):
    X, F = icosphere(0.3, 1)
    F = F.copy()
    if faces == "one_flipped":
        F[3] = F[3, ::-1]
    elif faces == "out_of_range":
        F[0, 0] = len(X)
    else:
        F[0, 1] = F[0, 0]
    with pytest.raises(MeshObstacleError, match=match):
        TriangleMeshObstacle(X, F)


# ---- motion --------------------------------------------------------------------------------

def test_translating_keyframes_move_at_the_translation_speed_and_hold_at_the_ends(rng):
    X0, F = icosphere(0.2, 2)
    step, T, K = np.array([0.01, -0.02, 0.005]), 0.05, 6  # m per keyframe, s, keyframes
    mesh = TriangleMeshObstacle(X0[None] + np.arange(K)[:, None, None] * step, F, T, start_time=0.1)
    P = _shell_points(rng, np.zeros(3), 0.2, 300)
    for t in (0.1, 0.1 + 1.3 * T, 0.1 + 3 * T, 0.1 + 4.99 * T):
        mesh.set_time(t)
        assert np.allclose(mesh.positions, X0 + (t - 0.1) / T * step, atol=ROUNDOFF)
        v = mesh.query(P + (t - 0.1) / T * step)[2]
        assert np.allclose(v, step / T, atol=ROUNDOFF)
    for t, k in ((0.0, 0), (0.1 + 5 * T, K - 1), (9.0, K - 1)):  # before the first, at and after the last
        mesh.set_time(t)
        assert np.allclose(mesh.positions, X0 + k * step, atol=ROUNDOFF) and np.all(mesh.vertex_velocities == 0)


def test_positions_are_linear_between_keyframes_and_velocity_is_their_difference(rng):
    X0, F = icosphere(0.2, 1)
    T = 0.04
    keys = X0[None] + 0.01 * rng.standard_normal((4, len(X0), 3))
    mesh = TriangleMeshObstacle(keys, F, T)
    assert mesh.moving
    for k, a in ((0, 0.25), (1, 0.5), (2, 0.9)):
        mesh.set_time((k + a) * T)
        assert np.allclose(mesh.positions, (1 - a) * keys[k] + a * keys[k + 1], atol=ROUNDOFF)
        assert np.allclose(mesh.vertex_velocities, (keys[k + 1] - keys[k]) / T, atol=1e-9)
        # the surface velocity at a closest point is the barycentric blend of the vertices' velocities
        out = mesh.closest(_shell_points(rng, np.zeros(3), 0.2, 50))
        fv = mesh.faces[out["face"]]
        assert np.allclose(out["velocity"], np.einsum("nk,nkd->nd", out["bary"], mesh.vertex_velocities[fv]))
    mesh.set_time(2 * T)  # at a keyframe: the velocity of the segment that starts there
    assert np.allclose(mesh.positions, keys[2], atol=ROUNDOFF)
    assert np.allclose(mesh.vertex_velocities, (keys[3] - keys[2]) / T, atol=1e-9)


def test_callable_positions_give_the_rigid_velocity(rng):
    X0, F = icosphere(0.3, 2, center=(0.5, 0.0, 0.0))
    w = 2.0  # rad/s about z

    def spin(t):
        c, s = np.cos(w * t), np.sin(w * t)
        return X0 @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T

    mesh = TriangleMeshObstacle(spin, F)
    mesh.set_time(0.7)
    out = mesh.closest(_shell_points(rng, spin(0.7).mean(axis=0), 0.3, 200))
    assert np.allclose(out["velocity"], np.cross([0, 0, w], out["point"]), atol=CALLABLE_VELOCITY_TOL)


# ---- OBJ sequences -------------------------------------------------------------------------

def test_obj_sequence_round_trip_and_topology_errors_name_the_file(tmp_path):
    centers = np.array([[0, 0, 0.1], [0.05, 0, 0.1], [0.1, 0.02, 0.12]])
    X, F = moving_sphere_keyframes(0.1, 1, centers)
    paths = write_obj_sequence(tmp_path / "seq", X, F)
    for source in (str(tmp_path / "seq" / "frame_*.obj"), tmp_path / "seq", [str(p) for p in paths]):
        Y, G, got = load_obj_sequence(source, scale=2.0)
        assert got == paths and np.array_equal(G, F) and np.allclose(Y, 2.0 * X, rtol=0, atol=OBJ_ROUNDTRIP)
    # polygons are split into fans; v/vt/vn tokens and negative indices are read
    quad = tmp_path / "quad.obj"
    quad.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1 -1/1\n")
    Y, G, _ = load_obj_sequence(str(quad))
    assert Y.shape == (1, 4, 3) and G.tolist() == [[0, 1, 2], [0, 2, 3]]
    # a frame with another vertex count (an extra vertex), or other faces, is named
    bad = tmp_path / "bad"
    write_obj_sequence(bad, X[:2], F)
    extra = write_obj_sequence(bad, [np.vstack([X[2], [[1.0, 1.0, 1.0]]])], F, stem="frame_x")
    with pytest.raises(ObjError, match=rf"frame_x_0000\.obj: has {X.shape[1] + 1} vertices"):
        load_obj_sequence(str(bad / "frame_*.obj"))
    extra[0].unlink()
    G = F.copy()
    G[[0, 1]] = G[[1, 0]]
    write_obj_sequence(bad, X[2:], G, stem="frame_y")
    with pytest.raises(ObjError, match=r"frame_y_0000\.obj: its faces differ"):
        load_obj_sequence(str(bad / "frame_*.obj"))
    with pytest.raises(ObjError, match="no file matches"):
        load_obj_sequence(str(tmp_path / "none_*.obj"))


# ---- the skinned body ------------------------------------------------------------------------

def test_capsule_tessellation_is_closed_and_outward():
    X, F = capsule_tessellation((0, 0, 0), (0, 0, 0.3), 0.1, 12)
    mesh = TriangleMeshObstacle(X, F)
    assert mesh.component_closed.all() and mesh.flipped_components == []
    assert np.allclose(Capsule((0, 0, 0), (0, 0, 0.3), 0.1).query(X)[0], 0.0, atol=ROUNDOFF)


def test_skinned_mannequin_mesh_is_the_capsule_body_up_to_its_facets(rng):
    body = Mannequin(Dance(), position=(0.5, -0.2, 0.0), heading=0.4, phase=0.3)
    segments = 12
    mesh = skinned_mannequin_mesh(body, segments=segments)
    assert mesh.moving and mesh.n_components == len(body.radii) and mesh.component_closed.all()
    # the deepest point of any facet below the capsules, at rest
    X, F = mesh.positions, mesh.faces
    u = np.array([(i, j) for i in range(FACET_SAMPLES + 1) for j in range(FACET_SAMPLES + 1 - i)]) / FACET_SAMPLES
    w = np.column_stack([1 - u.sum(axis=1), u])
    samples = np.einsum("sk,fkd->fsd", w, X[F])  # (F, S, 3)
    body.set_time(0.0)
    depth = (1 + FACET_SAMPLING_MARGIN) * max(  # each capsule's facets against that capsule (components in order)
        -Capsule(*body.ends[k], body.radii[k]).query(samples[mesh.face_component == k].reshape(-1, 3))[0].min()
        for k in range(len(body.radii)))
    assert 0 < depth < 0.1 * body.radii.max()
    for t in (0.0, 1.7):
        body.set_time(t)
        mesh.set_time(t)
        k = rng.integers(0, len(body.radii), 2000)
        axis = body.ends[k, 0] + rng.uniform(0, 1, (2000, 1)) * (body.ends[k, 1] - body.ends[k, 0])
        d = rng.standard_normal((2000, 3))
        P = axis + d / np.linalg.norm(d, axis=1)[:, None] * (body.radii[k] + rng.uniform(-0.04, 0.04, 2000))[:, None]
        diff = mesh.query(P)[0] - body.query(P)[0]
        assert diff.min() >= -ROUNDOFF and diff.max() <= depth


# ---- scenes --------------------------------------------------------------------------------

def test_mesh_obstacle_scene_keeps_the_cloth_outside_a_rising_obj_sequence(tmp_path):
    # an 80-triangle sphere rises 6 cm into a small sheet that starts 2 cm above it
    T = 0.04
    centers = np.array([[0.0, 0.0, 0.15 + 0.01 * k] for k in range(7)])
    X, F = moving_sphere_keyframes(0.15, 1, centers)
    write_obj_sequence(tmp_path / "seq", X, F)
    frames = 6
    sim = build_sim("scene=mesh_obstacle", f"scene.params.obstacle_obj={tmp_path}/seq/frame_*.obj",
                    f"scene.params.obstacle_frame_time={T}", "scene.params.drop_height=0.32",
                    "scene.params.size=0.5", "scene.params.steps_per_frame=4",
                    "scene.scales.small.resolution=8", f"frames={frames}")
    ob = sim.obstacle_set.obstacles[-1]
    assert isinstance(ob, TriangleMeshObstacle) and ob.n_keyframes == 7
    thickness = sim.scene.thickness
    free = ~sim.mesh.node_pinned
    touched = 0
    for f in range(frames):
        record = sim.advance_frame()
        touched = max(touched, record["contacts"])
        assert np.all(np.isfinite(sim.mesh.node_x)) and np.all(np.isfinite(sim.mesh.node_v))
        assert np.allclose(ob.positions, X[f + 1], atol=1e-12)  # the obstacle is at the frame's OBJ file
        assert ob.query(sim.mesh.node_x[free])[0].min() >= CONTACT_MARGIN * thickness
    assert touched > 0  # the sphere did reach the sheet


def test_mesh_obstacle_config_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match=r"obstacle_obj: .*no file matches"):
        build_sim("scene=mesh_obstacle", f"scene.params.obstacle_obj={tmp_path}/none_*.obj")
    X, F = moving_sphere_keyframes(0.1, 1, [[0, 0, 0.1], [0, 0, 0.2]])
    write_obj_sequence(tmp_path, X[:1], F, stem="a")
    write_obj_sequence(tmp_path, [np.vstack([X[1], [[1.0, 1.0, 1.0]]])], F, stem="b")  # one vertex more
    with pytest.raises(ConfigError, match=rf"obstacle_obj: .*b_0000\.obj: has {X.shape[1] + 1} vertices"):
        build_sim("scene=mesh_obstacle", f"scene.params.obstacle_obj={tmp_path}/*_0000.obj")
    with pytest.raises(ConfigError, match="body must be one of"):
        build_sim("scene=solo_dancer", "scene.params.body=spheres")


@pytest.mark.parametrize("scene", ["solo_dancer", "karate"])
def test_character_scenes_can_collide_with_the_skinned_mesh_body(scene):
    s = build_scene(scene, COTTON, resolution=8, body="mesh", body_segments=8)
    (ob,) = s.obstacles
    assert isinstance(ob, TriangleMeshObstacle) and ob.moving and ob.n_components == 17
    with pytest.raises(SceneError, match="body_segments"):
        build_scene(scene, COTTON, resolution=8, body="mesh", body_segments=2)


# ---- untangling ----------------------------------------------------------------------------

def test_untangle_moves_only_the_cloth_off_a_mesh_obstacle_poking_through_it():
    cloth = grid_mesh(0.4, 0.4, 4, 4, origin=(-0.2, -0.2, 0.0))
    cloth.update_rest_data(COTTON.density)
    apex = [0.03, 0.02, 0.02]  # a tetrahedron's tip 2 cm through one cloth face; every cloth node outside
    base = [[0.03 + 0.1 * np.cos(a), 0.02 + 0.1 * np.sin(a), -0.2] for a in (0, 2 * np.pi / 3, 4 * np.pi / 3)]
    tetra = TriangleMeshObstacle(np.vstack([apex, base]), [[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    assert tetra.query(cloth.node_x)[0].min() > 0
    x = cloth.node_x.copy()
    tris = mesh_obstacle_triangles([tetra])
    before = tetra.positions.copy()
    both = np.vstack([cloth.face_nodes, tetra.faces + len(x)])
    assert len(find_intersections(both, np.vstack([x, before]), n_fixed_faces=4)[0]) > 0
    stats = untangle(cloth.face_nodes, x, cloth.node_m, cloth.node_pinned, 0.005, 30, obstacles=tris)
    assert stats["intersections_found"] > 0 and stats["intersections_left"] == 0
    assert np.array_equal(tetra.positions, before)
    assert len(find_intersections(both, np.vstack([x, before]), n_fixed_faces=4)[0]) == 0
    assert np.all(np.isfinite(x)) and np.any(x != cloth.node_x)


# The kernel sums in numpy's order, but numpy's own order (its einsum, its vectorised arctan2) may
# differ on another CPU in the last bit: compared to round-off of unit vectors and angles.
PSEUDO_NORMAL_TOL = 1e-13


def test_pseudo_normals_kernel_matches_the_definition():
    """meshkernels.pseudo_normals against the vectorised definition on a jittered icosphere: unit
    face normals, vertex pseudo-normals weighted by the corner angles, edge pseudo-normals the sum
    of the two faces' normals (every edge of a closed mesh has two)."""
    from cloth.collision.meshkernels import pseudo_normals
    v, f = icosphere(0.3, subdivisions=2)
    x = v + 0.01 * np.random.default_rng(0).normal(size=v.shape)
    ob = TriangleMeshObstacle(x, f)
    t = x[f]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    fn = n / np.linalg.norm(n, axis=1)[:, None]
    vp = np.zeros_like(x)
    for k in range(3):
        e1, e2 = t[:, (k + 1) % 3] - t[:, k], t[:, (k + 2) % 3] - t[:, k]
        angle = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=1), np.sum(e1 * e2, axis=1))
        np.add.at(vp, f[:, k], angle[:, None] * fn)
    face_n, vert_pn, edge_pn = np.empty((len(f), 3)), np.empty_like(x), np.empty((ob._n_edges, 3))
    pseudo_normals(x, ob.faces, ob._face_edge, face_n, vert_pn, edge_pn)
    assert np.allclose(face_n, fn, rtol=0, atol=PSEUDO_NORMAL_TOL)
    assert np.allclose(vert_pn, vp, rtol=0, atol=PSEUDO_NORMAL_TOL)
    ep = np.zeros((ob._n_edges, 3))
    np.add.at(ep, ob._face_edge.ravel(), np.repeat(fn, 3, axis=0))
    assert np.allclose(edge_pn, ep, rtol=0, atol=PSEUDO_NORMAL_TOL)
    assert np.array_equal(ob.face_normals, face_n) and np.array_equal(ob._vert_pn, vert_pn)  # what set_time keeps
