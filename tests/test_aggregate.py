"""Aggregation of run folders (experiments.aggregate) and the figure scripts (paper_figures).

Run folders are made by the tests (config.yaml, frames.parquet, summary.json, optional
manifest.json and accuracy files), so every expected value is computed by hand here; the paper's
per-frame records (../shared/paper-timings) must give the paper's Table 1.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import FRAME_TIME_S, write_run, write_study_runs

from experiments.analysis import aggregate, tables
from experiments.analysis.aggregate import RunFolderWarning, load_runs, table1

PAPER_TIMINGS = Path(__file__).resolve().parents[2] / "shared" / "paper-timings"
# The paper prints times and speed-ups to 0.01: a value computed from its records may differ from
# the printed one by half of that, plus float noise (136.475 s printed as 136.47).
PRINTED_TOL = 0.005 + 1e-9
EXACT_TOL = 1e-12  # hand-computed means of a few binary-exact numbers: float rounding only

# The paper's Table 1 (Koh, Narain, O'Brien 2015), transcribed independently of the code under test:
# faces min/max/mean, vertices min/max/mean, s/frame min/max/mean, speed-up.
PAPER = {
    ("karate", "nonadaptive"): (123790, 123790, 123790, 63889, 63889, 63889, 136.47, 288.01, 161.44, 0.49),
    ("karate", "adaptive"): (25785, 71142, 41973, 14135, 37199, 22358, 31.41, 184.39, 79.04, 1.0),
    ("karate", "viewdep"): (5223, 39139, 21501, 3142, 20770, 11670, 5.52, 83.29, 33.02, 2.39),
    ("solo_dancer", "nonadaptive"): (43710, 43710, 43710, 22736, 22736, 22736, 27.31, 58.09, 29.27, 0.54),
    ("solo_dancer", "adaptive"): (12030, 21763, 18041, 6593, 11535, 9659, 7.78, 22.00, 15.80, 1.0),
    ("solo_dancer", "viewdep"): (730, 15951, 9638, 560, 8599, 5314, 0.83, 13.81, 7.55, 2.09),
    ("multiple_dancers", "nonadaptive"): (437100, 437100, 437100, 227360, 227360, 227360, 273.13, 580.85, 292.73,
                                          0.47),
    ("multiple_dancers", "adaptive"): (119515, 184340, 161028, 65505, 98630, 86897, 79.97, 178.24, 136.99, 1.0),
    ("multiple_dancers", "viewdep"): (11216, 102945, 36339, 7619, 56285, 21228, 12.02, 82.54, 30.76, 4.45),
}
COLS = ("faces_min", "faces_max", "faces_mean", "verts_min", "verts_max", "verts_mean", "time_min_s", "time_max_s",
        "time_mean_s", "speedup")
CUTS_S = (0.2,)  # the anticipation runs' camera cut (s)


def row(t: pd.DataFrame, **key) -> pd.Series:
    sel = t
    for k, v in key.items():
        sel = sel[sel[k] == v]
    assert len(sel) == 1, f"{key}: {len(sel)} rows"
    return sel.iloc[0]


# ---- Table 1 by hand -----------------------------------------------------------------------------

def test_table1_of_synthetic_runs_is_the_hand_computed_table(tmp_path):
    root = tmp_path / "results"
    write_run(root / "toy_nonadaptive", "toy", "nonadaptive", [100, 100, 100], [60, 60, 60], [2.0, 3.0, 4.0])
    write_run(root / "toy_adaptive", "toy", "adaptive", [40, 50, 90], [25, 30, 50], [1.0, 2.0, 1.5])
    write_run(root / "toy_viewdep", "toy", "viewdep", [10, 30, 20], [8, 18, 13], [0.5, 0.25, 0.75],
              timestamp="2025-01-02T00:00:00+00:00")
    # an earlier run of the same scene, scale, mode and variant: superseded by the later one
    write_run(root / "toy_viewdep_old", "toy", "viewdep", [1, 1, 1], [1, 1, 1], [9.0, 9.0, 9.0],
              timestamp="2025-01-01T00:00:00+00:00")
    # another scene: its speed-up is against its own adaptive run
    write_run(root / "other_adaptive", "other", "adaptive", [7, 9], [5, 6], [4.0, 4.0])
    write_run(root / "other_viewdep", "other", "viewdep", [3, 5], [2, 4], [1.0, 1.0])

    rs = load_runs([root])
    assert not rs.problems and len(rs.runs) == 6 and len(rs.frames) == 3 * 4 + 2 * 2
    t = table1(rs.runs)
    assert len(t) == 5
    expect = {  # (scene, mode): faces min/max/mean, verts min/max/mean, time min/max/mean, speed-up
        ("toy", "nonadaptive"): (100, 100, 100, 60, 60, 60, 2.0, 4.0, 3.0, 1.5 / 3.0),
        ("toy", "adaptive"): (40, 90, 60, 25, 50, 35, 1.0, 2.0, 1.5, 1.0),
        ("toy", "viewdep"): (10, 30, 20, 8, 18, 13, 0.25, 0.75, 0.5, 1.5 / 0.5),
        ("other", "adaptive"): (7, 9, 8, 5, 6, 5.5, 4.0, 4.0, 4.0, 1.0),
        ("other", "viewdep"): (3, 5, 4, 2, 4, 3, 1.0, 1.0, 1.0, 4.0),
    }
    for (scene, mode), values in expect.items():
        r = row(t, scene=scene, mode=mode)
        for col, v in zip(COLS, values):
            assert abs(r[col] - v) <= EXACT_TOL, f"{scene}/{mode} {col}: {r[col]} != {v}"
    assert row(t, scene="toy", mode="viewdep")["run"].endswith("toy_viewdep")
    assert any("toy_viewdep_old" in n and "superseded" in n for n in t.attrs["notes"])

    files = aggregate.write_table1(t, tmp_path / "out")
    assert [f.name for f in files] == ["table1.csv", "table1_paper.csv", "table1.md", "table1.tex"]
    back = pd.read_csv(files[0], keep_default_na=False)
    assert abs(row(back, scene="toy", mode="viewdep")["speedup"] - 3.0) <= EXACT_TOL
    md, tex = files[2].read_text(), files[3].read_text()
    assert "3.00×" in md and "0.50×" in md and "Solo Dancer" in md and "2.09×" in md
    assert r"3.00$\times$" in tex and r"\toprule" in tex and "123{,}790" in tex


def test_runs_are_labelled_by_the_settings_they_ran_with_the_scenes_over_the_modes(tmp_path):
    """A scene's own view settings (scene.view) win over the mode's in experiments.build, so the
    runs table reports the scene's: a karate nu_out sweep point ran at karate's nu_out."""
    write_run(tmp_path / "scene_wins", "karate", "viewdep", [4], [3], [1.0], view={"nu_out": 0.01, "margin": 0.3},
              scene_view={"nu_out": 0.1})
    write_run(tmp_path / "mode_only", "solo_dancer", "viewdep", [4], [3], [1.0], view={"nu_out": 0.3})
    runs = load_runs([tmp_path]).runs.set_index("scene")
    assert runs.loc["karate", "nu_out"] == 0.1 and runs.loc["karate", "margin"] == 0.3
    assert runs.loc["solo_dancer", "nu_out"] == 0.3


def test_without_an_adaptive_run_the_speedup_is_left_out_and_said(tmp_path):
    write_run(tmp_path / "a", "toy", "viewdep", [1, 2], [1, 2], [1.0, 1.0])
    t = table1(load_runs([tmp_path]).runs)
    assert len(t) == 1 and math.isnan(t["speedup"].iloc[0])
    assert any("no adaptive run" in n for n in t.attrs["notes"])


def test_repeats_give_medians_ranges_and_per_seed_speedups(tmp_path):
    """Three seeds per cell: statistics are medians of the per-run values, the time's range is the
    per-run means' min-max, and the speed-up is the median of per-seed ratios."""
    commit = {"git_commit": "a" * 40, "git_dirty": False}
    adaptive = {0: [1.0, 3.0], 1: [2.0, 2.0], 2: [4.0, 4.0]}   # per-run means 2, 2, 4
    viewdep = {0: [0.5, 0.5], 1: [1.0, 1.0], 2: [0.5, 1.5]}    # per-run means 0.5, 1, 1
    for seed in range(3):
        write_run(tmp_path / f"a{seed}", "toy", "adaptive", [10 * (seed + 1)] * 2, [5, 5], adaptive[seed],
                  seed=seed, manifest=commit)
        write_run(tmp_path / f"v{seed}", "toy", "viewdep", [seed + 1, seed + 3], [2, 2], viewdep[seed], seed=seed,
                  manifest=commit)
    t = table1(load_runs([tmp_path]).runs)
    a, v = row(t, mode="adaptive"), row(t, mode="viewdep")
    assert a["repeats"] == 3 and a["seeds"] == "0 1 2" and a["code"] == "a" * 12
    assert a["time_mean_s"] == 2.0 and (a["time_mean_lo_s"], a["time_mean_hi_s"]) == (2.0, 4.0)
    assert a["faces_mean"] == 20 and a["time_max_s"] == 3.0  # medians of (10, 20, 30) and of (3, 2, 4)
    assert v["time_mean_s"] == 1.0 and (v["time_mean_lo_s"], v["time_mean_hi_s"]) == (0.5, 1.0)
    assert v["faces_min"] == 2 and v["faces_max"] == 4  # medians of (1, 2, 3) and (3, 4, 5)
    # per seed: 2 / 0.5 = 4, 2 / 1 = 2, 4 / 1 = 4
    assert (v["speedup"], v["speedup_lo"], v["speedup_hi"]) == (4.0, 2.0, 4.0)
    md = aggregate.table1_markdown(t)
    assert "1.000 (0.500–1.000)" in md and "4.00× (2.00–4.00)" in md


