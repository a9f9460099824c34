"""Studies (conf/experiment/*) and where their runs go (conf/cluster/*).

Checks: every preset's every point composes and passes the run's own validation (so a study
never fails on its 7th run for a typo); a multirun goes through the default joblib launcher,
the submitit launcher (local mode: the SLURM code path without a scheduler) and the Ray
launcher against a local Ray instance; a study ends with its callback, which measures every run
against the reference run and aggregates the folders into tables.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pandas as pd
import pytest
import yaml
from helpers import ROOT, compose_config, config_choices, run_module

from experiments.launch import threads_per_run

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

EXPERIMENTS = config_choices("experiment")
# A tiny multirun: 2 frames of the sheet dropped on a sphere, no recording.
TINY = ["scene=sheet_on_sphere", "frames=2", "output.rerun=false", "output.progress=false"]


REPEATS_SWEEP = "range(0,${repeats})"  # every preset's seed sweep: repeats=N runs each point with seeds 0 .. N-1


def _sweep(experiment: str) -> dict:
    """The preset's swept keys and values (with what its _base sweeps), but its seeds
    (REPEATS_SWEEP, checked on its own)."""
    from omegaconf import OmegaConf

    cfg = compose_config(f"experiment={experiment}", return_hydra_config=True)
    params = OmegaConf.to_container(cfg.hydra.sweeper.params, resolve=False)
    assert params.get("seed") == REPEATS_SWEEP, f"{experiment}: the seeds come from `repeats`"
    return {k: [v.strip() for v in str(vals).split(",")] for k, vals in params.items() if k != "seed"}


def _runs(experiment: str) -> list[list[str]]:
    """Every run of a preset as a list of overrides (the grid the basic sweeper makes)."""
    grid = [[]]
    preset = yaml.safe_load((ROOT / "conf" / "experiment" / f"{experiment}.yaml").read_text())
    for key, values in _sweep(experiment).items():
        if values == ["${points}"]:  # its points list (table1's with its baseline)
            values = preset["points"].replace("${baseline}", str(preset.get("baseline"))).split(",")
        grid = [g + [f"{key}={v}"] for g in grid for v in values]
    return [[f"+experiment={experiment}"] + g for g in grid]


def test_presets_are_the_issue_s_studies():
    assert set(EXPERIMENTS) >= {"table1", "sweep_nu_out", "sweep_k", "sweep_T", "sweep_margin",
                                "ablation_buckling", "ablation_anticipation", "accuracy"}
    assert _sweep("table1") == {"scene": ["karate", "solo_dancer", "multiple_dancers"], "+point": ["${points}"]}
    # the non-adaptive row: the preset's fixed mesh unless the main job names the equal-quality one
    cfg = compose_config("+experiment=table1")
    assert cfg.baseline == "nonadaptive" and cfg.points == "nonadaptive,adaptive,viewdep,viewdep_nofloor"


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_name_and_the_older_plus_form_are_one_multirun(experiment):
    """`experiment=NAME` picks the preset from conf/config.yaml's defaults and is a multirun by
    itself (its _base); `+experiment=NAME`, the form before, is rewritten to it by the command
    line (experiments.checks.plain_experiment), since Hydra refuses to append a listed group."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from experiments.checks import plain_experiment

    assert plain_experiment([f"+experiment={experiment}", f"++experiment={experiment}", "+point=x"]) == \
        [f"experiment={experiment}", f"experiment={experiment}", "+point=x"]
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"experiment={experiment}"], return_hydra_config=True)
        with pytest.raises(Exception, match="experiment"):  # what plain_experiment spares the user
            compose(config_name="config", overrides=[f"+experiment={experiment}"])
    assert str(cfg.hydra.mode) == "RunMode.MULTIRUN" and cfg.study is not None
    assert cfg.hydra.callbacks.study._target_ == "experiments.callbacks.StudyCallback"
    assert OmegaConf.to_container(cfg.hydra.sweeper.params, resolve=False)["seed"] == REPEATS_SWEEP
    assert not cfg.output.progress and not cfg.output.rerun
    assert yaml.safe_load((ROOT / "conf" / "experiment" / f"{experiment}.yaml").read_text())["defaults"][0] == "_base"
    plus = compose_config(f"+experiment={experiment}")  # the helper takes the older form as the command line does
    assert OmegaConf.to_container(plus) == OmegaConf.to_container(compose_config(f"experiment={experiment}"))


