"""Self-collision: broad phase against brute force, the step response (proximity, CCD, impact
zones) leaves no collision and no crossing, conserves momentum; untangling removes crossings,
its contour-length gradient matches finite differences; the effect costs nothing when a scene
does not declare it; layered sheets stay apart in the frame loop in all modes."""

import numpy as np
import pytest
from helpers import build_sim, count_crossings, two_sheets

from cloth.collision.bvh import build_tree, cross_overlaps, face_boxes, self_overlaps
from cloth.collision.candidates import candidate_pairs
from cloth.collision.ccd import point_triangle_closest
from cloth.collision.response import ccd_pass
from cloth.collision.selfcollision import CCD_ETA_FRACTION, SelfCollisionParams, resolve_self_collisions
from cloth.collision.untangle import find_intersections, untangle
from cloth.core.material import Material
from cloth.core.mesh import grid_mesh, merge_meshes
from cloth.scenes.registry import layered_sheets
from cloth.simulation import Simulation

COTTON = Material("cotton", density=0.12, youngs_modulus=2.0e3, poisson_ratio=0.3, bending_stiffness=2e-6,
                  damping_mass=0.1, damping_stiffness=0.0)
THICKNESS = 0.005
# momentum is conserved up to round-off of sums over a few hundred nodes of O(1) m
MOMENTUM_TOL = 1e-12
# finite-difference step (m) and relative tolerance of the contour-length gradient: l is
# piecewise linear in a translation, so central differences are exact away from kinks
FD_STEP = 1e-7
FD_REL_TOL = 1e-5


def ccd_hits(mesh, x0, x1, thickness=THICKNESS):
    """CCD collisions left over the step x0 -> x1 (no response)."""
    eta = CCD_ETA_FRACTION * thickness
    vf, ee = candidate_pairs(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x1, eta)
    hits = np.empty((len(vf) + len(ee), 4), dtype=np.int64)
    inv_m = np.ones(mesh.n_nodes)
    return ccd_pass(vf, ee, mesh.face_nodes, mesh.edge_nodes, x0, x1.copy(), inv_m, eta, 0.0, False, hits,
                    np.zeros(x0.shape[0] + 1, dtype=bool), np.zeros((0, 7)))


# ------------------------------------------------------------------------------------------
def test_bvh_pairs_equal_brute_force():
    rng = np.random.default_rng(1)
    for n in (0, 1, 2, 7, 60, 400):
        c = rng.random((n, 3))
        s = 0.15 * rng.random((n, 3))
        lo, hi = c - s, c + s
        ov = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
        i, j = np.nonzero(np.triu(ov, 1))
        pairs = self_overlaps(lo, hi)
        assert list(map(tuple, pairs)) == sorted(zip(i, j))  # sorted, each pair once, i < j
        unsorted = self_overlaps(lo, hi, sort=False)  # the search's own order: the same pairs
        assert len(unsorted) == len(pairs) and sorted(map(tuple, unsorted)) == list(map(tuple, pairs))
        c2 = rng.random((35, 3))
        lo2, hi2 = c2 - 0.05, c2 + 0.05
        ov2 = np.all((lo[:, None] <= hi2[None]) & (lo2[None] <= hi[:, None]), axis=2)
        i, j = np.nonzero(ov2)
        cross = cross_overlaps(lo, hi, lo2, hi2)
        assert list(map(tuple, cross)) == sorted(zip(i, j))
        if n:  # with the second set's tree given, in the search's own order: the same pairs
            given = cross_overlaps(lo, hi, lo2, hi2, tree2=build_tree(lo2, hi2), sort=False)
            assert len(given) == len(cross) and sorted(map(tuple, given)) == list(map(tuple, cross))


