"""Screen-space accuracy (cloth.eval.screenspace, experiments.accuracy): the z-buffer rasteriser on
hand-computed cases, the error measures on known shifts, the distance to a mesh against brute
force, per-frame states, and the accuracy CLI on two tiny real runs."""

import json
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import yaml
from helpers import QUIET, run_config

from cloth.collision.ccd import point_triangle_closest
from cloth.collision.nearest import point_mesh_distance
from cloth.collision.obstacles import Plane, Sphere
from cloth.eval import visible
from cloth.eval.screenspace import (
    CLOTH,
    EMPTY,
    OCCLUDER,
    frame_errors,
    occluder_mesh,
    offscreen_distance,
    popping,
    rasterize,
    render_frame,
)
from cloth.io.states import StateError, load_state, merge_states, save_state
from cloth.view.camera import Camera

ROUNDOFF = 1e-9  # exact cases: only floating-point round-off remains
# Edges are sampled at pixel centres: a silhouette moves by whole rendered pixels, so a shift that
# is not a whole number of pixels is measured to within half a pixel.
HALF_PIXEL = 0.5
FLOAT32_M = 1e-6  # states store positions as float32: ~1e-7 relative at a few metres

W = H = 64
Z_CAM = 5.0  # the test camera sits at z = 5 looking down -z: depth = 5 - z


def _camera(width=W, height=H):
    return Camera((0.0, 0.0, Z_CAM), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, width, height, near=0.05, far=100.0)


def _world(cam, u, v, depth):
    """The world point seen at pixel position (u, v) at `depth` (inverse of Camera.project here)."""
    f = cam.focal_px
    return [(u - cam.width / 2) * depth / f, -(v - cam.height / 2) * depth / f, Z_CAM - depth]


def _quad(cam, u0, u1, v0, v1, depth):
    """Two triangles covering pixel positions [u0, u1] x [v0, v1] on the plane at `depth`."""
    x = np.array([_world(cam, u, v, depth) for u, v in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))])
    return x, np.array([[0, 1, 2], [0, 2, 3]])


def _big_quad(z):
    """A square far larger than the view, at height z."""
    x = np.array([[-50.0, -50, z], [50, -50, z], [50, 50, z], [-50, 50, z]])
    return x, np.array([[0, 1, 2], [0, 2, 3]])


# ---- the rasteriser ----------------------------------------------------------------------------

def test_triangle_facing_the_camera_covers_the_pixel_centres_inside_it():
    cam = _camera()
    x = np.array([_world(cam, u, v, 5.0) for u, v in ((2, 2), (12, 2), (2, 12))])
    img = render_frame(cam, x, [[0, 1, 2]])
    # pixel (i, j) has its centre at (i + 0.5, j + 0.5): inside iff (i - 2) + (j - 2) <= 9, i, j >= 2
    j, i = np.mgrid[:H, :W]
    expected = (i >= 2) & (j >= 2) & ((i - 2) + (j - 2) <= 9)
    assert expected.sum() == 55
    assert np.array_equal(img.cloth, expected)
    assert np.allclose(img.depth[expected], 5.0, rtol=ROUNDOFF)
    assert np.all(np.isinf(img.depth[~expected])) and np.all(img.mesh_id[~expected] == EMPTY)
    assert np.all(img.face[expected] == 0) and np.all(img.face[~expected] == -1)
    # seen from behind it covers the same pixels (no back-face culling)
    assert np.array_equal(render_frame(cam, x, [[0, 2, 1]]).cloth, expected)


def test_depth_of_a_tilted_plane_is_exact_also_where_it_is_clipped_at_the_near_plane():
    cam = _camera()
    a = 0.5  # the plane z = a x reaches behind the camera (z > 5) for x > 10: clipped at the near plane
    s = 40.0
    x = np.array([[-s, -s, -a * s], [s, -s, a * s], [s, s, a * s], [-s, s, -a * s]])
    img = render_frame(cam, x, [[0, 1, 2], [0, 2, 3]])
    assert img.cloth.all()
    # the ray through pixel centre (u, v) meets z = a x at depth 5 / (1 + a (u - W/2) / f)
    u = np.arange(W) + 0.5
    expected = Z_CAM / (1.0 + a * (u - W / 2) / cam.focal_px)
    assert np.allclose(img.depth, expected[None, :], rtol=ROUNDOFF, atol=0)
    assert set(np.unique(img.face)) == {0, 1}


