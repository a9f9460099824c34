"""The measurement tools (benchmark, mode comparison, collision cost, stability tables) run end
to end at a tiny size and write the tables they promise. Their figures are not asserted: they
are measurements for people, not tests, on machines that are shared and noisy."""

import json

import numpy as np
import pandas as pd
import pytest


def _only_child(path):
    (child,) = list(path.iterdir())
    return child


def test_benchmark_writes_time_per_step_by_phase(tmp_path):
    from experiments.benchmark import main
    page = tmp_path / "benchmark.md"
    main(["--resolutions", "4", "6", "--frames", "1", "--warmup", "1", "--out", str(tmp_path / "out"),
          "--report", str(page)])
    out = _only_child(tmp_path / "out")
    steps = pd.read_csv(out / "steps.csv")
    assert list(steps.faces) == [2 * 4 * 4, 2 * 6 * 6]
    for col in ("s_per_step", "physics_s_per_step", "solve_s_per_step", "collisions_s_per_step",
                "us_per_face_per_step", "share_outside_kernels_and_solver"):
        assert (steps[col] >= 0).all(), col
    assert (steps.share_outside_kernels_and_solver <= 1).all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["growth_exponent"] == pytest.approx(summary["growth_exponent"])  # finite, not NaN
    assert set(steps.solver) <= {"cholesky", "pcg"} and (steps.solves_capped == 0).all()
    from cloth.physics.linsolve import BENDING_HESSIAN_DEFAULT
    assert set(steps.bending_hessian) == {BENDING_HESSIAN_DEFAULT}  # the solver's default, as a run's
    text = page.read_text()  # --report: the per-face table, stamped with the code and the command
    from cloth.io.manifest import code_version
    assert code_version()["git_commit"] in text and "--resolutions 4 6" in text
    assert "| faces | bending_hessian | solver | sizing | remesh | physics | solve | collisions | all |" in text
    assert "| 32 |" in text and "| 72 |" in text


def test_benchmark_times_both_bending_hessians_on_the_same_sheet(tmp_path, capsys):
    from experiments.benchmark import main
    main(["--resolutions", "4", "--frames", "1", "--warmup", "1", "--bending-hessian", "both", "--out", str(tmp_path)])
    steps = pd.read_csv(_only_child(tmp_path) / "steps.csv")
    assert list(steps.bending_hessian) == ["projected", "gauss_newton"] and list(steps.faces) == [32, 32]
    assert "projected / gauss_newton: physics" in capsys.readouterr().out


# --modes matches the fixed mesh's faces to adaptive's mean through resolution_factor, which the
# preset's integer resolution rounds: within one cell per side of a 24-cell sheet (2 x 24^2 faces),
# a face count within about 2 x (1/24) + rounding of the target; 25 % covers the small counts here.
MATCHED_FACES = 0.25


def test_benchmark_modes_times_the_three_modes_per_face_and_phase(tmp_path):
    from experiments.benchmark import main
    main(["--modes", "--frames", "2", "--warmup", "3", "--out", str(tmp_path)])
    out = _only_child(tmp_path)
    modes = pd.read_csv(out / "modes.csv")
    assert list(modes["mode"]) == ["nonadaptive", "adaptive", "viewdep"]
    fixed, adaptive = modes.iloc[0], modes.iloc[1]
    assert abs(fixed.faces_mean - adaptive.faces_mean) <= MATCHED_FACES * adaptive.faces_mean
    from cloth.core.records import SIM_PHASES
    phases = [f"{p}_us_per_face_step" for p in SIM_PHASES]  # the collisions phase's parts are within it
    assert set(phases) <= set(modes.columns)
    # the phases add up to the whole (sim_s is their sum); the fixed mesh neither sizes nor remeshes
    assert np.allclose(modes[phases].sum(axis=1), modes["us_per_face_step"], rtol=1e-9)
    assert fixed.sizing_us_per_face_step == 0 and fixed.remesh_us_per_face_step == 0
    assert adaptive.remesh_us_per_face_step > 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["adaptive_over_fixed_frame_time"] == pytest.approx(adaptive.s_per_frame / fixed.s_per_frame)
    assert summary["scale"] == "small"
    with pytest.raises(SystemExit):
        main(["--modes", "--scene", "no_such_scene", "--out", str(tmp_path / "bad")])
    with pytest.raises(SystemExit):  # argparse names the choices
        main(["--modes", "--scale", "huge", "--out", str(tmp_path / "bad")])