def test_the_runs_table_says_how_much_room_the_sizing_had(tmp_path):
    extra = {"remeshed": [1, 0, 1], "faces_sized": [40, 0, 60], "faces_at_size_min": [10, 0, 30],
             "faces_at_size_max": [20, 0, 0], "edge_at_size_min_m": [0.04, float("nan"), 0.05]}
    write_run(tmp_path / "a", "toy", "adaptive", [40, 50, 60], [1, 1, 1], [1.0, 1.0, 1.0], extra_frames=extra)
    write_run(tmp_path / "n", "toy", "nonadaptive", [40, 40, 40], [1, 1, 1], [1.0, 1.0, 1.0])
    runs = load_runs([tmp_path]).runs.set_index("mode")
    # frames 1 and 3 remeshed: (10/40 + 30/60) / 2, (20/40 + 0) / 2, median(0.04, 0.05)
    assert runs.loc["adaptive", "size_min_fraction_mean"] == pytest.approx(0.375, abs=EXACT_TOL)
    assert runs.loc["adaptive", "size_max_fraction_mean"] == pytest.approx(0.25, abs=EXACT_TOL)
    assert runs.loc["adaptive", "edge_at_size_min_m"] == pytest.approx(0.045, abs=EXACT_TOL)
    assert math.isnan(runs.loc["nonadaptive", "size_min_fraction_mean"])