@pytest.mark.parametrize("seed, ccd_passes, jitter", [(0, 3, 0.3), (1, 3, 0.3), (2, 3, 0.3), (0, 1, 2.0), (1, 1, 2.0)])
def test_reused_broad_phase_gives_the_pairs_of_a_fresh_one(monkeypatch, seed, ccd_passes, jitter):
    """resolve_self_collisions finds the face pairs once and reuses them while no node has moved
    more than the thickness less the query's pad: the result (positions and record) is bitwise the
    one of a fresh broad phase at every query, on a step that needs proximity and CCD passes (the
    upper of two sheets pushed down through the lower one, with jitter of 0.3 thickness), and with
    one CCD pass only and jitter of 2 thicknesses, impact zones."""
    import cloth.collision.selfcollision as sc
    mesh, n_lower = two_sheets(n=10, gap=0.6 * THICKNESS)
    rng = np.random.default_rng(seed)
    x0 = mesh.node_x.copy()
    x1 = x0 + rng.normal(scale=jitter * THICKNESS, size=x0.shape)
    upper = np.arange(n_lower, mesh.n_nodes)
    bump = upper[np.linalg.norm(x0[upper, :2] - x0[upper, :2].mean(axis=0), axis=1) < 0.08]
    x1[bump, 2] -= 0.02  # through the lower sheet
    params = SelfCollisionParams(THICKNESS, ccd_passes=ccd_passes)
    runs = []
    for reuse in (True, False):
        monkeypatch.setattr(sc, "REUSE_BROAD_PHASE", reuse)
        x = x1.copy()
        stats = resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x, mesh.node_m,
                                        mesh.node_pinned, params)
        runs.append((x, stats))
    assert runs[0][1]["self_proximity"] > 0 and runs[0][1]["self_ccd_hits"] > 0
    if ccd_passes == 1:
        assert runs[0][1]["impact_zones"] > 0
    assert np.array_equal(runs[0][0], runs[1][0])
    assert runs[0][1] == runs[1][1]


def test_a_kept_obstacle_tree_is_refitted_and_finds_the_pairs_of_a_fresh_one():
    """candidates.obstacle_tree: a tree kept from pass to pass is refitted to the boxes' new places
    (the same object comes back) and finds exactly the pairs a fresh tree finds; moved far enough
    to loosen it past REFIT_GROWTH, it is built again."""
    from cloth.collision.candidates import REFIT_GROWTH, obstacle_tree
    rng = np.random.default_rng(3)
    centre, size = rng.random((300, 3)), 0.02 + 0.02 * rng.random((300, 3))
    query = rng.random((80, 3))
    qlo, qhi = query - 0.05, query + 0.05
    trees = {}
    first = obstacle_tree(centre - size, centre + size, trees)
    moved = centre + 0.01 * rng.normal(size=centre.shape)  # a small coherent motion: refitted
    lo, hi = moved - size, moved + size
    again = obstacle_tree(lo, hi, trees)
    assert again is first
    fresh = cross_overlaps(qlo, qhi, lo, hi)
    assert sorted(map(tuple, cross_overlaps(qlo, qhi, lo, hi, tree2=again, sort=False))) == list(map(tuple, fresh))
    shuffled = rng.permutation(moved)  # every box elsewhere: the refitted tree is loose, built again
    lo, hi = shuffled - size, shuffled + size
    rebuilt = obstacle_tree(lo, hi, trees)
    assert rebuilt is not first and trees["tree"] is rebuilt
    assert np.sum(rebuilt[1] - rebuilt[0]) <= REFIT_GROWTH * trees["extent"]


