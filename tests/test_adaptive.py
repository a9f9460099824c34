"""mode=adaptive in the frame loop: initial remesh, rebuilds only after a remesh, refinement where
the cloth folds, the pop filter, and long runs that stay finite and outside the obstacles."""

import copy

import numpy as np
import pytest
from helpers import build_sim, count_crossings, material_edge_lengths

from cloth.simulation import Simulation

ADAPTIVE = "mode=adaptive"
# Contact leaves nodes at the thickness (5 mm) above a surface, up to the projection's round-off.
CONTACT_SLACK = 1e-9
# A draped sheet at rest has kinetic energy ~1e-5 J (contact jitter); a remesh with its pop filter
# may add little more than that within the next frame. Without the filter the remesh spike of
# internal energy (~0.1 J here) would turn into kinetic energy.
POP_KE_BOUND_J = 2e-3
# The sheet comes to rest on the sphere (kinetic energy below this) by frame 30 to 55, by seed and
# round-off: its slide off the top is chaotic. The no-pop test waits for it, up to REST_FRAMES_MAX.
REST_KE_J = 5e-4
REST_FRAMES_MAX = 90
# The pop filter stops at |grad P| < 1e-3 of its first value, so two runs of it that take other
# Newton steps end at energies this close, not equal (measured: 1e-6 on a draped sheet).
POP_INEXACT_REL = 1e-4


def test_initial_remesh_refines_a_coarse_input_to_its_sizing():
    sim = build_sim(ADAPTIVE, "scene=hanging_sheet", "scene.scales.small.resolution=2",
                    "scene.scales.small.sizing.size_min=0.05")
    assert material_edge_lengths(sim.mesh).max() > 0.5  # 2 x 2 cells of a 1 m sheet
    sim.advance_frame()
    size_max = sim.remesher.sizing.size_max
    # a resting flat sheet asks for size_max everywhere: every edge at most that long
    assert material_edge_lengths(sim.mesh).max() <= size_max * (1 + 1e-9)
    assert sim.mesh.n_faces > 8


@pytest.mark.slow
def test_nonadaptive_never_remeshes_and_adaptive_rebuilds_only_after_a_remesh(monkeypatch):
    calls = {"n": 0}
    original = Simulation.rebuild

    def counting(self):
        calls["n"] += 1
        original(self)

    monkeypatch.setattr(Simulation, "rebuild", counting)
    sim = build_sim("scene=flag", "mode=nonadaptive")
    assert sim.remesher is None
    calls["n"] = 0
    faces = sim.mesh.n_faces
    for _ in range(3):
        rec = sim.advance_frame()
        assert rec["remeshed"] == 0 and rec["faces"] == faces
    assert calls["n"] == 0
    sim = build_sim(ADAPTIVE, "scene=flag", "mode.every=2")
    calls["n"] = 0
    changed = 0
    for _ in range(6):
        before = sim.mesh
        rec = sim.advance_frame()
        changed += sim.mesh is not before
        assert rec["remeshed"] == (1 if (sim.frame - 1) % 2 == 0 else 0)
    assert calls["n"] == changed and changed >= 1


SPHERE_RADIUS = 0.25  # m, conf/scene/sheet_on_sphere.yaml
FOLD_FRAME = 8  # the centre has folded over the sphere; the outer sheet still falls flat


@pytest.fixture(scope="module")
def draped_at_fold():
    """sheet_on_sphere in mode=adaptive at FOLD_FRAME, run once; tests get copies (`draped`)."""
    sim = build_sim(ADAPTIVE, "scene=sheet_on_sphere")
    while sim.frame < FOLD_FRAME:
        sim.advance_frame()
    return sim


@pytest.fixture
def draped(draped_at_fold):
    """A copy of draped_at_fold for one test to advance and change; it goes on bit-identically
    to the run it was copied from."""
    return copy.deepcopy(draped_at_fold)