def test_compare_modes_tabulates_the_three_modes(tmp_path):
    from experiments.compare_modes import main
    main(["--scenes", "sheet_on_sphere", "--frames", "3", "--out", str(tmp_path)])
    table = pd.read_csv(_only_child(tmp_path) / "table.csv")
    assert sorted(table["mode"]) == ["adaptive", "nonadaptive", "viewdep"]
    assert (table.filter(like="faces").to_numpy() > 0).all()


def test_stability_tool_writes_csv_and_markdown(tmp_path):
    from experiments.stability import main
    report = tmp_path / "report.md"
    main(["--scale", "small", "--frames", "2", "--seeds", "2", "--cases", "one_frame_step",
          "--out", str(tmp_path / "out"), "--report", str(report)])
    tmp_path = tmp_path / "out"
    text = report.read_text()
    assert "commit" in text and "## Per case and seed" in text and "Partial" not in text
    ran = pd.read_csv(report.with_suffix(".csv"))["commit"].iloc[0]
    assert f"Every run at commit {ran}." in text  # the code the runs ran, not only the code that wrote it
    out = _only_child(tmp_path)
    table = pd.read_csv(out / "table.csv")
    assert list(table["case"]) == ["one_frame_step"] * 2 and list(table["seed"]) == [0, 1] and table["ok"].all()
    assert "one_frame_step" in (out / "table.md").read_text()
    cases = (out / "cases.md").read_text()
    assert "seeds 0-1" in cases and "| one_frame_step | 2 | 2 |" in cases  # seeds run, seeds passed


def test_stability_set_adds_overrides_to_every_case_and_keys_resumed_runs(tmp_path, monkeypatch, capsys):
    """--set solver.bending_hessian=projected reaches every case's simulation and its rows ("set");
    a table of runs without it is not resumed as theirs; a bad override is refused before any run."""
    from experiments import stability

    built = []
    real = stability.build_simulation

    def spy(cfg, **kw):
        built.append(cfg.solver.bending_hessian)
        return real(cfg, **kw)

    monkeypatch.setattr(stability, "build_simulation", spy)
    common = ["--scale", "small", "--frames", "1", "--seeds", "1", "--cases", "one_frame_step"]
    stability.main(common + ["--out", str(tmp_path / "plain")])
    plain = _only_child(tmp_path / "plain") / "table.csv"
    stability.main(common + ["--out", str(tmp_path / "gn"), "--set", "solver.bending_hessian=projected",
                             "--resume", str(plain)])
    assert built == ["gauss_newton", "projected"]  # the plain run was not taken for the other's
    table = pd.read_csv(_only_child(tmp_path / "gn") / "table.csv", keep_default_na=False)
    assert table["set"].tolist() == ["solver.bending_hessian=projected"] and table["ok"].all()
    for bad in (["solver.no_such_key=1"], ["solver.bending_hessian"]):
        with pytest.raises(SystemExit):
            stability.main(common + ["--out", str(tmp_path / "bad"), "--set", *bad])
        assert "--set" in capsys.readouterr().err
    assert len(built) == 2 and not (tmp_path / "bad").exists()


def test_benchmark_times_a_scene_by_phase_and_collision_part(tmp_path, capsys):
    from experiments.benchmark import main
    main(["--scene", "layered_sheets", "--frames", "2", "--warmup", "1", "--out", str(tmp_path),
          "scene.scales.small.resolution=6"])
    row = pd.read_csv(_only_child(tmp_path) / "scene.csv").iloc[0]
    parts = ["contacts", "projection", "pass", "untangle"]
    assert row["collisions_us_per_face_step"] == pytest.approx(
        sum(row[f"collisions_{p}_us_per_face_step"] for p in parts), rel=1e-9)
    assert row["steps_per_frame"] >= row["scene_steps_per_frame"] >= 1 and row["faces_mean"] > 0
    out = capsys.readouterr().out
    assert "microseconds per face per step" in out and "untangle" in out
    with pytest.raises(SystemExit):
        main(["--scene", str(tmp_path / "nowhere.json")])
    assert "no such ARCSim configuration" in capsys.readouterr().err


def test_benchmark_against_refuses_an_unknown_revision_before_any_work(tmp_path, capsys):
    from experiments.benchmark import main
    with pytest.raises(SystemExit) as stop:
        main(["--against", "no-such-revision-0123", "--out", str(tmp_path / "out")])
    assert stop.value.code == 2 and "--against 'no-such-revision-0123': not a commit" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    with pytest.raises(SystemExit):
        main(["--against", "HEAD", "--modes", "--out", str(tmp_path / "out")])
    assert "with the sheet or the scene benchmark" in capsys.readouterr().err


