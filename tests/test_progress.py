"""The main job says where it is: runs planned per study (counted from the presets' sweeps), a line
per finished run with the time left, and a line at least every heartbeat while a run or the
study's evaluation goes on (experiments.progress)."""

import json
import threading
import time

import pytest

from experiments.progress import JobClock, StudyWatch, planned_runs

# The main job's table1 (experiments.paper.study_parts): each single character (its own multirun, its
# own fixed mesh) 3 seeds x 4 points (the fixed mesh, adaptive, viewdep, viewdep_nofloor), the crowd
# 1 scene x 1 seed x 4 points.
TABLE1_SINGLE = ["scale=small", "hydra.sweeper.params.scene=karate", "repeats=3",
                 "baseline=nonadaptive", "points='nonadaptive,adaptive,viewdep,viewdep_nofloor'"]
TABLE1_CROWD = ["scale=small", "hydra.sweeper.params.scene='multiple_dancers'", "repeats=1", "crowd_jobs=2",
                "baseline=nonadaptive", "points='nonadaptive,adaptive,viewdep,viewdep_nofloor'"]


def test_planned_runs_expand_the_presets_sweeps():
    assert planned_runs("table1", TABLE1_SINGLE) == 1 * 3 * 4
    assert planned_runs("table1", TABLE1_CROWD) == 1 * 1 * 4
    assert planned_runs("table1", ["scale=small"]) == 3 * 3 * 4  # the preset alone: 3 scenes, repeats 3
    assert planned_runs("table1", ["scale=small", "repeats=2"]) == 3 * 2 * 4
    assert planned_runs("no_such_study") is None  # a count is a convenience: never an error


def test_the_main_job_plans_every_multirun():
    from experiments.paper import parse_args, plan

    runs = plan(parse_args([]))
    assert list(runs) == ["accuracy", "table1_karate", "table1", "table1_crowd", "ablation_buckling",
                          "ablation_buckling_dancer"]
    assert runs["table1"] == runs["table1_karate"] == 3 * 4 and runs["table1_crowd"] == 4
    assert "accuracy_karate" in plan(parse_args(["--full"]))
    assert all(isinstance(n, int) and n > 0 for n in runs.values())


def test_time_left_is_the_runs_left_at_their_studys_mean():
    clock = JobClock({"a": 4, "b": 2})
    assert clock.left_s("a") == (None, None)  # nothing finished: no estimate
    clock.done["a"] += [10.0, 20.0]
    study, job = clock.left_s("a")
    assert study == pytest.approx(2 * 15.0)  # two runs of a left at a's mean
    assert job == pytest.approx(2 * 15.0 + 2 * 15.0)  # b has no run yet: every run's mean


def test_the_watch_reports_each_run_and_is_never_silent_for_a_heartbeat(tmp_path):
    lines = []
    clock = JobClock({"s": 3})
    heartbeat = 0.2

    def finish(name):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps({"status": "completed"}))

    def runs():  # a multirun: three runs, then an evaluation longer than a heartbeat
        for k in range(3):
            time.sleep(0.6)  # three heartbeats: a loaded machine may delay the watch
            finish(str(k))
        time.sleep(3 * heartbeat)

    with StudyWatch("[1/1] s:", "s", tmp_path, clock, log=lines.append, heartbeat_s=heartbeat, poll_s=0.02):
        t = threading.Thread(target=runs)
        t.start()
        t.join()
    done = [x for x in lines if " done (" in x]
    assert [x.split(" done")[0] for x in done] == ["[1/1] s: run 1/3", "[1/1] s: run 2/3", "[1/1] s: run 3/3"]
    assert "left in this study" in done[0] and "in the job" in done[0]
    assert any("run 2/3 running for" in x or "run 1/3 running for" in x for x in lines)
    assert any("all 3 runs done; evaluating" in x for x in lines)
    assert len(clock.done["s"]) == 3


def test_a_heartbeat_speaks_while_a_step_without_runs_goes_on():
    import time

    from experiments.progress import Heartbeat

    said = []
    with Heartbeat("[0] compiling", log=said.append, heartbeat_s=0.05):
        time.sleep(0.3)
    n = len(said)
    assert n >= 2 and all(s.startswith("[0] compiling: still going after") for s in said), said
    time.sleep(0.15)
    assert len(said) == n  # silent once the step has ended