def test_face_ratios_are_over_the_adaptive_mean_beside_the_papers(tmp_path):
    write_run(tmp_path / "n", "solo_dancer", "nonadaptive", [300, 300], [1, 1], [1.0, 1.0])
    write_run(tmp_path / "a", "solo_dancer", "adaptive", [100, 140], [1, 1], [1.0, 1.0])
    write_run(tmp_path / "v", "solo_dancer", "viewdep", [30, 90], [1, 1], [1.0, 1.0])
    write_run(tmp_path / "w", "solo_dancer", "viewdep", [40, 80], [1, 1], [1.0, 1.0], variant="viewdep_nofloor")
    t = table1(load_runs([tmp_path]).runs)
    r = tables.face_ratios(t)
    r = r.set_index(r["variant"].where(r["variant"] != "", r["mode"]))
    assert r.loc["nonadaptive", "faces_ratio"] == 2.5 and r.loc["viewdep", "faces_ratio"] == 0.5
    assert r.loc["viewdep_nofloor", "faces_ratio"] == 0.5
    # the paper's solo dancer: 43,710 / 18,041 and 9,638 / 18,041 (Table 1)
    assert r.loc["nonadaptive", "faces_ratio_paper"] == pytest.approx(43710 / 18041, abs=EXACT_TOL)
    assert r.loc["viewdep_nofloor", "faces_ratio_paper"] == pytest.approx(9638 / 18041, abs=EXACT_TOL)
    md = tables.table1_markdown(t)
    assert "2.50 | 2.42" in md and "View-dependent (viewdep_nofloor)" in md