def test_benchmark_against_exports_a_tree_that_imports_its_own_package(tmp_path):
    """The compared commit runs from its own files, not from this checkout's installed package."""
    from experiments.benchmark import export_revision, resolve_revision
    commit = resolve_revision("HEAD")
    src = export_revision(commit, tmp_path / "rev")
    assert (src / "cloth" / "simulation.py").is_file() and (src / "experiments" / "benchmark.py").is_file()
    assert len(commit) == 40


def test_benchmark_against_row_is_the_previous_time_over_this_trees():
    from experiments.benchmark import against_row
    rev = {"faces": 32, "s_per_step": 0.3, "physics_s_per_step": 0.2, "solve_s_per_step": 0.1}
    head = {"resolution": 4, "faces": 32, "s_per_step": 0.1, "physics_s_per_step": 0.05, "solve_s_per_step": 0.05,
            "remesh_s_per_step": 0.0}
    row = against_row(rev, head)
    assert row["speedup"] == pytest.approx(3.0) and row["physics_speedup"] == pytest.approx(4.0)
    assert row["solve_speedup"] == pytest.approx(2.0)
    assert "remesh_speedup" not in row  # a phase the previous commit does not record is not compared


def test_benchmark_scene_against_a_revision_writes_its_ratios(tmp_path, monkeypatch, capsys):
    """--scene with --against: REV's scene benchmark (its own code in a subprocess, stubbed here) and
    this tree's on the same scene; against.csv holds REV's microseconds per face per step over this
    tree's, per phase and collision part."""
    from cloth.core.records import COLLISION_PARTS, SIM_PHASES
    from experiments import benchmark
    head = {"scene": "layered_sheets", "mode": "adaptive", "faces_mean": 72.0, "steps_per_frame": 8.0,
            "s_per_frame": 0.1, "scene_steps_per_frame": 8, "steps_per_frame_max": 8, "collision_share": 0.5,
            **{f"{p}_us_per_face_step": 1.0 for p in SIM_PHASES},
            **{f"collisions_{p}_us_per_face_step": 1.0 for p in COLLISION_PARTS},
            "us_per_face_step": 10.0, "physics_us_per_face_step": 4.0, "collisions_us_per_face_step": 5.0,
            "collisions_pass_us_per_face_step": 4.0, "collisions_untangle_us_per_face_step": 0.0}
    seen = {}

    def rev_bench(src, args, out):
        seen["exported"] = (src / "cloth" / "simulation.py").is_file()  # REV's own tree, while it exists
        seen["args"] = (args.scene, args.mode, args.frames, args.warmup)
        return {**head, "s_per_frame": 0.3, "us_per_face_step": 30.0, "physics_us_per_face_step": 4.0,
                "collisions_us_per_face_step": 20.0, "collisions_pass_us_per_face_step": 16.0}

    monkeypatch.setattr(benchmark, "bench_scene_revision", rev_bench)
    monkeypatch.setattr(benchmark, "bench_scene", lambda *a, **k: dict(head))
    benchmark.main(["--scene", "layered_sheets", "--frames", "2", "--warmup", "1", "--against", "HEAD",
                    "--out", str(tmp_path)])
    assert seen["exported"] and seen["args"] == ("layered_sheets", "adaptive", 2, 1)
    row = pd.read_csv(_only_child(tmp_path) / "against.csv").iloc[0]
    assert row["speedup"] == pytest.approx(3.0) and row["physics_speedup"] == pytest.approx(1.0)
    assert row["collisions_pass_speedup"] == pytest.approx(4.0)
    assert "collisions_untangle_speedup" not in row.index  # nothing to divide by: not compared
    assert "HEAD / this tree, per face per step" in capsys.readouterr().out