def test_refinement_concentrates_where_the_cloth_folds(draped):
    sim = draped
    while sim.frame < FOLD_FRAME:
        sim.advance_frame()
    mesh = sim.mesh
    c = mesh.node_x[mesh.face_nodes].mean(axis=1)
    r = np.hypot(c[:, 0], c[:, 1])
    rim = (np.abs(r - SPHERE_RADIUS) < 0.05) & (c[:, 2] > 0.02)
    flat = (np.abs(mesh.world_face_normals()[:, 2]) > 0.95) & (r > SPHERE_RADIUS + 0.15)
    assert rim.sum() > 0 and flat.sum() > 0
    area = mesh.face_area
    density_rim = rim.sum() / area[rim].sum()
    density_flat = flat.sum() / area[flat].sum()
    assert density_rim > density_flat, (density_rim, density_flat)


@pytest.mark.slow
def test_remeshing_a_resting_draped_sheet_makes_no_pop(draped):
    sim = draped
    ke0 = sim.state_record()["kinetic_energy_j"]
    while (sim.frame < 30 or ke0 >= REST_KE_J) and sim.frame < REST_FRAMES_MAX:  # wait for it to rest
        sim.advance_frame()
        ke0 = sim.state_record()["kinetic_energy_j"]
    assert ke0 < REST_KE_J
    # a finer sizing forces many splits (and flips) under the draped cloth
    from dataclasses import replace
    sim.remesher.sizing = replace(sim.remesher.sizing, refine_angle=0.5 * sim.remesher.sizing.refine_angle)
    rec = sim.advance_frame()
    assert rec["remesh_splits"] > 20
    assert rec["pop_energy_after_j"] <= rec["pop_energy_before_j"] + 1e-12
    assert rec["kinetic_energy_j"] - ke0 < POP_KE_BOUND_J


@pytest.mark.parametrize("scene, overrides", [
    # the flag with coarse sizing keeps this short; sheet_on_sphere at its small preset is the case
    # that once diverged after ~125 frames (light corner nodes of coarse faces driven through the
    # ground by the solve; contact constraints in the solve fixed it, tests/test_contact_solve.py)
    ("flag", ["scene.scales.small.sizing.size_min=0.08", "scene.scales.small.resolution=12"]),
    ("sheet_on_sphere", []),
])
@pytest.mark.slow
def test_long_adaptive_runs_stay_finite_and_outside_obstacles(scene, overrides):
    sim = build_sim(ADAPTIVE, f"scene={scene}", *overrides)
    for _ in range(200):
        rec = sim.advance_frame()
        assert np.isfinite(rec["kinetic_energy_j"])
        if scene == "sheet_on_sphere":
            x = sim.mesh.node_x
            d = np.linalg.norm(x - [0, 0, 0.25], axis=1) - 0.25
            assert d.min() >= sim.scene.thickness - CONTACT_SLACK
            assert x[:, 2].min() >= sim.scene.thickness - CONTACT_SLACK
    assert sim.mesh.n_faces > 0


def _wavy_sheets(fine_below_x: float | None = None):
    """Two wavy 0.4 m sheets (16 x 16 cells) 1 mm apart; the upper one held (a handle: never
    collapsed). The sizing asks for 0.2 m edges (the lower sheet coarsens), or 1 cm where
    x < `fine_below_x` (it refines there). Returns (mesh, vert_M, data, handle)."""
    from cloth.core.mesh import grid_mesh, merge_meshes

    sheets = [grid_mesh(0.4, 0.4, 16, 16) for _ in range(2)]
    for m, dz in zip(sheets, (0.0, 0.001)):
        m.node_x[:, 2] = 0.005 * np.sin(2 * np.pi * m.node_x[:, 0] / 0.2) + dz
    mesh = merge_meshes(sheets)
    mesh.update_rest_data(0.12)
    vert_M = np.tile(np.eye(2) / 0.2 ** 2, (mesh.n_verts, 1, 1))
    if fine_below_x is not None:
        vert_M[mesh.vert_u[:, 0] < fine_below_x] = np.eye(2) / 0.01 ** 2
    data = np.hstack([mesh.node_x, mesh.node_v])
    handle = np.full(mesh.n_nodes, -1)
    handle[sheets[0].n_nodes:] = 0
    return mesh, vert_M, data, handle


