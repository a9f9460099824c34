"""Faults a run meets on a cluster: SIGTERM at a time limit (handled as Ctrl-C: records written,
status 'interrupted', resumable), SIGKILL during a write (no temporary file outlives it), and
power loss after a write (checkpoints and records are fsynced, with their folder)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from helpers import QUIET, ROOT, compose_config, module_env, run_module

from cloth.io import manifest
from cloth.io.checkpoint import CHECKPOINT_DIR, remove_checkpoint, save_checkpoint
from cloth.runner import read_journal
from cloth.signals import Terminated, sigterm_interrupts
from experiments import resume as resume_mod
from experiments.launch import run_from_config

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

NO_OUTPUT = (*QUIET, "output.states_every=0")
START_TIMEOUT_S = 180.0  # generous: the run's start (imports, numba's cache) on a loaded machine
POLL_S = 0.02
MODULE_TIMEOUT_S = 600


def _sigterm_at_call(monkeypatch, k: int):
    """The k-th Simulation.advance_frame call (counted from now) sends this process SIGTERM,
    as a scheduler would at a time limit, midway through advancing that frame."""
    from cloth.simulation import Simulation

    original, calls = Simulation.advance_frame, [0]

    def advance_frame(self):
        calls[0] += 1
        if calls[0] == k:
            os.kill(os.getpid(), signal.SIGTERM)
        return original(self)

    monkeypatch.setattr(Simulation, "advance_frame", advance_frame)


def _temp_files(run: Path) -> list[Path]:
    return [p for p in run.rglob("*.tmp")]


def test_sigterm_stops_a_run_as_ctrl_c_does_and_it_resumes(tmp_path, monkeypatch):
    """In this process: the runner's own handler (the one for a crowd's worker processes too)."""
    run = tmp_path / "run"
    cfg = compose_config("scene=hanging_sheet", "mode=adaptive", "frames=5", "output.checkpoint_every=1",
                         *NO_OUTPUT)
    before = signal.getsignal(signal.SIGTERM)
    with monkeypatch.context() as m:
        _sigterm_at_call(m, 3)  # frames 1 and 2 done and checkpointed
        with pytest.raises(Terminated, match="SIGTERM"):
            run_from_config(cfg, run)
    assert signal.getsignal(signal.SIGTERM) is before  # put back
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["frames_completed"] == 2
    assert summary["message"] == "stopped by SIGTERM"
    assert len(pd.read_parquet(run / "frames.parquet")) == 2 and not (run / "frames.jsonl").exists()
    summary = resume_mod.resume(run, progress=False)
    assert summary["status"] == "completed" and summary["frames_completed"] == 5
    assert not _temp_files(run)


def test_sigterm_during_a_resume_is_one_line_and_exit_143(tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    cfg = compose_config("scene=hanging_sheet", "frames=5", "output.checkpoint_every=1", *NO_OUTPUT)
    with monkeypatch.context() as m:
        _sigterm_at_call(m, 2)
        with pytest.raises(Terminated):
            run_from_config(cfg, run)
    with monkeypatch.context() as m:
        _sigterm_at_call(m, 2)  # the resumed run's second frame (frame 3)
        assert resume_mod.main([str(run), "--no-progress"]) == 128 + signal.SIGTERM
    err = capsys.readouterr().err.strip()
    assert err == (f"interrupted (SIGTERM): the frames so far are in {run}; continue with: "
                   f"python -m experiments.resume {run}")
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["frames_completed"] == 2
    assert resume_mod.main([str(run), "--no-progress"]) == 0
    assert json.loads((run / "summary.json").read_text())["frames_completed"] == 5


def test_sigterm_to_a_crowd_leaves_it_interrupted_and_resumable(tmp_path, monkeypatch):
    """The characters one after the other in this process (crowd_jobs=1): the runner of the
    character that was running writes its records, and the crowd combines what there is."""
    run = tmp_path / "crowd"
    cfg = compose_config("scene=multiple_dancers", "mode=viewdep", "scene.params.dancers=2", "crowd_jobs=1",
                         "frames=3", "output.checkpoint_every=1", *NO_OUTPUT)
    with monkeypatch.context() as m:
        _sigterm_at_call(m, 5)  # dancer_00 completes (3 calls); dancer_01 is stopped advancing frame 2
        with pytest.raises(Terminated):
            run_from_config(cfg, run)
    status = [json.loads((run / d / "summary.json").read_text())["status"] for d in ("dancer_00", "dancer_01")]
    assert status == ["completed", "interrupted"]
    assert json.loads((run / "summary.json").read_text())["status"] == "interrupted"
    summary = resume_mod.resume(run, progress=False)
    assert summary["status"] == "completed" and summary["frames_completed"] == 3


def test_the_handler_only_in_the_main_thread_and_the_previous_one_back(tmp_path):
    import threading

    seen = []

    def mine(signum, frame):
        seen.append(signum)

    previous = signal.signal(signal.SIGTERM, mine)
    try:
        with sigterm_interrupts():
            with sigterm_interrupts():
                with pytest.raises(Terminated):
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(1)  # the handler runs at the next bytecode; this never ends normally
                os.kill(os.getpid(), signal.SIGTERM)  # a second one while stopping: ignored
            os.kill(os.getpid(), signal.SIGTERM)  # still stopping (the outer block): ignored
        assert signal.getsignal(signal.SIGTERM) is mine and not seen
        os.kill(os.getpid(), signal.SIGTERM)
        assert seen == [signal.SIGTERM]  # after the blocks, the handler of before
        in_thread = []
        t = threading.Thread(target=lambda: in_thread.append(_enter_in_thread()))
        t.start()
        t.join()
        assert in_thread == [mine]
    finally:
        signal.signal(signal.SIGTERM, previous)


def _enter_in_thread():
    with sigterm_interrupts():  # not the main thread: nothing changes (signal.signal would raise)
        return signal.getsignal(signal.SIGTERM)


def test_sigterm_to_a_running_experiments_run_writes_its_records_and_resume_completes_it(tmp_path):
    """A real `python -m experiments.run`, sent SIGTERM once it has checkpointed frame 2."""
    run, n = tmp_path / "run", 40
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.run", "scene=hanging_sheet", f"frames={n}", "output.checkpoint_every=1",
         *NO_OUTPUT, f"hydra.run.dir={run}"],
        cwd=ROOT, env=module_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    info = run / CHECKPOINT_DIR / "state.json"
    deadline = time.monotonic() + START_TIMEOUT_S
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                if json.loads(info.read_text())["frame"] >= 2:
                    break
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(POLL_S)
        assert proc.poll() is None, "the run ended before it could be stopped"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=START_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    # one line naming the signal and how to continue, exit 128 + SIGTERM, as a shell reports it
    assert proc.returncode == 128 + signal.SIGTERM, err.decode()
    lines = err.decode().strip().splitlines()
    assert len(lines) == 1 and "interrupted (SIGTERM)" in lines[0] and "experiments.resume" in lines[0], lines
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["message"] == "stopped by SIGTERM"
    frames = pd.read_parquet(run / "frames.parquet")
    assert 2 <= len(frames) == summary["frames_completed"] < n
    assert frames["frame"].tolist() == list(range(1, len(frames) + 1))
    assert not (run / "frames.jsonl").exists() and not _temp_files(run)

    out = run_module("experiments.resume", str(run), "--no-progress", timeout=MODULE_TIMEOUT_S)
    assert out.returncode == 0, out.stdout + out.stderr
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["frames_completed"] == n
    assert pd.read_parquet(run / "frames.parquet")["frame"].tolist() == list(range(1, n + 1))
    assert not (run / CHECKPOINT_DIR).exists()


def _stale(folder: Path, name: str) -> Path:
    """A temporary file as atomic_write names it, left by a writer that SIGKILL stopped."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f".{name}.k1ll3d_x.tmp"
    path.write_bytes(b"\0" * 1000)
    return path


