"""A camera whose future is not known (mode.view.lookahead=false, cloth.view.live): exact on a
constant-velocity move, conservative (widened by its measured error) on an orbit, blind to a cut
until it happens; in the view-dependent sizing, the prescribed path refines ahead of a cut and the
live camera does not."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import build_sim

from cloth.view.camera import Camera
from cloth.view.live import LiveCamera, pose_error
from cloth.view.paths import CutPath, KeyframePath, OrbitPath, StaticPath

FRAME = 0.04  # s
POSE_TOL = 1e-9  # m, rad: a constant-velocity prediction of a linear move is exact but for round-off
FRUSTUM_TOL = 1e-9  # m (rad): a point on the true frustum's boundary tested against the widened one
# an orbit at 45 degrees per second seen 6 frames (0.24 s) ahead: a bound of a few degrees is a useful
# prediction; a bound of tens of degrees would refine everything, conservative but useless
WIDENING_MAX_DEG = 10.0


def _dolly():
    """A camera sliding along +x at 0.5 m/s, looking down at the ground (linear keyframes)."""
    return KeyframePath(np.array([0.0, 4.0]), np.array([[0.0, 0.0, 1.5], [2.0, 0.0, 1.5]]),
                        np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
                        np.array([30.0, 30.0]))


def test_a_constant_velocity_move_is_predicted_exactly_and_not_widened():
    path = _dolly()
    live = LiveCamera(path)
    for k in range(4):
        live.observe(0.5 + k * FRAME)
    t = 0.5 + 3 * FRAME + 0.2
    guess, true = live.camera_at(t), path.camera_at(t)
    assert np.allclose(guess.position, true.position, atol=POSE_TOL)
    assert np.allclose(guess.forward, true.forward, atol=POSE_TOL)
    assert live.error_bound(0.2) < POSE_TOL and guess.fov_y_deg == pytest.approx(30.0, abs=1e-6)
    assert live.camera_at(0.5 + FRAME) == path.camera_at(0.5 + FRAME)  # a time seen: the pose as it was


def test_on_an_orbit_the_widened_prediction_holds_what_the_true_camera_sees():
    path = OrbitPath(center=(0.0, 0.0, 0.5), radius=2.0, height=0.5, period_s=8.0)
    live = LiveCamera(path)
    for k in range(30):  # 1.2 s of frames: errors measured for horizons of 1 ... 15 frames
        live.observe(k * FRAME)
    now = 29 * FRAME
    for tau in (FRAME, 3 * FRAME, 6 * FRAME):
        true = path.camera_at(now + tau)
        guess, widened = live.best_guess_at(now + tau), live.camera_at(now + tau)
        assert pose_error(guess, true) > 0 and widened.fov_y_deg > true.fov_y_deg
        # the true frustum's corners at the look-at distance lie inside the widened prediction
        dist = np.linalg.norm(np.subtract(true.look_at, true.position))
        far = np.array(true.frustum_corners()[4:])
        corners = true.center + (far - true.center) * dist / true.far
        assert np.all(widened.distance_to_frustum(corners) <= FRUSTUM_TOL)
        # the widening is the measured error of that horizon (a steady orbit: the same as now), not more
        assert live.error_bound(tau) >= pose_error(guess, true) - FRUSTUM_TOL
        assert widened.fov_y_deg - true.fov_y_deg < WIDENING_MAX_DEG


def test_a_cut_is_not_seen_coming_and_the_new_shot_is_held_once_it_comes():
    a = Camera((0.3, 0.0, 1.5), (0.3, 0.0, 0.0), (1.0, 0.0, 0.0), 22.6)
    b = Camera((-0.3, 0.0, 1.5), (-0.3, 0.0, 0.0), (-1.0, 0.0, 0.0), 22.6)
    path = CutPath([0.0, 1.2], [StaticPath(a), StaticPath(b)])
    live = LiveCamera(path)
    assert live.cuts == ()  # announced to no one in advance
    for k in range(28):
        live.observe(k * FRAME)
    assert live.camera_at(1.2 + FRAME).position == a.position  # before the cut: the shot held
    live.observe(1.2 + FRAME)
    assert len(live.history) == 1 and live.camera_at(1.5).position == b.position


def _nu_of_revealed_faces(lookahead: bool, frame: int) -> float:
    """The mean view factor at `frame` of sheet_on_sphere under sheet_cut, the live camera having
    seen that frame and the two before, of the faces at the -x edge (out of frame, farther than the
    margin, until the cut at 1.2 s = frame 30; in frame after it)."""
    sim = build_sim("scene=sheet_on_sphere", "mode=viewdep", "camera=sheet_cut", "output.rerun=false",
                    f"mode.view.lookahead={str(lookahead).lower()}", "mode.view.anticipation_frames=5")
    sim.time = frame * FRAME
    rem = sim.remesher
    assert isinstance(rem.camera, LiveCamera) != lookahead
    if not lookahead:
        for k in (2, 1, 0):
            rem.camera.observe(sim.time - k * FRAME)
    nu, *_ = rem.view_factors(sim.mesh, sim.time)
    c = sim.mesh.node_x[sim.mesh.face_nodes].mean(axis=1)
    return float(nu[c[:, 0] < -0.4].mean())


def test_the_prescribed_path_refines_ahead_of_the_cut_and_the_live_camera_does_not():
    before = 27  # three frames before the cut: inside the 5-frame anticipation window
    prescribed, live = _nu_of_revealed_faces(True, before), _nu_of_revealed_faces(False, before)
    assert prescribed > 2 * live  # eq 4 sees the cut coming on the prescribed path only
    after = 31
    assert _nu_of_revealed_faces(False, after) == pytest.approx(_nu_of_revealed_faces(True, after), rel=0.05)


def test_a_live_camera_survives_a_checkpoint(tmp_path):
    """Its history and errors are plain lists of the project's classes: the safe unpickler reads them."""
    from cloth.io.checkpoint import load_checkpoint, save_checkpoint

    sim = build_sim("scene=sheet_on_sphere", "mode=viewdep", "camera=orbit", "output.rerun=false",
                    "mode.view.lookahead=false")
    rows = [sim.advance_frame() for _ in range(3)]
    save_checkpoint(tmp_path, sim, rows)
    back = load_checkpoint(tmp_path).sim.remesher.camera
    live = sim.remesher.camera
    assert isinstance(back, LiveCamera) and [t for t, _ in back.history] == [t for t, _ in live.history]
    assert back.history and back.camera_at(1.0) == live.camera_at(1.0)


