"""Crowds beyond the paper's ten dancers: the formation scales with scene.params.dancers (and is
the paper's 5 x 2 at ten), the crowd's camera frames the whole stage for any crowd (and is as
written at ten), a tiny crowd runs on both backends (Ray tasks, local processes) and gathers each
character's records into the crowd's (characters.csv, summary.json), a character that fails on Ray
is named while the others finish, bad crowd keys stop before any output, the default backend
(auto) is Ray only when Ray is installed and there is a Ray to use, and crowd_backend=ray without
Ray installed is one config error."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import yaml
from helpers import QUIET, ROOT, compose_config, module_env, read_frames, run_config, run_module
from omegaconf import OmegaConf

from cloth.runner import CHARACTER_COLUMNS, CHARACTERS_FILE
from cloth.scenes.registry import crowd_columns, crowd_placement
from cloth.view.paths import path_from_config
from experiments.build import ConfigError, build_camera, crowd_backend, crowd_size

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

# Positions are sums and products of a few multiples of the spacing: exact but for round-off.
ROUNDOFF = 1e-9
# The crowd's records are sums over its characters of float64 numbers (sim_s, faces): equal to the
# sums of the characters' own up to the order of the additions.
SUM_RTOL = 1e-12
# A dancer is "in the wide shot" when its feet and the top of its head (DANCER_HEIGHT above them)
# project inside the image, at least FRAME_MARGIN_PX from every border and between near and far.
DANCER_HEIGHT = 1.8  # m: the mannequin stands about 1.7 m tall
FRAME_MARGIN_PX = 20.0
# The paper's stage (conf/camera/crowd_shots.yaml is written for it): 5 x 2 dancers 3 m apart.
PAPER_X = np.array([-6.0, -3.0, 0.0, 3.0, 6.0] * 2)
PAPER_Y = np.array([-1.5] * 5 + [1.5] * 5)
# The times the crowd's camera is compared at: every frame of its 150 (25 fps), cuts included.
CAMERA_TIMES = np.arange(151) * 0.04
# A tiny crowd: the coarsest skirt (8 segments around the waist), 2 frames, no outputs but records.
TINY_CROWD = ("scene=multiple_dancers", "scene.scales.small.resolution=8", "frames=2", "output.states_every=0",
              *QUIET)


def _params(cfg):
    return cfg.scene.params


def _stage(cfg):
    p = _params(cfg)
    return crowd_placement(p.dancers, p.spacing, p.columns, p.phase_step, p.heading_step, p.phase_wrap)


# ---- the formation ---------------------------------------------------------------------------------

def test_ten_dancers_stand_on_the_paper_stage_as_before():
    cfg = compose_config("scene=multiple_dancers")
    assert cfg.scene.params.dancers == 10 and cfg.scene.params.columns is None  # auto
    pos, phases, headings = _stage(cfg)
    assert np.array_equal(pos[:, 0], PAPER_X) and np.array_equal(pos[:, 1], PAPER_Y) and not pos[:, 2].any()
    # auto is the paper's explicit 5 per row, to the last bit, phases and headings included
    explicit = crowd_placement(10, 3.0, 5, 0.37, 0.6, 1.0)
    for a, b in zip((pos, phases, headings), explicit):
        assert np.array_equal(a, b)
    assert np.array_equal(headings, 0.6 * np.arange(10))
    assert np.array_equal(phases, np.mod(0.37 * np.arange(10), 1.0))


def test_a_hundred_dancers_stand_in_sixteen_columns_no_two_closer_than_the_spacing():
    cfg = compose_config("scene=multiple_dancers", "scene.params.dancers=100")
    assert crowd_size(cfg) == 100
    pos, phases, headings = _stage(cfg)
    spacing = cfg.scene.params.spacing
    # ceil(sqrt(2.5 x 100)) = 16 per row, 7 rows (the last of 4): about 2.5 times as wide as deep
    assert crowd_columns(100) == 16
    rows = np.unique(pos[:, 1])
    assert len(rows) == 7 and np.allclose(np.diff(rows), spacing, atol=ROUNDOFF)
    per_row = [int(np.sum(pos[:, 1] == y)) for y in rows]
    assert per_row == [16] * 6 + [4]
    assert np.isclose(rows.mean(), 0.0, atol=ROUNDOFF)  # centred on the origin
    assert np.isclose(pos[:16, 0].mean(), 0.0, atol=ROUNDOFF)
    d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=2) + np.eye(100) * 1e9
    assert d.min() >= spacing - ROUNDOFF
    assert len(np.unique(headings)) == 100 and phases.min() >= 0 and phases.max() < cfg.scene.params.phase_wrap
    # a stated number of columns wins
    explicit = compose_config("scene=multiple_dancers", "scene.params.dancers=100", "scene.params.columns=10")
    assert len(np.unique(_stage(explicit)[0][:, 1])) == 10


def test_auto_columns_keep_the_paper_s_proportions():
    assert [crowd_columns(n) for n in (1, 3, 10)] == [5, 5, 5]  # up to ten: the paper's rows of five
    for n in (11, 37, 100, 250, 1000, 4321):
        c = crowd_columns(n)
        assert c * c >= 2.5 * n > (c - 1) ** 2  # the least c with c^2 >= 2.5 n
        rows = -(-n // c)
        assert 1.5 <= c / rows <= 3.5, (n, c, rows)  # about 2.5 times as many columns as rows


# ---- the camera ----------------------------------------------------------------------------------

def _written_shots():
    """conf/camera/crowd_shots.yaml's camera as written (without its stage_scale block)."""
    cam = yaml.safe_load((ROOT / "conf" / "camera" / "crowd_shots.yaml").read_text())
    cam.pop("stage_scale")
    return path_from_config(cam)