def test_table1s_fixed_mesh_of_adaptives_quality_is_compared_with_the_papers(tmp_path):
    """Table 1's non-adaptive row is the fixed mesh of adaptive's quality (variant 'fixed x1.14'):
    the side-by-side and the face ratios put it beside the paper's fixed mesh."""
    write_run(tmp_path / "n", "solo_dancer", "nonadaptive", [300, 300], [1, 1], [1.0, 1.0], variant="fixed x1.14")
    write_run(tmp_path / "a", "solo_dancer", "adaptive", [100, 140], [1, 1], [1.0, 1.0])
    t = table1(load_runs([tmp_path]).runs)
    sbs = tables.side_by_side(t).set_index("mode")
    assert sbs.loc["nonadaptive", "variant"] == "fixed x1.14" and sbs.loc["nonadaptive", "faces_mean_paper"] == 43710
    r = tables.face_ratios(t).set_index("mode")
    assert r.loc["nonadaptive", "faces_ratio"] == 2.5
    assert r.loc["nonadaptive", "faces_ratio_paper"] == pytest.approx(43710 / 18041, abs=EXACT_TOL)


def test_a_row_whose_runs_differ_in_commit_or_frames_is_refused_and_named(tmp_path):
    old, new = {"git_commit": "b" * 40}, {"git_commit": "c" * 40}
    write_run(tmp_path / "a0", "toy", "adaptive", [4, 4], [3, 3], [1.0, 1.0], seed=0, manifest=old)
    write_run(tmp_path / "a1", "toy", "adaptive", [4, 4], [3, 3], [1.0, 1.0], seed=1, manifest=new)
    write_run(tmp_path / "v0", "toy", "viewdep", [2, 2], [1, 1], [0.5, 0.5], seed=0, manifest=old)
    write_run(tmp_path / "v1", "toy", "viewdep", [2, 2, 2], [1, 1, 1], [0.5, 0.5, 0.5], seed=1, manifest=old)
    write_run(tmp_path / "n0", "toy", "nonadaptive", [9, 9], [5, 5], [2.0, 2.0], seed=0, manifest=old)
    t = table1(load_runs([tmp_path]).runs)
    assert list(t["mode"]) == ["nonadaptive"]  # both other rows are refused, so no speed-up either
    problems = "\n".join(t.attrs["problems"])
    assert "toy/small/adaptive refused: its runs differ in commit (" + "b" * 12 in problems
    assert "toy/small/viewdep refused: its runs differ in frames (2, 3)" in problems
    assert "a0" in problems and "v1" in problems
    # a dirty work tree is other code: the diff's hash is part of the label
    assert aggregate.code_label({"git_commit": "d" * 40, "git_dirty": True, "git_diff_sha1": "e" * 40}) \
        == "d" * 12 + "+diff:" + "e" * 8
    # the paper_figures command writes the refusals into problems.txt
    from paper_figures.__main__ import main as figures_main
    out = tmp_path / "fig"
    figures_main([str(tmp_path), "--out", str(out)])
    assert "toy/small/viewdep refused" in (out / "problems.txt").read_text()


def test_a_speedup_against_a_baseline_of_other_code_is_refused(tmp_path):
    write_run(tmp_path / "a", "toy", "adaptive", [4], [3], [1.0], manifest={"git_commit": "1" * 40})
    write_run(tmp_path / "v", "toy", "viewdep", [2], [1], [0.5], manifest={"git_commit": "2" * 40})
    t = table1(load_runs([tmp_path]).runs)
    assert len(t) == 2 and math.isnan(row(t, mode="viewdep")["speedup"])
    assert any("speed-up refused" in p for p in t.attrs["problems"])


# ---- broken folders --------------------------------------------------------------------------------

