"""Step control (issue 32): a step whose result fails a check is undone and taken again as two of
half its length, up to MAX_STEP_HALVINGS times in a row, and only then is the run declared
diverged. Each check is tested with a constructed step that explodes: one that explodes only at
its full length (the run goes on, the record says what was rejected), one that explodes at every
length (the run diverges with a message naming the check), and the restored state is exactly the
state before the step."""

import json

import numpy as np
import pandas as pd
import pytest
from helpers import build_sim

import cloth.simulation as simulation
from cloth.core.records import STEP_CHECKS
from cloth.runner import run
from cloth.simulation import KE_FLOOR_SPEED_M_S, KE_JUMP_FACTOR, MAX_STEP_HALVINGS, SimulationDiverged

SHEET = ("scene=hanging_sheet", "output.rerun=false")
BAD_FRAME = 2  # the frame (index before it is simulated) whose first step explodes
# The ways a constructed step explodes, by the check that must catch it.
KICKS = {
    "non_finite": lambda sim: sim.mesh.node_v.__setitem__((0, 0), np.nan),
    # one free node at twice the speed limit
    "speed": lambda sim: sim.mesh.node_v.__setitem__(_free(sim)[0], [2 * sim.max_speed, 0.0, 0.0]),
    # every free node at a speed whose energy is 4 x the jump bound over the floor, below max_speed
    "kinetic_energy": lambda sim: sim.mesh.node_v.__setitem__(
        _free(sim), [np.sqrt(4 * KE_JUMP_FACTOR) * KE_FLOOR_SPEED_M_S, 0.0, 0.0]),
}


def _free(sim):
    return np.flatnonzero(~sim.mesh.node_pinned)


def _exploding(monkeypatch, sim, kick, longer_than: float):
    """Make every step of frame BAD_FRAME's first step interval longer than `longer_than` (s)
    explode by `kick` at its end (after the implicit step, before the checks). Returns the list
    of (start time, length) of the steps taken in that interval."""
    taken = []
    original = simulation.Simulation._implicit_step
    first_end = BAD_FRAME * sim.scene.frame_time + sim.scene.frame_time / sim.scene.steps_per_frame

    def implicit_step(self, contacts, timings, stats):
        t0 = self.time
        original(self, contacts, timings, stats)
        if self.frame == BAD_FRAME and self.time <= first_end * (1 + 1e-12):
            taken.append((t0, self.dt))
            if self.dt > longer_than:
                kick(self)

    monkeypatch.setattr(simulation.Simulation, "_implicit_step", implicit_step)
    return taken


@pytest.mark.parametrize("check", sorted(KICKS))
def test_a_step_that_explodes_at_its_full_length_is_taken_again_as_two_halves(monkeypatch, tmp_path, check):
    sim = build_sim(*SHEET)
    h = sim.scene.frame_time / sim.scene.steps_per_frame
    taken = _exploding(monkeypatch, sim, KICKS[check], longer_than=0.75 * h)
    summary = run(sim, 4, tmp_path)
    assert summary["status"] == "completed"
    t_bad = BAD_FRAME * sim.scene.frame_time
    assert [t for t, _ in taken] == pytest.approx([t_bad, t_bad, t_bad + h / 2], rel=1e-12)
    assert [d for _, d in taken] == pytest.approx([h, h / 2, h / 2], rel=1e-12)
    frames = pd.read_parquet(tmp_path / "frames.parquet")
    bad = frames["frame"] == BAD_FRAME + 1
    assert list(frames["steps_rejected"]) == [1 if b else 0 for b in bad]
    assert int(frames.loc[bad, f"steps_rejected_{check}"].iloc[0]) == 1
    assert all(int(frames.loc[bad, f"steps_rejected_{c}"].iloc[0]) == 0 for c in STEP_CHECKS if c != check)
    assert frames.loc[bad, "dt_min_s"].iloc[0] == pytest.approx(h / 2, rel=1e-12)
    assert list(frames.loc[~bad, "dt_min_s"]) == pytest.approx([h] * int((~bad).sum()), rel=1e-12)
    assert int(frames.loc[bad, "steps"].iloc[0]) == sim.scene.steps_per_frame + 1
    assert np.isfinite(frames["max_speed_m_s"]).all() and frames["max_speed_m_s"].max() < 5.0
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["steps_rejected_total"] == 1 and on_disk[f"steps_rejected_{check}_total"] == 1
    assert on_disk["frames_with_rejected_steps"] == [BAD_FRAME + 1]
    assert on_disk["dt_min_s"] == pytest.approx(h / 2, rel=1e-12)
    assert any("taken again at half the length" in n for n in on_disk["notes"])
    assert sim.time == pytest.approx(4 * sim.scene.frame_time, rel=1e-12)  # frame times stay exact


@pytest.mark.parametrize("check,message", [("non_finite", "non-finite node positions"),
                                           ("speed", "exceeds max_speed"),
                                           ("kinetic_energy", "KE_JUMP_FACTOR")])
