"""Interpenetration recovery in the frame loop (paper section 3.4): after a remesh the adaptive
modes untangle crossings by contour minimisation, every mode untangles a start state that
crosses (a fixed mesh around a body), and a run whose untangling cannot finish goes
on from its best state and says in every frame's record what is left (it never aborts)."""

import numpy as np
import pytest
from helpers import COTTON, build_sim, count_crossings

import cloth.simulation as simulation
from cloth.collision.meshobstacle import TriangleMeshObstacle, mesh_obstacle_triangles
from cloth.collision.untangle import find_intersections, obstacle_crossings
from cloth.remeshing.adaptive import keep_obstacles_uncrossed
from cloth.scenes.registry import build_scene

LAYERED = ("scene=layered_sheets", "output.rerun=false")
BUMP_DEPTH = 0.02  # m below the lower sheet: a closed crossing well within the untangling's move bound
BUMP_WIDTH = 0.05  # m, the bump's Gaussian radius (a few faces of the 12x12 sheets)
FRAMES = 4


def _push_a_bump_through(sim):
    """Push the middle of the upper sheet down through the lower one (closed intersection contours)."""
    x = sim.mesh.node_x
    upper = x[:, 2] > np.median(x[:, 2]) + 1e-3
    c = x[upper, :2] - x[upper, :2].mean(axis=0)
    gap = x[upper, 2].min() - x[~upper, 2].max()
    x[upper, 2] -= (gap + BUMP_DEPTH) * np.exp(-np.sum(c ** 2, axis=1) / (2 * BUMP_WIDTH ** 2))
    n = count_crossings(sim.mesh)
    assert n > 0
    return n


@pytest.mark.parametrize("mode, camera", [("adaptive", "none"), ("viewdep", "sheet_half")])
def test_the_frame_loop_untangles_after_a_remesh(monkeypatch, mode, camera):
    calls = []
    original = simulation.Simulation.untangle

    def spy(self, stats):
        calls.append(self.frame)
        return original(self, stats)

    monkeypatch.setattr(simulation.Simulation, "untangle", spy)
    sim = build_sim(*LAYERED, f"mode={mode}", f"camera={camera}")
    _push_a_bump_through(sim)
    rec = sim.advance_frame()
    assert calls == [0]  # the first frame's remesh was followed by the untangling
    assert rec["intersections_found"] > 0 and rec["intersections_left"] == 0
    assert count_crossings(sim.mesh) == 0


def test_a_run_whose_untangling_cannot_finish_goes_on_and_records_what_is_left(monkeypatch):
    monkeypatch.setattr(simulation, "UNTANGLE_ITERATIONS", 0)  # the untangling finds but never moves
    sim = build_sim(*LAYERED, "mode=adaptive")
    _push_a_bump_through(sim)
    rec = sim.advance_frame()
    assert rec["remeshed"] == 1 and rec["intersections_left"] > 0
    # from now on the remesh changes nothing: the untangling runs because crossings are left
    monkeypatch.setattr(sim.remesher, "remesh", lambda s, timings, stats: False)
    for _ in range(FRAMES - 1):
        rec = sim.advance_frame()  # no exception: crossings are counted, not fatal
        assert np.all(np.isfinite(sim.mesh.node_x))
        # every frame counts them again (also where the remesh changed nothing)
        assert rec["intersections_left"] > 0 and rec["intersection_length_m"] > 0, rec["frame"]
    assert sim.frame == FRAMES
    # once the bound allows it, the next frame's untangling removes what was left
    monkeypatch.setattr(simulation, "UNTANGLE_ITERATIONS", 30)
    rec = sim.advance_frame()
    assert rec["intersections_left"] == 0 and count_crossings(sim.mesh) == 0


# A sheet of 25 nodes (0.25 m apart) lowered onto the mesh_obstacle scene's icosphere (radius
# 0.25 m, top at z = 0.5 m) so that the sphere's cap pokes through the faces around its top
# while every node stays outside: the crossing a coarse fixed garment can start with around a body.
CAP_HEIGHT = 0.02  # m of the sphere above the sheet
SHEET_SHIFT = (0.1, 0.08)  # m: no node or edge right over the sphere's top