def test_corrupt_and_half_written_folders_are_reported_by_name_and_skipped(tmp_path):
    good = write_run(tmp_path / "good", "toy", "adaptive", [4, 6], [3, 4], [1.0, 3.0])
    corrupt = write_run(tmp_path / "corrupt", "toy", "viewdep", [1, 2], [1, 2], [9.0, 9.0])
    (corrupt / "frames.parquet").write_bytes(b"PAR1 this is not a parquet file")
    no_summary = write_run(tmp_path / "no_summary", "toy", "viewdep", [1, 2], [1, 2], [9.0, 9.0])
    (no_summary / "summary.json").unlink()
    write_run(tmp_path / "interrupted", "toy", "viewdep", [1, 2], [1, 2], [9.0, 9.0], status="interrupted")
    write_run(tmp_path / "short", "toy", "viewdep", [1, 2], [1, 2], [9.0, 9.0], frames_requested=5)
    write_run(tmp_path / "nan", "toy", "viewdep", [1, 2], [1, 2], [9.0, float("nan")])
    bad_json = write_run(tmp_path / "bad_json", "toy", "viewdep", [1, 2], [1, 2], [9.0, 9.0])
    (bad_json / "summary.json").write_text('{"status": "compl')
    no_config = write_run(tmp_path / "no_config", "toy", "viewdep", [1, 2], [1, 2], [9.0, 9.0])
    (no_config / "config.yaml").unlink()

    with pytest.warns(RunFolderWarning) as record:
        rs = load_runs([tmp_path])
    reasons = {p.path.name: p.reason for p in rs.problems}
    assert reasons.keys() == {"corrupt", "no_summary", "interrupted", "short", "nan", "bad_json", "no_config"}
    assert "frames.parquet unreadable" in reasons["corrupt"]
    assert "no summary.json" in reasons["no_summary"]
    assert "'interrupted'" in reasons["interrupted"]
    assert "2 frames of 5 requested" in reasons["short"]
    assert "NaN in sim_s" in reasons["nan"]
    assert "summary.json unreadable" in reasons["bad_json"]
    assert "no config.yaml" in reasons["no_config"]
    assert all(r.startswith("skipped") for r in reasons.values())
    assert len(record) == len(rs.problems)
    assert {str(w.message).split(":")[0] for w in record} == {str(p.path) for p in rs.problems}
    assert list(rs.runs["path"]) == [str(good.resolve())]
    assert set(rs.frames["run"]) == set(rs.runs["run"])
    t = table1(rs.runs)
    assert len(t) == 1 and t["time_mean_s"].iloc[0] == 2.0  # (1 + 3) / 2: nothing of the broken runs


def test_unreadable_accuracy_is_reported_and_the_run_kept_without_it(tmp_path):
    run = write_run(tmp_path / "r", "toy", "viewdep", [1, 2], [1, 2], [1.0, 1.0])
    (run / "accuracy.json").write_text("not json")
    rs = load_runs([tmp_path], warn=False)
    assert len(rs.runs) == 1 and math.isnan(rs.runs["error_px_mean"].iloc[0])
    assert len(rs.problems) == 1 and "accuracy.json unreadable" in rs.problems[0].reason


def test_crowd_characters_are_not_counted_as_runs(tmp_path):
    crowd = write_run(tmp_path / "crowd", "multiple_dancers", "viewdep", [30, 50], [20, 30], [3.0, 5.0],
                      summary_extra={"characters": 2})
    for i, (faces, wall) in enumerate((([10, 20], [1.0, 2.0]), ([20, 30], [2.0, 3.0]))):
        # each character's folder is a whole run folder of its own (even with a config)
        write_run(crowd / f"dancer_{i:02d}", "multiple_dancers", "viewdep", faces, faces, wall)
    rs = load_runs([tmp_path])
    assert len(rs.runs) == 1 and rs.runs["path"].iloc[0] == str(crowd.resolve())
    r = rs.runs.iloc[0]
    assert r["characters"] == 2 and r["faces_max"] == 50 and r["time_mean_s"] == 4.0
    assert len(rs.frames) == 2
    # a root that is itself a run folder
    assert len(load_runs([crowd]).runs) == 1


def test_bad_root_is_one_clear_error_before_any_work(tmp_path, capsys):
    missing = tmp_path / "nope"
    assert aggregate.main([str(missing), "--out", str(tmp_path / "out")]) == 2
    assert f"root '{missing}' does not exist" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    from paper_figures.__main__ import main as figures_main
    assert figures_main([str(tmp_path), "--paper-timings", str(missing), "--out", str(tmp_path / "out")]) == 2
    assert "--paper-timings" in capsys.readouterr().err and not (tmp_path / "out").exists()