def test_stale_temporary_files_of_a_killed_writer_are_removed(tmp_path):
    run = tmp_path / "run"
    cfg = compose_config("scene=hanging_sheet", "frames=2", "output.checkpoint_every=1", *NO_OUTPUT)
    stale = [_stale(run / CHECKPOINT_DIR, "state.pkl"), _stale(run, "summary.json"), _stale(run, "frames.parquet"),
             _stale(run / "states", "frame_00001.npz")]
    keep = [run / "notes.tmp", run / ".notes.tmp", run / CHECKPOINT_DIR / "mine.txt"]  # not atomic_write's names
    for p in keep:
        p.write_text("x")
    summary = run_from_config(cfg, run)
    assert summary["status"] == "completed"
    assert not any(p.exists() for p in stale) and all(p.exists() for p in keep)
    assert (run / CHECKPOINT_DIR).is_dir()  # kept: someone else's file in it
    (run / CHECKPOINT_DIR / "mine.txt").unlink()
    # removing a checkpoint removes a killed write's temporary file beside it, and the folder
    stale = _stale(run / CHECKPOINT_DIR, "state.pkl")
    remove_checkpoint(run)
    assert not stale.exists() and not (run / CHECKPOINT_DIR).exists()


def test_a_write_that_fails_leaves_no_temporary_file(tmp_path):
    with pytest.raises(RuntimeError), manifest.atomic_write(tmp_path / "x.json") as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="reads fsync's file names from /proc")
