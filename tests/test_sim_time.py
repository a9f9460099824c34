"""Simulation time per frame (`sim_s`, the paper's Time/Frame): the sum of the simulation phases,
I/O outside it; Table 1 and the figures read it, and runs recorded before the column get it
from their phase columns."""

import numpy as np
import pandas as pd
import pytest
from helpers import COTTON

import cloth.runner
from cloth.core.records import PHASES, SIM_PHASES
from cloth.runner import JOURNAL_FILE, read_journal, run
from cloth.scenes.registry import build_scene
from cloth.simulation import Simulation
from experiments.analysis.aggregate import with_sim_seconds


def test_sim_s_is_the_sum_of_the_simulation_phases_and_io_is_outside(tmp_path):
    assert set(SIM_PHASES) == set(PHASES) - {"io", "other"}
    sim = Simulation(build_scene("sheet_on_sphere", COTTON, resolution=6))
    run(sim, 3, tmp_path, states_every=1, obj_every=1)  # I/O in every frame
    frames = pd.read_parquet(tmp_path / "frames.parquet")
    phases = frames[[f"time_{p}_s" for p in SIM_PHASES]].to_numpy()
    # the same additions in the same order: equal to the last bit
    assert np.array_equal(frames["sim_s"].to_numpy(), [sum(row) for row in phases.tolist()])
    assert (frames["time_io_s"] > 0).all()
    assert (frames["wall_s"] >= frames["sim_s"] + frames["time_io_s"]).all()


# The parts of the collisions phase are timed by the same clock reads as the phase, added in
# another order: equal to round-off of a sum of a few dozen terms of milliseconds (s).
PARTS_ROUNDOFF_S = 1e-12


def test_the_collision_phase_is_the_sum_of_its_parts(tmp_path):
    """time_collisions_s = contacts + projection + pass + untangle, per frame, in a scene that has
    all four (layered sheets with self-collision on a sphere); the summary totals each part."""
    import json

    from helpers import build_sim

    from cloth.core.records import COLLISION_PARTS

    sim = build_sim("scene=layered_sheets", "mode=adaptive")
    summary = run(sim, 3, tmp_path)
    frames = pd.read_parquet(tmp_path / "frames.parquet")
    parts = frames[[f"time_collisions_{p}_s" for p in COLLISION_PARTS]]
    assert (parts >= 0).all().all()
    assert np.allclose(parts.sum(axis=1), frames["time_collisions_s"], rtol=0, atol=PARTS_ROUNDOFF_S)
    for p in ("contacts", "projection", "pass"):  # every step of this scene runs them
        assert (frames[f"time_collisions_{p}_s"] > 0).all(), p
    assert frames["time_collisions_untangle_s"].iloc[0] > 0  # the start state is checked
    totals = json.loads((tmp_path / "summary.json").read_text())
    assert totals["time_collisions_pass_total_s"] == summary["time_collisions_pass_total_s"]
    for p in COLLISION_PARTS:
        assert totals[f"time_collisions_{p}_total_s"] == pytest.approx(frames[f"time_collisions_{p}_s"].sum())


def test_runs_recorded_before_sim_s_get_it_from_their_phase_columns():
    old = pd.DataFrame({f"time_{p}_s": [0.25 * (i + 1), 0.5] for i, p in enumerate(PHASES)})
    got = with_sim_seconds(old)["sim_s"].to_numpy()
    assert np.array_equal(got, [0.25 * (1 + 2 + 3 + 4 + 5), 0.5 * 5])  # binary-exact sums: io and other left out
    recorded = old.assign(sim_s=[1.0, 2.0])
    assert with_sim_seconds(recorded) is recorded
    assert "sim_s" not in with_sim_seconds(old.drop(columns="time_solve_s")).columns  # named missing by the loader


def test_each_frame_is_journalled_at_a_constant_cost_and_the_parquet_written_once(tmp_path, monkeypatch):
    """Before every frame the journal holds every finished frame (what a kill would leave); the
    whole frames.parquet is written once, at the end, and the journal is then removed."""
    parquet_writes = []
    write = cloth.runner.write_parquet_atomic
    monkeypatch.setattr(cloth.runner, "write_parquet_atomic", lambda *a: (parquet_writes.append(a[0]), write(*a)))
    sim = Simulation(build_scene("hanging_sheet", COTTON, resolution=4))
    advance, seen = sim.advance_frame, []

    def advance_frame():
        seen.append(len(read_journal(tmp_path / JOURNAL_FILE)))
        return advance()

    sim.advance_frame = advance_frame
    run(sim, 5, tmp_path)
    assert seen == [0, 1, 2, 3, 4]
    assert parquet_writes == [tmp_path / "frames.parquet"]
    assert not (tmp_path / JOURNAL_FILE).exists() and len(pd.read_parquet(tmp_path / "frames.parquet")) == 5


def test_a_journal_cut_mid_line_keeps_the_frames_before_it(tmp_path):
    path = tmp_path / JOURNAL_FILE
    path.write_text('{"frame": 1, "sim_s": 0.5}\n{"frame": 2, "sim_s": NaN}\n{"frame": 3, "si')
    kept = read_journal(path)
    assert kept["frame"].tolist() == [1, 2] and np.isnan(kept["sim_s"].iloc[1])
