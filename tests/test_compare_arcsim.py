"""ARCSim's output beside a run (experiments.compare_arcsim), and what it is made of: the surface
distance and bounding boxes of cloth.eval.surface against hand-computed cases, the reader of
ARCSim's output folder (cloth.io.arcsim_output) on files written here in ARCSim's format (src/io.cpp
save_obj, src/runphysics.cpp save_timings), the frames and columns of the comparison, its bad
inputs and its command line."""

import json
import math
import re

import numpy as np
import pandas as pd
import pytest
from helpers import read_frames, run_module, write_run

from cloth.core.mesh import grid_mesh
from cloth.eval.surface import bounding_box_difference, centroid_pattern, surface_distance, surface_samples
from cloth.io import arcsim_output as arcsim
from cloth.io.states import load_state, save_state
from experiments.analysis.compare_arcsim import main, parse_frames, ranges

# Distances of a 1 m sheet in float64 (closest point on a triangle, a square root): a few ulps of
# the coordinates, far below any cloth feature.
ROUNDOFF = 1e-12
# ARCSim's timing file has 8 module columns (proximity ... plasticity), per frame, from frame 1;
# C++'s default stream precision (6 digits) and a trailing space, as save_timings writes them.
TIMING_ROWS = [[0.000123, 0.0456, 0, 0.00789, 0.0123, 0, 1.2e-05, 0],
               [0.0002, 0.05, 0, 0.008, 0.011, 0, 2e-05, 0],
               [0.00021, 0.051, 0, 0.0081, 0.0125, 0, 2.1e-05, 0],
               [0.00019, 0.049, 0, 0.0079, 0.0119, 0, 1.9e-05, 0]]
D = 0.0375  # m, the distance between ARCSim's sheet and the run's in the constructed comparison


def sheet(n=4, size=1.0, origin=(0.0, 0.0, 0.0), axes=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))):
    """A flat n x n grid sheet: its Mesh (the run's side)."""
    return grid_mesh(size, size, n, n, origin=origin, axes=axes)


def write_arcsim_obj(path, node_x, face_nodes, vert_u, face_verts):
    """One NNNN_CC.obj as ARCSim's save_obj writes it: vt (with a vert label), v (with velocity and
    node label lines), an edge with its lines, faces n/t (with face label lines)."""
    lines = []
    for k, u in enumerate(vert_u):
        lines.append(f"vt {u[0]:.17g} {u[1]:.17g}")
        if k == 0:
            lines.append("vl 1")
    for x in node_x:
        lines += [f"v {x[0]:.17g} {x[1]:.17g} {x[2]:.17g}", "nv 0 0 -0.1", "nl 2"]
    lines += ["e 1 2", "ea 0.1", "el 1"]
    for fn, fv in zip(face_nodes, face_verts):
        lines += ["f " + " ".join(f"{n + 1}/{v + 1}" for n, v in zip(fn, fv)), "tl 0"]
    path.write_text("\n".join(lines) + "\n")