def test_bvh_rejects_bad_boxes():
    with pytest.raises(ValueError, match="finite"):
        self_overlaps(np.array([[0.0, 0, np.nan]]), np.ones((1, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        self_overlaps(np.zeros((2, 2)), np.ones((2, 2)))


def test_face_boxes_cover_the_motion():
    mesh, _ = two_sheets()
    x1 = mesh.node_x + np.array([0.0, 0.0, -0.05])
    lo, hi = face_boxes(mesh.face_nodes, mesh.node_x, x1, pad=0.001)
    for x in (mesh.node_x, x1):
        corners = x[mesh.face_nodes]
        assert np.all(corners >= lo[:, None] + 0.001 - 1e-15) and np.all(corners <= hi[:, None] - 0.001 + 1e-15)


# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("drop", [0.03, 0.2])
def test_sheet_driven_through_another_is_stopped(drop):
    """The upper sheet moves down through the lower one within one step (by 1.5x and 10x
    its distance): afterwards no CCD collision is left and the sheets do not cross."""
    mesh, n_lower = two_sheets()
    x0 = mesh.node_x.copy()
    x1 = x0.copy()
    x1[n_lower:, 2] -= drop
    before = ccd_hits(mesh, x0, x1)
    assert before > 0
    stats = resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x1, mesh.node_m,
                                    mesh.node_pinned, SelfCollisionParams(THICKNESS))
    assert stats["self_ccd_hits"] > 0 and stats["self_collisions_left"] == 0
    assert ccd_hits(mesh, x0, x1) == 0
    assert len(find_intersections(mesh.face_nodes, x1)[0]) == 0
    assert np.all(x1[n_lower:, 2] > x1[:n_lower, 2].min())  # the upper sheet stayed above


def test_random_crossings_resolved_and_momentum_kept():
    rng = np.random.default_rng(7)
    mesh, n_lower = two_sheets(n=5)
    m = mesh.node_m
    for trial in range(5):
        x0 = mesh.node_x.copy()
        x1 = x0 + 0.01 * rng.standard_normal(x0.shape)
        x1[n_lower:, 2] -= rng.uniform(0.02, 0.08)
        before = x1.copy()
        stats = resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x1, m,
                                        mesh.node_pinned, SelfCollisionParams(THICKNESS, friction=0.5))
        assert stats["self_collisions_left"] == 0, trial
        assert ccd_hits(mesh, x0, x1) == 0, trial
        assert len(find_intersections(mesh.face_nodes, x1)[0]) == 0, trial
        assert np.allclose(m @ x1, m @ before, rtol=0, atol=MOMENTUM_TOL), trial


def test_proximity_restores_the_thickness():
    """Sheets ending 1 mm apart are pushed to the thickness (vertex-face distances)."""
    mesh, n_lower = two_sheets(gap=0.01)
    x0 = mesh.node_x.copy()
    x1 = x0.copy()
    x1[n_lower:, 2] -= 0.009
    resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x1, mesh.node_m,
                            mesh.node_pinned, SelfCollisionParams(THICKNESS, proximity_passes=6))
    lower_faces = mesh.face_nodes[: len(mesh.face_nodes) // 2]
    d = [min(point_triangle_closest(x1[i], *x1[f])[0] for f in lower_faces) for i in range(n_lower, mesh.n_nodes)]
    assert min(d) > 0.9 * THICKNESS  # Gauss-Seidel passes leave a little of the overlap


def test_pinned_sheet_does_not_move():
    mesh, n_lower = two_sheets()
    mesh.node_pinned[:n_lower] = True
    x0 = mesh.node_x.copy()
    x1 = x0.copy()
    x1[n_lower:, 2] -= 0.05
    resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x1, mesh.node_m,
                            mesh.node_pinned, SelfCollisionParams(THICKNESS))
    assert np.array_equal(x1[:n_lower], x0[:n_lower])
    assert ccd_hits(mesh, x0, x1) == 0


def test_params_validated():
    with pytest.raises(ValueError, match="thickness"):
        SelfCollisionParams(0.0)
    with pytest.raises(ValueError, match="friction"):
        SelfCollisionParams(0.01, friction=-1)


# ------------------------------------------------------------------------------------------
def crossed_sheets(n=6, depth=0.04):
    """A horizontal sheet and a tilted one poking through it (a crossing of two pieces)."""
    flat = grid_mesh(0.4, 0.4, n, n, origin=(-0.2, -0.2, 0.0))
    # generic placement (no edge of one sheet through a node or edge of the other)
    tilted = grid_mesh(0.2, 0.2, n + 1, n + 1, origin=(-0.1037, -0.0913, -depth),
                       axes=((0.9950, 0.0998, 0.0), (-0.0599, 0.5970, 0.8)))
    mesh = merge_meshes([flat, tilted])
    mesh.update_rest_data(COTTON.density)
    return mesh, flat.n_nodes


def test_contour_length_gradient_matches_finite_differences():
    mesh, n_flat = crossed_sheets()
    x = mesh.node_x
    g = np.zeros_like(x)
    pairs, length, _ = find_intersections(mesh.face_nodes, x, g)
    assert len(pairs) > 0
    for d in range(3):
        e = np.zeros(3)
        e[d] = FD_STEP
        xp, xm = x.copy(), x.copy()
        xp[n_flat:] += e
        xm[n_flat:] -= e
        fd = ((find_intersections(mesh.face_nodes, xp)[1].sum() - find_intersections(mesh.face_nodes, xm)[1].sum())
              / (2 * FD_STEP))
        analytic = g[n_flat:, d].sum()
        assert abs(fd - analytic) <= FD_REL_TOL * max(1.0, abs(fd)), (d, fd, analytic)


