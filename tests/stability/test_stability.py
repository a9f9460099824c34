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
  80 frames (it diverged at frame 59 in the main job before step control and the bending fade).

Each for the seeds SEEDS. karate_no_floor (150 frames) is in `python -m experiments.stability --long`.
The larger versions (scale=paper, 100 frames) are `python -m experiments.stability`.
"""

import pytest

from experiments.stability import QUALITY_MIN, SHORT_CASE_NAMES, case, run_case

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