def test_a_fixed_mesh_run_untangles_a_start_state_that_crosses_a_mesh_obstacle(monkeypatch):
    scene = build_scene("mesh_obstacle", COTTON, resolution=4)
    (sphere,) = [o for o in scene.obstacles if isinstance(o, TriangleMeshObstacle)]
    x = scene.mesh.node_x
    x[:, :2] += SHEET_SHIFT
    x[:, 2] = sphere.positions[:, 2].max() - CAP_HEIGHT
    assert sphere.query(x)[0].min() > scene.thickness  # no node is inside or near the sphere

    def crossings():
        (ox, of), = mesh_obstacle_triangles([sphere])
        n = len(scene.mesh.face_nodes)
        pairs = find_intersections(np.vstack([scene.mesh.face_nodes, of + len(x)]),
                                   np.vstack([scene.mesh.node_x, ox]), n_fixed_faces=len(of))[0]
        return int(np.count_nonzero(pairs[:, 1] >= n)) if len(pairs) else 0

    assert crossings() > 0
    calls = []
    original = simulation.Simulation.untangle
    monkeypatch.setattr(simulation.Simulation, "untangle",
                        lambda self, stats: (calls.append(self.frame), original(self, stats)))
    sim = simulation.Simulation(scene)  # mode=nonadaptive: no remesher
    assert sim.stages.untangle and not sim.stages.remesh
    rec = sim.advance_frame()
    assert rec["intersections_found"] > 0 and rec["intersections_left"] == 0
    assert crossings() == 0
    for _ in range(2):
        sim.advance_frame()
        assert crossings() == 0
    assert calls == [0]  # the start state only: nothing was left for later frames


def test_a_step_whose_collision_pass_gave_up_is_followed_by_an_untangling(monkeypatch):
    """A fixed mesh untangles only its start state, unless a step's collision response leaves
    collisions. Step control first takes such a step again at half its length; a pass that gives
    up at every halving is accepted at the finest step, and the cloth is untangled right after it,
    before the frame's next step, so that the frame does not end crossing; the record counts it."""
    calls = []
    original = simulation.Simulation.untangle
    monkeypatch.setattr(simulation.Simulation, "untangle",
                        lambda self, stats: (calls.append((self.frame, self._substep)), original(self, stats)))
    real = simulation.resolve_self_collisions
    sim = build_sim(*LAYERED, "mode=nonadaptive")
    n, h = sim.scene.steps_per_frame, sim.scene.dt
    assert n > 2  # each untangling comes before a later step of the frame
    first_step_end = sim.scene.frame_time + h  # frame 1's first step: every pass within it gives up

    def response(*a, **k):
        s = real(*a, **k)
        if sim.frame == 1 and sim.time <= first_step_end * (1 + 1e-12):  # sim.time: the step's end
            s["self_collisions_left"] = 1  # as when the impact-zone rounds run out
        return s

    monkeypatch.setattr(simulation, "resolve_self_collisions", response)
    records = [sim.advance_frame() for _ in range(4)]
    finest = 2 ** simulation.MAX_STEP_HALVINGS  # steps of h / 16 that cover the first step
    # the start state, then after each of the finest steps, the k-th of them the k-th step taken
    assert calls == [(0, 0), *((1, k) for k in range(1, finest + 1))]
    assert [r["untangles"] for r in records] == [1, finest, 0, 0]
    # rejected: the step, its two halves, their four halves, ... down to the finest (accepted)
    assert records[1]["steps_rejected"] == records[1]["steps_rejected_collisions"] == finest - 1
    assert records[1]["steps"] == n - 1 + finest
    assert records[1]["dt_min_s"] == pytest.approx(h / finest, rel=1e-12)
    assert records[1]["self_collisions_left"] == 1 and records[2]["self_collisions_left"] == 0
    assert [r["steps_rejected"] for r in (records[0], records[2], records[3])] == [0, 0, 0]
    assert records[2]["dt_min_s"] == pytest.approx(h, rel=1e-12)
    assert sim.time == pytest.approx(4 * sim.scene.frame_time, rel=1e-12)