def test_accuracy_study_has_a_reference_ensemble_and_its_checks_and_the_anticipation_ablation_its_cut():
    """The main job's accuracy study: a reference ensemble of five members (the issue's "at least
    5 seeds"), the reference's two checks (twice as fine, half the time step), the fixed mesh at
    four resolutions; the anticipation window is swept by the anticipation ablation, on its cut
    into coarse cloth, over five seeds."""
    cfgs = [compose_config(*run) for run in _runs("accuracy")]
    refs = [c for c in cfgs if c.reference and c.reference_check is None]
    assert sorted(c.reference_member for c in refs) == [0, 1, 2, 3, 4]
    assert sorted(c.reference_check for c in cfgs if c.reference_check is not None) == ["fine", "half_dt"]
    assert len({c.resolution_factor for c in cfgs if c.mode.name == "nonadaptive" and not c.reference}) >= 4
    assert all(c.frames == 70 for c in cfgs)
    cfgs = [compose_config(*run) for run in _runs("ablation_anticipation")]
    leads = {(c.mode.view.anticipation, c.mode.view.anticipation_frames) for c in cfgs if c.mode.name == "viewdep"}
    assert leads == {(False, 5.0), (True, 0.0), (True, 2.0), (True, 5.0), (True, 10.0)}
    cut_to_hem = compose_config("scene=solo_dancer", "camera=dancer_cut_to_hem").camera
    assert all(c.camera == cut_to_hem for c in cfgs)
    assert compose_config("+experiment=ablation_anticipation").repeats == 5  # seeds 0-4 (the sweeper's seed axis)


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_a_preset_that_measures_accuracy_against_a_reference_saves_states(experiment):
    """The study callback measures every run against the sweep's reference from the runs' states
    (experiments.accuracy): a preset with a reference point and the callback's accuracy on must
    save them, or the callback fails at the end of the study (the dancer's buckling ablation did,
    in the main job)."""
    preset = yaml.safe_load((ROOT / "conf" / "experiment" / f"{experiment}.yaml").read_text())
    study = compose_config(f"experiment={experiment}", return_hydra_config=True).hydra.callbacks.study
    accuracy = study.get("accuracy", True)
    has_reference = any("reference" in values for values in _sweep(experiment).values())
    if experiment == "table1":  # its points come from the accuracy study's baseline, no reference
        assert not any("reference" in p for p in preset["points"].split(","))
    if accuracy and has_reference:  # every run: the reference and each run measured against it
        assert all(compose_config(*run).output.states_every >= 1 for run in _runs(experiment))


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_repeats_sweep_the_seeds_one_run_at_a_time(experiment):
    """`repeats=N` makes the sweeper run every point with seeds 0 .. N-1 (3 for Table 1 and both
    buckling ablations and the cameras and live-camera studies, 5 for the anticipation ablation, 1 for
    the others by default), and the
    local launcher runs one run at a time."""
    default = {"table1": 3, "ablation_anticipation": 5, "ablation_buckling": 3,
               "ablation_buckling_dancer": 3, "live_camera": 3, "cameras": 3}.get(experiment, 1)
    for extra, n in (((), default), (("repeats=5",), 5)):
        cfg = compose_config(f"+experiment={experiment}", *extra, return_hydra_config=True)
        assert cfg.repeats == n and cfg.hydra.sweeper.params.seed == f"range(0,{n})"
        assert cfg.hydra.launcher.n_jobs == 1


def test_table1_has_the_view_dependent_mode_without_the_contact_floor():
    floor = compose_config("scene=solo_dancer", "+point=viewdep")
    paper = compose_config("scene=solo_dancer", "+point=viewdep_nofloor")
    assert floor.mode.view.contact_size == 0.2 and paper.mode.view.contact_size is None
    assert paper.variant == "viewdep_nofloor" and paper.mode.name == "viewdep"
    strip = ("contact_size", "variant")
    assert {k: v for k, v in paper.mode.view.items() if k not in strip} == \
        {k: v for k, v in floor.mode.view.items() if k not in strip}