def bump_through_sheet(n=8, depth=0.03):
    """A small sheet above a larger one with a bump pushed down through it (closed contours)."""
    flat = grid_mesh(0.4, 0.4, n, n, origin=(-0.2, -0.2, 0.0))
    b = grid_mesh(0.2, 0.2, n + 1, n + 1, origin=(-0.1037, -0.0913, 0.01))
    c = b.node_x[:, :2] - b.node_x[:, :2].mean(axis=0)
    b.node_x[:, 2] -= (0.01 + depth) * np.exp(-np.sum(c ** 2, axis=1) / (2 * 0.04 ** 2))
    mesh = merge_meshes([flat, b])
    mesh.update_rest_data(COTTON.density)
    return mesh, flat.n_nodes


def test_untangle_removes_closed_crossings():
    mesh, n_flat = bump_through_sheet()
    x = mesh.node_x
    stats = untangle(mesh.face_nodes, x, mesh.node_m, mesh.node_pinned, THICKNESS, max_iterations=30)
    assert stats["intersections_found"] > 0 and stats["untangle_iterations"] >= 1
    assert stats["intersections_left"] == 0 and len(find_intersections(mesh.face_nodes, x)[0]) == 0
    assert np.all(np.isfinite(x))
    assert np.all(np.abs(x[:, 2]) < 0.1)  # moves bounded by the crossing depth, no blow-up


def test_open_contour_is_reported_not_hidden():
    """A hem through a sheet along its whole width: the known limit of contour minimisation."""
    mesh, _ = crossed_sheets()
    x = mesh.node_x
    stats = untangle(mesh.face_nodes, x, mesh.node_m, mesh.node_pinned, THICKNESS, max_iterations=10)
    assert stats["intersections_left"] == len(find_intersections(mesh.face_nodes, x)[0]) > 0
    assert np.all(np.isfinite(x)) and np.all(np.abs(x[:, 2]) < 0.2)


def test_untangle_reports_what_it_cannot_fix():
    mesh, _ = crossed_sheets()
    mesh.node_pinned[:] = True
    x = mesh.node_x
    stats = untangle(mesh.face_nodes, x, mesh.node_m, mesh.node_pinned, THICKNESS, max_iterations=5)
    assert stats["intersections_left"] > 0
    assert stats["intersection_depth_m"] > 0 and stats["intersection_length_m"] > 0


# ------------------------------------------------------------------------------------------
FRAMES = 25  # the upper sheet lands on the lower one on the sphere within ~15 frames


def test_layered_sheets_stay_apart_and_without_the_effect_they_cross():
    sim = Simulation(layered_sheets(COTTON, resolution=8))
    for _ in range(FRAMES):
        rec = sim.advance_frame()
        assert count_crossings(sim.mesh) == 0, rec["frame"]
        assert rec["self_collisions_left"] == 0
    assert rec["self_proximity"] > 0  # the layers are in contact at the end
    effects = set(sim.scene.effects) - {"self_collision"}
    bare = Simulation(layered_sheets(COTTON, resolution=8, effects=tuple(effects)))
    assert bare.self_collision is None
    for _ in range(FRAMES):
        bare.advance_frame()
    assert count_crossings(bare.mesh) > 0


def test_scene_without_the_effect_never_calls_it(monkeypatch):
    import cloth.simulation as frame_loop

    def boom(*a, **k):
        raise AssertionError("self-collision ran in a scene that does not declare it")

    monkeypatch.setattr(frame_loop, "resolve_self_collisions", boom)
    monkeypatch.setattr(frame_loop, "untangle", boom)
    effects = ("membrane", "bending", "gravity", "damping", "obstacles")
    sim = Simulation(layered_sheets(COTTON, resolution=4, effects=effects))
    rec = sim.advance_frame()
    assert rec["self_ccd_hits"] == 0 and rec["time_collisions_s"] >= 0


@pytest.mark.slow
@pytest.mark.parametrize("mode,camera", [("adaptive", "none"), ("viewdep", "sheet_half")])
def test_layered_sheets_adaptive_modes_untangle_after_remesh(mode, camera):
    """In the adaptive modes the remesh moves the layers; untangling and CCD keep them apart."""
    sim = build_sim("scene=layered_sheets", f"mode={mode}", f"camera={camera}")
    for _ in range(FRAMES):
        rec = sim.advance_frame()
        assert rec["intersections_left"] == 0 and rec["self_collisions_left"] == 0, rec["frame"]
        assert count_crossings(sim.mesh) == 0, rec["frame"]
    assert rec["remeshed"] == 1


