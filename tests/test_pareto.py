"""The Pareto figure's table (paper_figures.pareto) on made-up run folders with hand-computed
answers: the front told apart window by window (paired intervals), the fixed mesh of adaptive's
quality, and the re-synchronised error as its error axis."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from helpers import write_run

from experiments.analysis.aggregate import load_runs


def test_pareto_front_tells_runs_apart_window_by_window(tmp_path):
    """Runs restarted from the same states share their windows: a run whose error is lower in
    every window is told apart by the paired interval even where the windows' spread (the
    dance's phase) makes the unpaired intervals overlap."""
    from experiments.analysis.sync import bootstrap_interval, paired_difference_interval
    from paper_figures.pareto import pareto_table

    base = np.array([1.0, 3.0, 5.0, 7.0, 9.0])
    frames = [0, 10, 20, 30, 40]
    for i, (mode, t, shift) in enumerate((("nonadaptive", 1.0, 1.0), ("viewdep", 1.5, 0.9), ("adaptive", 2.0, 0.0))):
        e = base + shift
        lo, hi = bootstrap_interval(e)
        folder = write_run(tmp_path / f"{i}_{mode}", "solo_dancer", mode, [50] * 4, [30] * 4, [t] * 4,
                           study="accuracy", accuracy={"error_px_mean": 60.0},
                           sync={"sync_error_px_mean": float(e.mean()), "sync_error_px_lo": lo, "sync_error_px_hi": hi})
        pd.DataFrame({"sync_frame": frames, "sync_error_px": e}).to_parquet(folder / "sync.parquet", index=False)
    lo_v, hi_v = paired_difference_interval(pd.Series(base + 0.9, index=frames), pd.Series(base + 1.0, index=frames))
    assert lo_v == pytest.approx(-0.1) and hi_v == pytest.approx(-0.1)
    runs = load_runs([tmp_path]).runs
    t = pareto_table(runs).set_index("mode")
    assert t["on_front"].all()  # each slower run is lower in every window
    # without the windows, the intervals overlap: only the fastest is on the front
    for f in tmp_path.glob("*/sync.parquet"):
        f.unlink()
    t = pareto_table(runs).set_index("mode")
    assert t["on_front"].to_dict() == {"nonadaptive": True, "viewdep": False, "adaptive": False}


