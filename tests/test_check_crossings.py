"""The crossing check of a run's saved states (experiments.check_crossings) on constructed states
whose crossings, depths and clearances are computed by hand: a triangle through another, a node
inside a sphere, frame 0 apart from the verdict, a crowd's characters, and its bad inputs."""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import run_module

from cloth.collision.obstacles import CapsuleUnion
from cloth.io.states import save_state
from experiments.analysis.check_crossings import check_run, frame_list, main

# Distances and lengths of unit-size triangles in float64 (a closest point, a square root): a few
# ulps, far below any cloth feature. Obstacle meshes are stored in float32, so their distances
# carry its rounding (about 1e-7 relative).
ROUNDOFF = 1e-12
FLOAT32 = 1e-6

# The cloth: one triangle in the plane z = 0.
CLOTH = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# A triangle in the plane x = 0.25 whose edges AB and BC cross z = 0 at y = 0.1 and y = 0.4:
# it crosses the cloth along a segment of length 0.3.
THROUGH = np.array([[0.25, 0.1, -0.5], [0.25, 0.1, 0.5], [0.25, 0.7, -0.5]])
CROSSING_LENGTH = 0.3
# The cloth node nearest to THROUGH is the origin; its closest point is (0.25, 0.1, 0) on AB.
THROUGH_CLEARANCE = math.hypot(0.25, 0.1)
# A sphere (a capsule with coinciding ends) around the origin's node: 0.05 m deep.
SPHERE_CENTRE, SPHERE_RADIUS = (0.0, 0.0, -0.1), 0.15
SPHERE_DEPTH = 0.05


def cloth(x, faces):
    """What save_state reads of a mesh: node positions and faces as verts of nodes."""
    x = np.asarray(x, dtype=np.float64)
    return SimpleNamespace(node_x=x, vert_node=np.arange(len(x)), face_verts=np.asarray(faces))


def triangles(x):
    """A mesh obstacle for save_state: its display mesh is the triangles themselves."""
    x = np.asarray(x, dtype=np.float64)
    return SimpleNamespace(to_mesh=lambda: (x, np.arange(len(x)).reshape(-1, 3)))


def sphere(centre=SPHERE_CENTRE, radius=SPHERE_RADIUS):
    return CapsuleUnion(np.array([[centre, centre]]), [radius])


def save(run, frame, mesh, obstacles=()):
    save_state(run / "states" / f"frame_{frame:05d}.npz", mesh, frame, 0.04 * frame, obstacles)


@pytest.mark.slow
def test_a_triangle_through_the_cloth_is_one_pair_of_the_hand_computed_length(tmp_path):
    both = cloth(np.vstack([CLOTH, THROUGH]), [[0, 1, 2], [3, 4, 5]])
    save(tmp_path, 1, both)
    row = check_run(tmp_path).iloc[0]
    assert row["self_pairs"] == 1
    assert row["self_length_m"] == pytest.approx(CROSSING_LENGTH, abs=ROUNDOFF)
    assert row["obstacle_pairs"] == 0 and row["nodes_inside"] == 0
    assert row["clearance_m"] is None or math.isnan(row["clearance_m"])  # no obstacle


def test_a_mesh_obstacle_through_the_cloth_and_the_clearance(tmp_path):
    save(tmp_path, 1, cloth(CLOTH, [[0, 1, 2]]), [triangles(THROUGH)])
    row = check_run(tmp_path).iloc[0]
    assert row["self_pairs"] == 0
    assert row["obstacle_pairs"] == 1
    assert row["obstacle_length_m"] == pytest.approx(CROSSING_LENGTH, abs=FLOAT32)
    assert row["clearance_m"] == pytest.approx(THROUGH_CLEARANCE, abs=FLOAT32)


def test_a_node_inside_a_sphere_and_its_depth(tmp_path):
    save(tmp_path, 1, cloth(CLOTH, [[0, 1, 2]]), [sphere()])
    row = check_run(tmp_path).iloc[0]
    assert row["nodes_inside"] == 1
    assert row["deepest_m"] == pytest.approx(SPHERE_DEPTH, abs=FLOAT32)
    assert row["clearance_m"] == 0.0


def test_a_clean_state_and_its_clearance_to_a_sphere(tmp_path):
    save(tmp_path, 1, cloth(CLOTH + [0.0, 0.0, 0.2], [[0, 1, 2]]), [sphere()])
    row = check_run(tmp_path).iloc[0]
    assert (row["self_pairs"], row["obstacle_pairs"], row["nodes_inside"], row["deepest_m"]) == (0, 0, 0, 0.0)
    # nearest node: the origin's, 0.3 m above the centre
    assert row["clearance_m"] == pytest.approx(0.3 - SPHERE_RADIUS, abs=FLOAT32)