@pytest.mark.parametrize(("scene", "floor"), [("solo_dancer", 0.2), ("karate", 0.075)])
def test_a_scenes_own_contact_floor_holds_in_viewdep_and_is_off_without_the_floor(scene, floor):
    """karate's scene.view.contact_size wins over the mode's; +point=viewdep_nofloor turns both off
    (before, a scene's own floor silently overrode the point's null)."""
    from experiments.build import build_simulation

    built = {point: build_simulation(compose_config(f"scene={scene}", f"+point={point}", "scale=small"))[0]
             for point in ("viewdep", "viewdep_nofloor")}
    assert built["viewdep"].remesher.view.contact_size == floor
    assert built["viewdep_nofloor"].remesher.view.contact_size is None

@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_point_of_every_preset_validates(experiment):
    from experiments.build import build_simulation, crowd_size

    seen = set()
    for overrides in _runs(experiment):
        for scale in ("small", "paper"):
            cfg = compose_config(*overrides, f"scale={scale}")
            assert cfg.study == experiment
            assert cfg.variant, f"{overrides}: every point names its variant"
            point = overrides[-1].split("=", 1)[1]
            if point != "reference" and not point.startswith(("member/", "reference_check/")):
                assert not cfg.reference
            else:  # the reference, the members of its ensemble and its checks
                assert cfg.reference and cfg.mode.name == "nonadaptive"
            key = (cfg.scene.name, point, scale)
            if scale == "paper" or key in seen:  # building paper-scale meshes is slow; small checks every key
                continue
            seen.add(key)
            crowd_size(cfg)
            build_simulation(cfg, character=0 if cfg.scene.name == "multiple_dancers" else None)


# Frames of every distinct run of every preset in the slow check below: enough for a remesh, the
# view-dependent sizing and a step of each stage the run declares.
PRESET_FRAMES = 2


@pytest.mark.slow
@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_preset_runs(experiment):
    """Every distinct point of every preset (scene and point, at scale=small, seed 0) simulates
    PRESET_FRAMES frames: finite, the frames counted, no step control giving up (a crowd runs its
    first character, as a crowd run does for each)."""
    import numpy as np

    from experiments.build import build_simulation

    seen = set()
    for overrides in _runs(experiment):
        cfg = compose_config(*overrides, "scale=small")
        key = (cfg.scene.name, overrides[-1])
        if key in seen:
            continue
        seen.add(key)
        sim = build_simulation(cfg, character=0 if cfg.scene.name == "multiple_dancers" else None)[0]
        for _ in range(PRESET_FRAMES):
            record = sim.advance_frame()
        assert sim.frame == PRESET_FRAMES and np.isfinite(sim.mesh.node_x).all(), key
        assert record["faces"] > 0 and np.isfinite(record["kinetic_energy_j"]), key


def test_sweep_points_set_what_they_name():
    def cfg(point):
        return compose_config("scene=solo_dancer", f"+point={point}")
    assert cfg("nu_out/0.001").mode.view.nu_out == 0.001
    assert cfg("k/50").mode.buckling.k == 50
    assert cfg("T/0").mode.view.anticipation_frames == 0
    assert cfg("margin/0.8").mode.view.margin == 0.8
    assert cfg("buckling/none").mode.buckling is None
    assert cfg("buckling/uniform").mode.buckling.mode == "uniform"
    assert cfg("anticipation/off").mode.view.anticipation is False
    assert cfg("adaptive").mode.name == "adaptive"
    ref = cfg("reference")
    assert ref.reference and ref.mode.name == "nonadaptive"


def _multirun(tmp_path: Path, *overrides: str, env=None, timeout=600) -> Path:
    sweep = tmp_path / "sweep"
    # RAY_ADDRESS unset: a Ray run here starts its own local instance
    proc = run_module("experiments.run", "-m", *TINY, *overrides, f"hydra.sweep.dir={sweep}",
                      env={**(env or {}), "RAY_ADDRESS": None}, timeout=timeout)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return sweep


def _completed(sweep: Path) -> list[Path]:
    runs = sorted(p for p in sweep.iterdir() if (p / "summary.json").exists())
    return [r for r in runs if json.loads((r / "summary.json").read_text())["status"] == "completed"]