def test_crossing_guard_redoes_a_remesh_that_makes_the_cloth_cross_itself():
    """The lower of two wavy sheets is coarsened. Its collapses cut the troughs' corners, through
    the upper sheet: the plain remesh crosses; the guard redoes it with the crossings' nodes
    frozen and leaves none, while the lower sheet still coarsens where that crosses nothing."""
    from cloth.remeshing.adaptive import AdaptiveRemesher
    from cloth.remeshing.remesh import remesh

    mesh, vert_M, data, handle = _wavy_sheets()
    assert count_crossings(mesh) == 0
    plain = remesh(mesh, vert_M, data, handle)
    assert count_crossings(plain.mesh) > 0
    stats = {}
    guarded = AdaptiveRemesher()._avoid_crossings(mesh, vert_M, data, handle, plain, stats)
    assert count_crossings(guarded.mesh) == 0
    assert stats["remesh_guard_rounds"] >= 1 and stats["remesh_frozen_nodes"] > 0
    assert guarded.collapses > 0 and guarded.mesh.n_faces < mesh.n_faces
    assert "remesh_guard_fallback" not in stats


def test_crossing_guard_falls_back_to_splits_alone_when_its_rounds_still_cross(monkeypatch):
    """With no redo round allowed, a remesh that crosses falls back to splits alone (every node
    frozen): the lower sheet refines where it is asked to (x < 0.1 m) and nothing collapses or
    flips, so nothing crosses."""
    import cloth.remeshing.adaptive as adaptive
    from cloth.remeshing.remesh import remesh

    mesh, vert_M, data, handle = _wavy_sheets(fine_below_x=0.1)
    plain = remesh(mesh, vert_M, data, handle)
    assert count_crossings(plain.mesh) > 0 and plain.splits > 0 and plain.collapses > 0
    monkeypatch.setattr(adaptive, "CROSSING_GUARD_ROUNDS", 0)
    stats = {}
    got = adaptive.AdaptiveRemesher()._avoid_crossings(mesh, vert_M, data, handle, plain, stats)
    assert stats["remesh_guard_fallback"] == 1
    assert count_crossings(got.mesh) == 0
    assert got.splits > 0 and got.collapses == 0 and got.flips == 0 and got.mesh.n_faces > mesh.n_faces


def test_crossing_guard_keeps_the_mesh_when_every_redo_makes_a_sliver(monkeypatch):
    """Frozen nodes block the flips that repair a split's thin faces; a redo whose worst face falls
    below the quality floor (aspect_min / 3, or the plain remesh's worst if lower) is dropped. When
    the splits-alone fallback makes a sliver too, the frame keeps the mesh it had (no remesh):
    neither a crossing for the untangling nor a sliver for the solver."""
    from types import SimpleNamespace

    import cloth.remeshing.adaptive as adaptive
    from cloth.remeshing.remesh import remesh

    mesh, vert_M, data, handle = _wavy_sheets()  # the crossing case above
    plain = remesh(mesh, vert_M, data, handle)
    floor = min(adaptive.RemeshParams().aspect_min / 3, plain.mesh.face_quality().min())
    redos = []

    def sliver_redo(*args, frozen=None, **kw):  # the redo, with its worst face just under the floor
        redos.append(frozen.sum())
        return SimpleNamespace(mesh=SimpleNamespace(face_quality=lambda: np.array([0.999 * floor])))

    monkeypatch.setattr(adaptive, "remesh", sliver_redo)
    stats = {}
    kept = adaptive.AdaptiveRemesher()._avoid_crossings(mesh, vert_M, data, handle, plain, stats)
    assert len(redos) == 2 and 0 < redos[0] < mesh.n_nodes and redos[1] == mesh.n_nodes
    assert kept.mesh is mesh and not kept.changed and count_crossings(kept.mesh) == 0
    assert stats["remesh_guard_refused"] == 1 and stats["remesh_guard_fallback"] == 2
    assert "remesh_guard_rounds" not in stats


