"""Interpenetration recovery in the frame loop (paper section 3.4): after a remesh the adaptive
modes untangle crossings by contour minimisation, and a run whose untangling cannot finish goes
on from its best state and says in every frame's record what is left (it never aborts)."""

import numpy as np
import pytest
from helpers import build_sim, count_crossings

import cloth.simulation as simulation

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