def test_occluder_in_front_hides_the_cloth_and_one_behind_does_not():
    cam = _camera()
    cx, ct = _big_quad(0.0)  # cloth at depth 5
    ox, ot = _quad(cam, -10, 32, -10, 80, 3.0)  # occluder over the left half, at depth 3
    img = render_frame(cam, cx, ct, ox, ot)
    assert np.all(img.mesh_id[:, :32] == OCCLUDER) and np.all(img.mesh_id[:, 32:] == CLOTH)
    assert np.allclose(img.depth[:, :32], 3.0, rtol=ROUNDOFF) and img.cloth.sum() == H * 32
    ox, ot = _quad(cam, -10, 32, -10, 80, 7.0)  # the same occluder behind the cloth
    assert render_frame(cam, cx, ct, ox, ot).cloth.all()
    # the order of the meshes does not matter
    img2 = rasterize(cam, [(cx, ct, CLOTH), (_quad(cam, -10, 32, -10, 80, 3.0)[0], ot, OCCLUDER)])
    assert np.array_equal(img2.mesh_id, img.mesh_id)


def test_bad_triangle_index_is_rejected():
    with pytest.raises(ValueError, match="indexes outside"):
        render_frame(_camera(), np.zeros((3, 3)), [[0, 1, 3]])


# ---- error measures ----------------------------------------------------------------------------

def test_identical_meshes_give_zero_error():
    cam = _camera()
    x, t = _quad(cam, 10.3, 50.7, 8.2, 40.9, 4.0)
    a = render_frame(cam, x, t)
    e = frame_errors(a, render_frame(cam, x.copy(), t.copy()))
    assert e["error_px"] == 0 and e["silhouette_px"] == 0 and e["surface_px"] == 0 and e["iou"] == 1
    assert e["cloth_px_run"] == e["cloth_px_ref"] == a.cloth.sum() > 0


@pytest.mark.parametrize("scale", [1.0, 2.0])
def test_sideways_shift_of_a_strip_by_whole_pixels(scale):
    """A strip taller than the image (no top or bottom silhouette), 20 pixel columns wide,
    moved sideways by a world distance that spans 4 pixels."""
    cam = _camera()
    shift_px, n_cols = 4, 20
    ref_x, t = _quad(cam, 20.2, 40.2, -100, 200, 5.0)  # edges off pixel centres at both scales
    run_x = ref_x + [shift_px * 5.0 / cam.focal_px, 0.0, 0.0]
    e = frame_errors(render_frame(cam, run_x, t, resolution_scale=scale),
                     render_frame(cam, ref_x, t, resolution_scale=scale))
    assert e["silhouette_px"] == pytest.approx(shift_px, abs=ROUNDOFF)
    assert e["surface_px"] == pytest.approx(0.0, abs=ROUNDOFF)
    # per row: one-mask pixels at distances 1..s on either side, over n + s union pixels (scale 1)
    s, n = shift_px * scale, n_cols * scale
    assert e["error_px"] == pytest.approx(s * (s + 1) / (n + s) / scale, abs=ROUNDOFF)
    assert e["iou"] == pytest.approx((n - s) / (n + s), abs=ROUNDOFF)
    assert e["cloth_px_run"] == e["cloth_px_ref"] == n * H * scale


def test_sideways_shift_by_a_fraction_of_a_pixel_count():
    cam = _camera()
    ref_x, t = _quad(cam, 20.0, 40.0, -100, 200, 5.0)
    for shift_px in (2.3, 6.7):
        run_x = ref_x + [shift_px * 5.0 / cam.focal_px, 0.0, 0.0]
        e = frame_errors(render_frame(cam, run_x, t), render_frame(cam, ref_x, t))
        assert abs(e["silhouette_px"] - shift_px) <= HALF_PIXEL