def test_checkpoints_and_records_are_fsynced_with_their_folder(tmp_path, monkeypatch):
    synced = []
    real = os.fsync

    def fsync(fd):
        synced.append(Path(os.readlink(f"/proc/self/fd/{fd}")))
        real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    run = tmp_path / "run"
    cfg = compose_config("scene=hanging_sheet", "frames=2", "output.checkpoint_every=1", *NO_OUTPUT)
    from experiments.build import build_simulation

    sim, _ = build_simulation(cfg)
    rows = [sim.advance_frame()]
    save_checkpoint(run, sim, rows)
    ckpt = run / CHECKPOINT_DIR
    # the pickle and state.json, each fsynced as its temporary file, then their folder (and the
    # run folder, where the checkpoint folder was made)
    names = [p.name for p in synced]
    assert any(n.startswith(".state.pkl.") and n.endswith(".tmp") for n in names)
    assert any(n.startswith(".state.json.") and n.endswith(".tmp") for n in names)
    assert synced.count(ckpt) == 2 and run in synced
    synced.clear()
    run_from_config(cfg, tmp_path / "full")
    names = [p.name for p in synced]
    for target in ("summary.json", "frames.parquet", "final_state.npz", "state.pkl"):
        assert any(n.startswith(f".{target}.") for n in names), target
    assert (tmp_path / "full") in synced
    assert not any(n.startswith(".frame_") for n in names)  # per-frame states: not fsynced


def test_read_journal_of_an_interrupted_run_is_unaffected(tmp_path):
    """The journal is not a temporary file: a stale-file sweep never removes it."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "frames.jsonl").write_text('{"frame": 1}\n')
    manifest.remove_stale_temp_files(run)
    assert read_journal(run / "frames.jsonl")["frame"].tolist() == [1]


def test_output_resume_skips_a_completed_run_resumes_a_killed_one_and_refuses_another_config(tmp_path, monkeypatch,
                                                                                              capsys):
    """output.resume=true (what experiments.paper sets, so that a killed main job continues with the
    same --out): a folder holding nothing runs from the start; one whose run was killed after a
    checkpoint continues from it; one whose run completed is not run again; a folder holding a
    run of another config is refused naming the key that differs, before any work."""
    from cloth.simulation import Simulation
    from experiments.build import ConfigError
    from experiments.resuming import continue_in_place

    run = tmp_path / "run"
    asked = ("scene=hanging_sheet", "mode=adaptive", "frames=5", "output.checkpoint_every=1", *NO_OUTPUT)
    cfg = compose_config(*asked, "output.resume=true")
    assert continue_in_place(cfg, run) is None  # nothing there: the caller runs it from the start
    with monkeypatch.context() as m:
        _sigterm_at_call(m, 3)  # frames 1 and 2 done and checkpointed
        with pytest.raises(Terminated):
            run_from_config(cfg, run)
    summary = continue_in_place(cfg, run)
    assert summary["status"] == "completed" and summary["frames_completed"] == 5
    assert pd.read_parquet(run / "frames.parquet")["frame"].tolist() == [1, 2, 3, 4, 5]
    done = (run / "frames.parquet").stat().st_mtime_ns
    monkeypatch.setattr(Simulation, "advance_frame", lambda self: pytest.fail("a completed run was run again"))
    capsys.readouterr()
    again = continue_in_place(compose_config(*asked, "output.resume=true", "output.progress=true"), run)
    assert again["status"] == "completed" and "not run again" in capsys.readouterr().out
    assert (run / "frames.parquet").stat().st_mtime_ns == done
    with pytest.raises(ConfigError, match=r"output\.resume: .* another config \(frames: 5 there, 6 now\)"):
        continue_in_place(compose_config(*asked[:2], "frames=6", *asked[3:], "output.resume=true"), run)
    with pytest.raises(ConfigError, match=r"^seed: "):  # a bad value is named as without output.resume
        continue_in_place(compose_config(*asked, "seed=-1", "output.resume=true"), run)
