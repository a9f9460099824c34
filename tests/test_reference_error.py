"""The reference's own error (experiments.callbacks.reference_error): the reference restarted from
a reference twice as fine and from one with half the time step, and from its own states moved by
0.1 mm (the floor), on the study's windows; the runs table carries it on the reference's row, and
the Pareto table ranks no two points closer than RANK_FACTOR times it."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from helpers import QUIET, run_config

from experiments.analysis.runs import load_runs
from experiments.analysis.sync import perturbed
from experiments.callbacks import FLOOR_PERTURBATION_M, measure_accuracy
from paper_figures.pareto import RANK_FACTOR, equal_quality_fixed, pareto_front, reference_error

TINY = ["scene=sheet_on_sphere", "camera=sheet_half", "frames=4", "output.states_every=1",
        "scene.scales.small.reference.resolution=8", *QUIET]
SYNC = {"every": 2, "horizon": 2, "before_cut": 5, "resolution_scale": 0.25, "reference": False,
        "restart": "own_mesh", "per_frame": False}
ROUNDOFF_M = 1e-12  # a displacement's length after normalising a random direction: a few ulps


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A made-up accuracy study: the reference, its two checks and a coarse fixed mesh, measured."""
    base = tmp_path_factory.mktemp("study")
    runs = {"0_ref": ["reference=true", "variant=reference"],
            "1_fine": ["reference=true", "reference_check=fine"],
            "2_half_dt": ["reference=true", "reference_check=half_dt"],
            "3_fixed": ["mode=nonadaptive", "scene.scales.small.resolution=6"]}
    for name, extra in runs.items():
        run_config(base / name, *TINY, *extra)
    log = []
    measure_accuracy(base, log=log.append, sync=SYNC)
    return base, log


def test_a_perturbed_state_moves_every_free_node_by_the_distance_and_no_pinned_one():
    rng = np.random.default_rng(0)
    state = {"node_x": rng.normal(size=(50, 3)), "node_pinned": np.arange(50) % 7 == 0, "frame": 3}
    moved = perturbed(state, 1e-4, seed=5)
    d = np.linalg.norm(moved["node_x"] - state["node_x"], axis=1)
    assert np.all(d[state["node_pinned"]] == 0)
    assert np.allclose(d[~state["node_pinned"]], 1e-4, rtol=0, atol=ROUNDOFF_M)
    assert np.array_equal(perturbed(state, 1e-4, seed=5)["node_x"], moved["node_x"])  # seeded
    assert moved["frame"] == 3 and state["node_x"] is not moved["node_x"]


def test_the_reference_is_measured_against_its_checks_and_its_floor(study):
    base, log = study
    ref = base / "0_ref"
    for stem in ("sync_fine", "sync_half_dt", "sync_floor"):
        s = json.loads((ref / f"{stem}.json").read_text())
        assert s["windows"] == 2 and np.isfinite(s["sync_error_px_mean"]), stem
    # the floor starts FLOOR_PERTURBATION_M off the reference: a small error at h = 0, not none
    h0 = pd.read_parquet(ref / "sync_floor.parquet")["sync_error_h0_mm"]
    assert np.all(h0 > 0) and np.all(h0 <= 2 * FLOOR_PERTURBATION_M * 1e3)
    fine = json.loads((ref / "sync_fine.json").read_text())
    assert fine["sync_error_px_mean"] > 0 and fine["reference"].endswith("1_fine")
    # the checks are neither members of the reference ensemble nor measured as points
    assert not (base / "1_fine" / "accuracy.json").exists() and not (base / "2_half_dt" / "sync.json").exists()
    assert (base / "3_fixed" / "sync.json").exists()
    assert any("its own error: fine" in line for line in log)


def test_the_runs_table_and_the_pareto_table_carry_the_references_own_error(study):
    base, _ = study
    runs = load_runs([base]).runs
    ref = runs[runs["run"].str.endswith("0_ref")].iloc[0]
    assert np.isfinite(ref["reference_error_fine_px"]) and np.isfinite(ref["reference_floor_px"])
    assert set(runs["reference_check"]) == {"", "fine", "half_dt"}
    own, floor = reference_error(runs, "sheet_on_sphere", "small")
    assert own == max(ref["reference_error_fine_px"], ref["reference_error_half_dt_px"]) and floor > 0


