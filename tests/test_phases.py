"""Where Table 1's time goes (paper_figures.phases), on made-up runs with known phase times."""

from __future__ import annotations

import pytest
from helpers import write_run

from experiments.analysis.runs import load_runs
from paper_figures.phases import phase_table

RATIO_TOL = 1e-12  # ratios of binary fractions: rounding only


def _run(root, name, mode, faces, physics, collisions, seed=0):
    n = 4
    extra = {"steps": [8] * n, "time_sizing_s": [0.0] * n, "time_remesh_s": [0.0] * n,
             "time_physics_s": [physics] * n, "time_solve_s": [0.0] * n, "time_collisions_s": [collisions] * n,
             "time_collisions_pass_s": [collisions] * n}
    write_run(root / name, "karate", mode, [faces] * n, [faces // 2] * n, [physics + collisions] * n,
              variant=mode, extra_frames=extra, seed=seed)


def test_phases_per_face_and_against_adaptive(tmp_path):
    _run(tmp_path, "a0", "adaptive", 2048, 0.5, 0.5)
    _run(tmp_path, "v0", "viewdep", 1024, 0.25, 0.5)  # half the faces: physics halves, collisions do not
    _run(tmp_path, "v1", "viewdep", 1024, 0.25, 0.25, seed=1)
    table = phase_table(load_runs([tmp_path])).set_index("variant")
    v = table.loc["viewdep"]
    assert v["seeds"] == 2 and v["faces_vs_adaptive"] == 2.0
    assert v["physics_vs_adaptive"] == 2.0 and v["collisions_s"] == 0.375  # median of 0.5 and 0.25
    assert v["collisions_vs_adaptive"] == pytest.approx(0.5 / 0.375, rel=RATIO_TOL)
    assert v["physics_us_per_face_step"] == pytest.approx(1e6 * 0.25 / (1024 * 8), rel=RATIO_TOL)
    assert v["collisions_pass_share"] == pytest.approx(0.375 / 0.625, rel=RATIO_TOL)
    assert table.loc["adaptive", "sim_vs_adaptive"] == 1.0