def test_a_remesh_move_that_carries_a_face_into_a_mesh_obstacle_is_put_back():
    """keep_obstacles_uncrossed: a move (the push-out's, the pop filter's) that makes a face of the
    moved node cross a triangle-mesh obstacle is undone (every moved node of the crossing faces); one
    that adds no crossing is kept."""
    scene = build_scene("mesh_obstacle", COTTON, resolution=4)
    (sphere,) = [o for o in scene.obstacles if isinstance(o, TriangleMeshObstacle)]
    x = scene.mesh.node_x
    x[:, :2] += SHEET_SHIFT
    x[:, 2] = sphere.positions[:, 2].max() + 2 * scene.thickness  # just above the sphere's top
    sim = simulation.Simulation(scene)
    (ox, of), = mesh_obstacle_triangles([sphere])
    x_from = x.copy()
    assert len(obstacle_crossings(sim.mesh.face_nodes, x, [(ox, of)])) == 0
    top = np.argmin(sphere.query(x)[0])  # the node nearest the sphere
    x[top, 2] -= 10 * scene.thickness  # carried through the cap: its faces cross the sphere
    kept = np.argmax(np.linalg.norm(x - x[top], axis=1))  # far from it: shares no face with it
    x[kept, 2] += scene.thickness  # moved away from the sphere: no crossing
    assert len(obstacle_crossings(sim.mesh.face_nodes, x, [(ox, of)])) > 0
    assert keep_obstacles_uncrossed(sim, x_from) == 1
    assert np.array_equal(x[top], x_from[top]) and x[kept, 2] > x_from[kept, 2]
    assert len(obstacle_crossings(sim.mesh.face_nodes, x, [(ox, of)])) == 0
    assert keep_obstacles_uncrossed(sim, x_from) == 0  # nothing crosses: nothing put back


# Two sheets 0.6 thicknesses apart on a floor FLOOR_BELOW thicknesses under the lower one; the
# middle of the upper sheet is moved BUMP_DOWN thicknesses down: through the lower sheet, not to
# the floor. The self-collision response alone then carries the lower sheet 1.17 thicknesses down
# (the two sheets' impact zone moves together), through the floor (measured: 12 crossings).
FLOOR_BELOW_THICKNESSES = 1.0
BUMP_DOWN_THICKNESSES = 1.4


def test_the_remesh_motion_response_does_not_carry_cloth_into_a_mesh_obstacle():
    """collision_free_motion with a triangle-mesh obstacle takes it into the same pass, standing still:
    the upper sheet pushed down through the lower one ends above it, and the response's own
    moves (the impact zone of both sheets) do not carry the lower sheet through the floor below it,
    which the self-collision pass alone does (ARCSim's dress-blue, seed 1, frame 337)."""
    from types import SimpleNamespace

    from helpers import two_sheets

    from cloth.collision.obstacles import ObstacleSet
    from cloth.collision.selfcollision import SelfCollisionParams, resolve_self_collisions
    from cloth.remeshing.adaptive import collision_free_motion
    thickness = 0.005
    mesh, n_lower = two_sheets(gap=0.6 * thickness)
    z = -FLOOR_BELOW_THICKNESSES * thickness
    floor = TriangleMeshObstacle(np.array([[-1, -1, z], [2, -1, z], [2, 2, z], [-1, 2, z]], dtype=float),
                                 np.array([[0, 1, 2], [0, 2, 3]]))
    x_from = mesh.node_x.copy()
    upper = np.arange(n_lower, mesh.n_nodes)
    bump = upper[np.linalg.norm(x_from[upper, :2] - x_from[upper, :2].mean(axis=0), axis=1) < 0.07]
    mesh.node_x[bump, 2] -= BUMP_DOWN_THICKNESSES * thickness  # through the lower sheet, not to the floor
    x_moved = mesh.node_x.copy()
    triangles = mesh_obstacle_triangles([floor])
    assert len(obstacle_crossings(mesh.face_nodes, x_moved, triangles)) == 0
    params = SelfCollisionParams(thickness)
    alone = x_moved.copy()  # the self-collision pass alone: what the remesh did before
    resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x_from, alone, mesh.node_m,
                            mesh.node_pinned, params)
    assert len(obstacle_crossings(mesh.face_nodes, alone, triangles)) > 0
    sim = SimpleNamespace(mesh=mesh, self_collision=params, mesh_collision=params, mesh_obstacles=[floor],
                          obstacle_set=ObstacleSet([floor]), time=0.0, node_passing=np.zeros(mesh.n_nodes, dtype=bool))
    collision_free_motion(sim, x_from)
    assert len(obstacle_crossings(mesh.face_nodes, mesh.node_x, triangles)) == 0
    assert len(find_intersections(mesh.face_nodes, mesh.node_x)[0]) == 0
    assert mesh.node_x[:, 2].min() > z