def test_joblib_multirun_with_study_callback_measures_and_aggregates(tmp_path):
    """The default launcher runs a 3-run study (reference, adaptive, viewdep) in 2 processes; its
    callback writes accuracy and the re-synchronised error against the reference, and the study's
    tables."""
    sweep = _multirun(tmp_path, "camera=sheet_half", "+point=reference,adaptive,viewdep", "study=tiny",
                      "hydra.launcher.n_jobs=2",  # two at once: each with half of the cores
                      "output.states_every=1",  # a study that measures accuracy asks for the states
                      "+hydra.callbacks.study._target_=experiments.callbacks.StudyCallback",
                      "+hydra.callbacks.study.sync={every: 1, horizon: 1, resolution_scale: 0.25}")
    runs = _completed(sweep)
    assert len(runs) == 3
    cfgs = [yaml.safe_load((r / "config.yaml").read_text()) for r in runs]
    assert sorted(c["variant"] for c in cfgs) == ["adaptive", "reference", "viewdep"]
    for r, c in zip(runs, cfgs):
        acc = r / "accuracy.json"
        assert acc.exists() != bool(c["reference"]), f"{r.name}: accuracy against the reference, except the reference"
        if acc.exists():
            assert json.loads(acc.read_text())["frames"] >= 2
        sync = json.loads((r / "sync.json").read_text())  # the reference too: its restart measured
        assert sync["windows"] >= 2 and sync["horizon"] == 1
        if c["reference"]:
            assert sync["sync_error_px_mean"] < 1e-3  # restarted from its own states: its own continuation
    from experiments.analysis.aggregate import load_runs
    loaded = load_runs([sweep])
    assert len(loaded.runs) == 3 and not loaded.problems
    assert (sweep / "figures").is_dir() and any((sweep / "figures").iterdir())
    threads = {json.loads((r / "manifest.json").read_text())["numba_threads"] for r in runs}
    assert threads == {threads_per_run(os.cpu_count(), 2)}


def test_a_study_callback_with_unknown_sync_options_is_refused():
    from experiments.callbacks import StudyCallback

    assert StudyCallback(sync={"horizon": 4}).sync["every"] == 10  # the defaults for what is not given
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['horizn'\]"):
        StudyCallback(sync={"horizn": 4})
    with pytest.raises(ValueError, match="--horizon must be an integer >= 1"):
        StudyCallback(sync={"horizon": 0})
    assert StudyCallback(sync={"per_frame": True}).sync["per_frame"] is True
    with pytest.raises(ValueError, match="sync.per_frame: true or false"):
        StudyCallback(sync={"per_frame": "yes"})
    assert StudyCallback(sync={}).sync["members"] == 1 and StudyCallback(sync={"members": 5}).sync["members"] == 5
    with pytest.raises(ValueError, match="sync.members: an integer >= 1"):
        StudyCallback(sync={"members": 0})


def test_submitit_local_launcher(tmp_path):
    """cluster=slurm_local: the submitit launcher's code path (pickled jobs, results collected)."""
    sweep = _multirun(tmp_path, "cluster=slurm_local", "seed=0,1")
    assert len(_completed(sweep)) == 2


def test_slurm_preset_selects_the_submitit_slurm_launcher():
    cfg = compose_config("cluster=slurm", return_hydra_config=True)
    assert "SlurmLauncher" in cfg.hydra.launcher._target_
    assert cfg.hydra.launcher.cpus_per_task >= 1


def test_ray_launcher_on_a_local_ray_instance(tmp_path):
    sweep = _multirun(tmp_path, "cluster=ray", "seed=0,1", env={"RAY_NUM_CPUS": "2"})
    assert len(_completed(sweep)) == 2