# A thin capsule (a bone) whose axis runs along z through the cloth triangle's interior at
# (0.25, 0.25), its three nodes 0.25-0.79 m from the axis, outside its 0.05 m radius.
BONE_THROUGH = np.array([[[0.25, 0.25, -0.3], [0.25, 0.25, 0.3]]])
BONE_RADIUS = 0.05


def bone(ends, radius=BONE_RADIUS):
    return CapsuleUnion(np.asarray(ends, float), [radius])


@pytest.mark.parametrize(("ends", "pierced"), [
    (BONE_THROUGH, 1),  # the axis through the face, no node inside: what node contact cannot see
    (BONE_THROUGH + [0.0, 0.0, 0.4], 0),  # the same axis ending 0.1 m above the face: no axis through it
    (BONE_THROUGH + [0.6, 0.6, 0.0], 0),  # beside the face (x + y = 1.7 > 1), no node within reach
    ([[[-0.5, 0.25, 0.02], [1.5, 0.25, 0.02]]], 0),  # along the face, 2 cm above it: over it, not through
])
def test_a_capsule_axis_through_a_face_with_every_node_outside_is_counted_apart_from_the_verdict(
        tmp_path, ends, pierced):
    save(tmp_path, 1, cloth(CLOTH, [[0, 1, 2]]), [bone(ends)])
    row = check_run(tmp_path).iloc[0]
    assert row["faces_pierced"] == pierced
    assert row["nodes_inside"] == 0  # every node outside the capsule: only the face test sees it
    from experiments.analysis.check_crossings import record_frames, summarize
    summary = summarize(check_run(tmp_path), tmp_path, record_frames(tmp_path))
    assert summary["max_faces_pierced"] == pierced and bool(summary["frames_pierced"]) == bool(pierced)
    assert summary["clean"]  # reported, not in the verdict