def test_points_closer_than_the_references_own_error_are_not_ranked():
    # b is slower than a and better by 1 px, told apart by its interval; with the reference's own
    # error at 0.5 px, 1 px < RANK_FACTOR x 0.5 px: b is no longer on the front
    t, e, lo, hi = [1.0, 2.0], [10.0, 9.0], [9.8, 8.8], [10.2, 9.2]
    assert pareto_front(t, e, lo, hi).tolist() == [True, True]
    assert pareto_front(t, e, lo, hi, min_difference=RANK_FACTOR * 0.5).tolist() == [True, False]
    assert pareto_front(t, e, lo, hi, min_difference=RANK_FACTOR * 0.3).tolist() == [True, True]
    # a fixed mesh 1 px worse than adaptive, told apart by intervals, is of equal quality when the
    # reference cannot rank 1 px
    g = pd.DataFrame({"mode": ["adaptive", "nonadaptive"], "variant": ["", "fixed x1"], "run": ["a", "f"],
                      "faces_mean": [100.0, 80.0]})
    err, lo_s, hi_s = pd.Series([9.0, 10.0]), pd.Series([8.8, 9.8]), pd.Series([9.2, 10.2])
    assert equal_quality_fixed(g, "error_px", err, lo_s, hi_s) is None
    assert equal_quality_fixed(g, "error_px", err, lo_s, hi_s, min_difference=RANK_FACTOR * 0.5) == "f"


def test_a_study_measured_again_skips_the_windows_it_has_measured(study):
    """The callback run again on the same folders (experiments.paper continued in its --out) does
    not simulate a run's windows again while its sync.json is newer than the run and its
    reference and has the same options; a run finished since is measured again."""
    import os

    from experiments.callbacks import measured_already

    base, _ = study
    run, ref = base / "3_fixed", base / "0_ref"
    opts = {k: v for k, v in SYNC.items() if k not in ("reference", "members")}
    assert measured_already(run, ref, opts)
    assert not measured_already(run, ref, {**opts, "horizon": 3})  # other options
    assert not measured_already(run, base / "1_fine", opts)  # another reference
    log = []
    measure_accuracy(base, log=log.append, sync=SYNC)
    assert any("3_fixed measured already" in line for line in log)
    finished = (run / "summary.json").stat()
    later = (run / "sync.json").stat().st_mtime_ns + 10**9
    os.utime(run / "summary.json", ns=(later, later))  # the run finished after its measurement
    try:
        assert not measured_already(run, ref, opts)
    finally:  # the module's study as it was
        os.utime(run / "summary.json", ns=(finished.st_atime_ns, finished.st_mtime_ns))


def test_a_window_seen_from_a_further_view_is_measured_as_from_the_runs_camera(study):
    """sync.views: the window's end measured from further cameras as well (several cameras, beyond
    the paper), and sync.perceptual: FLIP there. From the run's own camera (sheet_half) it is the
    run's own error; from the sheet's other half (sheet_cut's second shot, as a camera config)
    another one."""
    from experiments.analysis.sync import evaluate_run, summarize, view_columns

    base, _ = study
    opts = {k: v for k, v in SYNC.items() if k not in ("reference", "members")}
    other = {"name": "minus", "position": [-0.3, 0.0, 1.5], "target": [-0.3, 0.0, 0.0], "up": [-1.0, 0.0, 0.0],
             "fov_y_deg": 22.6}
    table = evaluate_run(base / "3_fixed", base / "0_ref", **opts, views=["sheet_half", other], perceptual=True)
    same_px, same_mm = view_columns("sheet_half")
    assert np.allclose(table[same_px], table["sync_error_px"]) and np.allclose(table[same_mm], table["sync_error_mm"])
    minus_px, _ = view_columns("minus")
    assert np.all(np.isfinite(table[minus_px])) and not np.allclose(table[minus_px], table["sync_error_px"])
    s = summarize(table, base / "0_ref", opts["every"], opts["horizon"], opts["before_cut"], opts["resolution_scale"])
    assert s["sync_error_px_view_sheet_half_mean"] == pytest.approx(s["sync_error_px_mean"])
    # and the perceptual error (sync.perceptual): FLIP between shaded renders at each window's end
    assert np.all((table["flip"] > 0) & (table["flip"] < 1)) and s["flip_mean"] == pytest.approx(table["flip"].mean())