def test_untangle_moves_no_node_beyond_its_bound_and_keeps_the_best_state():
    """A tangle too deep to fix (the open hem through a sheet, at a thickness whose move bound
    is far below the crossing's depth): every node stays within MAX_MOVE_THICKNESSES thicknesses
    of where it was, and what is left is never more than what was found."""
    from cloth.collision.untangle import MAX_MOVE_THICKNESSES
    mesh, _ = crossed_sheets()
    x = mesh.node_x
    x0 = x.copy()
    thin = 1e-3  # m: bound 4 mm, much less than the sheets' crossing depth
    stats = untangle(mesh.face_nodes, x, mesh.node_m, mesh.node_pinned, thin, max_iterations=20)
    moved = np.linalg.norm(x - x0, axis=1)
    assert moved.max() <= MAX_MOVE_THICKNESSES * thin * (1 + 1e-9)
    assert 0 < stats["intersections_left"] <= stats["intersections_found"]
    assert stats["intersections_left"] == len(find_intersections(mesh.face_nodes, x)[0])


def test_collision_response_cannot_make_a_node_faster_than_the_guard():
    """The energy guard: after a step of two layers colliding, no node is faster than the fastest
    node before the response plus thickness / step (an inelastic response stays below that)."""
    sim = Simulation(layered_sheets(COTTON, resolution=8))
    for _ in range(12):  # the upper sheet lands on the lower one
        sim.advance_frame()
    h = sim.scene.dt
    mesh = sim.scene.mesh
    half = mesh.n_nodes // 2  # the two sheets: the first and the second half of the nodes
    upper = slice(0, half) if mesh.node_x[:half, 2].mean() > mesh.node_x[half:, 2].mean() else slice(half, None)
    mesh.node_v[upper] += np.array([0.0, 0.0, -3.0])  # slam the upper layer into the lower
    x_start = mesh.node_x.copy()
    mesh.node_x += h * mesh.node_v
    v_before = float(np.sqrt(np.max(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v))))
    stats = {k: 0 for k in ("self_velocity_clamped", "self_proximity", "self_ccd_hits", "self_ccd_passes",
                            "impact_zones", "impact_zone_rounds", "self_collisions_left")}
    sim.resolve_collisions(x_start, h, stats)
    v_after = float(np.sqrt(np.max(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v))))
    assert v_after <= v_before + sim.self_collision.thickness / h + 1e-9
    assert stats["self_ccd_hits"] + stats["self_proximity"] > 0  # the layers did collide


def test_remesh_motion_is_made_collision_free():
    """The push-out and pop filter after a remesh move nodes without looking at other layers;
    collision_free_motion treats that displacement like a step's motion: the upper sheet, moved
    down through the lower one, ends above it with no crossing, and velocities are untouched."""
    from types import SimpleNamespace

    from cloth.remeshing.adaptive import collision_free_motion
    mesh, n_lower = two_sheets()
    x_from = mesh.node_x.copy()
    upper = np.arange(n_lower, mesh.n_nodes)
    centre = x_from[upper, :2].mean(axis=0)
    bump = upper[np.linalg.norm(x_from[upper, :2] - centre, axis=1) < 0.07]  # the middle of the upper sheet
    mesh.node_x[bump, 2] -= 0.03
    assert len(find_intersections(mesh.face_nodes, mesh.node_x)[0]) > 0  # the motion alone crosses
    v = mesh.node_v.copy()
    hits = collision_free_motion(SimpleNamespace(mesh=mesh, self_collision=SelfCollisionParams(THICKNESS)), x_from)
    assert hits > 0
    assert len(find_intersections(mesh.face_nodes, mesh.node_x)[0]) == 0
    assert np.all(mesh.node_x[bump, 2] > mesh.node_x[:n_lower, 2].min())  # the bump stayed above
    assert np.array_equal(mesh.node_v, v)


# A flat sheet whose edges are 1.5 thicknesses long: a node lies closer than the thickness to
# faces two rings away, in the sheet's own plane (as on ARCSim's sphere.json at its sizes: 7.8 mm
# edges, 5 mm thickness). An irregular (jittered) grid puts some of them well inside it.
FINE_EDGE_THICKNESSES = 1.5
JITTER = 0.3  # of an edge, in the sheet's plane
FOLD_GAP = 0.4 * THICKNESS  # m between two such sheets lying on each other
# the two Gauss-Seidel passes leave a flat fold at the thickness to round-off (measured: 1.000);
# 1 % leaves room for the normals the first pass tilts
FOLD_SEPARATION_TOL = 0.01