def test_frame_0_is_listed_but_the_verdict_is_on_the_frames_after_it(tmp_path, capsys):
    save(tmp_path, 0, cloth(CLOTH, [[0, 1, 2]]), [triangles(THROUGH)])
    save(tmp_path, 5, cloth(CLOTH + [0.0, 0.0, 0.6], [[0, 1, 2]]), [triangles(THROUGH)])
    assert main([str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "frame 0 (before the start state's untangling): 0 self pairs, 1 obstacle pairs" in printed
    assert "no state after frame 0" in printed
    summary = json.loads((tmp_path / "check_crossings" / "summary.json").read_text())
    assert summary["clean"] and summary["start_state"]["obstacle_pairs"] == 1
    assert summary["frames"] == "0, 5"

    save(tmp_path, 10, cloth(CLOTH, [[0, 1, 2]]), [triangles(THROUGH)])
    assert main([str(tmp_path), "--out", str(tmp_path / "again")]) == 1
    assert "crossing in frames 10" in capsys.readouterr().out
    summary = json.loads((tmp_path / "again" / "summary.json").read_text())
    assert not summary["clean"] and summary["frames_crossing"] == "10"
    assert [int(f) for f in check_run(tmp_path, "5:10")["frame"]] == [5, 10]


def test_records_of_frames_without_a_state_count(tmp_path, capsys):
    """A frame whose record says its untangling left crossings ends crossing (no later step
    removes them): it fails the verdict even when no saved state shows it."""
    for frame in (0, 5):
        save(tmp_path, frame, cloth(CLOTH + [0.0, 0.0, 0.6], [[0, 1, 2]]), [triangles(THROUGH)])
    records = [{"frame": k, "intersections_left": 0, "self_collisions_left": 0, "obstacle_collisions_left": 0}
               for k in range(1, 6)]
    records[1]["obstacle_collisions_left"] = 2  # frame 2: a step gave up, its untangling cleared it
    records[2].update(obstacle_collisions_left=1, intersections_left=6)  # frame 3: it did not
    records[3]["intersections_left"] = 6  # frame 4: still there at the next frame's untangling
    (tmp_path / "frames.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    assert main([str(tmp_path)]) == 1
    printed = capsys.readouterr().out
    assert "no state after frame 0 has cloth crossing" in printed
    assert "untangling left crossings in frames 3-4; a collision pass gave up in frames 2-3" in printed
    summary = json.loads((tmp_path / "check_crossings" / "summary.json").read_text())
    assert not summary["clean"] and summary["records"] == 5
    assert main([str(tmp_path), "--frames", "5:", "--out", str(tmp_path / "late")]) == 0


def test_a_crowd_sums_its_characters(tmp_path):
    save(tmp_path / "dancer_0", 1, cloth(CLOTH, [[0, 1, 2]]), [triangles(THROUGH)])
    save(tmp_path / "dancer_1", 1, cloth(CLOTH, [[0, 1, 2]]), [triangles(THROUGH), sphere()])
    row = check_run(tmp_path).iloc[0]
    assert row["obstacle_pairs"] == 2 and row["nodes_inside"] == 1
    assert row["clearance_m"] == 0.0


def test_frame_lists():
    assert frame_list(range(0, 501, 5)) == "0-500 every 5"
    assert frame_list([0, 2, 3, 4, 7]) == "0, 2-4, 7"
    assert frame_list([3, 4, 5]) == "3-5"
    assert frame_list([5, 10]) == "5, 10"
    assert frame_list([]) == ""


@pytest.mark.parametrize("make, frames, message", [
    (lambda run: None, None, "does not exist"),
    (lambda run: run.mkdir(), None, "has no states"),
    (lambda run: save(run, 1, cloth(CLOTH, [[0, 1, 2]])), "2:3", "none of the saved states (1) is in it"),
    (lambda run: save(run, 1, cloth(CLOTH, [[0, 1, 2]])), "x", "--frames"),
    (lambda run: ((run / "states").mkdir(parents=True), (run / "states" / "frame_00001.npz").write_text("no")),
     None, "cannot read state file"),
])
def test_bad_inputs_are_named_before_any_work(tmp_path, capsys, make, frames, message):
    run = tmp_path / "run"
    make(run)
    argv = [str(run)] + (["--frames", frames] if frames else [])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("check_crossings error:") and message in err
    assert not (run / "check_crossings").exists()


@pytest.mark.slow
def test_the_command_line(tmp_path):
    save(tmp_path, 3, cloth(CLOTH, [[0, 1, 2]]), [sphere()])
    done = run_module("experiments.check_crossings", str(tmp_path))
    assert done.returncode == 1, done.stderr
    assert "crossing in frames 3" in done.stdout
    assert (tmp_path / "check_crossings" / "crossings.csv").read_text().startswith("frame,time_s,faces")


def _run_folder(run, crossing: bool, seed: int):
    """A run folder as experiments.run leaves it: states, config, summary and manifest."""
    save(run, 0, cloth(CLOTH + [0.0, 0.0, 0.6], [[0, 1, 2]]), [triangles(THROUGH)])
    save(run, 5, cloth(CLOTH if crossing else CLOTH + [0.0, 0.0, 0.6], [[0, 1, 2]]), [triangles(THROUGH)])
    (run / "config.yaml").write_text(f"scene: {{name: arcsim, params: {{conf: /x/conf/flag.json}}}}\n"
                                     f"mode: {{name: adaptive}}\nseed: {seed}\n")
    (run / "summary.json").write_text(json.dumps({"status": "completed", "frames_completed": 5, "faces_mean": 1.0,
                                                  "faces_max": 1, "steps_rejected_total": 0}))
    (run / "manifest.json").write_text(json.dumps({"git_commit": "0123456789abcdef", "git_dirty": False}))


def test_several_runs_and_their_report(tmp_path, capsys):
    clean, bad = tmp_path / "flag_s0", tmp_path / "flag_s1"
    for run, crossing, seed in ((clean, False, 0), (bad, True, 1)):
        run.mkdir()
        _run_folder(run, crossing, seed)
    page = tmp_path / "crossings.md"
    assert main([str(clean), str(bad), "--report", str(page)]) == 1  # the worst of the two
    text = page.read_text()
    assert "1 of 2 runs clean" in text and "python -m experiments.check_crossings" in text
    lines = [x for x in text.splitlines() if x.startswith("| flag_s")]
    assert lines[0].startswith("| flag_s0 | flag | adaptive | 0 | completed |") and "| none |" in lines[0]
    assert lines[0].endswith("| True | 0123456789 |")
    assert "| 5 |" in lines[1] and lines[1].endswith("| False | 0123456789 |")
    with pytest.raises(SystemExit):  # one output folder for two runs: refused before any work
        main([str(clean), str(bad), "--out", str(tmp_path / "o")])
    assert not (tmp_path / "o").exists()