def test_the_crowd_camera_at_ten_dancers_is_the_written_one():
    written = _written_shots()
    for overrides in (("scene=multiple_dancers",), ("scene=multiple_dancers", "scene.params.columns=5"),
                      ("scene=solo_dancer", "camera=crowd_shots")):  # not a crowd: the shots as written
        path = build_camera(compose_config(*overrides))
        assert path.cuts == written.cuts == (1.6, 4.0)
        for t in CAMERA_TIMES:
            assert path.camera_at(t) == written.camera_at(t), (overrides, t)  # every field, to the last bit


@pytest.mark.parametrize("overrides", [("scene.params.dancers=10",), ("scene.params.dancers=100",),
                                       ("scene.params.dancers=1000",),
                                       ("scene.params.dancers=100", "scene.params.columns=100"),  # one row
                                       ("scene.params.dancers=100", "scene.params.columns=2")])  # a deep stage
def test_the_wide_shot_frames_every_dancer_and_the_close_up_its_front_row_dancer(overrides):
    cfg = compose_config("scene=multiple_dancers", *overrides)
    pos = _stage(cfg)[0]
    path = build_camera(cfg)
    for t in (0.0, 1.0, 1.6):  # the wide shot, and the dolly's first key where it takes over
        cam = path.camera_at(t)
        points = np.vstack([pos, pos + [0.0, 0.0, DANCER_HEIGHT]])
        px, depth = cam.project(points)
        assert np.all(cam.inside(points)), f"t = {t}: a dancer outside the frustum"
        assert np.all(px >= FRAME_MARGIN_PX) and np.all(px[:, 0] <= cam.width - FRAME_MARGIN_PX) \
            and np.all(px[:, 1] <= cam.height - FRAME_MARGIN_PX), f"t = {t}: a dancer at the image's border"
    # the dolly ends on, and the close-up looks at, the second dancer of the front row (row 0: the
    # smallest y), as on the paper's stage
    front = np.flatnonzero(np.isclose(pos[:, 1], pos[:, 1].min()))
    target = pos[front[1]] + [0.0, 0.0, 1.0]
    written = _written_shots()
    for t in (4.0, 5.0):
        cam, paper = path.camera_at(t), written.camera_at(t)
        assert np.allclose(cam.look_at, target, atol=ROUNDOFF)
        # the same shot, moved with its dancer
        assert np.allclose(np.subtract(cam.position, cam.look_at), np.subtract(paper.position, paper.look_at),
                           atol=ROUNDOFF)
        px, _ = cam.project(pos[front[1]][None] + [0.0, 0.0, 1.0])
        assert np.allclose(px, [cam.width / 2, cam.height / 2], atol=1e-6)


