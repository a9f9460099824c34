"""One job per output folder (experiments.joblock): a live job's lock refuses a second job before
any work, naming the first; a killed job's lock is taken over; the lock goes with the job."""

import json
import os
import socket
import subprocess
import sys

import pytest

from experiments.joblock import LOCK_NAME, FolderInUse, JobLock


def _write_lock(folder, pid, host=None):
    (folder / LOCK_NAME).write_text(json.dumps({"pid": pid, "host": host or socket.gethostname(),
                                                "started": "2026-12-07T10:00:00", "command": "python -m first"}))


@pytest.fixture
def live_process():
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield p.pid
    p.kill()
    p.wait()


def test_a_live_jobs_lock_refuses_a_second_job_naming_it(tmp_path, live_process):
    _write_lock(tmp_path, live_process)
    with pytest.raises(FolderInUse, match=f"pid {live_process}.*python -m first"):
        with JobLock(tmp_path, "python -m second"):
            pass
    assert json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == live_process  # left to its owner


def test_a_killed_jobs_lock_is_taken_over_and_released_at_the_end(tmp_path):
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()  # its pid has ended
    _write_lock(tmp_path, p.pid)
    with JobLock(tmp_path, "python -m second") as lock:
        held = json.loads((tmp_path / LOCK_NAME).read_text())
        assert held["pid"] == os.getpid() and held["command"] == "python -m second"
        assert lock.taken_over["pid"] == p.pid
    assert not (tmp_path / LOCK_NAME).exists()


def test_a_lock_from_another_host_is_refused_with_how_to_clear_it(tmp_path):
    _write_lock(tmp_path, 1, host="elsewhere")
    with pytest.raises(FolderInUse, match="host elsewhere.*delete"):
        with JobLock(tmp_path, "python -m second"):
            pass


def test_the_lock_goes_when_the_job_fails(tmp_path):
    with pytest.raises(ValueError):
        with JobLock(tmp_path, "python -m job"):
            assert (tmp_path / LOCK_NAME).exists()
            raise ValueError("the job failed")
    assert not (tmp_path / LOCK_NAME).exists()


def test_the_main_job_and_the_stability_suite_refuse_a_folder_in_use(tmp_path, live_process, capsys):
    from experiments import paper, stability

    _write_lock(tmp_path, live_process)
    assert paper.main(["--out", str(tmp_path), "--studies", "table1"]) == 2
    assert f"pid {live_process}" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == [LOCK_NAME]  # nothing written, nothing run
    with pytest.raises(SystemExit, match=f"in use by another job \\(pid {live_process}"):
        stability.main(["--scale", "small", "--seeds", "1", "--cases", "one_frame_step", "--out", str(tmp_path)])
    assert sorted(p.name for p in tmp_path.iterdir()) == [LOCK_NAME]