def test_the_fixed_mesh_of_adaptives_quality_is_the_coarsest_not_told_apart_as_worse(tmp_path):
    from paper_figures.pareto import pareto_table

    base = np.array([1.0, 3.0, 5.0, 7.0, 9.0])
    frames = [0, 10, 20, 30, 40]
    # adaptive: base; fixed meshes 4 px, 1 px (told apart: worse) and +-0.5 px around it (not told apart)
    cases = (("adaptive", "adaptive", 1.0, 500, base), ("nonadaptive", "fixed x0.5", 0.2, 100, base + 4.0),
             ("nonadaptive", "fixed x0.7", 0.4, 200, base + 1.0),
             ("nonadaptive", "fixed x1.4", 1.5, 900, base + np.array([0.5, -0.5, 0.5, -0.5, 0.5])),
             ("nonadaptive", "fixed x2", 3.0, 1600, base - 0.2))
    for i, (mode, variant, t, faces, e) in enumerate(cases):
        folder = write_run(tmp_path / f"{i}", "solo_dancer", mode, [faces] * 4, [faces // 2] * 4, [t] * 4,
                           study="accuracy", variant=variant, accuracy={"error_px_mean": 60.0},
                           sync={"sync_error_px_mean": float(e.mean()), "sync_error_px_lo": float(e.mean()) - 3,
                                 "sync_error_px_hi": float(e.mean()) + 3})
        pd.DataFrame({"sync_frame": frames, "sync_error_px": e}).to_parquet(folder / "sync.parquet", index=False)
    t = pareto_table(load_runs([tmp_path]).runs).set_index("variant")
    assert t["equal_quality"].to_dict() == {"fixed x0.5": False, "fixed x0.7": False, "adaptive": False,
                                            "fixed x1.4": True, "fixed x2": False}
    # Table 1 names it with its error (the mean of its windows, base + 0.1) beside adaptive's (base: 5)
    from experiments.analysis.aggregate import table1, table1_runs
    from paper_figures.table1 import baseline_notes

    runs = load_runs([tmp_path]).runs
    notes = baseline_notes(runs, table1(table1_runs(runs)))
    assert len(notes) == 1 and "is fixed x1.4 (900 faces, 5.1 px (2.1-8.1) against adaptive's 5 px)" in notes[0]
    assert notes[0].endswith("Table 1's non-adaptive rows of solo_dancer: fixed x0.5, fixed x0.7, fixed x1.4, fixed x2")


# ---- the figures -----------------------------------------------------------------------------------

def test_pareto_front_by_hand():
    from paper_figures.pareto import pareto_front
    # (time, error): (1, 5) fastest; (2, 3) better error; (3, 4) dominated by (2, 3); (4, 1) best error;
    # (4, 1) twice: equal points do not dominate each other
    on = pareto_front([1, 2, 3, 4, 4], [5, 3, 4, 1, 1])
    assert on.tolist() == [True, True, False, True, True]
    # with intervals: (2, 3) [2.5, 3.5] is told apart from (1, 5) [4, 6]; (4, 1) [0, 4.5] overlaps
    # (1, 5)'s interval: not on the front, though no point dominates it
    on = pareto_front([1, 2, 4], [5, 3, 1], lo=[4, 2.5, 0], hi=[6, 3.5, 4.5])
    assert on.tolist() == [True, True, False]


def test_pareto_table_uses_the_resynchronised_error_and_its_interval(tmp_path):
    from paper_figures.pareto import pareto_table

    s = "solo_dancer"
    for i, (mode, t, e, lo, hi) in enumerate((("nonadaptive", 1.0, 4.0, 3.5, 4.5), ("adaptive", 2.0, 2.0, 1.8, 2.2),
                                              ("viewdep", 1.5, 3.9, 3.0, 4.6))):
        write_run(tmp_path / f"{i}_{mode}", s, mode, [50] * 4, [30] * 4, [t] * 4, study="accuracy",
                  accuracy={"error_px_mean": 60.0}, sync={"sync_error_px_mean": e, "sync_error_px_lo": lo,
                                                          "sync_error_px_hi": hi, "windows": 15, "horizon": 8,
                                                          "sync_error_mm_mean": 2 * e, "sync_error_mm_lo": 2 * lo,
                                                          "sync_error_mm_hi": 2 * hi,
                                                          "sync_error_px1080_mean": 1.5 * e,
                                                          "sim_s_mean": 3 * t, "faces_mean": 40.0})
    runs = load_runs([tmp_path]).runs
    assert runs["sync_windows"].tolist() == [15, 15, 15] and runs["sync_horizon"].tolist() == [8, 8, 8]
    t = pareto_table(runs).set_index("mode")
    assert set(t["error"]) == {"sync_error_px"}
    assert t.loc["adaptive", "error_px"] == 2.0 and t.loc["adaptive", "error_lo_px"] == 1.8
    units = ["error_mm", "error_lo_mm", "error_hi_mm", "error_px1080"]
    assert t.loc["adaptive", units].tolist() == pytest.approx([4.0, 3.6, 4.4, 3.0])
    # each point's cost in its windows, beside the free run's
    assert t.loc["adaptive", ["window_time_s", "window_faces", "windows"]].tolist() == pytest.approx([6.0, 40.0, 15])
    # viewdep is faster than adaptive but its error is not told apart from nonadaptive's, which is faster still
    assert t["on_front"].to_dict() == {"nonadaptive": True, "viewdep": False, "adaptive": True}
    assert t.loc["viewdep", "speedup"] == pytest.approx(2.0 / 1.5)


def _mm_runs(tmp_path, cases, frames):
    """Run folders of solo_dancer with millimetre windows (sync.parquet) and resolution factors."""
    import yaml
    for i, (mode, variant, factor, faces, e) in enumerate(cases):
        folder = write_run(tmp_path / f"{i}", "solo_dancer", mode, [faces] * 4, [faces // 2] * 4, [1.0] * 4,
                           study="accuracy", variant=variant, accuracy={"error_px_mean": 60.0},
                           sync={"sync_error_px_mean": float(e.mean())})
        if factor is not None:
            cfg = yaml.safe_load((folder / "config.yaml").read_text())
            (folder / "config.yaml").write_text(yaml.safe_dump({**cfg, "resolution_factor": factor}))
        pd.DataFrame({"sync_frame": frames, "sync_error_px": e, "sync_error_mm": e}).to_parquet(
            folder / "sync.parquet", index=False)
    return load_runs([tmp_path]).runs


def test_equal_quality_by_equivalence_is_the_coarsest_fixed_mesh_within_the_margin(tmp_path):
    """Two one-sided tests on constructed windows: adaptive's errors `base`; x0.5 is 12 mm worse in
    every window (its interval is [12, 12]: outside), x1 is 3 mm worse (inside a 5 mm margin), x2
    is 1 mm better (inside). The coarsest equivalent is x1; between x0.5 (hi 12) and x1 (hi 3) the
    upper bound reaches the 5 mm margin 7/9 of the way, in log(factor): 0.5 * 2 ** (7 / 9)."""
    from paper_figures.pareto import equivalence_table, equivalent_resolution

    frames = list(range(0, 60, 5))
    base = np.linspace(10.0, 40.0, len(frames))
    runs = _mm_runs(tmp_path, (("adaptive", "adaptive", None, 2000, base),
                               ("nonadaptive", "fixed x0.5", 0.5, 600, base + 12.0),
                               ("nonadaptive", "fixed x1", 1.0, 2500, base + 3.0),
                               ("nonadaptive", "fixed x2", 2.0, 10000, base - 1.0)), frames)
    t = equivalence_table(runs, margin_mm=5.0)
    assert t["variant"].tolist() == ["fixed x0.5", "fixed x1", "fixed x2"]
    assert t["equivalent"].tolist() == [False, True, True]
    assert t["lo_mm"].tolist() == pytest.approx([12.0, 3.0, -1.0]) and t["windows"].tolist() == [12] * 3
    best = equivalent_resolution(t, margin_mm=5.0)
    assert best["variant"] == "fixed x1" and best["bracketed"]
    assert best["interpolated_factor"] == pytest.approx(0.5 * 2 ** (7 / 9))
    # a tighter margin than x1's difference: only x2 is equivalent, and x1 (hi 3 > 2) brackets it
    best = equivalent_resolution(equivalence_table(runs, margin_mm=2.0), margin_mm=2.0)
    assert best["variant"] == "fixed x2" and best["interpolated_factor"] == pytest.approx(2 ** (1 / 4))
    # a margin inside which no mesh is equivalent: x2 (1 mm better) is still not worse, and x1 (hi 3 > 0.5)
    # brackets it: the factor where hi reaches 0.5 mm, (3 - 0.5) / (3 + 1) of the way from x1 to x2
    t = equivalence_table(runs, margin_mm=0.5)
    assert not t["equivalent"].any() and t["not_worse"].tolist() == [False, False, True]
    best = equivalent_resolution(t, margin_mm=0.5)
    assert best["variant"] == "fixed x2" and best["interpolated_factor"] == pytest.approx(2 ** 0.625)
    # none qualifies when every fixed mesh is worse by more than the margin
    worse = runs[runs["variant"] != "fixed x2"]
    assert equivalent_resolution(equivalence_table(worse, margin_mm=2.0), margin_mm=2.0) is None


def test_equivalence_needs_millimetre_windows(tmp_path):
    from paper_figures.pareto import equivalence_table

    frames = [0, 10, 20]
    runs = _mm_runs(tmp_path, (("adaptive", "adaptive", None, 2000, np.array([1.0, 2.0, 3.0])),
                               ("nonadaptive", "fixed x1", 1.0, 2500, np.array([1.0, 2.0, 3.0]))), frames)
    for f in tmp_path.glob("*/sync.parquet"):  # an evaluation older than the millimetre error
        pd.read_parquet(f).drop(columns="sync_error_mm").to_parquet(f, index=False)
    assert equivalence_table(runs).empty


def test_the_pareto_figure_writes_the_equivalence_table(tmp_path):
    from paper_figures.pareto import make

    frames = list(range(0, 40, 5))
    base = np.linspace(10.0, 40.0, len(frames))
    _mm_runs(tmp_path / "runs", (("adaptive", "adaptive", None, 2000, base),
                                        ("nonadaptive", "fixed x1", 1.0, 2500, base + 1.0)), frames)
    logs = []
    make(load_runs([tmp_path / "runs"]), tmp_path / "fig", log=logs.append)
    eq = pd.read_csv(tmp_path / "fig" / "equivalence.csv")
    assert eq[["scene", "variant", "equivalent"]].values.tolist() == [["solo_dancer", "fixed x1", True]]
    assert any("equal quality (not worse than adaptive by more than 5 mm): fixed x1 (x1 as run)" in line
               for line in logs), logs
    chosen = pd.read_csv(tmp_path / "fig" / "equal_quality.csv")  # what the main job's Table 1 takes
    assert chosen[["scene", "variant", "interpolated_factor"]].values.tolist() == [["solo_dancer", "fixed x1", 1.0]]


def test_the_anticipation_table_over_seeds_pairs_each_window_with_the_same_seeds_run_without():
    from paper_figures.ablations import SEED_MEDIANS, over_seeds

    per_seed = pd.DataFrame({"scene": "solo_dancer", "scale": "small",
                             "anticipation": ["off", "off", "off", "T=5", "T=5", "T=5"], "seed": [0, 1, 2, 0, 1, 2],
                             "sync_error_px_cut_mean": [4.0, 6.0, 9.0, 1.0, 2.0, 8.0],
                             **{c: [1.0, 2.0, 30.0, 4.0, 5.0, 6.0] for c in SEED_MEDIANS}})
    t = over_seeds(per_seed).set_index("anticipation")
    assert t.loc["T=5", "seeds"] == 3 and t.loc["T=5", "faces_mean"] == 5.0 and t.loc["off", "faces_mean"] == 2.0
    assert abs(t.loc["T=5", "sync_error_px_cut_mean"] - 11.0 / 3) <= 1e-12
    assert abs(t.loc["T=5", "cut_vs_off_px"] - (-3.0 - 4.0 - 1.0) / 3) <= 1e-12  # paired by seed
    lo, hi = t.loc["T=5", ["cut_vs_off_lo_px", "cut_vs_off_hi_px"]]
    assert lo <= t.loc["T=5", "cut_vs_off_px"] <= hi
    assert np.isnan(t.loc["off", "cut_vs_off_px"])


def test_the_equivalence_table_takes_the_adaptive_run_with_windows_not_another_studys(tmp_path):
    from paper_figures.pareto import make

    frames = list(range(0, 40, 5))
    base = np.linspace(10.0, 40.0, len(frames))
    _mm_runs(tmp_path / "runs", (("adaptive", "adaptive", None, 2000, base),
                                 ("nonadaptive", "fixed x1", 1.0, 2500, base + 1.0)), frames)
    # Table 1's adaptive run of the same scene, later and without windows
    write_run(tmp_path / "runs" / "t1_ad", "solo_dancer", "adaptive", [2000] * 4, [1000] * 4, [1.0] * 4,
              study="table1", variant="adaptive")
    make(load_runs([tmp_path / "runs"]), tmp_path / "fig", log=lambda *_: None)
    assert pd.read_csv(tmp_path / "fig" / "equivalence.csv")["equivalent"].tolist() == [True]


def test_an_integration_point_is_compared_window_by_window_with_its_base_and_kept_out_of_equal_quality(tmp_path):
    """conf/point/bending/ and steps/: "adaptive, bending gauss_newton" 0.5 mm worse in every window
    (interval [0.5, 0.5]: worse), "viewdep, bending gauss_newton" 1 mm better (not worse); the fixed
    meshes with the other Hessian or 16 steps, far better than adaptive, are not the fixed mesh of
    adaptive's quality (a fixed mesh is judged against the adaptive run that integrates as it does)."""
    import yaml

    from paper_figures.pareto import equivalence_table, integration_table

    frames = list(range(0, 60, 5))
    base = np.linspace(10.0, 40.0, len(frames))
    cases = (("adaptive", "adaptive", None, 2000, base),
             ("adaptive", "adaptive, bending gauss_newton", None, 2000, base + 0.5),
             ("viewdep", "viewdep", None, 800, base + 10.0),
             ("viewdep", "viewdep, bending gauss_newton", None, 800, base + 9.0),
             ("nonadaptive", "nonadaptive", 1.0, 2500, base + 20.0),
             ("nonadaptive", "nonadaptive, bending gauss_newton", 1.0, 2500, base - 5.0),
             ("nonadaptive", "nonadaptive, 16 steps", 1.0, 2500, base - 8.0),
             ("nonadaptive", "nonadaptive, membrane gauss_newton", 1.0, 2500, base - 9.0))
    _mm_runs(tmp_path, cases, frames)
    for i, (_, variant, *_rest) in enumerate(cases):
        path = tmp_path / f"{i}" / "config.yaml"
        cfg = yaml.safe_load(path.read_text())
        if "gauss_newton" in variant:
            path.write_text(yaml.safe_dump({**cfg, "solver": {"bending_hessian": "gauss_newton"}}))
        if "membrane" in variant:
            path.write_text(yaml.safe_dump({**cfg, "solver": {"membrane_hessian": "gauss_newton"}}))
        if "16 steps" in variant:
            cfg["scene"].setdefault("params", {})["steps_per_frame"] = 16
            path.write_text(yaml.safe_dump(cfg))
    runs = load_runs([tmp_path]).runs
    assert sorted(runs["bending_hessian"]) == ["gauss_newton"] * 3 + ["projected"] * 5
    assert sorted(runs["membrane_hessian"]) == ["gauss_newton"] + ["projected"] * 7
    assert runs.set_index("variant").loc["nonadaptive, 16 steps", "steps_per_frame"] == 16
    t = integration_table(runs).set_index("variant")
    assert t.loc["adaptive, bending gauss_newton", ["lo_mm", "hi_mm"]].tolist() == pytest.approx([0.5, 0.5])
    assert not t.loc["adaptive, bending gauss_newton", "not_worse"]
    assert t.loc["viewdep, bending gauss_newton", "diff_mm"] == pytest.approx(-1.0)
    assert t.loc["viewdep, bending gauss_newton", "not_worse"]
    assert t.loc["nonadaptive, bending gauss_newton", ["base", "diff_mm"]].tolist() == ["nonadaptive", -25.0]
    assert t.loc["nonadaptive, 16 steps", ["option", "diff_mm"]].tolist() == ["16 steps", -28.0]
    membrane = t.loc["nonadaptive, membrane gauss_newton"]
    assert [membrane["option"], membrane["diff_mm"]] == ["membrane gauss_newton", -29.0]
    assert t["windows"].tolist() == [len(frames)] * 5
    assert equivalence_table(runs)["variant"].tolist() == ["nonadaptive"]  # neither other integration