def test_main_job_warms_the_kernel_cache_before_any_study(tmp_path, monkeypatch):
    """experiments.paper first runs its two-frame warm-up (a config that composes), then each
    study's multirun, then the figures; a failing study makes the job exit non-zero."""
    from experiments import paper
    calls = []

    def fake_call(cmd, **kwargs):
        calls.append(cmd)
        return 1 if "experiment=accuracy" in cmd else 0

    monkeypatch.setattr(paper.subprocess, "call", fake_call)
    rc = paper.main(["--out", str(tmp_path), "--studies", "table1", "accuracy"])
    assert rc == 1
    assert calls[0][:3] == paper.WARMUP[:3] and calls[0][-1] == f"hydra.run.dir={tmp_path / 'warmup'}"
    # the accuracy study first (whatever the order asked), then table1 in three parts: each single
    # character with 3 repeats (its own fixed mesh), the crowd once, 2 characters at a time
    assert "experiment=accuracy" in calls[1] and "hydra.launcher.n_jobs=1" in calls[1]
    assert "experiment=table1" in calls[2] and "hydra.sweeper.params.scene=karate" in calls[2]
    assert "repeats=3" in calls[2] and f"hydra.sweep.dir={tmp_path / 'table1_karate'}" in calls[2]
    assert "experiment=table1" in calls[3] and "hydra.sweeper.params.scene=solo_dancer" in calls[3]
    assert "repeats=3" in calls[3] and f"hydra.sweep.dir={tmp_path / 'table1'}" in calls[3]
    assert f"output.stills_every={paper.TABLE1_STILLS_EVERY}" in calls[3]  # the report's stills of each mode
    assert "experiment=table1" in calls[4] and "hydra.sweeper.params.scene='multiple_dancers'" in calls[4]
    assert "repeats=1" in calls[4] and f"hydra.sweep.dir={tmp_path / 'table1_crowd'}" in calls[4]
    # the accuracy study failed: no equal-quality mesh, the preset's fixed mesh
    assert all("baseline=nonadaptive" in calls[k] for k in (2, 3, 4))
    points = "points='nonadaptive,adaptive,viewdep,viewdep_nofloor'"
    assert all(points in calls[k] for k in (2, 3, 4))
    assert calls[5][2] == "paper_figures"
    for part in (calls[2], calls[3], calls[4]):  # each part composes, and sweeps what it says
        cfg = compose_config(*[a for a in part[3:] if not a.startswith("hydra.sweep.dir")], return_hydra_config=True)
        assert cfg.study == "table1" and cfg.hydra.sweeper.params.scene in ("karate", "solo_dancer",
                                                                              "multiple_dancers")
        assert cfg.points == "nonadaptive,adaptive,viewdep,viewdep_nofloor"
    overrides = [a for a in paper.WARMUP[3:]]
    cfg = compose_config(*overrides)
    assert cfg.scene.name == "karate" and cfg.mode.name == "viewdep"
    # the command is kept for the measurement pages' stamp; --docs goes on to the figures
    assert (tmp_path / "command.txt").read_text().strip() == \
        f"python -m experiments.paper --out {tmp_path} --studies table1 accuracy"
    calls.clear()
    paper.main(["--out", str(tmp_path), "--studies", "table1", "--docs", str(tmp_path / "docs")])
    assert calls[-1][2] == "paper_figures" and calls[-1][-2:] == ["--docs", str(tmp_path / "docs")]


def test_table1_baseline_is_the_accuracy_study_s_equal_quality_mesh(tmp_path):
    """The main job's Table 1 takes as its non-adaptive row the fixed mesh that the accuracy study's
    Pareto table marks equal_quality (named by its run's resolution_factor); the preset's fixed
    mesh when there is none, or no accuracy study."""
    from experiments import paper

    args = paper.parse_args(["--out", str(tmp_path)])
    assert args.studies[:2] == ["accuracy", "table1"]
    full = paper.parse_args(["--full"]).studies  # the default job and the sweeps and anticipation it leaves out
    assert [s for s in full if s in args.studies] == args.studies and {
        "accuracy_karate", "sweep_nu_out", "sweep_k", "sweep_T", "sweep_margin", "ablation_anticipation"} <= set(full)
    assert full.index("accuracy_karate") < full.index("table1")  # karate's fixed mesh found before Table 1
    with pytest.raises(SystemExit):
        paper.parse_args(["--full", "--studies", "table1"])
    logs = []
    assert paper.equal_quality_point(tmp_path, logs.append) == "nonadaptive" and "missing" in logs[-1]
    fig = tmp_path / "accuracy" / "figures"
    fig.mkdir(parents=True)
    for name, factor in (("3_solo_dancer_nonadaptive", 1.0), ("4_solo_dancer_nonadaptive", 1.4)):
        (tmp_path / "accuracy" / name).mkdir()
        (tmp_path / "accuracy" / name / "config.yaml").write_text(yaml.safe_dump({"resolution_factor": factor}))
    table = pd.DataFrame({"scene": ["solo_dancer"] * 2, "variant": ["nonadaptive", "fixed x1.4"],
                          "run": ["3_solo_dancer_nonadaptive", "4_solo_dancer_nonadaptive"],
                          "error_px": [31.0, 18.7], "equal_quality": [False, True]})
    table.to_csv(fig / "pareto.csv", index=False)
    assert paper.equal_quality_point(tmp_path, logs.append) == "resolution/1.4" and "fixed x1.4" in logs[-1]
    parts = dict(paper.study_parts("table1", args, tmp_path))
    for folder in ("table1", "table1_karate", "table1_crowd"):
        assert "baseline=resolution/1.4" in parts[folder]
        cfg = compose_config("+experiment=table1", *[a for a in parts[folder] if a.startswith(("baseline", "points"))],
                             "+point=resolution/1.4")
        assert cfg.baseline == "resolution/1.4" and cfg.resolution_factor == 1.4
        assert cfg.points == "resolution/1.4,adaptive,viewdep,viewdep_nofloor"
    table.assign(equal_quality=[False, False]).to_csv(fig / "pareto.csv", index=False)
    assert paper.equal_quality_point(tmp_path, logs.append) == "nonadaptive" and "reaches" in logs[-1]
    table.assign(equal_quality=[True, False]).to_csv(fig / "pareto.csv", index=False)
    assert paper.equal_quality_point(tmp_path, logs.append) == "nonadaptive"  # the preset's own mesh