def test_a_step_that_explodes_at_every_length_ends_the_run_after_the_last_halving(monkeypatch, tmp_path,
                                                                                 check, message):
    sim = build_sim(*SHEET)
    h = sim.scene.frame_time / sim.scene.steps_per_frame
    taken = _exploding(monkeypatch, sim, KICKS[check], longer_than=0.0)
    with pytest.raises(SimulationDiverged, match=message) as info:
        run(sim, 4, tmp_path)
    assert f"frame {BAD_FRAME + 1}:" in str(info.value) and "MAX_STEP_HALVINGS" in str(info.value)
    # h, h/2, h/4, ... each the first half of the one before: all start at the frame's start
    assert [d for _, d in taken] == pytest.approx([h / 2 ** k for k in range(MAX_STEP_HALVINGS + 1)], rel=1e-12)
    frames = pd.read_parquet(tmp_path / "frames.parquet")
    assert list(frames["frame"]) == list(range(1, BAD_FRAME + 1))  # the frames before it are kept
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "diverged" and f"frame {BAD_FRAME + 1}" in summary["message"]
    # the diverged frame has no record; its rejections (one per length tried) are in the totals
    assert summary["steps_rejected_total"] == MAX_STEP_HALVINGS + 1
    assert summary[f"steps_rejected_{check}_total"] == MAX_STEP_HALVINGS + 1
    assert summary["frames_with_rejected_steps"] == [BAD_FRAME + 1]
    assert summary["dt_min_s"] == pytest.approx(h / 2 ** MAX_STEP_HALVINGS, rel=1e-12)
    assert any("taken again at half the length" in n for n in summary["notes"])


def _start_frame(sim):
    """Empty timings and counters, and the frame's step bookkeeping, as advance_frame sets them up."""
    timings = {p: 0.0 for p in simulation.PHASES}
    stats = {"solver_iterations": 0, "solver_iterations_max": 0, "solver_residual": 0.0, "solves_capped": 0,
             "contacts": 0, "dt_min_s": np.inf, **{k: 0 for k in simulation.STEP_RECORD if k != "dt_min_s"},
             **simulation.COLLISION_RECORD, **simulation.STRAIN_LIMIT_RECORD}
    sim._frame_dt, sim._substep, sim._ticks = sim.scene.frame_time / sim.scene.steps_per_frame, 0, 0
    return timings, stats


def test_a_rejected_step_restores_the_state_before_it(monkeypatch):
    """The state after an undone step is the state before it, bit for bit: taking the step again
    as two halves gives what two half steps from that state give without any rejection."""
    def two_halves(sim):
        for _ in range(BAD_FRAME):
            sim.advance_frame()
        timings, stats = _start_frame(sim)
        sim.last_dv = None  # the undone step leaves no warm start: compare with none
        sim._controlled_step(1, timings, stats)
        sim._controlled_step(1, timings, stats)
        return sim.mesh.node_x.copy(), sim.mesh.node_v.copy(), sim.time

    reference = two_halves(build_sim(*SHEET))
    sim = build_sim(*SHEET)
    _exploding(monkeypatch, sim, KICKS["speed"], longer_than=0.75 * sim.scene.frame_time / sim.scene.steps_per_frame)
    for _ in range(BAD_FRAME):
        sim.advance_frame()
    timings, stats = _start_frame(sim)
    sim._controlled_step(0, timings, stats)
    assert stats["steps_rejected"] == 1 and stats["dt_min_s"] == sim._frame_dt / 2
    np.testing.assert_array_equal(sim.mesh.node_x, reference[0])
    np.testing.assert_array_equal(sim.mesh.node_v, reference[1])
    assert sim.time == reference[2]


def test_the_kinetic_energy_check_lets_a_cloth_at_rest_start_to_fall_and_catches_a_jump():
    """The floor: a cloth at rest (kinetic energy 0, no elastic energy) may gain the energy of its
    mass at up to KE_FLOOR_SPEED_M_S x sqrt(KE_JUMP_FACTOR) in one step; more is a jump, and so is
    any tenfold rise above the floor; the elastic energy at the step's start counts in the budget
    (what a stretched cloth may release into motion)."""
    sim = build_sim(*SHEET)
    free = _free(sim)
    sim.mesh.node_v[:] = 0.0
    sim._step_gave_up = False
    sim.last_energy = {"membrane": 0.0, "bending": 0.0, "gravity": -3.0}  # gravity is no budget
    before = sim._free_kinetic_energy()
    mass = before[1]
    assert before[0] == 0.0 and mass > 0
    sim.mesh.node_v[free] = [0.0, 0.0, -0.9 * np.sqrt(KE_JUMP_FACTOR) * KE_FLOOR_SPEED_M_S]
    assert sim.step_failure(before) is None
    sim.mesh.node_v[free] = [0.0, 0.0, -1.1 * np.sqrt(KE_JUMP_FACTOR) * KE_FLOOR_SPEED_M_S]
    assert sim.step_failure(before) == "kinetic_energy"
    # the same speed from a stretched state: elastic energy of 0.5 M (1 m/s)^2 doubles the budget
    sim.last_energy = {"membrane": 0.3 * mass, "bending": 0.2 * mass}
    assert sim.step_failure(before) is None
    sim.last_energy = {}
    sim.mesh.node_v[free] = [0.0, 0.0, -3.0]  # moving at 3 m/s: energy 9 x the floor's
    moving = sim._free_kinetic_energy()
    sim.mesh.node_v[free] *= np.sqrt(KE_JUMP_FACTOR * 1.2)  # 1.2 x the bound: 10 x (9 + 1) x the floor
    assert sim.step_failure(moving) == "kinetic_energy"
    sim.mesh.node_v[free] = [0.0, 0.0, -3.0 * np.sqrt(KE_JUMP_FACTOR * 0.9)]
    assert sim.step_failure(moving) is None