# Energy left by the pop filter after refining coarse cloth draped on the sphere (J, seeds 0-5):
# one pop filter then one push-out 14.3, 15.7, 21.6, 18.4, 16.5, 9.1; alternated three times
# 9.3, 9.2, 14.1, 12.3, 11.5, 6.5. The largest Green strain is no measure of it: a few faces
# decide it, and it scatters from 2 to 46 with the seed for either.
ALTERNATION_GAIN = 0.8  # the alternation leaves at most this fraction of one round's energy
# Later rounds restricted to the faces near what the push-out moved (POP_PUSH_RINGS) leave the
# same energy as full rounds up to this relative difference (measured: below 0.5 %).
RESTRICTED_ROUNDS_REL = 0.01


def _refine_on_sphere(seed, monkeypatch, rounds, rings):
    from dataclasses import replace

    import cloth.remeshing.adaptive
    monkeypatch.setattr(cloth.remeshing.adaptive, "POP_PUSH_ROUNDS", rounds)
    monkeypatch.setattr(cloth.remeshing.adaptive, "POP_PUSH_RINGS", rings)
    sim = build_sim(ADAPTIVE, "scene=sheet_on_sphere", "scene.scales.small.sizing.size_min=0.4",
                    "mode.sizing.size_max=0.4", f"seed={seed}")
    while sim.frame < 25:  # 36 faces, draped
        sim.advance_frame()
    sim.remesher.sizing = replace(sim.remesher.sizing, size_min=0.04, size_max=0.2)
    return sim.advance_frame()


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_refining_coarse_cloth_on_the_sphere_alternates_pop_filter_and_push_out(seed, monkeypatch):
    """Refining 0.4 m faces draped on the 0.25 m sphere puts the new midpoints inside it by up to
    the chords' sagitta; pushed out, they stretch their small faces. Alternating the pop filter
    with the push-out (cloth.remeshing.adaptive.POP_PUSH_ROUNDS) relaxes more of that than one round of
    each, and restricting the later rounds to the pushed nodes' surroundings changes nothing."""
    one = _refine_on_sphere(seed, monkeypatch, 1, -1)
    assert one["remesh_nodes_pushed_out"] > 100 and one["remesh_max_depth_m"] > 0.05  # the case is hard
    assert one["remesh_nodes_passing"] == 0  # under the sphere's chords: pushed, none passes (PASSING_MIDDLE)
    full = _refine_on_sphere(seed, monkeypatch, 3, -1)
    restricted = _refine_on_sphere(seed, monkeypatch, 3, 2)
    assert full["pop_energy_after_j"] < ALTERNATION_GAIN * one["pop_energy_after_j"]
    assert restricted["pop_energy_after_j"] == pytest.approx(full["pop_energy_after_j"], rel=RESTRICTED_ROUNDS_REL)


def test_sizing_at_bounds_counts_the_clamped_faces_and_their_realised_edges():
    from cloth.core.mesh import grid_mesh
    from cloth.remeshing.sizing import clamp_sizing, sizing_at_bounds

    mesh = grid_mesh(0.4, 0.2, 4, 2)  # 16 faces, material edges 0.1 m (sides) and 0.1414 m (diagonals)
    size_min, size_max = 0.02, 0.2
    raw = np.zeros((mesh.n_faces, 2, 2))
    raw[:5] = np.diag([1 / 0.01**2, 1.0])          # finer than size_min one way: clamped to size_min
    raw[5:9] = np.diag([1 / 0.05**2, 1 / 0.05**2])  # inside the bounds
    raw[9:] = np.diag([1.0, 4.0])                   # coarser than size_max both ways: at size_max
    M = clamp_sizing(raw, size_min, size_max, aspect_min=0.2)
    got = sizing_at_bounds(mesh, M, size_min, size_max)
    assert got["faces_at_size_min"] == 5 and got["faces_at_size_max"] == 7 and got["faces_sized"] == 16
    sides = np.linalg.norm(mesh.vert_u[mesh.face_verts[:5]] - mesh.vert_u[np.roll(mesh.face_verts[:5], -1, 1)], axis=2)
    assert got["edge_at_size_min_m"] == pytest.approx(np.median(sides))  # 2 of every 3 sides are 0.1 m
    assert got["edge_at_size_min_m"] == pytest.approx(0.1)
    none = sizing_at_bounds(mesh, M[5:9].repeat(4, axis=0), size_min, size_max)
    assert none["faces_at_size_min"] == 0 and np.isnan(none["edge_at_size_min_m"])


