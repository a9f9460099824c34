"""Triangle-mesh obstacles: closest point, sign and normal against closed forms and brute force,
keyframe interpolation and velocities, OBJ sequences, the skinned mannequin, the mesh_obstacle
scene, untangling cloth from a mesh obstacle, and the cloth-obstacle collisions within each step
(a spike tip and a coarse sheet on a sphere that node-based contact lets through, impact zones
on a rotating obstacle, the CCD slab rejection, the skinned body in solo_dancer)."""

import numpy as np
import pytest
import trimesh.creation
from hydra import compose, initialize_config_dir

from cloth.ccd import point_triangle_closest
from cloth.character import Dance, Mannequin
from cloth.material import Material
from cloth.mesh import grid_mesh
from cloth.meshobstacle import (MeshObstacleError, TriangleMeshObstacle, capsule_tessellation, icosphere,
                                load_obj_sequence, mesh_obstacle_triangles, mesh_obstacles, moving_sphere_keyframes,
                                skinned_mannequin_mesh, write_obj_sequence)
from cloth.obstacles import Capsule, Sphere
from cloth.scene import SceneError
from cloth.scenes import build_scene
from cloth.untangle import find_intersections, untangle
from experiments.build import ConfigError, build_simulation

# Distances are sums and square roots of O(1) numbers.
ROUNDOFF = 1e-12
# Positions written with 17 significant digits and scaled once: a few ulps.
OBJ_ROUNDTRIP = 1e-14
# Central difference of a callable over cloth.meshobstacle.VELOCITY_STEP = 1e-4 s of a rotation
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

COTTON = Material("cotton", density=0.12, youngs_modulus=2.0e3, poisson_ratio=0.3, bending_stiffness=5e-6,
                  damping_mass=0.05, damping_stiffness=2e-3)
rng = np.random.default_rng(11)


def _shell_points(center, radius, n):
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

def test_sphere_mesh_matches_the_analytic_sphere_within_its_tessellation():
    R, c = 0.5, np.array([0.1, -0.2, 0.3])
    X, F = icosphere(R, 3, c)
    mesh = TriangleMeshObstacle(X, F)
    n_f = mesh.face_normals
    sagitta = R - np.min(np.einsum("fi,fi->f", n_f, X[F[:, 0]] - c))  # deepest facet below the sphere
    alpha = np.arccos(np.clip(np.einsum("fi,fki->fk", n_f, (X[F] - c) / R), -1, 1)).max()  # facets' angular radius
    P = _shell_points(c, R, 5000)
    phi, normal, velocity = mesh.query(P)
    phi_s, normal_s, _ = Sphere(c, R).query(P)
    assert np.all(phi - phi_s >= -ROUNDOFF)  # the mesh is inscribed: its signed distance is never smaller
    assert np.all(phi - phi_s <= sagitta + ROUNDOFF)
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0, atol=ROUNDOFF)
    lean = np.arccos(np.clip(np.einsum("ij,ij->i", normal, normal_s), -1, 1))
    assert lean.max() <= NORMAL_LEAN * alpha
    assert np.all(velocity == 0.0) and not mesh.moving


def test_signs_and_distances_on_a_nonconvex_closed_mesh_match_brute_force():
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


def test_query_radius_cuts_off_far_points():
    X, F = icosphere(0.3, 2)
    exact = TriangleMeshObstacle(X, F)
    near = TriangleMeshObstacle(X, F, query_radius=0.1)
    P = _shell_points(np.zeros(3), 0.3, 2000)
    phi, _, _ = exact.query(P)
    out = near.closest(P)
    far = np.abs(phi) >= 0.1
    assert far.any() and (~far).any()
    assert np.allclose(out["phi"][~far], phi[~far], atol=ROUNDOFF)
    assert np.all(out["phi"][far] == 0.1) and np.all(out["face"][far] == -1) and np.all(out["normal"][far] == 0)


def test_overlapping_closed_components_are_a_union():
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