def test_depth_shift_gives_the_surface_error_at_the_reference_depth():
    cam = _camera()
    near_x, t = _big_quad(0.0)  # depth 5
    far_x, _ = _big_quad(-0.5)  # depth 5.5
    a, b = render_frame(cam, far_x, t), render_frame(cam, near_x, t)
    e = frame_errors(a, b)
    assert e["surface_px"] == pytest.approx(0.5 * cam.focal_px / 5.0, rel=ROUNDOFF)
    assert e["error_px"] == pytest.approx(e["surface_px"], rel=ROUNDOFF)
    assert e["silhouette_px"] == 0 and e["iou"] == 1
    assert frame_errors(b, a)["surface_px"] == pytest.approx(0.5 * cam.focal_px / 5.5, rel=ROUNDOFF)


def test_cloth_missing_from_one_image_costs_the_image_diagonal():
    cam = _camera()
    x, t = _quad(cam, 10.3, 20.7, 10.2, 20.9, 4.0)
    a = render_frame(cam, x, t)
    e = frame_errors(a, render_frame(cam, x[:0], t[:0]))
    assert e["error_px"] == pytest.approx(np.hypot(W, H)) and e["iou"] == 0 and np.isnan(e["surface_px"])
    e = frame_errors(render_frame(cam, x[:0], t[:0]), render_frame(cam, x[:0], t[:0]))
    assert e["error_px"] == 0 and e["iou"] == 1 and e["cloth_px_run"] == 0


def test_images_of_different_size_are_rejected():
    cam = _camera()
    x, t = _big_quad(0.0)
    with pytest.raises(ValueError, match="differ in size"):
        frame_errors(render_frame(cam, x, t), render_frame(cam, x, t, resolution_scale=0.5))


# ---- distance to the reference surface ---------------------------------------------------------

def test_point_mesh_distance_matches_brute_force():
    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, (40, 3))
    tris = np.array([rng.choice(40, 3, replace=False) for _ in range(60)])
    pts = rng.uniform(-1.5, 1.5, (200, 3))
    brute = np.array([min(point_triangle_closest(p, *x[t])[0] for t in tris) for p in pts])
    assert np.allclose(point_mesh_distance(pts, x, tris), brute, rtol=ROUNDOFF, atol=ROUNDOFF)


def test_offscreen_distance_hand_case():
    cam = _camera()  # at depth 5 the frustum reaches |x|, |y| <= 5 tan 20 deg = 1.82 m
    ref_x, ref_t = np.array([[-10.0, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]]), [[0, 1, 2], [0, 2, 3]]
    run_x = np.array([[0.0, 0.0, 0.7],     # in view: not counted however far from the surface
                      [5.0, 0.0, 0.3],     # out of view, 0.3 m above the reference surface
                      [-6.0, 2.0, -0.1],   # 0.1 m below it
                      [12.0, 0.0, 0.0]])   # beyond its edge x = 10: 2 m away
    d, n = offscreen_distance(cam, run_x, ref_x, ref_t)
    assert n == 3 and d == pytest.approx((0.3 + 0.1 + 2.0) / 3, rel=ROUNDOFF)
    d, n = offscreen_distance(cam, run_x[:1], ref_x, ref_t)
    assert n == 0 and np.isnan(d)


# ---- popping ------------------------------------------------------------------------------------

def _wall(depth: float, n: int = 2):
    """A square 2 m wide facing a camera on the -y side, `depth` m in front of it."""
    from cloth.core.mesh import grid_mesh
    m = grid_mesh(2.0, 2.0, n, n, origin=(-1.0, depth, -1.0), axes=((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))
    return m.node_x, m.face_nodes


def test_popping_is_zero_for_steady_or_uniform_motion_and_the_jump_of_a_one_frame_pop():
    cam = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 1.0, 0.0), up=(0.0, 0.0, 1.0), width=64, height=48)
    img = {z: render_frame(cam, *_wall(z)) for z in (3.0, 3.03, 3.06)}
    assert popping(img[3.0], img[3.0], img[3.0]) == 0.0
    assert popping(img[3.0], img[3.03], img[3.06]) == pytest.approx(0.0, abs=1e-9)  # uniform motion
    # a pop of 3 cm that lasts one frame: |z+ - 2 z + z-| f / z = 0.06 f / 3.03
    assert popping(img[3.0], img[3.03], img[3.0]) == pytest.approx(0.06 * cam.focal_px / 3.03, rel=1e-6)
    empty = render_frame(cam, np.zeros((0, 3)), np.zeros((0, 3), int))
    assert np.isnan(popping(img[3.0], empty, img[3.0]))
    with pytest.raises(ValueError, match="differ in size"):
        popping(img[3.0], img[3.0], render_frame(cam, *_wall(3.0), resolution_scale=0.5))