def test_the_anticipation_table_labels_a_live_camera():
    from paper_figures.ablations import lead_label

    assert lead_label({"anticipation": True, "T": 5.0, "lookahead": False}) == "live T=5"
    assert lead_label({"anticipation": True, "T": 5.0, "lookahead": True}) == "T=5"
    assert lead_label({"anticipation": True, "T": 5.0, "lookahead": float("nan")}) == "T=5"  # not viewdep
    assert lead_label({"anticipation": False, "T": 5.0, "lookahead": False}) == "off"


def test_a_restart_never_sees_the_future_and_sees_the_frames_before_it():
    """A first observation at t (a window restarted mid-run) first observes the frames of the
    last ERROR_WINDOW_S; time going back (a restart at an earlier frame) forgets every later pose."""
    path = OrbitPath(center=(0.0, 0.0, 0.5), radius=2.0, height=0.5, period_s=8.0)
    fresh = LiveCamera(path, FRAME)
    fresh.observe(1.0)
    running = LiveCamera(path, FRAME)
    for k in range(26):
        running.observe(k * FRAME)  # from 0 to 1.0 s, frame by frame
    assert [t for t, _ in fresh.history] == pytest.approx([t for t, _ in running.history])
    a, b = fresh.camera_at(1.2), running.camera_at(1.2)  # the same prediction, the same widening
    assert np.allclose(a.position, b.position, atol=POSE_TOL) and a.fov_y_deg == pytest.approx(b.fov_y_deg)
    assert a.fov_y_deg > path.camera_at(1.2).fov_y_deg  # the errors were measured on the frames before
    running.observe(0.5)  # restarted at an earlier frame
    assert max(t for t, _ in running.history) == pytest.approx(0.5)
    assert running.camera_at(0.9) != path.camera_at(0.9)  # a prediction, not the pose it had seen
