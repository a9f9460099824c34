"""Cloth against triangle-mesh obstacles within each step (proximity, CCD, impact zones): a spike
tip and a coarse sheet on a sphere that node-based contact lets through, impact zones on a
rotating obstacle, the CCD slab rejection, the skinned body in solo_dancer."""

import numpy as np
import pytest
from helpers import COTTON, after_every_step, build_sim, compose_config

from cloth.collision.ccd import point_triangle_closest
from cloth.collision.meshobstacle import (
    TriangleMeshObstacle,
    mesh_obstacles,
)
from cloth.collision.untangle import find_intersections
from cloth.core.mesh import grid_mesh
from cloth.scenes.bodies import icosphere
from cloth.scenes.registry import build_scene
from experiments.build import build_simulation

# Distances are sums and square roots of O(1) numbers.
ROUNDOFF = 1e-12

# A free node ends every step at the contact thickness (the projection's fixed point); half the
# thickness is margin for what the last projection pass leaves.
CONTACT_MARGIN = 0.5


# ---- cloth-obstacle collisions within the step (proximity, CCD, impact zones) ------------------
# The node-based contact sees only cloth nodes; an obstacle's tip or edge can pass through the
# inside of a cloth face. Crossings below are counted exactly (cloth.collision.untangle.find_intersections,
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
    after_every_step(sim, lambda sim: seen.append((sim.steps_taken, _cloth_obstacle_crossings(sim))))


SPIKE_RISE = 0.12  # m in one frame of 4 steps: 3 cm per step, six times the 5 mm thickness


def _spike_through_coarse_sheet():
    """A 2 x 2-cell sheet (0.3 m legs) pinned at its corners, without gravity, and the tip of a
    thin tetrahedron (3 cm across) 2 cm below the middle of one face; in the second frame the
    tetrahedron rises SPIKE_RISE (keyframes), then holds. No cloth node comes near it."""
    from cloth.collision.obstacles import Static
    from cloth.core.scene import Handle, Scene
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
    off.stages = off.stages.without("obstacle_ccd")  # node-based contact only, as before
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
    import cloth.simulation as sc
    import cloth.stages
    from cloth.scenes.registry import layered_sheets
    from cloth.simulation import Simulation

    calls = {"resolve": 0, "mesh_obstacles": 0}
    resolve, find = sc.resolve_collisions_with_obstacles, sc.mesh_obstacles

    def counting_resolve(*a, **k):
        calls["resolve"] += 1
        return resolve(*a, **k)

    def counting_find(*a, **k):
        calls["mesh_obstacles"] += 1
        return find(*a, **k)

    monkeypatch.setattr(sc, "resolve_collisions_with_obstacles", counting_resolve)
    monkeypatch.setattr(sc, "mesh_obstacles", counting_find)
    monkeypatch.setattr(cloth.stages, "mesh_obstacles", counting_find)  # the stage plan looks for them too
    for scene in (build_scene("hanging_sheet", COTTON, resolution=4),  # no obstacle
                  build_scene("sheet_on_sphere", COTTON, resolution=4),  # analytic obstacles
                  layered_sheets(COTTON, resolution=4)):  # analytic obstacles and self_collision
        sim = Simulation(scene)  # may look for mesh obstacles once, when it plans its stages
        assert sim.mesh_collision is None and not sim.stages.obstacle_ccd
        calls["mesh_obstacles"] = 0
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
    cfg = compose_config("scene=mesh_obstacle", "mode=nonadaptive", "scene.params.drop_height=0.56",
               "scene.scales.small.resolution=6", f"frames={frames}")
    runs = {}
    for on in (False, True):
        sim, _ = build_simulation(cfg)
        if not on:
            sim.stages = sim.stages.without("obstacle_ccd")
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
    middle within one step, one half sweeping down through the sheet. A zone holding obstacle
    nodes is separated by inelastic projection (cloth.collision.impactzones): the sheet's nodes
    are pushed down ahead of the plate, no farther than its sweep and the thickness, and no
    collision is left. (The plate's mean displacement, about zero here, would leave them.)"""
    from cloth.collision.candidates import candidate_pairs
    from cloth.collision.response import ccd_pass
    from cloth.collision.selfcollision import (
        CCD_ETA_FRACTION,
        SelfCollisionParams,
        resolve_collisions_with_obstacles,
    )

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
    moved = np.linalg.norm(x1 - x0, axis=1) > ROUNDOFF
    sweep = 0.1 * np.sin(a) - 0.01  # m, how far below the sheet the plate's lower edge ends
    assert moved.any() and np.all(x1[moved, 2] < x0[moved, 2])
    assert np.linalg.norm(x1 - x0, axis=1).max() <= sweep + params.thickness
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
    assert ccd_pass(vf, ee, fn, en, X0, X1, inv_m, eta, 0.0, False, hits, np.zeros(len(X0) + 1, dtype=bool),
                    np.zeros((0, 7))) == 0


# The slab rejection before the CCD cubic must never reject a pair that touches: checked against
# the distance sampled at SLAB_SAMPLES times over the step (a touch shorter than 1 / SLAB_SAMPLES
# of the step could hide between samples, so random near misses are drawn, not grazes).
SLAB_SAMPLES = 401


def test_ccd_slab_rejection_is_exact_on_random_near_misses():
    from cloth.collision.ccd import ee_separated, segment_segment_closest, vf_separated

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


@pytest.mark.slow
def test_solo_dancer_with_the_skinned_mesh_body_stays_outside_it():
    # small and short: 32 segments around the waist, 8 frames of 0.08 s (16 steps of 5 ms, the
    # scene's step) so that the falling skirt reaches the hips and legs (from about frame 6)
    frames = 8
    sim = build_sim("scene=solo_dancer", "mode=nonadaptive", "scene.params.body=mesh",
                    "scene.params.frame_time=0.08", "scene.params.steps_per_frame=16",
                    "scene.scales.small.resolution=32", f"frames={frames}")
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
    from cloth.core.scene import Scene
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
