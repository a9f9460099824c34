"""Stability suite, small sizes (the larger versions: python -m experiments.stability).

Every case (experiments/stability.py, CASES) runs at scale=small for its `frames_small` frames
and must: run to the end (no exception), keep every value finite, keep the kinetic energy
below 1/2 M v^2 for the case's speed bound (a 1 m free fall, or the body's fastest parts),
leave no intersection (untangling after remeshes and CCD within steps both report zero left,
and, where the scene declares self_collision, no crossing face pair at the end), and keep
every face above the quality bound
QUALITY_MIN. The cases:

- one_frame_step: layered sheets, adaptive, one step per frame (dt = 0.04 s);
- stiff_material: layered sheets, adaptive, stretch and bending 100x stiffer than cotton;
- nu_out_0.001: layered sheets, viewdep, half the sheets in view, nu_out = 0.001;
- buckling_k1 / buckling_k50: the same with buckling compensation k = 1 and k = 50;
- cut_every_3_frames: viewdep, the camera jumps between two halves every 3 frames;
- orbit_1s: viewdep, the camera circles the sheets once per second;
- karate_2x: karate in layered skirts at twice its speed, adaptive;
- crushed_sheet: a strip folds onto itself and a plate presses the pile to 4 cm, adaptive;
- crushed_sheet_fixed: the same, nonadaptive, 48 cells along the strip (1,440 faces);
- thin_triangles: layered sheets from an input grid of cells 12x longer than wide, adaptive;
- thin_garment: solo_dancer's skirt from cells 12x longer across than around, adaptive, with
  self-collision;
- dancer_nu_out_0.3: the standing dancer, camera on her torso, skirt coarsened to nu_out = 0.3,
  80 frames (it diverged at frame 59 in the main job before step control and the bending fade);
- crowd_dancer_no_floor: dancer 5 of the ten dancers, viewdep without the contact floor, 40 frames
  (it diverged at frame 21 in the main job at 2a4c163, when split nodes made inside a leg were
  pushed through it).

Each for the seeds SEEDS. karate_no_floor (150 frames) is in `python -m experiments.stability --long`.
The larger versions (scale=paper, 100 frames) are `python -m experiments.stability`.
"""

import pytest

from experiments.stability import QUALITY_MIN, SHORT_CASE_NAMES, case, run_case

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

# Seeds of the scenes' jitter each case runs with here (python -m experiments.stability: 5): a case
# that passes for one trajectory and fails for the next says nothing about the method.
SEEDS = (0, 1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("case", [case(n) for n in SHORT_CASE_NAMES], ids=SHORT_CASE_NAMES)
def test_case_stays_stable(case, seed):
    row = run_case(case, case.frames_small, "small", seed)
    assert row["error"] == "" and row["frames_run"] == case.frames_small, row
    assert row["finite"], row
    assert row["max_kinetic_energy_j"] <= row["kinetic_energy_bound_j"], row
    assert row["intersections_left_max"] == 0 and row["self_collisions_left_max"] == 0, row
    assert row["crossings_at_end"] == 0 or not row["self_collision"], row  # declared: the cloth may cross itself
    assert row["min_face_quality"] >= QUALITY_MIN, row
    assert row["ok"]


@pytest.mark.parametrize("argv", [["--seeds", "0"], ["--frames", "0"], ["--cases", "nope"]])
def test_a_bad_argument_stops_before_any_run(argv, tmp_path, capsys):
    from experiments.stability import main

    with pytest.raises(SystemExit) as info:
        main([*argv, "--out", str(tmp_path)])
    assert info.value.code == 2 and argv[0] in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def _fake_run_case(calls, folders=None):
    def run(c, frames, scale, seed, checkpoints=None, extra=()):
        calls.append((c.name, seed))
        if folders is not None:
            folders.append(checkpoints)
        return {"case": c.name, "seed": seed, "what": c.what, "frames": frames, "error": "", "set": " ".join(extra),
                "frames_run": frames,
                "max_kinetic_energy_j": 0.1, "kinetic_energy_bound_j": 1.0, "min_face_quality": 0.3,
                "steps_rejected": 0, "s_per_frame": 0.1, "ok": True}
    return run


def test_resume_keeps_the_runs_an_earlier_suite_finished(tmp_path, monkeypatch):
    """A killed suite resumed from its table runs only what it had not: the paper-scale suite takes
    several sittings. The report's .csv beside it holds every run, with the commit that made it."""
    import pandas as pd

    import experiments.stability as stability

    calls, folders = [], []
    monkeypatch.setattr(stability, "run_case", _fake_run_case(calls, folders))
    first = tmp_path / "first.md"
    stability.main(["--scale", "small", "--cases", "crushed_sheet", "--seeds", "1", "--out", str(tmp_path / "a"),
                    "--report", str(first)])
    assert calls == [("crushed_sheet", 0)]
    # each run keeps its checkpoint under --out, where the next suite with that --out finds it
    assert folders == [tmp_path / "a" / "checkpoints" / "small_crushed_sheet_seed0_40f"]
    earlier = pd.read_csv(first.with_suffix(".csv"))
    assert list(earlier["case"]) == ["crushed_sheet"] and earlier["commit"].notna().all()
    calls.clear()
    second = tmp_path / "second.md"
    stability.main(["--scale", "small", "--cases", "crushed_sheet", "one_frame_step", "--seeds", "2",
                    "--out", str(tmp_path / "b"), "--report", str(second), "--resume", str(first.with_suffix(".csv"))])
    assert calls == [("crushed_sheet", 1), ("one_frame_step", 0), ("one_frame_step", 1)]  # seed 0 kept
    table = pd.read_csv(second.with_suffix(".csv"))
    assert len(table) == 4 and table["ok"].all()
    calls.clear()  # a suite of another case resumed from it keeps the earlier cases' runs in its report
    third = tmp_path / "third.md"
    stability.main(["--scale", "small", "--cases", "crushed_sheet", "--seeds", "2",
                    "--out", str(tmp_path / "d"), "--report", str(third), "--resume", str(second.with_suffix(".csv"))])
    assert calls == []  # both seeds of crushed_sheet were there
    kept = pd.read_csv(third.with_suffix(".csv"))
    assert sorted(zip(kept["case"], kept["seed"])) == sorted(zip(table["case"], table["seed"]))
    calls.clear()  # another scale (or frame count) is another suite: nothing is kept
    stability.main(["--scale", "small", "--frames", "3", "--cases", "crushed_sheet", "--seeds", "1",
                    "--out", str(tmp_path / "c"), "--resume", str(second.with_suffix(".csv"))])
    assert calls == [("crushed_sheet", 0)]


def test_resume_from_a_file_that_is_not_a_table_stops(tmp_path):
    from experiments.stability import main

    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(SystemExit) as info:
        main(["--scale", "small", "--out", str(tmp_path / "o"), "--resume", str(bad)])
    assert "not a stability table" in str(info.value.code)