def test_the_default_main_job_leaves_the_accuracy_studys_integration_points_to_full(tmp_path):
    """Without --full the accuracy study runs every point but the integration points (bending/,
    membrane/, steps/), and the planned count says so; --full runs the preset's whole list."""
    from experiments import paper

    every = compose_config("+experiment=accuracy").points.split(",")
    integration = [p for p in every if p.startswith(paper.ACCURACY_FULL_ONLY)]
    assert len(integration) == 12 and "reference" in every and "viewdep" in every
    [(folder, extra)] = paper.study_parts("accuracy", paper.parse_args(["--out", str(tmp_path)]), tmp_path)
    cfg = compose_config("+experiment=accuracy", *extra)
    assert folder == "accuracy" and cfg.points.split(",") == [p for p in every if p not in integration]
    assert paper.study_parts("accuracy", paper.parse_args(["--full"]), tmp_path) == [("accuracy", [])]
    default = paper.plan(paper.parse_args(["--studies", "accuracy"]))["accuracy"]
    assert default == paper.plan(paper.parse_args(["--full"]))["accuracy"] - len(integration)


def test_table1_baseline_at_the_interpolated_factor_of_the_millimetre_windows(tmp_path):
    """With the accuracy study's equal_quality.csv, Table 1's non-adaptive row is the fixed mesh at
    its interpolated factor (conf/point/fixed_factor), in both parts of the job."""
    from experiments import paper
    from experiments.build import build_simulation

    fig = tmp_path / "accuracy" / "figures"
    fig.mkdir(parents=True)
    pd.DataFrame({"scene": ["solo_dancer"], "scale": ["small"], "run": ["4_x1.4"], "variant": ["fixed x1.4"],
                  "resolution_factor": [1.4], "faces_mean": [4787.0], "interpolated_factor": [1.2345],
                  "bracketed": [True]}).to_csv(fig / "equal_quality.csv", index=False)
    logs = []
    assert paper.equal_quality_baseline(tmp_path, logs.append) == ["baseline=fixed_factor", "baseline_factor=1.23"]
    assert "x1.23" in logs[-1] and "fixed x1.4" in logs[-1]
    args = paper.parse_args(["--out", str(tmp_path)])
    for folder, extra in paper.study_parts("table1", args, tmp_path):
        assert "baseline_factor=1.23" in extra and any(a.startswith("points='fixed_factor,") for a in extra), folder
    cfg = compose_config("scene=solo_dancer", "+point=fixed_factor", "baseline_factor=1.23")
    assert cfg.mode.name == "nonadaptive" and cfg.resolution_factor == 1.23 and cfg.variant == "fixed x1.23"
    sim, _ = build_simulation(cfg)
    base, _ = build_simulation(compose_config("scene=solo_dancer", "mode=nonadaptive"))
    assert sim.mesh.n_faces > base.mesh.n_faces  # round(31 x 1.23) = 38 segments against 31