def _fine_flat_sheet(n=10):
    edge = FINE_EDGE_THICKNESSES * THICKNESS
    mesh = grid_mesh(n * edge, n * edge, n, n)
    rng = np.random.default_rng(3)
    inner = (mesh.node_x[:, 0] > 1e-9) & (mesh.node_x[:, 0] < n * edge - 1e-9) & \
            (mesh.node_x[:, 1] > 1e-9) & (mesh.node_x[:, 1] < n * edge - 1e-9)
    mesh.node_x[inner, :2] += JITTER * edge * rng.uniform(-1, 1, (int(inner.sum()), 2))
    mesh.update_rest_data(COTTON.density)
    return mesh


def test_proximity_acts_across_the_sheet_not_along_it():
    """No pair of a flat sheet is pushed apart in the sheet's plane, however fine its mesh:
    in-plane pushes stretched fine meshes by their pins (response.INTERIOR_TOLERANCE)."""
    mesh = _fine_flat_sheet()
    x0 = mesh.node_x.copy()
    # nodes closer than the thickness to faces they are not a corner of do exist, in the plane
    close = sum(1 for f in range(mesh.n_faces) for i in range(mesh.n_nodes)
                if i not in mesh.face_nodes[f]
                and point_triangle_closest(x0[i], *x0[mesh.face_nodes[f]])[0] < THICKNESS)
    assert close > 0
    x1 = x0.copy()
    stats = resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x1, mesh.node_m,
                                    mesh.node_pinned, SelfCollisionParams(thickness=THICKNESS))
    assert stats["self_proximity"] == 0
    assert np.array_equal(x1, x0)


def test_a_fold_of_a_fine_sheet_is_still_pushed_across_to_the_thickness():
    """The same fine sheet with a second one lying on it closer than the thickness: the pairs
    across the gap are found, and every node of the upper sheet ends the thickness away from
    the lower one (before the rule it did not: 0.91 of it)."""
    lower = _fine_flat_sheet()
    upper = _fine_flat_sheet()
    upper.node_x[:, 2] += FOLD_GAP
    upper.node_x[:, :2] += 0.37 * FINE_EDGE_THICKNESSES * THICKNESS  # nodes over face interiors
    both = merge_meshes([lower, upper])
    both.update_rest_data(COTTON.density)
    x0 = both.node_x.copy()
    x1 = x0.copy()
    stats = resolve_self_collisions(both.face_nodes, both.face_edges, both.edge_nodes, x0, x1, both.node_m,
                                    both.node_pinned, SelfCollisionParams(thickness=THICKNESS, friction=0.0))
    assert stats["self_proximity"] > 0 and stats["self_collisions_left"] == 0
    n = lower.n_nodes
    gaps = [min(point_triangle_closest(x1[n + i], *x1[lower.face_nodes[f]])[0] for f in range(lower.n_faces))
            for i in range(upper.n_nodes)]
    assert min(gaps) >= (1.0 - FOLD_SEPARATION_TOL) * THICKNESS