def test_the_wide_shot_never_comes_nearer_than_written():
    """A crowd smaller than the paper's (one or three dancers) keeps the written wide shot; the
    close-up follows the front row's second dancer, or its only one."""
    written = _written_shots()
    for n, front in ((1, 0), (3, 1)):
        cfg = compose_config("scene=multiple_dancers", f"scene.params.dancers={n}")
        path = build_camera(cfg)
        assert path.camera_at(0.0) == written.camera_at(0.0)
        assert np.allclose(path.camera_at(4.0).look_at, _stage(cfg)[0][front] + [0.0, 0.0, 1.0], atol=ROUNDOFF)


def test_bad_stage_scale_and_fit_tags_name_the_key():
    cfg = compose_config("scene=multiple_dancers")
    OmegaConf.set_struct(cfg, False)
    cfg.camera.stage_scale.stage.dancers = 1
    with pytest.raises(ConfigError, match=r"^camera\.stage_scale\.stage\.dancers: must be an integer >= 2"):
        build_camera(cfg)
    cfg = compose_config("scene=multiple_dancers")
    OmegaConf.set_struct(cfg, False)
    cfg.camera.shots[0].camera.fit = "crowd"
    with pytest.raises(ConfigError, match=r"^camera: camera: fit must be one of stage, dancer"):
        build_camera(cfg)


def test_the_old_count_key_is_named():
    """A run folder's config of before the rename (scene.params.count) is refused with the new name."""
    cfg = compose_config("scene=multiple_dancers")
    OmegaConf.set_struct(cfg, False)
    cfg.scene.params.count = 2
    with pytest.raises(ConfigError, match=r"^scene\.params\.count: was renamed scene\.params\.dancers"):
        crowd_size(cfg)


# ---- the backends ------------------------------------------------------------------------------

