"""output.usd_every: the run as a USD stage (cloth.io.usd), read back with pxr and compared with the
run's own saved states; a resumed run continues the stage; a missing pxr is a config error."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import QUIET, compose_config, run_config

from cloth.io.states import load_state
from cloth.io.usd import USD_FILE, VERTICAL_APERTURE_MM, camera_matrix
from cloth.view.camera import Camera

pxr = pytest.importorskip("pxr", reason="the usd extra (usd-core) is part of the dev install")
from pxr import Usd, UsdGeom  # noqa: E402 - after the skip above

FLOAT32_M = 1e-6  # m: positions are stored as float32 (relative 6e-8 of coordinates below 1 m, and more)
FRAMES, EVERY = 4, 2
RUN = ("scene=sheet_on_sphere", "mode=viewdep", "camera=sheet_half", f"frames={FRAMES}",
       f"output.usd_every={EVERY}", f"output.states_every={EVERY}", *QUIET)


@pytest.fixture(scope="module")
def usd_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("usd") / "run"
    summary = run_config(run, *RUN)
    assert summary["status"] == "completed"
    return run


def test_the_stage_holds_the_cloth_of_the_saved_states_at_every_written_frame(usd_run):
    stage = Usd.Stage.Open(str(usd_run / USD_FILE))
    cfg = compose_config(*RUN)
    fps = 1.0 / cfg.scene.params.frame_time
    assert stage.GetTimeCodesPerSecond() == pytest.approx(fps) and stage.GetFramesPerSecond() == pytest.approx(fps)
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, FRAMES)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    cloth = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Cloth"))
    assert [int(t) for t in cloth.GetPointsAttr().GetTimeSamples()] == list(range(0, FRAMES + 1, EVERY))
    pv = UsdGeom.PrimvarsAPI(cloth)
    faces_seen = set()
    for frame in range(0, FRAMES + 1, EVERY):
        state = load_state(usd_run / "states" / f"frame_{frame:05d}.npz")
        x = np.asarray(cloth.GetPointsAttr().Get(frame))
        assert x.shape == state["node_x"].shape and np.abs(x - state["node_x"]).max() < FLOAT32_M
        idx = np.asarray(cloth.GetFaceVertexIndicesAttr().Get(frame)).reshape(-1, 3)
        assert np.array_equal(idx, state["face_nodes"])
        assert set(np.asarray(cloth.GetFaceVertexCountsAttr().Get(frame))) == {3}
        st = np.asarray(pv.GetPrimvar("st").Get(frame))
        assert np.allclose(st, state["vert_u"][state["face_verts"]].reshape(-1, 2), atol=FLOAT32_M)
        assert pv.GetPrimvar("st").GetInterpolation() == UsdGeom.Tokens.faceVarying
        nu = np.asarray(pv.GetPrimvar("viewFactor").Get(frame))
        assert nu.shape == (len(idx),) and nu.min() >= 0 and nu.max() <= 1 and nu.min() < 1 == nu.max()
        faces_seen.add(len(idx))
    assert len(faces_seen) > 1  # the remesher changed the topology, and the stage follows it
    sphere = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Obstacles/sphere"))
    assert sphere and len(sphere.GetPointsAttr().Get()) > 0 and not sphere.GetPointsAttr().GetTimeSamples()
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
    assert cam and cam.GetFocalLengthAttr().Get(0) > 0
    # USD's own validators (schema types, primvar sizes, stage metadata, ...) find nothing
    from pxr import UsdValidation

    registry = UsdValidation.ValidationRegistry()
    errors = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators()).Validate(stage)
    assert not errors, [e.GetMessage() for e in errors]


def test_the_usd_camera_has_the_cameras_pose_and_field_of_view():
    cam = Camera(position=(1.0, -2.0, 0.5), look_at=(0.0, 0.0, 0.2), up=(0, 0, 1), fov_y_deg=40.0, width=1280,
                 height=720)
    m = camera_matrix(cam)
    assert np.allclose(m[3, :3], cam.position)
    forward = -m[2, :3]  # USD cameras look down -Z
    assert np.allclose(forward, (np.subtract(cam.look_at, cam.position)) / np.linalg.norm(
        np.subtract(cam.look_at, cam.position)))
    assert np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3)) and m[1, 2] > 0  # orthonormal, +Y up tilts to +z
    f = 0.5 * VERTICAL_APERTURE_MM / np.tan(np.radians(40.0) / 2)
    assert np.degrees(2 * np.arctan(0.5 * VERTICAL_APERTURE_MM / f)) == pytest.approx(40.0)


def test_output_usd_every_needs_pxr_and_a_count(monkeypatch):
    import importlib.util

    from experiments.build import ConfigError
    from experiments.checks import check_output

    with pytest.raises(ConfigError, match=r"^output\.usd_every: "):
        check_output(compose_config("output.usd_every=-1"))
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pxr" else real(name, *a))
    with pytest.raises(ConfigError, match=r"^output\.usd_every: .*usd-core"):
        check_output(compose_config("output.usd_every=2"))
    check_output(compose_config("output.usd_every=0"))  # not asked for: no pxr needed


def test_a_run_resumed_from_its_checkpoint_continues_its_stage(tmp_path, monkeypatch):
    """Killed (SIGTERM) after frame 3 with a checkpoint at frame 2: the resumed run drops the
    stage's samples after frame 2 and writes frames 3-5 again, as an uninterrupted run would."""
    import os
    import signal

    from cloth.signals import Terminated
    from cloth.simulation import Simulation
    from experiments.launch import run_from_config
    from experiments.resuming import resume

    run = tmp_path / "run"
    cfg = compose_config("scene=hanging_sheet", "mode=adaptive", "frames=5", "output.checkpoint_every=2",
                         "output.usd_every=1", "output.states_every=1", *QUIET)
    original, calls = Simulation.advance_frame, [0]

    def advance_frame(self):
        calls[0] += 1
        if calls[0] == 4:  # frames 1-3 done and written, the checkpoint at frame 2
            os.kill(os.getpid(), signal.SIGTERM)
        return original(self)

    with monkeypatch.context() as m:
        m.setattr(Simulation, "advance_frame", advance_frame)
        with pytest.raises(Terminated):
            run_from_config(cfg, run)
    written = Usd.Stage.Open(str(run / USD_FILE))
    assert [int(t) for t in UsdGeom.Mesh(written.GetPrimAtPath("/World/Cloth")).GetPointsAttr().GetTimeSamples()] \
        == [0, 1, 2, 3]
    del written
    assert resume(run, progress=False)["status"] == "completed"
    stage = Usd.Stage.Open(str(run / USD_FILE))
    cloth = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Cloth"))
    assert [int(t) for t in cloth.GetPointsAttr().GetTimeSamples()] == list(range(6))
    assert stage.GetEndTimeCode() == 5
    for frame in range(6):
        state = load_state(run / "states" / f"frame_{frame:05d}.npz")
        assert np.abs(np.asarray(cloth.GetPointsAttr().Get(frame)) - state["node_x"]).max() < FLOAT32_M
        assert np.array_equal(np.asarray(cloth.GetFaceVertexIndicesAttr().Get(frame)).reshape(-1, 3),
                              state["face_nodes"])


def test_a_crowd_writes_one_stage_per_character_and_one_that_holds_them(tmp_path):
    """crowd.usda references each character's cloth.usdc under /World/dancer_NN; the camera comes
    with the first character only."""
    run = tmp_path / "crowd"
    summary = run_config(run, "scene=multiple_dancers", "scene.params.dancers=2", "scene.scales.small.resolution=8",
                         "frames=2", "crowd_jobs=1", "output.usd_every=1", "output.states_every=1", *QUIET)
    assert summary["status"] == "completed"
    stage = Usd.Stage.Open(str(run / "crowd.usda"))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 2)
    for i in range(2):
        cloth = UsdGeom.Mesh(stage.GetPrimAtPath(f"/World/dancer_{i:02d}/Cloth"))
        state = load_state(run / f"dancer_{i:02d}" / "states" / "frame_00002.npz")
        assert np.abs(np.asarray(cloth.GetPointsAttr().Get(2)) - state["node_x"]).max() < FLOAT32_M
    assert stage.GetPrimAtPath("/World/dancer_00/Camera") and not stage.GetPrimAtPath("/World/dancer_01/Camera")
