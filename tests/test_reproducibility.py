"""Reproducibility: self-contained run folders, replay, checkpoints and resume of killed runs.

Runs are deterministic and independent of the thread count, so every comparison here demands
bit-identical values (no tolerance) in every column except the wall-clock ones.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import QUIET, ROOT, compose_config, module_env, run_config, run_module
from omegaconf import OmegaConf

from cloth.runner import read_journal
from experiments import replay as replay_mod
from experiments import resume as resume_mod
from experiments.build import ConfigError
from experiments.launch import run_from_config

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

NO_OUTPUT = (*QUIET, "output.states_every=0")  # no recording, progress bar or per-frame states
KILL_TIMEOUT_S = 120.0  # generous bound for the killed run to reach its checkpoint on a loaded machine
POLL_S = 0.02  # polling interval while waiting for the checkpoint
MODULE_TIMEOUT_S = 300  # a replay or resume of a few frames in a new process


def _deterministic(frames: pd.DataFrame) -> pd.DataFrame:
    return frames[[c for c in frames.columns if not replay_mod.machine_dependent(c)]].reset_index(drop=True)


def _assert_same_run(a: Path, b: Path, n_frames: int) -> None:
    """Same records (wall-clock columns aside) and bit-identical final positions and velocities."""
    fa, fb = pd.read_parquet(a / "frames.parquet"), pd.read_parquet(b / "frames.parquet")
    assert list(fa["frame"]) == list(range(1, n_frames + 1))
    pd.testing.assert_frame_equal(_deterministic(fa), _deterministic(fb), check_exact=True)
    sa, sb = np.load(a / "final_state.npz"), np.load(b / "final_state.npz")
    assert int(sa["frame"]) == int(sb["frame"]) == n_frames
    assert np.array_equal(sa["node_x"], sb["node_x"]) and np.array_equal(sa["node_v"], sb["node_v"])


def _reference(run_dir: Path, out: Path) -> Path:
    """The uninterrupted run of `run_dir`'s saved config, in this process."""
    cfg = OmegaConf.load(run_dir / "config.yaml")
    cfg.output.rerun = False
    cfg.output.progress = False
    run_from_config(cfg, out)
    return out