def test_karate_takes_its_own_fixed_mesh_of_adaptives_quality_when_its_accuracy_study_ran(tmp_path):
    """With accuracy_karate's equal_quality.csv, Table 1's karate row is karate's own fixed mesh; the
    solo dancer keeps its own and the crowd inherits the dancer's, and the log says so."""
    from experiments import paper

    for study, scene, factor in (("accuracy", "solo_dancer", 1.23), ("accuracy_karate", "karate", 0.91)):
        fig = tmp_path / study / "figures"
        fig.mkdir(parents=True)
        pd.DataFrame({"scene": [scene], "scale": ["small"], "run": ["x"], "variant": ["fixed x1"],
                      "resolution_factor": [1.0], "faces_mean": [1.0], "interpolated_factor": [factor],
                      "bracketed": [True]}).to_csv(fig / "equal_quality.csv", index=False)
    logs = []
    assert paper.equal_quality_baseline(tmp_path, logs.append, scene="karate")[1] == "baseline_factor=0.91"
    assert "its own" in logs[-1]
    assert paper.equal_quality_baseline(tmp_path, logs.append, scene="multiple_dancers")[1] == "baseline_factor=1.23"
    assert "inherited" in logs[-1]
    parts = dict(paper.study_parts("table1", paper.parse_args(["--full", "--out", str(tmp_path)]), tmp_path))
    assert "baseline_factor=0.91" in parts["table1_karate"] and "hydra.sweeper.params.scene=karate" in parts[
        "table1_karate"]
    assert "baseline_factor=1.23" in parts["table1"] and "baseline_factor=1.23" in parts["table1_crowd"]
    (tmp_path / "accuracy_karate" / "figures" / "equal_quality.csv").unlink()  # karate's study did not run
    assert paper.equal_quality_baseline(tmp_path, logs.append, scene="karate")[1] == "baseline_factor=1.23"
    assert "inherited" in logs[-1]


def test_a_preset_runs_as_a_multirun_and_its_callback_aggregates(tmp_path):
    """An experiment preset end to end (2 frames): `experiment=NAME` alone is a multirun
    (conf/experiment/_base.yaml), its points run through the default launcher, the study callback
    measures them against the reference and writes the study's figures."""
    sweep = tmp_path / "sweep"
    proc = run_module("experiments.run", "experiment=ablation_anticipation", "frames=2",  # a multirun without -m
                      "repeats=1",  # one seed: the preset's five are what a study needs, not this test
                      "hydra.callbacks.study.sync.horizon=1",  # the preset's 8-frame windows do not fit in 2
                      f"hydra.sweep.dir={sweep}", timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    runs = _completed(sweep)
    cfgs = [yaml.safe_load((r / "config.yaml").read_text()) for r in runs]
    assert len(runs) == 7 and {c["study"] for c in cfgs} == {"ablation_anticipation"}
    assert {c["scene"]["name"] for c in cfgs} == {"solo_dancer"}
    assert sum(bool(c["reference"]) for c in cfgs) == 1
    assert sorted((c["mode"]["view"]["anticipation"], c["mode"]["view"]["anticipation_frames"],
                   c["mode"]["view"]["lookahead"]) for c in cfgs if not c["reference"]) == [
        (False, 5, True), (True, 0, True), (True, 2, True), (True, 5, False), (True, 5, True), (True, 10, True)]
    assert sum((r / "accuracy.json").exists() for r in runs) == 6
    # the re-synchronised error: frame 0's window only (every = 1000; the cuts come later)
    assert all(json.loads((r / "sync.json").read_text())["windows"] == 1 for r in runs)
    assert any((sweep / "figures").iterdir())
    # the launcher runs one at a time (conf/cluster/local.yaml): each run had every core
    threads = {json.loads((r / "manifest.json").read_text())["numba_threads"] for r in runs}
    assert threads == {threads_per_run(os.cpu_count(), 1)}
    assert {c["seed"] for c in cfgs} == {0}


def test_runs_at_once_share_the_cores():
    assert [threads_per_run(2, n) for n in (1, 2, 3)] == [2, 1, 1]
    assert [threads_per_run(8, n) for n in (1, 2, 3, 8, 16)] == [8, 4, 2, 1, 1]