def test_the_frame_record_counts_faces_at_the_sizing_bounds():
    sim = build_sim(ADAPTIVE, "scene=hanging_sheet", "scene.scales.small.resolution=2",
                    "scene.scales.small.sizing.size_min=0.05")
    rec = sim.advance_frame()
    # a resting flat sheet asks for size_max everywhere; the record counts the input mesh's faces
    assert rec["faces_at_size_max"] == 8 and rec["faces_at_size_min"] == 0 and rec["faces_sized"] == 8
    fixed = build_sim("scene=hanging_sheet", "scene.scales.small.resolution=2").advance_frame()
    assert fixed["faces_at_size_min"] == 0 and np.isnan(fixed["edge_at_size_min_m"])


def test_push_strain_is_the_largest_push_over_the_shortest_edge_at_its_node():
    from cloth.core.mesh import grid_mesh
    from cloth.remeshing.adaptive import push_strain

    mesh = grid_mesh(1.0, 0.5, 4, 4)  # cells 0.25 x 0.125 m: every node's shortest edge is 0.125 m
    mesh.update_rest_data(0.1)
    d = np.zeros((mesh.n_nodes, 3))
    moved = np.zeros(mesh.n_nodes, bool)
    assert push_strain(mesh, d, moved) == 0.0
    d[7] = (0.0, 0.0, 0.005)  # 5 mm
    d[12] = (0.001, 0.0, 0.0)
    moved[[7, 12]] = True
    assert push_strain(mesh, d, moved) == pytest.approx(0.005 / 0.125, rel=1e-12)


def _pop_filter_calls(monkeypatch, n: int) -> list:
    """The arguments (deep copies) of the first `n` pop filter calls of a sheet landing on the
    sphere in mode=adaptive."""
    import cloth.remeshing.adaptive as adaptive_mod
    import cloth.remeshing.popfilter as popfilter_mod

    calls = []

    def capture(mesh, terms, changed, target, params, solver):
        calls.append(copy.deepcopy((mesh, terms, changed, target, params, solver)))
        return popfilter_mod.pop_filter(mesh, terms, changed, target, params, solver)

    sim = build_sim(ADAPTIVE, "scene=sheet_on_sphere")
    monkeypatch.setattr(adaptive_mod, "pop_filter", capture)
    while len(calls) < n:
        sim.advance_frame()
    return calls


def test_the_pop_filter_s_inexact_newton_solves_end_where_exact_ones_do(monkeypatch):
    """The pop filter solves its Newton systems by PCG to NEWTON_SOLVE_TOLERANCE (1e-4): on the
    remeshes of a sheet landing on the sphere, it ends at the energy that near-exact solves reach."""
    import cloth.remeshing.popfilter as popfilter_mod

    for args in _pop_filter_calls(monkeypatch, 3):
        inexact = popfilter_mod.pop_filter(*copy.deepcopy(args))
        with monkeypatch.context() as m:
            m.setattr(popfilter_mod, "NEWTON_SOLVE_TOLERANCE", 1e-12)
            exact = popfilter_mod.pop_filter(*copy.deepcopy(args))
        assert exact["iterations"] > 0 and exact["energy_after_j"] < exact["energy_before_j"]
        assert inexact["energy_after_j"] == pytest.approx(exact["energy_after_j"], rel=POP_INEXACT_REL)


def test_the_pop_filter_never_throws_the_cloth_where_the_old_forces_are_huge(monkeypatch):
    """Old-mesh forces far beyond the cloth's (as where cloth was caught between body parts) put
    the filter's minimum metres away, past every node's edges: the filter then keeps the remesh's
    positions and says so; with the real forces it relaxes as before."""
    import cloth.remeshing.popfilter as popfilter_mod

    calls = _pop_filter_calls(monkeypatch, 1)
    mesh, terms, changed, target, params, solver = copy.deepcopy(calls[0])
    relaxed = popfilter_mod.pop_filter(mesh, terms, changed, target, params, solver)
    assert relaxed["reverted"] == 0 and relaxed["energy_after_j"] < relaxed["energy_before_j"]
    assert not np.array_equal(mesh.node_x, calls[0][0].node_x)  # it moved the nodes
    mesh, terms, changed, target, params, solver = copy.deepcopy(calls[0])
    x_remeshed = mesh.node_x.copy()
    thrown = target + OLD_FORCE_N * np.array([0.0, 0.0, 1.0])  # every node pulled up by the old mesh
    out = popfilter_mod.pop_filter(mesh, terms, changed, thrown, params, solver)
    assert out["reverted"] == 1 and out["energy_after_j"] == out["energy_before_j"]
    assert np.array_equal(mesh.node_x, x_remeshed)