def write_arcsim_out(folder, shapes: dict, timing=None, frame_time=0.04, cloth=0):
    """An ARCSim output folder: frame -> (node_x, face_nodes, vert_u, face_verts), its timing file
    (rows for frames 1, 2, ...), conf.json with // comments, and an obstacle's files."""
    folder.mkdir(parents=True, exist_ok=True)
    for k, mesh in shapes.items():
        write_arcsim_obj(folder / f"{k:04d}_{cloth:02d}.obj", *mesh)
        (folder / f"{k:04d}obs00.txt").write_text("0 0 0\n1 0 0 0\n1\n")
    if timing is not None:
        (folder / "timing").write_text("".join(" ".join(f"{v:g}" for v in row) + " \n" for row in timing))
    conf = ['// a scene', '{', f'  "frame_time": {frame_time!r}, // s', '  "frame_steps": 8,',
            '  "cloths": [{"mesh": "meshes//square.obj"}] /* a comment */', '}']
    (folder / "conf.json").write_text("\n".join(conf) + "\n")
    (folder / "obs_00.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    return folder


def mesh_arrays(mesh, shift=(0.0, 0.0, 0.0)):
    return mesh.node_x + np.asarray(shift), mesh.face_nodes, mesh.vert_u, mesh.face_verts


def state_arrays(state, shift=(0.0, 0.0, 0.0)):
    return state["node_x"] + np.asarray(shift), state["face_nodes"], state["vert_u"], state["face_verts"]


# ---- cloth.eval.surface ------------------------------------------------------------------------

def test_samples_are_the_vertices_and_equal_parts_weighted_by_area():
    m = sheet(n=2, size=1.0)
    x, tris = m.vert_x(), m.face_verts
    for n in (1, 2, 3, 7):
        p = centroid_pattern(n)
        assert p.shape == (n * n, 3) and np.allclose(p.sum(axis=1), 1.0)
        assert len(np.unique(np.round(p, 12), axis=0)) == n * n
        assert np.allclose(p.mean(axis=0), 1 / 3)  # equal parts: their centroids average to the triangle's
    points, weights = surface_samples(x, tris, spacing=0.3)  # longest edges 0.71 m: n = 3
    assert np.isclose(weights.sum(), 1.0, rtol=0, atol=ROUNDOFF)  # the sheet's area, 1 m^2
    assert np.array_equal(points[:9], x) and np.all(weights[:9] == 0)  # the vertices count in the max only
    assert len(points) == 9 + 8 * 9


def test_distance_of_a_mesh_to_itself_is_zero():
    m = sheet(n=5, axes=((0.8, 0.0, 0.6), (0.0, 1.0, 0.0)))
    d = surface_distance(m.vert_x(), m.face_verts, m.vert_x(), m.face_verts)
    assert d["mean_m"] < ROUNDOFF and d["max_m"] < ROUNDOFF


def test_distance_to_a_copy_moved_along_its_normal_is_the_move():
    a1, a2 = np.array([0.8, 0.0, 0.6]), np.array([0.0, 1.0, 0.0])  # a tilted sheet
    normal = np.cross(a1, a2)
    m = sheet(n=5, axes=(a1, a2))
    x = m.vert_x()
    d = surface_distance(x, m.face_verts, x + 0.0375 * normal, m.face_verts)
    for key in ("mean_m", "max_m", "mean_a_to_b_m", "mean_b_to_a_m", "max_a_to_b_m", "max_b_to_a_m"):
        assert abs(d[key] - 0.0375) < ROUNDOFF, key


def test_distance_to_a_copy_shifted_in_its_plane_hand_computed():
    # The unit square against itself moved by s along x: the strip 0 <= x < s of A is s - x from
    # B's edge (and B's strip beyond x = 1 alike), the rest 0, so each one-sided mean is
    # int_0^s (s - x) dx / 1 m^2 = s^2 / 2 and the max s (A's vertices at x = 0). The centroid rule
    # is exact here: x = s is a grid line and the distance is linear on each part.
    s = 0.25
    m = sheet(n=4)
    x = m.vert_x()
    d = surface_distance(x, m.face_verts, x + [s, 0.0, 0.0], m.face_verts, spacing=0.25)
    assert abs(d["mean_a_to_b_m"] - s * s / 2) < ROUNDOFF and abs(d["mean_b_to_a_m"] - s * s / 2) < ROUNDOFF
    assert abs(d["mean_m"] - s * s / 2) < ROUNDOFF and abs(d["max_m"] - s) < ROUNDOFF


def test_bounding_box_difference_is_exact():
    xa = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5], [0.5, -1.0, 0.25]])
    xb = np.array([[0.25, 0.0, -0.5], [1.5, 1.0, 0.5], [0.5, -0.75, 0.0]])
    box = bounding_box_difference(xa, xb)  # B minus A: lower corners (0.25, -0.75, -0.5) - (0, -1, 0) ...
    assert box == {"min_dx_m": 0.25, "min_dy_m": 0.25, "min_dz_m": -0.5,
                   "max_dx_m": 0.5, "max_dy_m": -1.0, "max_dz_m": 0.0, "largest_m": 1.0}


# ---- cloth.io.arcsim_output ---------------------------------------------------------------------------

def test_arcsim_folder_is_read_as_arcsim_writes_it(tmp_path):
    m = sheet(n=3)
    out = write_arcsim_out(tmp_path / "out", {0: mesh_arrays(m), 1: mesh_arrays(m, (0, 0, -0.1))},
                           timing=TIMING_ROWS[:1])
    write_arcsim_obj(out / "0001_01.obj", *mesh_arrays(m))  # a second cloth
    files = arcsim.frame_files(out)
    assert sorted(files) == [0, 1] and sorted(files[1]) == [0, 1]  # obs_00.obj and NNNNobs00.txt are not frames
    f = arcsim.read_cloth_obj(files[1][0])
    assert np.array_equal(f.node_x, m.node_x + [0, 0, -0.1])
    assert np.array_equal(f.face_nodes, m.face_nodes) and np.array_equal(f.face_verts, m.face_verts)
    assert np.array_equal(f.vert_u, m.vert_u) and f.n_faces == 18
    both = arcsim.concatenate([arcsim.read_cloth_obj(p) for p in files[1].values()])
    assert both.n_faces == 36 and both.face_nodes.max() == 2 * m.node_x.shape[0] - 1
    timing = arcsim.read_timing(out / "timing", last_frame=1)
    assert timing.modules == arcsim.TIMING_MODULES and not timing.note
    assert np.array_equal(timing.frame_seconds()[1], TIMING_ROWS[0])  # the first line is frame 1
    assert arcsim.conf_frame_time(arcsim.read_conf(out / "conf.json")) == 0.04
    assert arcsim.conf_frame_time({"timestep": 0.005, "save_frames": 8}) == 0.04