# ---- states ------------------------------------------------------------------------------------

def test_state_round_trip_with_obstacles(tmp_path):
    mesh = SimpleNamespace(node_x=np.array([[0.0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1.5]]),
                           vert_node=np.array([0, 1, 2, 3, 1]), face_verts=np.array([[0, 1, 2], [4, 3, 2]]))
    obstacles = [Sphere((0.0, 0.0, 0.3), 0.25), Plane()]
    f = save_state(tmp_path / "states" / "frame_00007.npz", mesh, 7, 0.28, obstacles)
    assert [p.name for p in f.parent.iterdir()] == ["frame_00007.npz"]  # no temporary file left
    s = load_state(f)
    assert s["frame"] == 7 and s["time"] == 0.28
    assert np.allclose(s["node_x"], mesh.node_x, atol=FLOAT32_M)
    assert s["face_nodes"].tolist() == [[0, 1, 2], [1, 3, 2]]
    assert s["capsule_ends"].shape == (1, 2, 3) and np.allclose(s["capsule_radii"], [0.25])
    assert s["obstacle_x"].shape == (4, 3) and s["obstacle_faces"].shape == (2, 3)  # the ground's square
    ox, of = occluder_mesh(s)
    assert of.max() < len(ox) and len(ox) > 4
    r = np.linalg.norm(ox[4:] - [0.0, 0.0, 0.3], axis=1)  # the sphere's vertices lie on it
    assert np.allclose(r, 0.25, atol=FLOAT32_M)
    both = merge_states([s, s])
    assert both["node_x"].shape == (8, 3) and both["face_nodes"][2:].tolist() == [[4, 5, 6], [5, 7, 6]]
    assert both["capsule_ends"].shape == (2, 2, 3) and both["obstacle_faces"].max() == 7


def test_bad_state_file_names_the_file(tmp_path):
    bad = tmp_path / "frame_00001.npz"
    np.savez(bad, node_x=np.zeros((3, 3)))
    with pytest.raises(StateError, match="frame_00001.npz.*lacks"):
        load_state(bad)
    (tmp_path / "frame_00002.npz").write_text("not a zip")
    with pytest.raises(StateError, match="frame_00002.npz"):
        load_state(tmp_path / "frame_00002.npz")


# ---- the accuracy CLI on two tiny real runs ----------------------------------------------------