OLD_FORCE_N = 1e4  # N per node: the order the karate skirt's stretched region carried into its pop filter


# A leg (a vertical capsule, 4 cm radius, 20 cm long) through the middle of one edge of a coarse
# sheet (0.3 m cells): the remesh's split of that edge puts a node on the leg's axis, 4 cm deep.
LEG_RADIUS = 0.04
LEG_AXIS = (0.15, 0.3)  # the midpoint of the edge from (0, 0.3) to (0.3, 0.3)
# the sheet falls past the leg's lower end (0.14 m below the node) in about 0.17 s
LEG_FRAMES = 6


def _sheet_through_a_leg():
    from helpers import COTTON, simulation_in_mode

    from cloth.collision.obstacles import Capsule
    from cloth.core.mesh import grid_mesh
    from cloth.core.scene import Scene

    mesh = grid_mesh(0.6, 0.6, 2, 2)
    mesh.update_rest_data(COTTON.density)
    leg = Capsule((*LEG_AXIS, -0.1), (*LEG_AXIS, 0.1), LEG_RADIUS)
    scene = Scene("leg", mesh, COTTON, {"membrane", "bending", "gravity", "obstacles"}, frame_time=0.04,
                  steps_per_frame=4, obstacles=[leg])
    return simulation_in_mode(scene, "adaptive")


def test_a_node_split_inside_a_thin_obstacle_passes_through_it_until_it_is_out():
    """A coarse face through a leg (contact holds nodes, not faces): the split node made inside
    it is not pushed to the nearest surface, which would hook the cloth around the leg, but
    passes (cloth.remeshing.adaptive.mark_passing): contact leaves it alone while it is inside and
    takes it back once it is out."""
    from helpers import after_every_step

    sim = _sheet_through_a_leg()
    seen = []

    def check(s):
        phi = s.obstacle_set.query(s.mesh.node_x)[0]
        free = ~s.mesh.node_pinned
        # every node inside the leg passes (none was pushed or held by contact), and a node passes
        # only while it was inside at the step's start
        assert np.all(s.node_passing[free & (phi < -CONTACT_SLACK)])
        seen.append(int(s.node_passing.sum()))

    after_every_step(sim, check)
    first = sim.advance_frame()
    assert first["remesh_nodes_passing"] == 1 and first["remesh_nodes_pushed_out"] == 0
    inside = sim.mesh.node_x[sim.node_passing][0]
    assert np.hypot(*(inside[:2] - LEG_AXIS)) == pytest.approx(0.0, abs=1e-9)  # left on the axis
    while sim.frame < LEG_FRAMES:
        sim.advance_frame()
    assert seen[0] == 1 and seen[-1] == 0  # released below the leg
    phi = sim.obstacle_set.query(sim.mesh.node_x)[0]
    assert phi.min() > 0.0


def test_without_passing_the_split_node_is_pushed_out_of_the_leg(monkeypatch):
    """The case above is one the exemption decides: with it off, the push-out moves the split
    node to the leg's surface."""
    import cloth.remeshing.adaptive

    monkeypatch.setattr(cloth.remeshing.adaptive, "PASSING_DEPTH", float("inf"))
    sim = _sheet_through_a_leg()
    first = sim.advance_frame()
    assert first["remesh_nodes_passing"] == 0 and first["remesh_nodes_pushed_out"] >= 1
    # from the axis to the contact thickness off the surface
    assert first["remesh_max_depth_m"] == pytest.approx(LEG_RADIUS + sim.scene.thickness, rel=1e-6)