def test_aggregate_cli_writes_its_tables(tmp_path, capsys):
    write_run(tmp_path / "runs" / "a", "toy", "adaptive", [4, 6], [3, 4], [1.0, 3.0])
    write_run(tmp_path / "runs" / "v", "toy", "viewdep", [1, 2], [1, 2], [0.5, 0.5])
    broken = tmp_path / "runs" / "broken"
    broken.mkdir()
    (broken / "config.yaml").write_text("scene: {name: toy}\nmode: {name: adaptive}\n")
    out = tmp_path / "agg"
    assert aggregate.main([str(tmp_path / "runs"), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert f"warning: {broken.resolve()}: skipped: no summary.json" in captured.err
    assert "4.00×" in captured.out
    for name in ("runs.csv", "frames.parquet", "problems.txt", "table1.csv", "table1_paper.csv", "table1.md",
                 "table1.tex"):
        assert (out / name).stat().st_size > 0, name
    assert len(pd.read_parquet(out / "frames.parquet")) == 4
    assert str(broken.resolve()) in (out / "problems.txt").read_text()


# ---- the paper's own records -------------------------------------------------------------------------

PAPER_FILES = {("karate", "nonadaptive"): ["karate_hires.csv"], ("karate", "adaptive"): ["karate_rahuls.csv"],
               ("karate", "viewdep"): ["karate_vd.csv"], ("solo_dancer", "nonadaptive"): ["solo_hires_1.csv"],
               ("solo_dancer", "adaptive"): ["solo_rahuls_1.csv"], ("solo_dancer", "viewdep"): ["solo_vd_1.csv"],
               ("multiple_dancers", "viewdep"): [f"crowd_vd_{i}.csv" for i in range(10)]}


def test_code_states_the_papers_table1_as_printed():
    for (scene, mode), values in PAPER.items():
        assert aggregate.PAPER_TABLE1[scene][mode] == pytest.approx(values, abs=0), (scene, mode)


@pytest.mark.skipif(not PAPER_TIMINGS.is_dir(), reason=f"the paper's per-frame records are not at {PAPER_TIMINGS}")
def test_paper_timings_reproduce_the_papers_table1(tmp_path):
    """Run folders made from the paper's per-frame records give the paper's Table 1 (the crowd as
    one run of ten characters; the paper's records have no adaptive crowd, so no speed-up there)."""
    for (scene, mode), names in PAPER_FILES.items():
        tables = [pd.read_csv(PAPER_TIMINGS / n) for n in names]
        total = {c: sum(t[c].to_numpy() for t in tables) for c in ("Faces", "Verts", "Time/Frame")}
        top = write_run(tmp_path / f"{scene}_{mode}", scene, mode, total["Faces"], total["Verts"],
                        total["Time/Frame"], summary_extra={"characters": len(tables)} if len(tables) > 1 else None)
        if len(tables) > 1:
            for i, t in enumerate(tables):
                write_run(top / f"dancer_{i:02d}", scene, mode, t["Faces"], t["Verts"], t["Time/Frame"])
    rs = load_runs([tmp_path])
    assert not rs.problems and len(rs.runs) == len(PAPER_FILES)
    t = table1(rs.runs)
    for (scene, mode) in PAPER_FILES:
        r, paper = row(t, scene=scene, mode=mode), PAPER[(scene, mode)]
        for col, v in zip(COLS, paper):
            if col == "speedup" and scene == "multiple_dancers":
                assert math.isnan(r[col])
            elif col.startswith(("faces", "verts")):
                assert round(r[col]) == v, f"{scene}/{mode} {col}: {r[col]} != {v}"
            else:
                assert abs(r[col] - v) <= PRINTED_TOL, f"{scene}/{mode} {col}: {r[col]} != {v}"


@pytest.mark.slow
def test_paper_figures_write_every_expected_file(tmp_path, capsys):
    from paper_figures.__main__ import main as figures_main
    from paper_figures.ablations import CUT_WINDOW_FRAMES

    root = tmp_path / "results"
    write_study_runs(root)
    n = 20
    assert 4 + CUT_WINDOW_FRAMES <= n, "the window after the cut must fit in the runs"
    t = np.arange(1, n + 1) * FRAME_TIME_S
    after = (t >= CUTS_S[0] - 1e-9) & (t < CUTS_S[0] + CUT_WINDOW_FRAMES * FRAME_TIME_S - 1e-9)
    for on, T, err, cut_sync in ((True, 5, np.full(n, 2.5), 1.0), (False, 5, np.where(after, 5.0, 2.5), 4.0),
                                 (True, 2, np.where(after, 3.0, 2.5), 2.0)):
        write_run(root / "anticipation" / f"vd_{on}_{T}", "solo_dancer", "viewdep", np.full(n, 20), np.full(n, 12),
                  np.full(n, 0.5), study="ablation_anticipation", view={"anticipation": on, "anticipation_frames": T},
                  camera_cuts=CUTS_S, extra_frames={"faces_in_view": np.full(n, 9)},
                  accuracy={"error_px_mean": float(err.mean()), "popping_px_mean": 0.1},
                  accuracy_frames={"frame": np.arange(1, n + 1), "error_px": err,
                                   "popping_px": np.where(after, 0.3, 0.1)},
                  sync={"sync_error_px_mean": 1.0, "sync_error_px_lo": 0.9, "sync_error_px_hi": 1.1,
                        "sync_error_px_cut_mean": cut_sync})
    broken = root / "t1" / "3_broken"
    broken.mkdir()
    (broken / "config.yaml").write_text("scene: {name: solo_dancer}\nmode: {name: viewdep}\n")
    timings = tmp_path / "paper-timings"  # a tiny stand-in for the paper's records
    timings.mkdir()
    for name in ("solo_hires_1.csv", "solo_rahuls_1.csv", "solo_vd_1.csv"):
        pd.DataFrame({"FrameNum": [1, 2, 3], "Time/Frame": [3.0, 2.0, 1.0], "Faces": [9, 9, 9],
                      "Verts": [5, 5, 5]}).to_csv(timings / name, index=False)
    out = tmp_path / "figures"
    assert figures_main([str(root), "--out", str(out), "--paper-timings", str(timings)]) == 0
    printed = capsys.readouterr()
    expected = {"runs.csv", "problems.txt", "table1.csv", "table1_paper.csv", "table1.md", "table1.tex",
                "fig8_solo_dancer_small.png", "fig8_solo_dancer_small.pdf", "sweep_nu_out.png", "sweep_nu_out.pdf",
                "sweep_T.png", "sweep_T.pdf",  # the anticipation runs at T = 2 and 5
                "sweeps.csv", "sweeps.md", "ablation_buckling.png", "ablation_buckling.pdf", "ablation_buckling.csv",
                "ablation_buckling.md", "ablation_anticipation.png", "ablation_anticipation.pdf",
                "ablation_anticipation.csv", "ablation_anticipation.md", "ablation_anticipation_seeds.csv",
                "ablation_anticipation_seeds.md", "pareto.png", "pareto.pdf", "pareto.csv",
                "pareto.md", "phases.csv", "phases.md"}
    written = {p.name for p in out.iterdir()}
    assert written == expected, f"missing {expected - written}, unexpected {written - expected}"
    for name in expected - {"problems.txt"}:
        assert (out / name).stat().st_size > 0, name
        assert str(out / name) in printed.out, f"{name}: where it went is not printed"
    assert "3_broken" in (out / "problems.txt").read_text() and "3_broken" in printed.err

    # Table 1 from the table1 study only: its speed-ups by hand (adaptive 1.0 s / viewdep 0.5 s)
    t1 = pd.read_csv(out / "table1.csv", keep_default_na=False)
    assert len(t1) == 3 and abs(row(t1, mode="viewdep")["speedup"] - 2.0) <= EXACT_TOL
    # sweep: speed-up against the study's adaptive run (1.0 s per frame)
    sw = pd.read_csv(out / "sweeps.csv")
    assert sw[sw["parameter"] == "T"]["value"].tolist() == [2.0, 5.0]  # the anticipation study's T runs
    sw = sw[sw["parameter"] == "nu_out"]
    assert sw["value"].tolist() == [0.001, 0.01, 0.1]
    assert np.allclose(sw["speedup"], [1.0 / 0.25, 1.0 / 0.5, 1.0 / 0.8], rtol=0, atol=EXACT_TOL)
    # buckling: the three compensations in order, with their ballooning
    ab = pd.read_csv(out / "ablation_buckling.csv")
    assert ab["compensation"].tolist() == ["none", "uniform", "adaptive k=10"]
    assert ab["offscreen_distance_m_mean"].tolist() == [0.05, 0.01, 0.02]
    # anticipation: the error after the cut, by hand
    an = pd.read_csv(out / "ablation_anticipation.csv")
    assert an["anticipation"].tolist() == ["off", "T=2", "T=5"]  # off first, then by the window
    assert row(an, anticipation="T=5")["error_px_after_cut_mean"] == 2.5
    assert row(an, anticipation="off")["error_px_after_cut_mean"] == 5.0
    assert row(an, anticipation="T=2")["error_px_after_cut_mean"] == 3.0
    assert an["sync_error_px_cut_mean"].tolist() == [4.0, 2.0, 1.0]
    assert np.allclose(an["popping_px_after_cut_mean"], 0.3, rtol=0, atol=EXACT_TOL)
    assert an["faces_in_view_after_cut"].tolist() == [9] * 3
    assert an["seeds"].tolist() == [1] * 3 and np.allclose(an["cut_vs_off_px"].iloc[1:], [2.0 - 4.0, 1.0 - 4.0])
    # Pareto over every run with accuracy (same scene): fastest is nu_out=0.001 (0.25 s, 4 px),
    # nu_out=0.01 at 0.5 s with 2 px dominates nu_out=0.1 (0.8 s, 3 px) and the anticipation (2.5, 3.75 px)
    # and buckling (3, 4, 5 px) runs at 0.5 s; adaptive (1 s, 0.5 px) is the most accurate.
    p = pd.read_csv(out / "pareto.csv", keep_default_na=False)
    front = sorted(p[p["on_front"]]["run"])
    assert front == sorted(["sweep/1_vd", "sweep/2_vd", "sweep/0_ad"]), front


def test_a_crowds_records_sum_the_sizing_bounds_of_its_characters(tmp_path):
    from cloth.core.records import PHASES
    from cloth.runner import combine_crowd

    dirs = []
    for i, (at_min, edge) in enumerate(((10, 0.04), (30, 0.06))):
        d = tmp_path / f"dancer_{i:02d}"
        d.mkdir()
        pd.DataFrame({"frame": [1], "sim_time_s": [0.04], "faces": [100], "verts": [60], "nodes": [60], "sim_s": [1.0],
                      "wall_s": [1.1], "solver_iterations": [7],
                      "max_speed_m_s": [1.0], "min_face_quality": [0.5], "remeshed": [1], "faces_sized": [100],
                      "faces_at_size_min": [at_min], "faces_at_size_max": [5],
                      "edge_at_size_min_m": [edge], **{f"time_{p}_s": [0.1] for p in PHASES}}
                     ).to_parquet(d / "frames.parquet", index=False)
        (d / "summary.json").write_text(json.dumps({"status": "completed"}))
        dirs.append(d)
    rows, _ = combine_crowd(dirs, tmp_path)
    r = rows.iloc[0]
    assert (r["faces_sized"], r["faces_at_size_min"], r["faces_at_size_max"]) == (200, 40, 10)
    assert r["edge_at_size_min_m"] == pytest.approx(0.05, abs=EXACT_TOL)


def test_a_sweep_never_mixes_studies_or_runs_that_differ_in_more_than_its_parameter(tmp_path):
    """The main job's root holds several studies. A sweep's points come from one study and share
    every other view setting (the occlusion test, the contact floor), its baseline is that
    study's adaptive run, and its error is the re-synchronised one where measured."""
    from paper_figures.sweeps import sweep_points

    root = tmp_path / "results"
    n = 4
    sync = {"sync_error_px_mean": 7.0, "sync_error_px_lo": 6.0, "sync_error_px_hi": 8.0}
    for study, adaptive_s in (("accuracy", 1.0), ("ablation_buckling_dancer", 0.2)):
        write_run(root / study / "ad", "solo_dancer", "adaptive", np.full(n, 20), np.full(n, 12),
                  np.full(n, adaptive_s), study=study)
    # accuracy: nu_out 0.01 and 0.1, occlusion on; and an occlusion-off run at nu_out 0.001
    for nu, s in ((0.01, 0.5), (0.1, 0.4)):
        write_run(root / "accuracy" / f"vd_{nu}", "solo_dancer", "viewdep", np.full(n, 9), np.full(n, 6), np.full(n, s),
                  study="accuracy", view={"nu_out": nu, "occlusion": True}, sync=sync,
                  accuracy={"error_px_mean": 70.0})
    write_run(root / "accuracy" / "vd_occl_off", "solo_dancer", "viewdep", np.full(n, 9), np.full(n, 6),
              np.full(n, 0.6), study="accuracy", view={"nu_out": 0.001, "occlusion": False})
    # another study's nu_out 0.3 point, with every view setting as the accuracy runs'
    write_run(root / "ablation_buckling_dancer" / "vd_0.3", "solo_dancer", "viewdep", np.full(n, 9), np.full(n, 6),
              np.full(n, 0.1), study="ablation_buckling_dancer", view={"nu_out": 0.3, "occlusion": True})
    pts = sweep_points(load_runs([root]).runs, "nu_out")
    assert pts["value"].tolist() == [0.01, 0.1] and set(pts["study"]) == {"accuracy"}
    assert np.allclose(pts["speedup"], [1.0 / 0.5, 1.0 / 0.4], rtol=0, atol=EXACT_TOL)  # the accuracy study's adaptive
    assert set(pts["error"]) == {"sync_error_px"} and pts["error_px"].tolist() == [7.0, 7.0]
    # the accuracy study's occlusion-off run is not a point, and is named with the setting it differs in;
    # the other study's run is not this sweep's at all, so it is not listed
    refused: list = []
    sweep_points(load_runs([root]).runs, "nu_out", refused)
    assert [Path(run).name for run, _ in refused] == ["vd_occl_off"] and "occlusion" in refused[0][1], refused
