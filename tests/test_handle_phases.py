"""A handle's life (ARCSim's start_time, end_time, fade_time): waiting, pinned, fading, released.

cloth.core.scene.Handle moves between the phases at each step's start; the fading spring is
cloth.physics.forces.HandleSprings. Checked: the phases and the strength by hand, the spring's
force and stiffness against finite differences of its energy, a sheet whose corner is free before
the start, held where it was then, pulled by a fading spring and let go, in both a fixed and an
adaptive mesh, and a run resumed from a saved state mid-fade.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import COTTON, simulation_in_mode

from cloth.collision.obstacles import Linear, Static
from cloth.core.mesh import grid_mesh
from cloth.core.scene import Handle, Scene, SceneError
from cloth.io.states import load_state, save_state
from cloth.physics.assembly import SparsityPattern
from cloth.physics.forces import ForceAccumulator, HandleSprings
from cloth.simulation import Simulation

FRAME_TIME = 1 / 30  # s
ROUNDOFF_M = 1e-9  # m, positions after a few float operations
# Central differences of a quadratic energy are exact up to round-off of the energy's terms.
FD_REL = 1e-6
# A restart starts the iterative solver without its warm start, so the resumed positions agree with
# the uninterrupted run's to the solve's tolerance, not to round-off (a lost or misplaced spring
# moves the corner by millimetres in one frame).
RESTART_M = 1e-7
EFFECTS = frozenset({"membrane", "bending", "gravity", "damping"})


def _handle(**times) -> Handle:
    h = Handle(np.array([0]), Static(), **times)
    h.check("test")
    return h


def test_phases_and_strength_by_hand():
    h = _handle(start_time=0.1, end_time=0.3, fade_time=0.2)
    assert [h.phase(t) for t in (0.0, 0.0999, 0.1, 0.2999, 0.3, 0.4999, 0.5, 1.0)] == [
        "waiting", "waiting", "pinned", "pinned", "fading", "fading", "released", "released"]
    # ARCSim's strength: (1 - (t - end) / fade)^4, 1 at the end time, 0 at end + fade
    assert h.strength(0.3) == 1.0 and h.strength(0.5) == 0.0
    assert h.strength(0.4) == pytest.approx(0.5**4, rel=1e-12)
    assert h.strength(0.35) == pytest.approx(0.75**4, rel=1e-12)


@pytest.mark.parametrize("times", [dict(start_time=-1.0), dict(start_time=0.5, end_time=0.5),
                                   dict(end_time=1.0, fade_time=-0.1),
                                   dict(end_time=1.0, fade_time=0.5, stiffness=0.0)])
def test_inconsistent_times_are_named(times):
    mesh = grid_mesh(0.6, 0.6, 2, 2)
    with pytest.raises(SceneError, match="handle"):
        Scene("bad", mesh, COTTON, EFFECTS, frame_time=FRAME_TIME, steps_per_frame=1,
              handles=[Handle(np.array([0]), Static(), **times)])


def test_the_fading_spring_is_the_gradient_and_hessian_of_its_energy():
    rng = np.random.default_rng(4)
    mesh = grid_mesh(0.6, 0.6, 2, 2)
    h = Handle(np.array([1, 4]), Linear((0.3, -0.2, 0.1)), end_time=0.2, fade_time=0.4, stiffness=750.0)
    h.state = "fading"
    h.attach(mesh.node_x + 0.05 * rng.standard_normal(mesh.node_x.shape), 0.1)
    pattern = SparsityPattern(mesh.n_nodes, {})
    term = HandleSprings([h])
    term.rebuild(mesh, pattern)
    t = 0.33
    x0 = mesh.node_x + 0.02 * rng.standard_normal(mesh.node_x.shape)

    def evaluate(x):
        mesh.node_x[:] = x
        acc = ForceAccumulator.zeros(mesh.n_nodes, pattern)
        term.accumulate(mesh, t, acc)
        return acc

    acc = evaluate(x0)
    k = 750.0 * h.strength(t)
    assert acc.energy["handle_springs"] == pytest.approx(
        0.5 * k * np.sum((h.targets(t) - x0[h.nodes]) ** 2), rel=1e-12)
    K = pattern.to_scipy(acc.K).toarray()
    eps = 1e-6
    for n in (1, 4, 2):  # the handle's nodes and one it does not hold
        for d in range(3):
            xp, xm = x0.copy(), x0.copy()
            xp[n, d] += eps
            xm[n, d] -= eps
            ap, am = evaluate(xp), evaluate(xm)
            de = (ap.energy["handle_springs"] - am.energy["handle_springs"]) / (2 * eps)
            assert acc.force[n, d] == pytest.approx(-de, rel=FD_REL, abs=1e-9)
            df = (ap.force - am.force).ravel() / (2 * eps)
            assert np.allclose(K[:, 3 * n + d], -df, rtol=FD_REL, atol=1e-6)
    # outside its fading phase the spring is not there
    h.state = "pinned"
    assert not evaluate(x0).force.any()


@pytest.mark.parametrize("mode", ["nonadaptive", "adaptive"])
def test_a_corner_is_free_before_the_start_held_where_it_was_then_faded_and_let_go(mode):
    """A sheet hanging by one corner (pinned from t = 0); the other corner's handle starts at
    0.1 s (3 frames), ends at 0.2 s and fades over 0.1 s. Before its start that corner falls;
    from it to the end it stays where it was at the start; in the fade it is free but pulled
    back (it ends nearer to its target than a corner with no spring would be); then released."""
    mesh = grid_mesh(0.6, 0.6, 6, 6, origin=(0, 0, 1.0))
    held, late = np.array([0]), np.array([6])
    handles = [Handle(held, Static()),
               Handle(late, Static(), start_time=0.1, end_time=0.2, fade_time=0.1, stiffness=50.0)]
    scene = Scene("late", mesh, COTTON, EFFECTS, frame_time=FRAME_TIME, steps_per_frame=3, handles=handles)
    x_rest = mesh.node_x[late[0]].copy()
    sim = simulation_in_mode(scene, mode)
    h = sim.scene.handles[1]
    assert h.state == "waiting" and not sim.mesh.node_pinned[h.nodes].any()
    for _ in range(3):
        sim.advance_frame()
    assert h.nodes.size == 1 and not sim.mesh.node_pinned[h.nodes].any()
    x_start = sim.mesh.node_x[h.nodes[0]].copy()
    assert x_start[2] < x_rest[2] - 1e-3  # it fell while waiting
    for _ in range(3):  # frames 4-6: the first step of frame 4 starts at 0.1 s and takes hold
        sim.advance_frame()
        assert h.state == "pinned" and sim.mesh.node_pinned[h.nodes].all()
        assert np.abs(sim.mesh.node_x[h.nodes[0]] - x_start).max() < ROUNDOFF_M
    sim.advance_frame()  # 0.2-0.233 s: fading
    assert h.state == "fading" and not sim.mesh.node_pinned[h.nodes].any()
    assert "handle_springs" in sim.stages.forces
    for _ in range(3):
        sim.advance_frame()
    assert h.state == "released" and h.nodes.size == 0
    assert sim.mesh.node_pinned.sum() == sim.scene.handles[0].nodes.size


def test_a_run_resumed_mid_fade_continues_as_the_uninterrupted_one(tmp_path):
    def scene():
        mesh = grid_mesh(0.6, 0.6, 5, 5, origin=(0, 0, 1.0))
        return Scene("fade", mesh, COTTON, EFFECTS, frame_time=FRAME_TIME, steps_per_frame=2,
                     handles=[Handle(np.array([0]), Static()),
                              Handle(np.array([5]), Linear((0.0, 0.0, 0.3)), start_time=0.05,
                                     end_time=0.1, fade_time=0.2, stiffness=80.0)])

    whole = Simulation(scene())
    for _ in range(5):
        whole.advance_frame()
        if whole.frame == 4:  # 0.133 s: fading
            path = save_state(tmp_path / "state.npz", whole.mesh, whole.frame, whole.time,
                              handles=whole.scene.handles, restart=True)
    resumed = Simulation(scene())
    resumed.restart_from(load_state(path))
    assert [h.state for h in resumed.scene.handles] == ["pinned", "fading"]
    resumed.advance_frame()
    assert np.abs(resumed.mesh.node_x - whole.mesh.node_x).max() < RESTART_M