def test_open_mesh_sign_is_the_side_of_the_face_and_inward_closed_meshes_are_flipped():
    square = TriangleMeshObstacle([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    assert not square.component_closed[0]
    P = np.column_stack([rng.uniform(0, 1, (50, 2)), rng.uniform(-0.5, 0.5, 50)])
    phi, normal, _ = square.query(P)
    assert np.allclose(phi, P[:, 2], atol=ROUNDOFF) and np.allclose(normal[:, 2], 1.0)
    X, F = icosphere(0.3, 2)
    inward = TriangleMeshObstacle(X, F[:, ::-1])
    assert inward.flipped_components == [0]
    Q = _shell_points(np.zeros(3), 0.3, 200)
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

def test_translating_keyframes_move_at_the_translation_speed_and_hold_at_the_ends():
    X0, F = icosphere(0.2, 2)
    step, T, K = np.array([0.01, -0.02, 0.005]), 0.05, 6  # m per keyframe, s, keyframes
    mesh = TriangleMeshObstacle(X0[None] + np.arange(K)[:, None, None] * step, F, T, start_time=0.1)
    P = _shell_points(np.zeros(3), 0.2, 300)
    for t in (0.1, 0.1 + 1.3 * T, 0.1 + 3 * T, 0.1 + 4.99 * T):
        mesh.set_time(t)
        assert np.allclose(mesh.positions, X0 + (t - 0.1) / T * step, atol=ROUNDOFF)
        v = mesh.query(P + (t - 0.1) / T * step)[2]
        assert np.allclose(v, step / T, atol=ROUNDOFF)
    for t, k in ((0.0, 0), (0.1 + 5 * T, K - 1), (9.0, K - 1)):  # before the first, at and after the last
        mesh.set_time(t)
        assert np.allclose(mesh.positions, X0 + k * step, atol=ROUNDOFF) and np.all(mesh.vertex_velocities == 0)


def test_positions_are_linear_between_keyframes_and_velocity_is_their_difference():
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
        out = mesh.closest(_shell_points(np.zeros(3), 0.2, 50))
        fv = mesh.faces[out["face"]]
        assert np.allclose(out["velocity"], np.einsum("nk,nkd->nd", out["bary"], mesh.vertex_velocities[fv]))
    mesh.set_time(2 * T)  # at a keyframe: the velocity of the segment that starts there
    assert np.allclose(mesh.positions, keys[2], atol=ROUNDOFF)
    assert np.allclose(mesh.vertex_velocities, (keys[3] - keys[2]) / T, atol=1e-9)


def test_callable_positions_give_the_rigid_velocity():
    X0, F = icosphere(0.3, 2, center=(0.5, 0.0, 0.0))
    w = 2.0  # rad/s about z

    def spin(t):
        c, s = np.cos(w * t), np.sin(w * t)
        return X0 @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T

    mesh = TriangleMeshObstacle(spin, F)
    mesh.set_time(0.7)
    out = mesh.closest(_shell_points(spin(0.7).mean(axis=0), 0.3, 200))
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
    with pytest.raises(MeshObstacleError, match=rf"frame_x_0000\.obj: has {X.shape[1] + 1} vertices"):
        load_obj_sequence(str(bad / "frame_*.obj"))
    extra[0].unlink()
    G = F.copy()
    G[[0, 1]] = G[[1, 0]]
    write_obj_sequence(bad, X[2:], G, stem="frame_y")
    with pytest.raises(MeshObstacleError, match=r"frame_y_0000\.obj: its faces differ"):
        load_obj_sequence(str(bad / "frame_*.obj"))
    with pytest.raises(MeshObstacleError, match="no file matches"):
        load_obj_sequence(str(tmp_path / "none_*.obj"))


# ---- the skinned body ------------------------------------------------------------------------

def test_capsule_tessellation_is_closed_and_outward():
    X, F = capsule_tessellation((0, 0, 0), (0, 0, 0.3), 0.1, 12)
    mesh = TriangleMeshObstacle(X, F)
    assert mesh.component_closed.all() and mesh.flipped_components == []
    assert np.allclose(Capsule((0, 0, 0), (0, 0, 0.3), 0.1).query(X)[0], 0.0, atol=ROUNDOFF)


def test_skinned_mannequin_mesh_is_the_capsule_body_up_to_its_facets():
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

CONF = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "conf")


def _cfg(*overrides):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def test_mesh_obstacle_scene_keeps_the_cloth_outside_a_rising_obj_sequence(tmp_path):
    # an 80-triangle sphere rises 6 cm into a small sheet that starts 2 cm above it
    T = 0.04
    centers = np.array([[0.0, 0.0, 0.15 + 0.01 * k] for k in range(7)])
    X, F = moving_sphere_keyframes(0.15, 1, centers)
    write_obj_sequence(tmp_path / "seq", X, F)
    frames = 6
    sim, _ = build_simulation(_cfg("scene=mesh_obstacle", f"scene.params.obstacle_obj={tmp_path}/seq/frame_*.obj",
                                   f"scene.params.obstacle_frame_time={T}", "scene.params.drop_height=0.32",
                                   "scene.params.size=0.5", "scene.params.steps_per_frame=4",
                                   "scene.scales.small.resolution=8", f"frames={frames}"))
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
        build_simulation(_cfg("scene=mesh_obstacle", f"scene.params.obstacle_obj={tmp_path}/none_*.obj"))
    X, F = moving_sphere_keyframes(0.1, 1, [[0, 0, 0.1], [0, 0, 0.2]])
    write_obj_sequence(tmp_path, X[:1], F, stem="a")
    write_obj_sequence(tmp_path, [np.vstack([X[1], [[1.0, 1.0, 1.0]]])], F, stem="b")  # one vertex more
    with pytest.raises(ConfigError, match=rf"obstacle_obj: .*b_0000\.obj: has {X.shape[1] + 1} vertices"):
        build_simulation(_cfg("scene=mesh_obstacle", f"scene.params.obstacle_obj={tmp_path}/*_0000.obj"))
    with pytest.raises(ConfigError, match="body must be one of"):
        build_simulation(_cfg("scene=solo_dancer", "scene.params.body=spheres"))


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


# ---- cloth-obstacle collisions within the step (proximity, CCD, impact zones) ------------------
# The node-based contact sees only cloth nodes; an obstacle's tip or edge can pass through the
# inside of a cloth face. Crossings below are counted exactly (cloth.untangle.find_intersections,
# the untangling's own test): no tolerance.

def _cloth_obstacle_crossings(sim) -> int:
    """Crossing (cloth face, obstacle face) pairs of the simulation now."""
    mesh, count = sim.mesh, 0
    for ob in mesh_obstacles(sim.obstacle_set):
        both = np.vstack([mesh.face_nodes, ob.faces + mesh.n_nodes])
        pairs = find_intersections(both, np.vstack([mesh.node_x, ob.positions]), n_fixed_faces=len(ob.faces))[0]
        count += int(np.count_nonzero(pairs[:, 1] >= mesh.n_faces))
    return count


def _check_every_step(sim, seen: list):
    """Make sim append (step, cloth-obstacle crossings) to `seen` after each of its steps."""
    step = sim.step

    def checked(timings, stats):
        step(timings, stats)
        seen.append((sim.steps_taken, _cloth_obstacle_crossings(sim)))
    sim.step = checked


SPIKE_RISE = 0.12  # m in one frame of 4 steps: 3 cm per step, six times the 5 mm thickness


def _spike_through_coarse_sheet():
    """A 2 x 2-cell sheet (0.3 m legs) pinned at its corners, without gravity, and the tip of a
    thin tetrahedron (3 cm across) 2 cm below the middle of one face; in the second frame the
    tetrahedron rises SPIKE_RISE (keyframes), then holds. No cloth node comes near it."""
    from cloth.obstacles import Static
    from cloth.scene import Handle, Scene
    from cloth.simulation import Simulation

    sheet = grid_mesh(0.6, 0.6, 2, 2, origin=(-0.3, -0.3, 0.3))
    corners = np.flatnonzero(np.all(np.abs(sheet.node_x[:, :2]) > 0.29, axis=1))
    c = sheet.node_x[sheet.face_nodes[0]].mean(axis=0)
    apex = [c[0], c[1], c[2] - 0.02]
    base = [[c[0] + 0.015 * np.cos(a), c[1] + 0.015 * np.sin(a), c[2] - 0.22]
            for a in (0, 2 * np.pi / 3, 4 * np.pi / 3)]
    X = np.vstack([apex, base])
    spike = TriangleMeshObstacle(np.stack([X, X + [0.0, 0.0, SPIKE_RISE]]),
                                 [[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], frame_time=0.04, start_time=0.04,
                                 name="spike")
    scene = Scene("spike", sheet, COTTON, {"membrane", "bending", "damping", "obstacles"}, frame_time=0.04,
                  steps_per_frame=4, obstacles=[spike], handles=[Handle(corners, Static())], thickness=0.005)
    return Simulation(scene)


def test_a_spike_tip_rising_through_a_coarse_face_is_stopped_only_by_the_step_collisions():
    frames = 5
    off = _spike_through_coarse_sheet()
    off.mesh_collision = None  # node-based contact only, as before
    records = [off.advance_frame() for _ in range(frames)]
    assert all(r["contacts"] == 0 for r in records)  # no cloth node ever came near the spike
    assert _cloth_obstacle_crossings(off) > 0  # ... and its tip went through the face

    on = _spike_through_coarse_sheet()
    assert on.mesh_collision is not None
    seen = []
    _check_every_step(on, seen)
    records = [on.advance_frame() for _ in range(frames)]
    assert len(seen) == frames * on.scene.steps_per_frame and all(n == 0 for _, n in seen), seen
    assert records[1]["obstacle_ccd_hits"] > 0  # the tip was caught by CCD in the step it rose
    assert all(r["obstacle_collisions_left"] == 0 for r in records)
    assert np.all(np.isfinite(on.mesh.node_x)) and np.all(np.isfinite(on.mesh.node_v))
    # the tip ends 10 cm above the sheet's plane (z = 0.3): the face it was under was lifted on it
    assert on.mesh.node_x[:, 2].max() > 0.3 + SPIKE_RISE / 2
    spike = on.obstacle_set.obstacles[0]
    assert np.array_equal(spike.positions, spike.keyframes[-1])  # the spike itself is not moved


def test_scenes_without_a_mesh_obstacle_never_run_the_cloth_obstacle_pass(monkeypatch):
    import cloth.meshobstacle as mo
    import cloth.selfcollision as sc
    from cloth.scenes import layered_sheets
    from cloth.simulation import Simulation

    calls = {"resolve": 0, "mesh_obstacles": 0}
    resolve, find = sc.resolve_collisions_with_obstacles, mo.mesh_obstacles

    def counting_resolve(*a, **k):
        calls["resolve"] += 1
        return resolve(*a, **k)

    def counting_find(*a, **k):
        calls["mesh_obstacles"] += 1
        return find(*a, **k)

    monkeypatch.setattr(sc, "resolve_collisions_with_obstacles", counting_resolve)
    monkeypatch.setattr(mo, "mesh_obstacles", counting_find)
    for scene in (build_scene("hanging_sheet", COTTON, resolution=4),  # no obstacle
                  build_scene("sheet_on_sphere", COTTON, resolution=4),  # analytic obstacles
                  layered_sheets(COTTON, resolution=4)):  # analytic obstacles and self_collision
        sim = Simulation(scene)
        assert sim.mesh_collision is None
        rec = sim.advance_frame()
        assert rec["obstacle_ccd_hits"] == 0 and rec["obstacle_proximity"] == 0 and rec["obstacle_collisions_left"] == 0
    assert calls == {"resolve": 0, "mesh_obstacles": 0}
    # the same counters count once per step when the scene has a mesh obstacle
    sim = _spike_through_coarse_sheet()
    sim.advance_frame()
    assert calls["resolve"] == sim.scene.steps_per_frame


def test_mesh_obstacle_scene_nonadaptive_ends_every_step_without_a_cloth_obstacle_crossing():
    # 6 x 6 cells (17 cm) over the 7 cm facets of the icosphere: a face spans the sphere's cap
    # with a sagitta of ~1.4 cm, more than the thickness, so node-based contact alone lets the
    # sphere's vertices through the faces (checked first); the step's collisions do not
    frames = 8
    cfg = _cfg("scene=mesh_obstacle", "mode=nonadaptive", "scene.params.drop_height=0.56",
               "scene.scales.small.resolution=6", f"frames={frames}")
    runs = {}
    for on in (False, True):
        sim, _ = build_simulation(cfg)
        if not on:
            sim.mesh_collision = None
        seen = []
        _check_every_step(sim, seen)
        runs[on] = (sim, seen, [sim.advance_frame() for _ in range(frames)])
    assert max(n for _, n in runs[False][1]) > 0
    sim, seen, records = runs[True]
    assert len(seen) == frames * sim.scene.steps_per_frame and all(n == 0 for _, n in seen), seen
    assert max(r["obstacle_proximity"] for r in records) > 0  # the sheet did lie on the sphere
    assert all(r["obstacle_collisions_left"] == 0 for r in records)
    assert np.all(np.isfinite(sim.mesh.node_x)) and np.all(np.isfinite(sim.mesh.node_v))


def test_impact_zones_move_with_a_rotating_obstacle_and_leave_no_collision():
    """Impact zones alone (no CCD passes): a plate 1 cm above a sheet tilts 30 degrees about its
    middle within one step, one half sweeping down through the sheet. The zone follows the
    plate's rigid motion (pinned_fit), so it converges in one round; the plate's mean
    displacement (a translation, about zero here) would leave the collisions."""
    from cloth.selfcollision import (CCD_ETA_FRACTION, SelfCollisionParams, _ccd_pass, candidate_pairs,
                                     resolve_collisions_with_obstacles)

    sheet = grid_mesh(0.3, 0.3, 6, 6, origin=(-0.15, -0.15, 0.0))
    sheet.update_rest_data(COTTON.density)
    y0 = np.array([[-0.1, -0.1, 0.01], [0.1, -0.1, 0.01], [0.1, 0.1, 0.01], [-0.1, 0.1, 0.01]])
    plate = TriangleMeshObstacle(y0, [[0, 1, 2], [0, 2, 3]])
    a = np.radians(30.0)
    R = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    y1 = (y0 - y0.mean(axis=0)) @ R.T + y0.mean(axis=0)
    x0 = sheet.node_x.copy()
    x1 = x0.copy()  # the sheet at rest
    params = SelfCollisionParams(thickness=0.005, proximity_passes=0, ccd_passes=0)
    obstacles = [(y0, y1.copy(), *plate.collision_topology())]
    stats = resolve_collisions_with_obstacles(sheet.face_nodes, sheet.face_edges, sheet.edge_nodes, x0, x1,
                                              sheet.node_m, sheet.node_pinned, params, obstacles, self_pairs=False)
    assert stats["impact_zone_rounds"] >= 1 and stats["obstacle_collisions_left"] == 0
    assert np.array_equal(obstacles[0][1], y1)  # the obstacle is never moved
    moved = np.linalg.norm(x1 - x0, axis=1) > 0
    assert moved.any() and np.allclose(x1[moved], (x0[moved] - y0.mean(axis=0)) @ R.T + y0.mean(axis=0), atol=ROUNDOFF)
    # an independent CCD pass over the corrected step finds nothing
    n, (faces, f_edges, e_nodes) = sheet.n_nodes, plate.collision_topology()
    fn = np.vstack([sheet.face_nodes, faces + n]).astype(np.int64)
    fe = np.vstack([sheet.face_edges, f_edges + sheet.n_edges]).astype(np.int64)
    en = np.vstack([sheet.edge_nodes, e_nodes + n]).astype(np.int64)
    X0, X1 = np.vstack([x0, y0]), np.vstack([x1, y1])
    inv_m = np.concatenate([np.ones(n), np.zeros(4)])
    eta = CCD_ETA_FRACTION * params.thickness
    vf, ee = candidate_pairs(fn, fe, en, X0, X1, eta, inv_m, n_fixed_faces=2, self_pairs=False, first_fixed=n)
    hits = np.empty((len(vf) + len(ee), 4), dtype=np.int64)
    assert len(vf) + len(ee) > 0
    assert _ccd_pass(vf, ee, fn, en, X0, X1, inv_m, eta, 0.0, False, hits, np.zeros(len(X0) + 1, dtype=bool)) == 0


# The slab rejection before the CCD cubic must never reject a pair that touches: checked against
# the distance sampled at SLAB_SAMPLES times over the step (a touch shorter than 1 / SLAB_SAMPLES
# of the step could hide between samples, so random near misses are drawn, not grazes).
SLAB_SAMPLES = 401


def test_ccd_slab_rejection_is_exact_on_random_near_misses():
    from cloth.ccd import ee_separated, segment_segment_closest, vf_separated

    r = np.random.default_rng(5)
    eta = 0.01
    ts = np.linspace(0.0, 1.0, SLAB_SAMPLES)
    rejected = 0
    for _ in range(300):
        P0 = r.uniform(-0.1, 0.1, (4, 3))
        P1 = P0 + r.uniform(-0.08, 0.08, (4, 3))
        if vf_separated(P0[0], P0[1], P0[2], P0[3], P1[0], P1[1], P1[2], P1[3], eta):
            rejected += 1
            P = P0[None] + ts[:, None, None] * (P1 - P0)[None]
            d = min(point_triangle_closest(p[0], p[1], p[2], p[3])[0] for p in P)
            assert d > eta
        if ee_separated(P0[0], P1[0], P0[1], P1[1], P0[2], P1[2], P0[3], P1[3], eta):
            rejected += 1
            P = P0[None] + ts[:, None, None] * (P1 - P0)[None]
            d = min(segment_segment_closest(p[0], p[1], p[2], p[3])[0] for p in P)
            assert d > eta
    assert rejected > 100  # the rejection does reject


def test_solo_dancer_with_the_skinned_mesh_body_stays_outside_it():
    # small and short: 32 segments around the waist, 8 frames of 0.08 s (16 steps of 5 ms, the
    # scene's step) so that the falling skirt reaches the hips and legs (from about frame 6)
    frames = 8
    sim, _ = build_simulation(_cfg("scene=solo_dancer", "mode=nonadaptive", "scene.params.body=mesh",
                                   "scene.params.frame_time=0.08", "scene.params.steps_per_frame=16",
                                   "scene.scales.small.resolution=32", f"frames={frames}"))
    (body,) = mesh_obstacles(sim.obstacle_set)
    assert sim.mesh_collision is not None
    records = [sim.advance_frame() for _ in range(frames)]
    assert max(r["obstacle_proximity"] + r["contacts"] for r in records) > 0  # the skirt did touch the body
    assert np.all(np.isfinite(sim.mesh.node_x)) and np.all(np.isfinite(sim.mesh.node_v))
    assert body.query(sim.mesh.node_x)[0].min() > 0.0  # no cloth node inside the body
    assert _cloth_obstacle_crossings(sim) == 0 and records[-1]["obstacle_collisions_left"] == 0


def test_a_cloth_node_inside_a_mesh_obstacle_at_a_step_start_is_let_out():
    """Continuous collision detection keeps every pair on its starting side; a node that starts a
    step inside the obstacle (here put 2 cm into a sphere) would be held in against the node
    contact's push-out. Such nodes are left out of the cloth-obstacle pairs for that step."""
    from cloth.scene import Scene
    from cloth.simulation import Simulation

    sheet = grid_mesh(0.6, 0.6, 6, 6, origin=(-0.3, -0.3, 0.25))
    X, F = icosphere(0.25, 2)
    mid = int(np.argmin(np.linalg.norm(sheet.node_x[:, :2], axis=1)))
    sheet.node_x[mid, 2] = 0.23
    ball = TriangleMeshObstacle(X, F)
    assert ball.query(sheet.node_x[[mid]])[0][0] < 0
    sim = Simulation(Scene("inside", sheet, COTTON, {"membrane", "bending", "damping", "obstacles"}, frame_time=0.04,
                           steps_per_frame=4, obstacles=[ball]))
    record = sim.advance_frame()
    assert ball.query(sim.mesh.node_x[[mid]])[0][0] >= CONTACT_MARGIN * sim.scene.thickness
    assert _cloth_obstacle_crossings(sim) == 0 and record["obstacle_collisions_left"] == 0