@pytest.fixture(scope="module")
def finished_run_once(tmp_path_factory):
    """A completed 3-frame run, made once; tests get copies (`finished_run`)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    run_config(out, "scene=hanging_sheet", "frames=3", "output.checkpoint_every=2", *NO_OUTPUT)
    return out


@pytest.fixture
def finished_run(finished_run_once, tmp_path):
    """A copy of the completed run for one test (file modes kept): what a test or the code under
    test writes into it no other test sees."""
    return Path(shutil.copytree(finished_run_once, tmp_path / "finished_run"))


def test_run_folder_is_self_contained(finished_run):
    manifest = json.loads((finished_run / "manifest.json").read_text())
    for key in ("seed", "git_commit", "git_dirty", "git_diff_sha1", "numba_threads", "blas", "packages", "env",
                "recording_id", "python", "cpu_model"):
        assert key in manifest, key
    assert "NUMBA_NUM_THREADS" in manifest["env"] and "PYTHONHASHSEED" in manifest["env"]
    assert OmegaConf.load(finished_run / "config.yaml").frames == 3
    state = np.load(finished_run / "final_state.npz")
    assert int(state["frame"]) == 3 and state["node_x"].dtype == np.float64
    assert not (finished_run / "checkpoint").exists()  # a completed run drops its checkpoint
    assert not list(finished_run.rglob("*.tmp"))  # atomic writers leave no temporary files
    umask = os.umask(0)
    os.umask(umask)
    for name in ("frames.parquet", "summary.json", "manifest.json", "config.yaml", "final_state.npz"):
        assert (finished_run / name).stat().st_mode & 0o777 == 0o666 & ~umask, name


def test_replay_of_a_short_run_matches_with_one_thread(finished_run, tmp_path):
    """A new process with one numba thread reproduces a run made with the default thread count."""
    out = run_module("experiments.replay", str(finished_run), "--out", str(tmp_path / "replay"),
                     env={"NUMBA_NUM_THREADS": "1"}, timeout=MODULE_TIMEOUT_S)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "verdict: MATCH" in out.stdout and "final positions (frame 3, " in out.stdout
    report = json.loads((tmp_path / "replay" / "replay_report.json").read_text())
    assert report["verdict"] == "match" and report["final_states_compared"] == 1
    assert report["environment"]["threads"]["replay"]["numba_threads"] == 1
    assert "wall_s" in report["checks"][0]["frames"]["columns_excluded"]
    assert "kinetic_energy_j" in report["checks"][0]["frames"]["columns_compared"]


def test_replay_of_an_adaptive_run_matches(quiet_run):
    """The remesher carries state from frame to frame; a replay in a new process reproduces it."""
    run = quiet_run("scene=sheet_on_sphere", "mode=adaptive", "frames=3", "output.states_every=0")
    frames = pd.read_parquet(run / "frames.parquet")
    assert (frames["remesh_splits"] + frames["remesh_collapses"]).sum() > 0  # it did change the mesh
    out = run_module("experiments.replay", str(run), timeout=MODULE_TIMEOUT_S)
    assert out.returncode == 0, out.stdout + out.stderr
    replays = list(run.glob("replay_*"))  # default: inside the run folder
    assert len(replays) == 1 and (replays[0] / "replay_report.json").exists()


def test_replay_reports_the_first_difference(finished_run, tmp_path):
    run = tmp_path / "tampered"
    shutil.copytree(finished_run, run)
    frames = pd.read_parquet(run / "frames.parquet")
    frames.loc[1, "kinetic_energy_j"] = np.nextafter(frames.loc[1, "kinetic_energy_j"], np.inf)  # frame 2, 1 ulp
    frames.to_parquet(run / "frames.parquet", index=False)
    state = dict(np.load(run / "final_state.npz"))
    state["node_x"] = state["node_x"] + 1e-12
    np.savez(run / "final_state.npz", **state)

    report = replay_mod.replay(run, tmp_path / "r1")
    assert report["verdict"] == "mismatch"
    first = report["checks"][0]["frames"]["first_difference"]
    assert first["frame"] == 2 and list(first["columns"]) == ["kinetic_energy_j"]
    final = report["checks"][0]["final_state"]
    assert not final["identical"] and final["max_distance_m"] == pytest.approx(np.sqrt(3) * 1e-12, rel=1e-3)
    text = replay_mod.format_report(report)
    assert "first difference at frame 2" in text and "MISMATCH" in text
    # round-off sized differences pass an explicit relative tolerance, and say so
    assert replay_mod.main([str(run), "--out", str(tmp_path / "r2"), "--tolerance", "1e-9"]) == 0
    assert json.loads((tmp_path / "r2" / "replay_report.json").read_text())["verdict"] == "tolerance match"


def test_replay_bad_input_is_one_message(finished_run, tmp_path, capsys):
    assert replay_mod.main([str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip() == f"cannot replay: {tmp_path / 'nope'}: no such folder"
    (tmp_path / "empty").mkdir()
    assert replay_mod.main([str(tmp_path / "empty")]) == 2
    assert "not a run folder (no config.yaml)" in capsys.readouterr().err
    assert replay_mod.main([str(finished_run), "--frames", "4"]) == 2
    assert "recorded only 3 frames" in capsys.readouterr().err
    assert not list(finished_run.glob("replay_*"))  # nothing was run


def test_killed_run_resumes_to_the_uninterrupted_result(tmp_path):
    """SIGKILL a run once it has a checkpoint past frame 2, resume it: same records, same positions."""
    run, n = tmp_path / "killed", 16
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.run", "scene=sheet_on_sphere", "mode=viewdep", "camera=sheet_half",
         f"frames={n}", "output.checkpoint_every=2", *NO_OUTPUT, f"hydra.run.dir={run}"],
        cwd=ROOT, env=module_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    info = run / "checkpoint" / "state.json"
    deadline = time.monotonic() + KILL_TIMEOUT_S
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                if json.loads(info.read_text())["frame"] > 2:
                    break
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(POLL_S)
        assert proc.poll() is None, "the run ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    frame = json.loads(info.read_text())["frame"]
    assert frame > 2 and not (run / "summary.json").exists()
    kept = read_journal(run / "frames.jsonl")  # what a kill leaves: the records of every finished frame
    assert frame <= len(kept) < n and kept["frame"].tolist() == list(range(1, len(kept) + 1))

    out = run_module("experiments.resume", str(run), "--no-progress", timeout=MODULE_TIMEOUT_S)
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"from frame {frame}" in out.stdout
    assert json.loads((run / "summary.json").read_text())["status"] == "completed"
    assert [r["from_frame"] for r in json.loads((run / "manifest.json").read_text())["resumes"]] == [frame]
    assert not (run / "checkpoint").exists()
    _assert_same_run(run, _reference(run, tmp_path / "reference"), n)


def _fail_at_call(monkeypatch, k: int):
    """Make the k-th Simulation.advance_frame call (counted from now) raise, as a crash would."""
    from cloth.simulation import Simulation

    original, calls = Simulation.advance_frame, [0]

    def advance_frame(self):
        calls[0] += 1
        if calls[0] == k:
            raise RuntimeError("simulated crash")
        return original(self)

    monkeypatch.setattr(Simulation, "advance_frame", advance_frame)


def test_failed_run_resumes_into_a_second_recording(tmp_path, monkeypatch):
    run = tmp_path / "run"
    cfg = compose_config("scene=hanging_sheet", "mode=adaptive", "frames=5", "output.checkpoint_every=2",
                         "output.progress=false", "output.states_every=0")
    with monkeypatch.context() as m:
        _fail_at_call(m, 4)  # frames 1-3 done, checkpoint at frame 2
        with pytest.raises(RuntimeError, match="simulated crash"):
            run_from_config(cfg, run)
    assert json.loads((run / "summary.json").read_text())["status"] == "failed"
    assert len(pd.read_parquet(run / "frames.parquet")) == 3
    summary = resume_mod.resume(run, progress=False)
    assert summary["status"] == "completed" and summary["frames_completed"] == 5
    rid = json.loads((run / "manifest.json").read_text())["recording_id"].encode()
    first, second = (run / "recording.rrd").read_bytes(), (run / "recording_from_00002.rrd").read_bytes()
    assert rid in first and rid in second  # the second file continues the same recording
    _assert_same_run(run, _reference(run, tmp_path / "reference"), 5)


def test_crowd_resumes_each_character_from_its_own_checkpoint(tmp_path, monkeypatch):
    run = tmp_path / "crowd"
    cfg = compose_config("scene=multiple_dancers", "mode=viewdep", "scene.params.dancers=2", "crowd_jobs=1", "frames=4",
                         "output.checkpoint_every=2", *NO_OUTPUT)
    with monkeypatch.context() as m:
        _fail_at_call(m, 7)  # dancer_00 completes (4 calls); dancer_01 fails advancing frame 2 -> 3
        with pytest.raises(RuntimeError, match="simulated crash"):
            run_from_config(cfg, run)
    assert json.loads((run / "dancer_00" / "summary.json").read_text())["status"] == "completed"
    assert json.loads((run / "dancer_01" / "checkpoint" / "state.json").read_text())["frame"] == 2
    summary = resume_mod.resume(run, progress=False)
    assert summary["status"] == "completed" and summary["characters"] == 2
    reference = tmp_path / "reference"
    run_from_config(cfg, reference)
    pd.testing.assert_frame_equal(_deterministic(pd.read_parquet(run / "frames.parquet")),
                                  _deterministic(pd.read_parquet(reference / "frames.parquet")), check_exact=True)
    for d in ("dancer_00", "dancer_01"):
        _assert_same_run(run / d, reference / d, 4)


def test_resume_refuses_completed_and_checkpointless_folders(finished_run, tmp_path, capsys):
    assert resume_mod.main([str(finished_run)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"cannot resume: {finished_run}: the run already completed (summary.json); nothing to resume")
    killed = tmp_path / "no_checkpoint"
    shutil.copytree(finished_run, killed)
    (killed / "summary.json").unlink()  # as if killed before its first checkpoint
    assert resume_mod.main([str(killed)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"cannot resume: {killed}: no checkpoint") and len(err.splitlines()) == 1
    assert resume_mod.main([str(tmp_path / "nope")]) == 2
    assert "no such folder" in capsys.readouterr().err


def test_bad_checkpoint_interval_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match=r"^output.checkpoint_every: must be an integer >= 0"):
        run_config(tmp_path / "run", "scene=hanging_sheet", "output.checkpoint_every=-1", *NO_OUTPUT)
    assert not (tmp_path / "run").exists()