TINY = ["scene=sheet_on_sphere", "camera=sheet_half", "frames=3", "output.states_every=1", *QUIET]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A coarse run and its finer reference (run folders with per-frame states), made once and
    only read: a test that writes into a run (the accuracy CLI does) works on a copy."""
    base = tmp_path_factory.mktemp("accuracy")
    run, ref = base / "run", base / "ref"
    run_config(run, *TINY, "mode=nonadaptive", "scene.scales.small.resolution=8")
    run_config(ref, *TINY, "mode=nonadaptive", "scene.scales.small.resolution=12")  # the finer one
    return run, ref


def test_runs_write_a_state_per_frame(runs):
    run, _ = runs
    files = sorted(p.name for p in (run / "states").iterdir())
    assert files == [f"frame_{k:05d}.npz" for k in range(4)]  # frame 0 and every frame
    s = load_state(run / "states" / "frame_00003.npz")
    assert s["frame"] == 3 and s["time"] == pytest.approx(0.12) and s["face_nodes"].shape == (128, 3)
    assert s["capsule_ends"].shape == (1, 2, 3)  # the sphere; the ground is a tessellated square
    assert s["node_x"].dtype == np.float64 and np.all(np.isfinite(s["node_x"]))


def test_accuracy_cli_writes_its_files(runs, tmp_path, capsys):
    from experiments.analysis.accuracy import COLUMNS, main

    run, ref = runs
    run = _copy_with(run, tmp_path / "run")  # the CLI writes its files into the run folder
    assert main([str(run), "--reference", str(ref), "--resolution-scale", "0.25"]) == 0
    table = pd.read_parquet(run / "accuracy.parquet")
    assert list(table.columns) == list(COLUMNS) and table["frame"].tolist() == [0, 1, 2, 3]
    assert np.all(np.isfinite(table["error_px"])) and np.all(table["error_px"] >= 0)
    assert np.all((table["iou"] >= 0) & (table["iou"] <= 1))
    summary = json.loads((run / "accuracy.json").read_text())
    for c in COLUMNS:
        assert f"{c}_mean" in summary and f"{c}_max" in summary
    assert summary["error_px_mean"] == pytest.approx(table["error_px"].mean())
    assert summary["error_px_max"] == pytest.approx(table["error_px"].max())
    assert summary["frames"] == 4 and summary["resolution"] == [320, 180]
    assert summary["reference"] == str(ref.resolve()) and "screenspace-v2" in summary["definition"]
    # popping needs the frames on both sides: none at the first and last frame
    pop = table["popping_px"].to_numpy()
    assert np.isnan(pop[0]) and np.isnan(pop[-1]) and np.all(np.isfinite(pop[1:-1])) and np.all(pop[1:-1] >= 0)
    assert summary["popping_still_px_mean"] is not None  # split by the run's remesh records
    assert "4 frames" in capsys.readouterr().out


def test_reference_against_itself_has_no_error(runs):
    from experiments.analysis.accuracy import evaluate_run

    _, ref = runs
    table = evaluate_run(ref, ref, resolution_scale=0.25)
    assert np.all(table["error_px"] == 0) and np.all(table["iou"] == 1)
    # its out-of-view nodes lie on its own surface
    assert np.all(table["offscreen_distance_m"].fillna(0) < ROUNDOFF)


def _copy_with(src: Path, dst: Path, edit=None) -> Path:
    shutil.copytree(src, dst)
    if edit is not None:
        cfg = yaml.safe_load((dst / "config.yaml").read_text())
        edit(cfg)
        (dst / "config.yaml").write_text(yaml.safe_dump(cfg))
    return dst


def _shifted_member(ref: Path, dst: Path, dx: float) -> Path:
    """A copy of `ref` whose every state has the cloth moved by dx metres along x: a member of an
    ensemble that differs from `ref` by a known amount."""
    shutil.copytree(ref, dst)
    for f in (dst / "states").glob("frame_*.npz"):
        s = load_state(f)
        s["node_x"] = s["node_x"] + [dx, 0.0, 0.0]
        np.savez(f, **{k: v for k, v in s.items() if k != "restart"})
    return dst


@pytest.mark.slow
def test_reference_ensemble_gives_mean_interval_and_chaos_floor(runs, tmp_path, capsys):
    from experiments.analysis.accuracy import FLOOR_SATURATION, evaluate_runs, main

    run, ref = runs
    members = [ref, _shifted_member(ref, tmp_path / "m1", 0.03), _shifted_member(ref, tmp_path / "m2", -0.03)]
    single = [evaluate_runs([run], m, resolution_scale=0.25)[0] for m in members]
    table = evaluate_runs([run], members, resolution_scale=0.25)[0]
    assert table["members"].tolist() == [3] * 4
    # each column the mean over the members; the interval brackets it
    mean = np.mean([t["error_px"] for t in single], axis=0)
    assert np.allclose(table["error_px"], mean)
    assert np.all(table["error_lo_px"] <= table["error_px"] + ROUNDOFF)
    assert np.all(table["error_px"] <= table["error_hi_px"] + ROUNDOFF)
    # the floor: the median error between pairs of members, each pair measured as a run against a reference
    pair = lambda a, b: evaluate_runs([a], b, resolution_scale=0.25)[0]["error_px"].to_numpy()  # noqa: E731
    floors = np.median([pair(members[1], members[0]), pair(members[2], members[0]), pair(members[2], members[1])],
                       axis=0)
    assert np.allclose(table["floor_px"], floors) and np.all(table["floor_px"] > 0)
    assert np.allclose(table["error_ratio"], table["error_px"] / table["floor_px"])
    # one member: no floor
    assert single[0]["floor_px"].isna().all() and single[0]["members"].tolist() == [1] * 4
    run = _copy_with(run, tmp_path / "run")
    assert main([str(run), "--reference", *map(str, members), "--resolution-scale", "0.25"]) == 0
    summary = json.loads((run / "accuracy.json").read_text())
    assert summary["members"] == 3 and len(summary["reference"]) == 3
    f = table["floor_px"].to_numpy()
    sat = int(table["frame"][np.flatnonzero(f >= FLOOR_SATURATION * f.max())[0]])
    assert summary["floor_saturation_frame"] == sat
    assert "floor" in capsys.readouterr().out
    # statistics of visible cloth per shot: the run's shot mean of its per-frame values, the
    # members' mean of theirs (each member's own, as a run against itself), the distance in spreads
    vis = pd.read_parquet(run / "visible.parquet")
    assert set(vis["statistic"]) == set(visible.STATISTICS) and vis["shot"].tolist() == [0] * 5
    vis = vis.set_index("statistic")
    own = {name: [evaluate_runs([m], m, resolution_scale=0.25)[0][name].mean() for m in members]
           for name in ("visible_area_px", "silhouette_length_px", "wrinkle_energy_px2")}
    spread_seen = False
    for name, values in own.items():
        row, spread = vis.loc[name], np.std(values, ddof=1)
        assert row["run"] == pytest.approx(table[name].mean())
        assert row["members_mean"] == pytest.approx(np.mean(values))
        assert row["members_spread"] == pytest.approx(spread, abs=1e-12)
        if spread > 1e-9 * abs(np.mean(values)):
            spread_seen = True
            assert row["distance"] == pytest.approx(abs(row["run"] - np.mean(values)) / spread)
            assert summary[f"{name}_distance_mean"] == pytest.approx(row["distance"])
    assert spread_seen  # the shifted members differ in at least one statistic
    assert summary["hem_radius_m_distance_mean"] is None  # the sheet has no pins: no hem
    assert "visible-v1" in summary["definition"]


@pytest.mark.parametrize("edit, message", [
    (lambda c: c["camera"]["camera"].update(fov_y_deg=30.0), r"camera config differs .* camera\.camera\.fov_y_deg"),
    (lambda c: c["scene"].update(name="flag"), r"scene 'sheet_on_sphere' differs from the reference's 'flag'"),
    (lambda c: c["scene"]["params"].update(frame_time=0.02), r"frame time 0\.04 s differs .* 0\.02 s"),
    (lambda c: c["scene"]["params"].update(sphere_radius=0.3), r"scene\.params\.sphere_radius differs"),
])
def test_mismatched_reference_is_rejected_before_any_work(runs, tmp_path, capsys, edit, message):
    from experiments.analysis.accuracy import main

    run, ref = runs
    run = _copy_with(run, tmp_path / "run")
    bad = _copy_with(ref, tmp_path / "bad_ref", edit)
    assert main([str(run), "--reference", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("accuracy error:") and len(err.strip().splitlines()) == 1
    assert re.search(message, err), err
    assert not (run / "accuracy.parquet").exists() and not (run / "accuracy.json").exists()


def test_missing_states_and_short_reference_are_named(runs, tmp_path, capsys):
    from experiments.analysis.accuracy import main

    run, ref = runs
    bare = _copy_with(run, tmp_path / "bare")
    shutil.rmtree(bare / "states")
    assert main([str(bare), "--reference", str(ref)]) == 2
    assert f"{bare}: no per-frame states" in capsys.readouterr().err
    short = _copy_with(ref, tmp_path / "short")
    (short / "states" / "frame_00003.npz").unlink()
    assert main([str(run), "--reference", str(short)]) == 2
    assert "the reference has no state for 1 of the run's 4 frames (first [3])" in capsys.readouterr().err
    assert main([str(run), "--reference", str(ref), "--resolution-scale", "0"]) == 2
    assert "--resolution-scale must be a number > 0" in capsys.readouterr().err