def test_a_bad_backend_is_refused_before_any_output(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(ConfigError, match=r"^crowd_backend: must be one of auto, ray, processes .*got 'threads'"):
        run_config(out, *TINY_CROWD, "crowd_backend=threads")
    assert not out.exists()
    # the command line: one line naming the key, exit 2, nothing of a run in its folder
    hydra_dir = tmp_path / "cli"
    proc = run_module("experiments.run", *TINY_CROWD, "crowd_backend=threads", f"hydra.run.dir={hydra_dir}",
                      timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "config error: crowd_backend: must be one of auto, ray, processes (where a crowd's characters run), "
        "got 'threads'"]
    assert {p.name for p in hydra_dir.iterdir()} <= {".hydra", "run.log"}  # Hydra's own, no run's file


# experiments.run's command line in a process where `import ray` finds nothing (Ray not installed)
WITHOUT_RAY = ("import sys; sys.modules['ray'] = None; sys.argv = ['cloth-run', *sys.argv[1:]]; "
               "from experiments.run import cli; cli()")
RAY_MISSING_LINE = 'config error: crowd_backend: ray is not installed (pip install -e ".[ray]")'


def test_auto_runs_a_crowd_on_ray_only_when_ray_is_installed_and_there_is_a_ray_to_use(monkeypatch):
    import experiments.build

    cfg = compose_config("scene=multiple_dancers")
    assert cfg.crowd_backend == "auto"  # the default
    for installed, address, expected in ((True, None, "processes"), (True, "head:6379", "ray"),
                                         (False, None, "processes"), (False, "head:6379", "processes")):
        monkeypatch.setattr(experiments.build, "ray_installed", lambda installed=installed: installed)
        if address is None:
            monkeypatch.delenv("RAY_ADDRESS", raising=False)
        else:
            monkeypatch.setenv("RAY_ADDRESS", address)
        assert crowd_backend(cfg) == expected, (installed, address)
        # a stated backend is kept: processes whatever Ray there is
        assert crowd_backend(OmegaConf.merge(cfg, {"crowd_backend": "processes"})) == "processes"


def test_ray_without_ray_installed_is_one_config_error_before_any_work(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails, find_spec finds nothing
    out = tmp_path / "run"
    with pytest.raises(ConfigError) as exc:
        run_config(out, *TINY_CROWD, "crowd_backend=ray")
    assert f"config error: {exc.value}" == RAY_MISSING_LINE
    assert not out.exists()
    # the command line: that one line, exit 2, nothing of a run in its folder
    hydra_dir = tmp_path / "cli"
    proc = subprocess.run([sys.executable, "-c", WITHOUT_RAY, *TINY_CROWD, "crowd_backend=ray",
                           f"hydra.run.dir={hydra_dir}"], cwd=ROOT, env=module_env(), capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [RAY_MISSING_LINE]
    assert {p.name for p in hydra_dir.iterdir()} <= {".hydra", "run.log"}


@pytest.mark.parametrize("backend", ["ray", "processes"])
def test_a_tiny_crowd_gathers_its_characters_records(tmp_path, monkeypatch, backend):
    monkeypatch.delenv("RAY_ADDRESS", raising=False)  # a local Ray instance, of crowd_jobs CPUs
    out = tmp_path / "crowd"
    summary = run_config(out, *TINY_CROWD, "scene.params.dancers=3", "crowd_jobs=2", f"crowd_backend={backend}")
    assert summary["status"] == "completed" and summary["characters"] == 3
    assert summary["crowd_backend"] == backend
    assert summary["crowd_ran_in"] == {"ray": "ray (local instance, 2 CPUs)",
                                       "processes": "processes (joblib loky, 2 at once)"}[backend]
    table = pd.read_csv(out / CHARACTERS_FILE)
    assert list(table.columns) == list(CHARACTER_COLUMNS)
    assert table["character"].tolist() == [0, 1, 2] and set(table["status"]) == {"completed"}
    parts = []
    for i in range(3):
        d = out / f"dancer_{i:02d}"
        assert (d / "frames.parquet").is_file() and (d / "summary.json").is_file()
        f = read_frames(d)
        parts.append(f)
        row = table.iloc[i]
        assert row["frames"] == len(f) == 2
        assert row["sim_s_mean"] == pytest.approx(f["sim_s"].mean(), rel=SUM_RTOL)
        assert row["sim_total_s"] == pytest.approx(f["sim_s"].sum(), rel=SUM_RTOL)
        assert row["faces_mean"] == pytest.approx(f["faces"].mean(), rel=SUM_RTOL)
        assert row["in_view_fraction"] == 1.0  # the wide shot sees every dancer in every frame
    # the crowd's records are the characters' summed
    total = read_frames(out)
    assert np.allclose(total["sim_s"], sum(p["sim_s"] for p in parts), rtol=SUM_RTOL, atol=0)
    assert summary["sim_total_s"] == pytest.approx(table["sim_total_s"].sum(), rel=SUM_RTOL)
    assert summary["sim_s_mean"] == pytest.approx(table["sim_s_mean"].sum(), rel=SUM_RTOL)
    assert summary["faces_mean"] == pytest.approx(table["faces_mean"].sum(), rel=SUM_RTOL)
    on_disk = json.loads((out / "summary.json").read_text())
    # JSON's null is the table's NaN (a column of nulls reads back as objects)
    pd.testing.assert_frame_equal(pd.DataFrame(on_disk["character_table"]).fillna(np.nan).infer_objects(),
                                  table, check_dtype=False)
    # each character ran in a worker of its own backend: on Ray with one thread of everything
    workers = on_disk["workers"]
    assert len(workers) == 3 and all(w["pid"] != os.getpid() for w in workers)
    if backend == "ray":
        for w in workers:
            assert w["numba_threads"] == 1
            assert (w["MKL_NUM_THREADS"], w["OMP_NUM_THREADS"], w["NUMBA_NUM_THREADS"]) == ("1", "1", "1")


def test_a_character_that_fails_on_ray_is_named_and_the_others_finish(tmp_path, monkeypatch):
    """Character 1 cannot make its folder (a file is in the way): it fails in its Ray worker, the
    others run to their end, the crowd's records say which one failed and how, and the run raises."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    out = tmp_path / "crowd"
    out.mkdir()
    (out / "dancer_01").write_text("in the way")
    with pytest.raises(FileExistsError):
        run_config(out, *TINY_CROWD, "frames=1", "scene.params.dancers=3", "crowd_jobs=2", "crowd_backend=ray")
    summary = json.loads((out / "summary.json").read_text())
    table = pd.read_csv(out / CHARACTERS_FILE)
    assert table["status"].tolist() == ["completed", "missing", "completed"]
    assert summary["status"] == "missing"
    assert summary["message"].startswith("character 1: FileExistsError")
    assert summary["workers"][1] is None and summary["workers"][0]["numba_threads"] == 1


# ---- the crowd_scaling study ---------------------------------------------------------------------

def test_the_crowd_scaling_study_is_a_preset_the_main_job_runs_only_on_request(tmp_path):
    from experiments import paper

    cfg = compose_config("+experiment=crowd_scaling", return_hydra_config=True)
    assert cfg.study == "crowd_scaling" and cfg.frames == 50 and cfg.scene.name == "multiple_dancers"
    params = cfg.hydra.sweeper.params
    assert params["scene.params.dancers"] == "1,10,100" and params["+point"] == "adaptive,viewdep"
    assert "crowd_scaling" in paper.STUDIES and "crowd_scaling" not in paper.DEFAULT_STUDIES
    args = paper.parse_args(["--studies", "crowd_scaling"])
    assert args.studies == ["crowd_scaling"]
    [(folder, extra)] = paper.study_parts("crowd_scaling", args, tmp_path)
    cmd = paper.study_command("crowd_scaling", tmp_path, args.scale, args.jobs, args.frames, extra, folder)
    assert "experiment=crowd_scaling" in cmd and "+experiment=crowd_scaling" not in cmd
    assert f"hydra.sweep.dir={tmp_path / 'crowd_scaling'}" in cmd
    assert "output.resume=true" in cmd  # a killed main job continues in its --out (experiments.resuming)


# Made-up crowd runs: adaptive's time per frame 0.5 n (1 + seed) s for n dancers (frames of 0.25
# and 1.75 times that), the view-dependent mode's SPEEDUPS[scale][n][seed] times less; faces 100 n
# and 25 n. Every number is a binary fraction: the table's values are exact but for rounding.
SPEEDUPS = {"small": {1: (2.0, 2.5), 10: (4.0, 5.0), 100: (8.0, 10.0)},  # grows: median 2.25, 4.5, 9
            "paper": {1: (3.0,), 10: (4.0,), 100: (2.0,)}}  # up, then down
TABLE_TOL = 1e-12  # means and ratios of binary fractions: float rounding only


def _scaling_runs(root):
    from helpers import write_run

    k = 0

    def run(n, mode, seed, scale, time, faces, **kw):
        nonlocal k
        k += 1
        return write_run(root / f"{k}_{scale}_{n}_{mode}_{seed}", "multiple_dancers", mode, [faces] * 2, [faces] * 2,
                         [0.25 * time, 1.75 * time] if mode == "adaptive" else [time, time], scale=scale, seed=seed,
                         variant=kw.pop("variant", mode), summary_extra={"characters": n},
                         study=kw.pop("study", "crowd_scaling"), **kw)

    for scale, sizes in SPEEDUPS.items():
        for n, speedups in sizes.items():
            for seed, s in enumerate(speedups):
                base = 0.5 * n * (1 + seed)
                run(n, "adaptive", seed, scale, base, 100 * n, timestamp="2025-01-02T00:00:00+00:00")
                run(n, "viewdep", seed, scale, base / s, 25 * n, timestamp="2025-01-02T00:00:00+00:00")
    # left out: an earlier run of the same cell (superseded), another study's crowd, another variant
    run(10, "viewdep", 0, "small", 99.0, 1, timestamp="2025-01-01T00:00:00+00:00")
    run(10, "viewdep", 0, "small", 99.0, 1, study="table1")
    run(10, "viewdep", 0, "small", 99.0, 1, variant="viewdep_nofloor", timestamp="2025-01-03T00:00:00+00:00")
    # refused: the two modes of 1000 dancers ran other code
    run(1000, "adaptive", 0, "small", 500.0, 1, manifest={"git_commit": "a" * 40})
    run(1000, "viewdep", 0, "small", 50.0, 1, manifest={"git_commit": "b" * 40})


def test_the_crowd_scaling_table_gives_the_speed_up_at_each_crowd_size(tmp_path):
    from experiments.analysis.aggregate import load_runs, table1, table1_runs
    from paper_figures import crowd_scaling

    root = tmp_path / "runs"
    _scaling_runs(root)
    runs = load_runs([root], warn=False).runs
    t = crowd_scaling.crowd_scaling_table(runs)
    assert [(r.scale, r.dancers) for r in t.itertuples()] == [("paper", 1), ("paper", 10), ("paper", 100),
                                                              ("small", 1), ("small", 10), ("small", 100)]
    for r in t.itertuples():
        s = np.array(SPEEDUPS[r.scale][r.dancers])
        base = 0.5 * r.dancers * (1 + np.arange(len(s)))
        assert r.frames == 2 and r.repeats == len(s)
        assert r.adaptive_s == pytest.approx(np.median(base), rel=TABLE_TOL)
        assert r.viewdep_s == pytest.approx(np.median(base / s), rel=TABLE_TOL)
        assert r.adaptive_per_character_s == pytest.approx(np.median(base) / r.dancers, rel=TABLE_TOL)
        assert (r.adaptive_faces, r.viewdep_faces) == (100 * r.dancers, 25 * r.dancers)
        assert r.speedup == pytest.approx(np.median(s), rel=TABLE_TOL)
        assert (r.speedup_lo, r.speedup_hi) == pytest.approx((s.min(), s.max()), rel=TABLE_TOL)
        # never the superseded, other-study or other-variant runs (made 19th to 21st)
        assert not {"19_small_10_viewdep_0", "20_small_10_viewdep_0", "21_small_10_viewdep_0"} & set(r.runs.split(", "))
        assert len(r.runs.split(", ")) == 2 * r.repeats
    small, paper = t[t["scale"] == "small"], t[t["scale"] == "paper"]
    assert small["speedup_grows"].tolist() == [None, True, True]
    assert paper["speedup_grows"].tolist() == [None, True, False]
    assert t.attrs["verdict"] == {"paper": False, "small": True}
    assert len(t.attrs["problems"]) == 1 and "1000 dancers" in t.attrs["problems"][0] \
        and "commit" in t.attrs["problems"][0]
    assert any("superseded" in n for n in t.attrs["notes"])
    # the files, through the figure scripts' command line
    out = tmp_path / "figures"
    assert crowd_scaling.main([str(root), "--out", str(out)]) == 0
    csv = pd.read_csv(out / "crowd_scaling.csv")
    assert np.allclose(csv["speedup"], t["speedup"], rtol=TABLE_TOL, atol=0)
    md = (out / "crowd_scaling.md").read_text()
    assert "At scale=small the speed-up grows with the crowd (1: 2.25× → 10: 4.50× → 100: 9.00×)" in md
    assert "At scale=paper the speed-up does not grow with the crowd" in md
    # crowds of other sizes never make Table 1's rows
    assert table1(table1_runs(runs[runs["study"] == "crowd_scaling"])).empty


def test_the_character_table_gives_what_a_character_costs_out_of_view():
    from cloth.runner import characters_table

    # character 0: 2 frames in view at 0.2 s, 2 wholly out of view at 0.01 s, 1 in frame edge
    # (no face in view, not beyond the margin: neither kind); character 1: always in view
    f0 = pd.DataFrame({"sim_s": [0.2, 0.2, 0.01, 0.01, 0.05], "faces": [900, 900, 60, 60, 300],
                       "wall_s": [0.3] * 5, "faces_in_view": [500, 400, 0, 0, 0],
                       "character_out_of_view": [0, 0, 1, 1, 0]})
    f1 = pd.DataFrame({"sim_s": [0.3, 0.1], "faces": [1000, 1000], "wall_s": [0.4, 0.2],
                       "faces_in_view": [800, 700], "character_out_of_view": [0, 0]})
    table = characters_table([f0, f1], [{"status": "completed"}] * 2)
    assert table.loc[0, "frames_out_of_view"] == 2
    assert table.loc[0, "sim_s_out_of_view_mean"] == pytest.approx(0.01)
    assert table.loc[0, "sim_s_in_view_mean"] == pytest.approx(0.2)
    assert table.loc[0, "out_of_view_cost_ratio"] == pytest.approx(0.05)
    assert table.loc[1, "frames_out_of_view"] == 0 and np.isnan(table.loc[1, "out_of_view_cost_ratio"])
    assert table.loc[1, "sim_s_in_view_mean"] == pytest.approx(0.2)