def test_cloth_layers_keep_their_own_thickness_and_obstacles_theirs():
    """self_thickness (ARCSim's projection thickness between cloth layers) applies to cloth-cloth
    pairs only: the fold above ends self_thickness apart, not the obstacle thickness."""
    lower = _fine_flat_sheet()
    upper = _fine_flat_sheet()
    upper.node_x[:, 2] += 0.2 * THICKNESS
    upper.node_x[:, :2] += 0.37 * FINE_EDGE_THICKNESSES * THICKNESS
    both = merge_meshes([lower, upper])
    both.update_rest_data(COTTON.density)
    x0 = both.node_x.copy()
    thin = 0.5 * THICKNESS
    x1 = x0.copy()
    params = SelfCollisionParams(thickness=THICKNESS, self_thickness=thin, friction=0.0)
    resolve_self_collisions(both.face_nodes, both.face_edges, both.edge_nodes, x0, x1, both.node_m,
                            both.node_pinned, params)
    n = lower.n_nodes
    gaps = np.array([min(point_triangle_closest(x1[n + i], *x1[lower.face_nodes[f]])[0]
                         for f in range(lower.n_faces)) for i in range(upper.n_nodes)])
    assert gaps.min() >= (1.0 - FOLD_SEPARATION_TOL) * thin
    assert np.median(gaps) < 0.75 * THICKNESS  # not pushed to the obstacle thickness
    with pytest.raises(ValueError, match="self_thickness"):
        SelfCollisionParams(thickness=THICKNESS, self_thickness=0.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_zone_rounds_on_moved_pairs_give_the_hits_of_every_pair(monkeypatch, seed):
    """An impact-zone round after the first tests only the pairs with a node the previous round
    moved or hit (ZONE_ROUNDS_MOVED_ONLY): positions and record are bitwise those of testing every
    pair in every round, on two sheets pushed through each other with one CCD pass and jitter of
    four thicknesses (3-8 rounds)."""
    import cloth.collision.selfcollision as sc
    mesh, n_lower = two_sheets(n=10, gap=0.6 * THICKNESS)
    rng = np.random.default_rng(seed)
    x0 = mesh.node_x.copy()
    x1 = x0 + rng.normal(scale=4.0 * THICKNESS, size=x0.shape)
    upper = np.arange(n_lower, mesh.n_nodes)
    bump = upper[np.linalg.norm(x0[upper, :2] - x0[upper, :2].mean(axis=0), axis=1) < 0.08]
    x1[bump, 2] -= 0.02
    params = SelfCollisionParams(THICKNESS, ccd_passes=1)
    runs = []
    for moved_only in (True, False):
        monkeypatch.setattr(sc, "ZONE_ROUNDS_MOVED_ONLY", moved_only)
        x = x1.copy()
        stats = resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x, mesh.node_m,
                                        mesh.node_pinned, params)
        runs.append((x, stats))
    assert runs[0][1]["impact_zone_rounds"] >= 3  # rounds after the first, where the filter acts
    assert np.array_equal(runs[0][0], runs[1][0])
    assert runs[0][1] == runs[1][1]


def _edge_pair_hits(x0, x1, eta):
    """ccd_pass on one edge-edge pair (edges 0-1 and 2-3), without response: its hit count."""
    edge_nodes = np.array([[0, 1], [2, 3]], dtype=np.int64)
    face_nodes = np.zeros((0, 3), dtype=np.int64)
    hits = np.empty((1, 4), dtype=np.int64)
    return ccd_pass(np.zeros((0, 2), dtype=np.int64), np.array([[0, 1]], dtype=np.int64), face_nodes, edge_nodes,
                    x0, x1, np.ones(4), eta, 0.0, False, hits, np.zeros(5, dtype=bool), np.zeros((0, 7)))


@pytest.mark.parametrize("gap_in_eta, motion, hit", [
    (0.4, "together", False),  # within eta at the start, moved rigidly: the step closes nothing
    (0.4, "apart", False),
    (0.4, "through", True),  # crossing passes through distance 0
    (0.4, "closer", True),  # from 0.4 eta to 0.1 eta: closed past START_TOUCH_FRACTION
    (0.0, "together", True),  # touching exactly at the start: still a hit
    (3.0, "closer", True),  # from 3 eta to 0.1 eta: an ordinary touch
])
def test_a_pair_touching_at_the_start_is_a_hit_only_if_the_step_closes_it(gap_in_eta, motion, hit):
    """Two crossed edges gap_in_eta * eta apart at x0 (the second above the first): a pair within eta
    at the start is a CCD hit only if the step brings it within START_TOUCH_FRACTION of its starting
    distance (a rigid impact zone holding it apart otherwise stays a hit in every round)."""
    from cloth.collision.response import START_TOUCH_FRACTION
    eta = 1e-5
    z = gap_in_eta * eta
    x0 = np.array([[-1.0, 0, 0], [1.0, 0, 0], [0, -1.0, z], [0, 1.0, z]]) * [0.01, 0.01, 1]
    x1 = x0 + [0.002, 0.001, 0.0]  # both edges carried alike
    if motion == "apart":
        x1[2:, 2] += 5 * eta
    elif motion == "through":
        x1[2:, 2] -= 5 * eta
    elif motion == "closer":
        x1[2:, 2] = 0.1 * eta
    assert START_TOUCH_FRACTION * 0.4 > 0.1  # "closer" closes past the fraction
    assert (_edge_pair_hits(x0, x1, eta) == 1) is hit