def test_a_killed_stability_run_continues_from_its_checkpoint(tmp_path, monkeypatch):
    """A run stopped after its checkpoint of frame 2 (as a kill would) leaves it; the next suite
    continues from it and ends with the figures of a run never stopped, and no checkpoint left."""
    from experiments import stability
    c, frames = stability.case("one_frame_step"), 4
    whole = stability.run_case(c, frames, "small", seed=1)
    save = stability.save_checkpoint

    def save_then_stop(run_dir, sim, rows):
        save(run_dir, sim, rows)
        if sim.frame == 2:
            raise KeyboardInterrupt  # not an Exception: run_case does not catch it, as with a kill

    folder = stability.checkpoint_dir(tmp_path, c, "small", 1, frames)
    monkeypatch.setattr(stability, "save_checkpoint", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        stability.run_case(c, frames, "small", seed=1, checkpoints=folder, checkpoint_wall_s=0.0)
    monkeypatch.setattr(stability, "save_checkpoint", save)
    assert (folder / "checkpoint" / "state.pkl").is_file()
    resumed = stability.run_case(c, frames, "small", seed=1, checkpoints=folder, checkpoint_wall_s=0.0)
    assert resumed["resumed_at_frame"] == 2 and whole["resumed_at_frame"] == 0
    assert resumed["checkpoint_commit"]
    for key in ("ok", "frames_run", "max_kinetic_energy_j", "min_face_quality", "faces_max", "crossings_at_end",
                "steps_rejected"):
        assert resumed[key] == whole[key], key  # bit for bit: the checkpoint holds the whole state
    assert not (tmp_path / "checkpoints").exists()  # removed, with its folders, when the run ended


def test_collision_cost_tabulates_the_share_of_collisions(tmp_path):
    from experiments.collision_cost import main
    main(["--frames", "2", "--resolutions", "6", "10", "--dancer-frames", "2", "--out", str(tmp_path)])
    table = pd.read_csv(_only_child(tmp_path) / "table.csv")
    assert len(table) == 2 + 3  # two crushed-sheet resolutions, adaptive, the dancer twice
    assert ((table.collision_share >= 0) & (table.collision_share <= 1)).all()
    assert table.collision_time_exponent.notna().sum() == 1


needs_cholesky = pytest.mark.skipif(
    __import__("cloth.physics.linsolve", fromlist=["x"]).cholesky_available() is not None,
    reason="the crossover compares the factorization with PCG: pypardiso (x86_64) only")


@needs_cholesky
def test_solver_crossover_times_both_methods_on_every_solve_and_keeps_the_runs_own(tmp_path, capsys):
    """Every system of the run solved by both methods; the page and tables written."""
    from cloth.physics import integrator, linsolve
    from experiments.solver_crossover import main

    page = tmp_path / "crossover.md"
    main(["--frames", "2", "--out", str(tmp_path / "out"), "--report", str(page),
          "--scene", "layered_sheets", "scene.scales.small.resolution=6"])  # the override after --scene's names
    assert integrator.solve is linsolve.solve  # the stand-in is gone after the run
    out_dir = _only_child(tmp_path / "out")
    solves = pd.read_csv(out_dir / "solves.csv")
    assert len(solves) > 0 and (solves[["pcg_ms", "cholesky_ms"]] > 0).all().all()
    assert solves["new_pattern"].iloc[0]  # the first solve analyses the pattern
    summary = json.loads((out_dir / "summary.json").read_text())
    (scene,) = summary["scenes"]
    totals = pd.DataFrame(scene["totals"])
    assert summary["current_threshold"] == linsolve.AUTO_CHOLESKY_UNKNOWNS and scene["scene"] == "layered_sheets"
    assert totals["solve_s"].min() == pytest.approx(
        totals.loc[totals["threshold"] == scene["best_threshold"], "solve_s"].iloc[0])
    assert "layered_sheets: total solve time by threshold" in page.read_text()
    assert "fastest threshold" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--scene", "layered_sheets", "nowhere"])
    assert "no conf/scene/nowhere.yaml" in capsys.readouterr().err


def test_solver_crossover_totals_follow_the_threshold():
    """Hand-made solves: below the threshold PCG's time counts, from it up the factorization's."""
    from experiments.solver_crossover import band_table, threshold_totals

    df = pd.DataFrame({"unknowns": [100, 400, 2000], "pcg_ms": [1.0, 4.0, 20.0],
                       "cholesky_ms": [3.0, 2.0, 5.0]})
    totals = threshold_totals(df).set_index("threshold")["solve_s"]
    assert totals[0] == pytest.approx(1e-3 * (3 + 2 + 5))
    assert totals[150] == pytest.approx(1e-3 * (1 + 2 + 5))  # the best: PCG below 150 only
    assert totals[2001] == pytest.approx(1e-3 * (1 + 4 + 20))
    bands = band_table(df).set_index("unknowns")
    assert bands.loc["0-150", "pcg_over_cholesky"] == pytest.approx(1 / 3) and bands["solves"].sum() == 3


def test_solver_crossover_hands_the_run_its_own_methods_solution():
    from cloth.physics.linsolve import SolverOptions
    from experiments.solver_crossover import SolveTimer

    class Pattern:
        pass

    timer = SolveTimer(lambda pattern, data, b, options, x0=None: (options.method, 7, 0.0))
    b = np.zeros((4, 3))
    assert timer(Pattern(), None, b, SolverOptions("pcg"))[0] == "pcg"
    assert timer(Pattern(), None, b, SolverOptions("cholesky"))[0] == "cholesky"
    assert len(timer.rows) == 2 and timer.rows[0]["unknowns"] == 12 and timer.rows[0]["pcg_iterations"] == 7