def test_arcsim_reader_names_bad_files(tmp_path):
    (tmp_path / "timing").write_text("".join(" ".join(f"{v:g}" for v in r) + " \n" for r in TIMING_ROWS))
    resumed = arcsim.read_timing(tmp_path / "timing", last_frame=2)  # `arcsim resume` appended lines
    assert "resumed" in resumed.note and resumed.frame_seconds() == {}
    (tmp_path / "timing").write_text("0.1 0.2\n0.1\n")
    with pytest.raises(arcsim.ArcsimError, match="columns"):
        arcsim.read_timing(tmp_path / "timing")
    (tmp_path / "0000_00.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(arcsim.ArcsimError, match="material coordinate"):
        arcsim.read_cloth_obj(tmp_path / "0000_00.obj")
    (tmp_path / "0000_00.obj").write_text("vt 0 0\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 4/1\n")
    with pytest.raises(arcsim.ArcsimError, match="v line 4 of 3"):
        arcsim.read_cloth_obj(tmp_path / "0000_00.obj")


# ---- the comparison ----------------------------------------------------------------------------

RUN_SIM_S = [0.31, 0.12, 0.125, 0.118]  # the run's sim_s of frames 1-4
RUN_FACES = [32, 32, 32, 32]


@pytest.fixture
def constructed(tmp_path):
    """(ARCSim folder, run folder): ARCSim's sheet D above the run's at frames 0-4, with a timing
    file; the run's records for frames 1-4 (write_run) and its states (the project's writer) at
    frames 0-3 only, so frame 4's shape is missing."""
    m = sheet(n=4)
    a_out = write_arcsim_out(tmp_path / "arcsim", {k: mesh_arrays(m, (0, 0, D)) for k in range(5)}, TIMING_ROWS)
    run = write_run(tmp_path / "run", "sheet_on_sphere", "adaptive", faces=RUN_FACES, verts=[25] * 4,
                    sim_s=RUN_SIM_S)
    for k in range(4):
        save_state(run / "states" / f"frame_{k:05d}.npz", m, k, 0.04 * k, restart=True)
    return a_out, run


def test_frames_faces_times_and_shapes_of_a_constructed_pair(constructed, tmp_path):
    a_out, run = constructed
    out = tmp_path / "cmp"
    assert main([str(a_out), str(run), "--out", str(out)]) == 0
    t = pd.read_csv(out / "compare.csv")
    assert t["frame"].tolist() == [0, 1, 2, 3, 4]  # ARCSim's 0000 is the initial state, as the run's frame 0
    assert t["arcsim_faces"].tolist() == [32] * 5 and t["run_faces"].tolist() == [32] * 5  # frame 0: the state's
    assert math.isnan(t["arcsim_s"][0]) and math.isnan(t["run_sim_s"][0])  # no frame 0 on either side
    assert np.allclose(t["arcsim_s"][1:], np.sum(TIMING_ROWS, axis=1), rtol=0, atol=1e-15)
    assert t["arcsim_physics_s"][1:].tolist() == [r[1] for r in TIMING_ROWS]
    assert t["run_sim_s"][1:].tolist() == RUN_SIM_S
    assert np.allclose(t["time_s"], 0.04 * np.arange(5), rtol=0, atol=1e-15)
    shaped = t[t["frame"] < 4]
    for col in ("dist_mean_m", "dist_max_m", "dist_mean_arcsim_to_run_m", "dist_max_run_to_arcsim_m"):
        assert np.all(np.abs(shaped[col] - D) < ROUNDOFF), col
    assert (shaped["bbox_min_dz_m"] == -D).all() and (shaped["bbox_max_dz_m"] == -D).all()  # run minus ARCSim
    assert (shaped[["bbox_min_dx_m", "bbox_min_dy_m", "bbox_max_dx_m", "bbox_max_dy_m"]] == 0).all().all()
    assert (shaped["bbox_largest_m"] == D).all()
    assert (shaped["arcsim_material_area_m2"] == 1.0).all() and (shaped["run_material_area_m2"] == 1.0).all()
    assert math.isnan(t["dist_mean_m"][4])  # the run kept no shape of frame 4
    s = json.loads((out / "summary.json").read_text())
    assert s["frames_compared"] == 5 and s["statistics"]["arcsim_s"]["frames"] == 4
    assert s["statistics"]["run_sim_s"]["median"] == float(np.median(RUN_SIM_S))
    assert s["statistics"]["run_sim_s"]["max"] == max(RUN_SIM_S)
    assert abs(s["statistics"]["dist_max_m"]["max"] - D) < ROUNDOFF and s["statistics"]["dist_max_m"]["frames"] == 4
    assert s["missing"]["run_shape"] == "4" and s["missing"]["arcsim_time"] == "0" and s["missing"]["run_time"] == "0"
    assert s["frame_time_s"] == {"arcsim": 0.04, "run": 0.04}
    assert any("no run shape at frames 4" in n for n in s["notes"])
    assert (out / "compare.png").stat().st_size > 0


def test_frames_option_and_missing_timing(constructed, tmp_path, capsys):
    a_out, run = constructed
    (a_out / "timing").unlink()
    assert main([str(a_out), str(run), "--out", str(tmp_path / "cmp"), "--frames", "1:2"]) == 0
    t = pd.read_csv(tmp_path / "cmp" / "compare.csv")
    assert t["frame"].tolist() == [1, 2] and t["arcsim_s"].isna().all()
    s = json.loads((tmp_path / "cmp" / "summary.json").read_text())
    assert s["missing"]["arcsim_time"] == "1-2 (no timing file)"
    assert "over 2 frames (1-2)" in capsys.readouterr().out
    assert parse_frames("3") == (3, 3) and parse_frames(":4") == (0, 4) and parse_frames("2:") == (2, math.inf)
    assert ranges([0, 2, 3, 4, 7]) == "0, 2-4, 7"


@pytest.mark.parametrize("case, message", [
    ("no_arcsim", "ARCSim output .*: no such folder"),
    ("other_cloth", r"no NNNN_00\.obj frame files .*it has cloths 01 \(--cloth\)"),
    ("no_run", "run folder .*: no such folder"),
    ("empty_run", "run folder .*: no frames"),
    ("no_overlap", "no frame in both: ARCSim has 10-12, the run has 0-4"),
    ("bad_frames", "--frames: expected a:b"),
])
def test_bad_inputs_stop_with_one_message_before_any_work(constructed, tmp_path, capsys, case, message):
    a_out, run = constructed
    m = sheet(n=4)
    if case == "no_arcsim":
        a_out = tmp_path / "nowhere"
    elif case == "other_cloth":
        for p in a_out.glob("*_00.obj"):
            p.rename(p.with_name(p.name.replace("_00.obj", "_01.obj")))
    elif case == "no_run":
        run = tmp_path / "nowhere"
    elif case == "empty_run":
        run = tmp_path / "empty"
        run.mkdir()
    elif case == "no_overlap":
        a_out = write_arcsim_out(tmp_path / "late", {k: mesh_arrays(m) for k in (10, 11, 12)})
    out = tmp_path / "cmp"
    argv = [str(a_out), str(run), "--out", str(out)] + (["--frames", "x"] if case == "bad_frames" else [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("compare_arcsim error: ")
    assert re.search(message, err), err
    assert not out.exists()


@pytest.mark.slow
def test_cli_writes_its_three_files_and_prints_the_table(constructed, tmp_path):
    a_out, run = constructed
    r = run_module("experiments.compare_arcsim", str(a_out), str(run), timeout=120)
    assert r.returncode == 0, r.stderr
    out = run / "compare_arcsim"  # the default --out
    assert {p.name for p in out.iterdir()} == {"compare.csv", "summary.json", "compare.png"}
    assert "dist_mean_m" in r.stdout and "over 5 frames (0-4)" in r.stdout and "median" in r.stdout
    assert "missing (frames): arcsim_time 0; run_time 0; run_shape 4" in r.stdout


def test_a_real_run_against_its_own_states_written_as_arcsim(quiet_run, tmp_path):
    run = quiet_run("scene=sheet_on_sphere", "frames=3", "output.states_every=1")
    shapes = {k: state_arrays(load_state(run / "states" / f"frame_{k:05d}.npz")) for k in range(4)}
    a_out = write_arcsim_out(tmp_path / "arcsim", shapes, TIMING_ROWS[:3])
    assert main([str(a_out), str(run), "--out", str(tmp_path / "cmp")]) == 0
    t = pd.read_csv(tmp_path / "cmp" / "compare.csv")
    frames = read_frames(run)
    assert t["frame"].tolist() == [0, 1, 2, 3]
    assert t["run_sim_s"][1:].tolist() == frames["sim_s"].tolist()
    assert t["run_faces"][1:].tolist() == t["arcsim_faces"][1:].tolist() == frames["faces"].tolist()
    assert (t["dist_max_m"] < ROUNDOFF).all() and (t["bbox_largest_m"] == 0).all()
    s = json.loads((tmp_path / "cmp" / "summary.json").read_text())
    assert s["notes"] == [] and s["missing"]["run_shape"] == ""
