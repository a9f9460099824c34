"""Restarts and the re-synchronised error: material-space transfer (cloth.core.transfer), restart
states (cloth.io.states format 2), Simulation.restart_from, the correspondence error
(cloth.eval.correspondence) on constructed cases with known answers, and experiments.sync on
tiny real runs."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from helpers import QUIET, compose_config, run_config

from cloth.core.mesh import grid_mesh, merge_meshes
from cloth.core.transfer import (
    MaterialTransferError,
    face_components,
    locate,
    match_components,
    transfer_node_values,
)
from cloth.eval.correspondence import correspondence_error, pixel_points
from cloth.eval.screenspace import render_frame
from cloth.io.states import READABLE_FORMATS, StateError, load_state, require_restart, save_state
from cloth.view.camera import Camera
from experiments.build import build_simulation

ROUNDOFF = 1e-9  # exact arithmetic up to a few ulps of metre-sized coordinates
# A sample is the point seen at a pixel centre; a rigid shift of k pixels moves every one by k,
# up to the round-off of the ray-triangle intersection and of two projections.
SHIFT_TOL_PX = 1e-6
# A run restarted from its own state agrees with its continuation to the solver's tolerance
# (the CG warm start is not part of a state): far below a pixel after a few frames.
SELF_RESTART_PX = 1e-3
SELF_RESTART_M = 1e-6


def sheet(n: int, size: float = 1.0, origin=(0.0, 0.0, 0.0)):
    return grid_mesh(size, size, n, n, origin=origin)


# ---- material-space transfer -------------------------------------------------------------------

def test_locate_finds_the_face_and_weights_of_inside_points_and_the_nearest_of_outside_ones():
    m = sheet(6)
    comp, bounds = face_components(m.vert_u, m.face_verts)
    assert comp.max() == 0 and np.allclose(bounds, [[0, 0, 1, 1]])
    rng = np.random.default_rng(1)
    p = rng.uniform(0.0, 1.0, (500, 2))
    face, w, d = locate(m.vert_u, m.face_verts, comp, p, np.zeros(500, int))
    assert np.all(d == 0) and np.all(w >= -ROUNDOFF) and np.allclose(w.sum(axis=1), 1.0)
    assert np.allclose(np.einsum("pk,pkd->pd", w, m.vert_u[m.face_verts[face]]), p, atol=ROUNDOFF)
    out = np.array([[1.3, 0.5], [-0.2, -0.2], [0.5, 1.05]])
    face, w, d = locate(m.vert_u, m.face_verts, comp, out, np.zeros(3, int))
    assert d == pytest.approx([0.3, np.hypot(0.2, 0.2), 0.05], abs=ROUNDOFF)
    closest = np.einsum("pk,pkd->pd", w, m.vert_u[m.face_verts[face]])
    assert np.allclose(closest, [[1.0, 0.5], [0.0, 0.0], [0.5, 1.0]], atol=ROUNDOFF)


def test_transfer_reproduces_linear_fields_within_the_matching_piece():
    """Two pieces whose patterns overlap in material space (as karate's skirts): each takes its
    values from its own piece, and a field linear in the material coordinates is carried exactly."""
    A = np.array([[1.0, 0.2], [0.1, 0.9], [0.3, -0.4]])

    def field(u, piece):
        return u @ A.T + (0.0 if piece == 0 else 10.0)

    fine = merge_meshes([sheet(9, 1.0), grid_mesh(0.6, 0.4, 7, 5)])
    coarse = merge_meshes([sheet(4, 1.0), grid_mesh(0.6, 0.4, 3, 2)])
    src = {"vert_u": fine.vert_u, "vert_node": fine.vert_node, "face_verts": fine.face_verts}
    n_first = sheet(9).n_nodes
    node_u = np.zeros((fine.n_nodes, 2))
    node_u[fine.vert_node] = fine.vert_u
    src["node_x"] = np.vstack([field(node_u[:n_first], 0), field(node_u[n_first:], 1)])
    src["node_v"] = -src["node_x"]
    out, dist = transfer_node_values(src, coarse.vert_u, coarse.vert_node, coarse.face_verts)
    c_first = sheet(4).n_nodes
    cu = np.zeros((coarse.n_nodes, 2))
    cu[coarse.vert_node] = coarse.vert_u
    expect = np.vstack([field(cu[:c_first], 0), field(cu[c_first:], 1)])
    assert np.all(dist <= ROUNDOFF)
    assert np.allclose(out["node_x"], expect, atol=1e-9) and np.allclose(out["node_v"], -expect, atol=1e-9)


def test_pieces_of_another_garment_are_refused():
    _, a = face_components(sheet(3).vert_u, sheet(3).face_verts)
    other = grid_mesh(2.0, 0.5, 4, 1)
    _, b = face_components(other.vert_u, other.face_verts)
    assert match_components(a, a).tolist() == [0]
    with pytest.raises(MaterialTransferError, match="matches no piece"):
        match_components(a, b)


# ---- states with restart data ------------------------------------------------------------------

def test_restart_state_round_trip_and_older_states(tmp_path):
    cfg = compose_config("scene=solo_dancer", "scene.scales.small.resolution=10", "frames=1", *QUIET)
    sim, _ = build_simulation(cfg)
    mesh = sim.mesh
    f = save_state(tmp_path / "frame_00000.npz", mesh, 0, 0.0, sim.obstacle_set.obstacles, sim.scene.handles,
                   restart=True)
    s = load_state(f)
    assert s["restart"] and 2 in READABLE_FORMATS
    for k in ("node_x", "node_v", "vert_u"):
        assert np.array_equal(s[k], getattr(mesh, k))  # float64: exact
    assert np.array_equal(s["face_verts"], mesh.face_verts) and np.array_equal(s["node_pinned"], mesh.node_pinned)
    h = sim.scene.handles[0]
    assert np.all(s["node_handle"][h.nodes] == 0) and np.sum(s["node_handle"] >= 0) == len(h.nodes)
    assert np.array_equal(s["handle_local"][h.nodes], h.local)
    plain = load_state(save_state(tmp_path / "frame_00001.npz", mesh, 1, 0.04))
    assert not plain["restart"]
    with pytest.raises(StateError, match="frame_00001.npz holds positions only"):
        require_restart(plain, tmp_path / "frame_00001.npz")
    np.savez(tmp_path / "old.npz", format=np.int32(1), frame=np.int64(0), time=np.float64(0.0),  # format 1
             node_x=mesh.node_x.astype(np.float32), face_nodes=mesh.face_nodes,
             capsule_ends=np.zeros((0, 2, 3), np.float32), capsule_radii=np.zeros(0, np.float32),
             obstacle_x=np.zeros((0, 3), np.float32), obstacle_faces=np.zeros((0, 3), np.int32))
    old = load_state(tmp_path / "old.npz")
    assert not old["restart"] and old["node_x"].shape == mesh.node_x.shape


# ---- Simulation.restart_from --------------------------------------------------------------------

DANCER = ("scene=solo_dancer", "scene.scales.small.resolution=10", "frames=3", *QUIET)


def _advance(sim, frames):
    for _ in range(frames):
        sim.advance_frame()


@pytest.mark.parametrize("mode", ["nonadaptive", "adaptive"])
def test_a_restart_from_its_own_state_continues_as_the_run(tmp_path, mode):
    """Run 2 frames, save, restart a fresh simulation from the file: its mesh, handles, clock and
    obstacles are the run's, and one more frame lands where the run's own next frame does."""
    cfg = compose_config(*DANCER, f"mode={mode}")
    a, _ = build_simulation(cfg)
    _advance(a, 2)
    f = save_state(tmp_path / "s.npz", a.mesh, a.frame, a.time, a.obstacle_set.obstacles, a.scene.handles,
                   restart=True)
    b, _ = build_simulation(cfg)
    b.restart_from(load_state(f))
    assert (b.frame, b.time, b.steps_taken) == (a.frame, a.time, a.steps_taken)
    assert b.mesh.n_faces == a.mesh.n_faces and np.array_equal(b.mesh.node_x, a.mesh.node_x)
    assert np.array_equal(b.mesh.node_v, a.mesh.node_v)
    for ha, hb in zip(a.scene.handles, b.scene.handles):
        assert np.array_equal(ha.nodes, hb.nodes) and np.allclose(ha.local, hb.local, atol=ROUNDOFF)
    assert np.array_equal(b.obstacle_set.obstacles[0].ends, a.obstacle_set.obstacles[0].ends)
    a.advance_frame()
    b.advance_frame()
    assert b.mesh.n_faces == a.mesh.n_faces
    assert np.abs(b.mesh.node_x - a.mesh.node_x).max() < SELF_RESTART_M


def test_a_fixed_mesh_restarts_from_a_finer_runs_state_by_interpolation(tmp_path):
    fine, _ = build_simulation(compose_config(*DANCER, "mode=nonadaptive", "scene.scales.small.resolution=20"))
    _advance(fine, 2)
    f = save_state(tmp_path / "s.npz", fine.mesh, fine.frame, fine.time, fine.obstacle_set.obstacles,
                   fine.scene.handles, restart=True)
    coarse, _ = build_simulation(compose_config(*DANCER, "mode=nonadaptive"))
    n_faces = coarse.mesh.n_faces
    coarse.restart_from(load_state(f))
    assert coarse.mesh.n_faces == n_faces and coarse.time == fine.time  # its own mesh, the state's clock
    h = coarse.scene.handles[0]
    assert np.allclose(coarse.mesh.node_x[h.nodes], h.targets(fine.time), atol=ROUNDOFF)  # on its own motion
    # every coarse node lies on the fine cloth (a node of a finer polygon's border, within a sagitta)
    from cloth.collision.nearest import point_mesh_distance
    d = point_mesh_distance(coarse.mesh.node_x, fine.mesh.node_x, fine.mesh.face_nodes)[0]
    assert d.max() < 0.01
    coarse.advance_frame()
    assert np.all(np.isfinite(coarse.mesh.node_x))


def test_the_symmetric_restart_puts_a_remeshing_mode_on_its_own_mesh(tmp_path):
    """restart_from(state, own_mesh=...): a remeshing mode restarts on its own run's mesh with the
    reference's positions transferred by material coordinates, as a fixed mesh does: at frame 0,
    where the adaptive run's mesh is the fixed mesh of the same resolution, both restart to the
    same positions; at frame 2 the adaptive mesh is its own and lies on the reference's cloth."""
    def saved(sim, name):
        return load_state(save_state(tmp_path / name, sim.mesh, sim.frame, sim.time, sim.obstacle_set.obstacles,
                                     sim.scene.handles, restart=True))

    fine_cfg = compose_config(*DANCER, "mode=nonadaptive", "scene.scales.small.resolution=20")
    fine, _ = build_simulation(fine_cfg)
    ref0 = saved(fine, "ref0.npz")
    adaptive_cfg = compose_config(*DANCER, "mode=adaptive")
    a, _ = build_simulation(adaptive_cfg)
    own0 = saved(a, "own0.npz")
    fixed, _ = build_simulation(compose_config(*DANCER, "mode=nonadaptive"))
    fixed.restart_from(ref0)
    b, _ = build_simulation(adaptive_cfg)
    b.restart_from(ref0, own_mesh=own0)
    assert np.array_equal(b.mesh.face_verts, fixed.mesh.face_verts)  # the same mesh ...
    assert np.array_equal(b.mesh.node_x, fixed.mesh.node_x)  # ... given the same positions, to the bit
    _advance(fine, 2)
    _advance(a, 2)
    ref2, own2 = saved(fine, "ref2.npz"), saved(a, "own2.npz")
    c, _ = build_simulation(adaptive_cfg)
    c.restart_from(ref2, own_mesh=own2)
    assert c.mesh.n_faces == a.mesh.n_faces and np.array_equal(c.mesh.vert_u, a.mesh.vert_u)
    from cloth.collision.nearest import point_mesh_distance
    assert point_mesh_distance(c.mesh.node_x, fine.mesh.node_x, fine.mesh.face_nodes)[0].max() < 0.01
    h = c.scene.handles[0]
    assert np.allclose(c.mesh.node_x[h.nodes], h.targets(fine.time), atol=ROUNDOFF)  # on its own motion
    with pytest.raises(ValueError, match="own_mesh is a state of frame 0"):
        build_simulation(adaptive_cfg)[0].restart_from(ref2, own_mesh=own0)
    c.advance_frame()
    assert np.all(np.isfinite(c.mesh.node_x))


def test_a_state_of_another_frame_time_is_refused(tmp_path):
    a, _ = build_simulation(compose_config(*DANCER))
    f = save_state(tmp_path / "s.npz", a.mesh, 3, 0.1, a.obstacle_set.obstacles, a.scene.handles, restart=True)
    with pytest.raises(ValueError, match="another frame time"):
        a.restart_from(load_state(f))


# ---- the correspondence error ------------------------------------------------------------------

CAM = Camera(position=(0.5, -3.0, 0.5), look_at=(0.5, 0.0, 0.5), up=(0.0, 0.0, 1.0), fov_y_deg=40.0,
             width=160, height=120)


def _facing_sheet(n: int, shift_px: float = 0.0) -> dict:
    """A flat sheet in the plane y = 0 facing CAM, moved sideways by `shift_px` camera pixels."""
    m = grid_mesh(1.0, 1.0, n, n, origin=(0.0, 0.0, 0.0), axes=((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))
    x = m.node_x.copy()
    x[:, 0] += shift_px * 3.0 / CAM.focal_px  # depth 3 m: one pixel is 3 / f metres
    return {"node_x": x, "face_nodes": m.face_nodes, "vert_u": m.vert_u, "vert_node": m.vert_node,
            "face_verts": m.face_verts}


def test_pixel_points_are_the_points_seen_at_the_pixel_centres():
    ref = _facing_sheet(4)
    img = render_frame(CAM, ref["node_x"], ref["face_nodes"])
    face, w = pixel_points(img, CAM, ref["node_x"], ref["face_nodes"])
    p = np.einsum("pk,pkd->pd", w, ref["node_x"][ref["face_nodes"][face]])
    px, _ = CAM.project(p)
    rows, cols = np.nonzero(img.cloth)
    assert np.allclose(px, np.column_stack([cols + 0.5, rows + 0.5]), atol=1e-6)


@pytest.mark.parametrize("run_n", [4, 3])  # the same mesh, and a coarser mesh of the same sheet
def test_identical_states_give_zero_and_a_rigid_shift_of_k_pixels_gives_k(run_n):
    ref = _facing_sheet(4)
    img = render_frame(CAM, ref["node_x"], ref["face_nodes"])
    same = correspondence_error(CAM, img, ref, _facing_sheet(run_n))
    assert same["sync_error_px"] == pytest.approx(0.0, abs=SHIFT_TOL_PX) and same["sync_samples"] == img.cloth.sum()
    for k in (1.0, 7.5):
        e = correspondence_error(CAM, img, ref, _facing_sheet(run_n, k))
        assert e["sync_error_px"] == pytest.approx(k, abs=SHIFT_TOL_PX)
        assert e["sync_error_p90_px"] == pytest.approx(k, abs=SHIFT_TOL_PX)


@pytest.mark.parametrize("run_n", [4, 3])
def test_a_rigid_shift_of_k_mm_at_a_constant_depth_gives_k_mm(run_n):
    """The depth-scaled pixel: the sheet faces the camera at 3 m, so a sideways shift of k mm is
    k mm at every sample, whatever the pixels it spans; the 1080p pixels are the camera's times
    the ratio of the diagonals."""
    ref = _facing_sheet(4)
    img = render_frame(CAM, ref["node_x"], ref["face_nodes"])
    for k_mm in (1.0, 12.5):
        e = correspondence_error(CAM, img, ref, _facing_sheet(run_n, k_mm * 1e-3 * CAM.focal_px / 3.0))
        assert e["sync_error_mm"] == pytest.approx(k_mm, rel=SHIFT_TOL_PX)
        assert e["sync_error_p90_mm"] == pytest.approx(k_mm, rel=SHIFT_TOL_PX)
        scale = np.hypot(1920, 1080) / np.hypot(CAM.width, CAM.height)
        assert e["sync_error_px1080"] == pytest.approx(e["sync_error_px"] * scale, rel=ROUNDOFF)


def test_no_cloth_in_view_gives_nan():
    ref = _facing_sheet(3)
    away = Camera(position=(0.5, 3.0, 0.5), look_at=(0.5, 6.0, 0.5), width=40, height=30)
    img = render_frame(away, ref["node_x"], ref["face_nodes"])
    e = correspondence_error(away, img, ref, ref)
    assert np.isnan(e["sync_error_px"]) and np.isnan(e["sync_error_mm"]) and e["sync_samples"] == 0


# ---- experiments.sync on tiny real runs ----------------------------------------------------------

TINY = ["scene=sheet_on_sphere", "camera=sheet_half", "frames=4", "output.states_every=1", *QUIET]


@pytest.fixture(scope="module")
def sync_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("sync")
    runs = {"ref": ["mode=nonadaptive", "scene.scales.small.resolution=10"],
            "fixed": ["mode=nonadaptive", "scene.scales.small.resolution=6"],
            "adaptive": ["mode=adaptive"]}
    for name, extra in runs.items():
        run_config(base / name, *TINY, *extra)
    return base


def _copies(sync_runs, tmp_path, *names) -> dict:
    """{name: a copy of the fixture's run folder in tmp_path}: sync writes into the runs it measures."""
    runs = {name: tmp_path / name for name in names}
    for name, d in runs.items():
        shutil.copytree(sync_runs / name, d)
    return runs


def test_sync_frames_include_the_lead_of_each_cut():
    from experiments.analysis.sync import sync_frames

    assert sync_frames(30, 10, 8) == [(0, False), (10, False), (20, False)]
    assert sync_frames(30, 10, 8, cut_frames=[12, 40, 3], before_cut=5) == [
        (0, False), (7, True), (10, False), (20, False)]  # 40 - 5 + 8 > 30, 3 - 5 < 0: no window


def test_sync_cli_measures_each_run_and_the_reference_against_itself_is_zero(sync_runs, tmp_path, capsys):
    from experiments.analysis.sync import COLUMNS, main

    ref = sync_runs / "ref"
    runs = []
    for name in ("ref", "fixed", "adaptive"):
        runs.append(tmp_path / name)
        shutil.copytree(sync_runs / name, runs[-1])
    assert main([*map(str, runs), "--reference", str(ref), "--every", "2", "--horizon", "2",
                 "--resolution-scale", "0.25"]) == 0
    for run in runs:
        table = pd.read_parquet(run / "sync.parquet")
        assert list(table.columns) == list(COLUMNS)
        assert table["sync_frame"].tolist() == [0, 2] and table["frame"].tolist() == [2, 4]
        assert np.all(np.isfinite(table["sync_error_px"])) and not table["diverged"].any()
        s = json.loads((run / "sync.json").read_text())
        assert s["windows"] == 2 and s["horizon"] == 2 and "correspondence-v1" in s["definition"]
        for measure in ("sync_error_px", "sync_error_mm", "sync_error_px1080"):  # each with its interval
            assert s[f"{measure}_lo"] <= s[f"{measure}_mean"] <= s[f"{measure}_hi"], measure
    self_error = pd.read_parquet(runs[0] / "sync.parquet")["sync_error_px"]
    assert self_error.max() < SELF_RESTART_PX
    fixed = pd.read_parquet(runs[1] / "sync.parquet")
    assert fixed["faces_mean"].iloc[0] < pd.read_parquet(runs[0] / "sync.parquet")["faces_mean"].iloc[0]


def test_sync_restarts_a_remeshing_mode_on_its_own_mesh_and_records_the_error_at_h0(sync_runs, tmp_path):
    from experiments.analysis.sync import main

    ref = sync_runs / "ref"
    runs = _copies(sync_runs, tmp_path, "ref", "adaptive")
    assert main([*map(str, runs.values()), "--reference", str(ref), "--every", "2", "--horizon", "2",
                 "--resolution-scale", "0.25", "--restart", "own_mesh"]) == 0
    for d in runs.values():
        table = pd.read_parquet(d / "sync.parquet")
        assert np.all(np.isfinite(table["sync_error_h0_px"])) and np.all(np.isfinite(table["sync_error_px"]))
        s = json.loads((d / "sync.json").read_text())
        assert s["restart"] == "own_mesh" and s["sync_error_h0_px_mean"] is not None
    assert pd.read_parquet(runs["ref"] / "sync.parquet")["sync_error_h0_px"].max() < SELF_RESTART_PX  # itself
    bare = tmp_path / "no_states"
    shutil.copytree(sync_runs / "adaptive", bare)
    shutil.rmtree(bare / "states")
    assert main([str(bare), "--reference", str(ref), "--every", "2", "--horizon", "2", "--restart", "own_mesh"]) == 2


def test_sync_refuses_a_reference_without_restart_data_and_bad_options(sync_runs, tmp_path, capsys):
    from experiments.analysis.sync import main

    ref = tmp_path / "ref"
    shutil.copytree(sync_runs / "ref", ref)
    s = load_state(ref / "states" / "frame_00002.npz")
    np.savez(ref / "states" / "frame_00002.npz", **{k: s[k] for k in
             ("format", "frame", "time", "node_x", "face_nodes", "capsule_ends", "capsule_radii", "obstacle_x",
              "obstacle_faces")})
    run = sync_runs / "fixed"
    assert main([str(run), "--reference", str(ref), "--every", "2", "--horizon", "2"]) == 2
    assert "frame_00002.npz holds positions only" in capsys.readouterr().err
    assert main([str(run), "--reference", str(sync_runs / "ref"), "--horizon", "0"]) == 2
    assert "--horizon must be an integer >= 1" in capsys.readouterr().err
    assert main([str(run), "--reference", str(sync_runs / "ref"), "--horizon", "9"]) == 2
    assert "no window of 9 frames fits in 4 frames" in capsys.readouterr().err
    assert not (run / "sync.parquet").exists()


def test_sync_per_frame_records_every_frame_of_every_window_and_the_reference_is_zero_at_each(sync_runs, tmp_path):
    from experiments.analysis.sync import FRAME_COLUMNS, main

    ref = sync_runs / "ref"
    runs = _copies(sync_runs, tmp_path, "ref", "adaptive")
    assert main([*map(str, runs.values()), "--reference", str(ref), "--every", "2", "--horizon", "2",
                 "--resolution-scale", "0.25", "--restart", "own_mesh", "--per-frame"]) == 0
    for d in runs.values():
        frames = pd.read_parquet(d / "sync_frames.parquet")
        windows = pd.read_parquet(d / "sync.parquet")
        assert list(frames.columns) == list(FRAME_COLUMNS)
        assert frames[["sync_frame", "h", "frame"]].values.tolist() == [[0, 1, 1], [0, 2, 2], [2, 1, 3], [2, 2, 4]]
        # the last frame of a window is the window's own error, measured the same way
        at_h = frames[frames["h"] == 2].set_index("sync_frame")["sync_error_px"]
        assert np.allclose(at_h, windows.set_index("sync_frame")["sync_error_px"], rtol=0, atol=SELF_RESTART_PX)
        by_h = json.loads((d / "sync.json").read_text())["sync_error_px_by_h"]
        assert sorted(by_h) == ["1", "2"]
    # the reference restarted from itself stays on itself at every frame of the window, not only at H
    assert pd.read_parquet(runs["ref"] / "sync_frames.parquet")["sync_error_px"].max() < SELF_RESTART_PX
    assert pd.read_parquet(runs["adaptive"] / "sync_frames.parquet")["sync_error_px"].max() > SELF_RESTART_PX


def test_sync_restarts_every_window_from_each_member_and_pairs_them_member_by_member(sync_runs, tmp_path):
    from experiments.analysis.sync import main, paired_difference_interval, read_windows

    member = tmp_path / "member"  # the reference's configuration with another seed: another trajectory
    run_config(member, *TINY, "mode=nonadaptive", "scene.scales.small.resolution=10", "seed=1")
    ref = sync_runs / "ref"
    runs = _copies(sync_runs, tmp_path, "ref", "fixed")
    assert main([*map(str, runs.values()), "--reference", str(ref), str(member), "--every", "2", "--horizon", "2",
                 "--resolution-scale", "0.25"]) == 0
    for d in runs.values():
        table = pd.read_parquet(d / "sync.parquet")
        assert table[["member", "sync_frame"]].values.tolist() == [[0, 0], [0, 2], [1, 0], [1, 2]]
        s = json.loads((d / "sync.json").read_text())
        assert s["windows"] == 4 and s["members"] == 2
        assert table["shot"].tolist() == [0] * 4 and list(s["sync_error_px_by_shot"]) == ["0"]  # camera without cuts
    # the reference's configuration restarted from either member's state continues as that member
    assert pd.read_parquet(runs["ref"] / "sync.parquet")["sync_error_px"].max() < SELF_RESTART_PX
    # two runs pair window by window within each member
    a, b = read_windows(runs["fixed"]), read_windows(runs["ref"])
    assert list(a.index) == [(0, 0), (0, 2), (1, 0), (1, 2)]
    lo, hi = paired_difference_interval(a, b)
    assert 0 < lo <= hi


def test_windows_are_grouped_by_the_shot_they_end_in():
    from experiments.analysis.sync import _by_shot

    t = pd.DataFrame({"shot": [0, 0, 1, 2], "sync_error_px": [1.0, 3.0, 5.0, np.nan],
                      "sync_error_mm": [2.0, 2.0, 1.0, 4.0]})
    assert _by_shot(t) == {"sync_error_px_by_shot": {0: 2.0, 1: 5.0, 2: None},
                           "sync_error_mm_by_shot": {0: 2.0, 1: 1.0, 2: 4.0}}
