"""Hydra configs: every config composes and builds; every bad value gives its one message."""

import json

import numpy as np
import pandas as pd
import pytest
from helpers import compose_config, config_choices, run_module
from hydra.errors import MissingConfigException

from cloth.view.paths import StaticPath
from experiments.build import ConfigError, build_camera, build_simulation

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

SCENES = config_choices("scene")
MATERIALS = config_choices("material")
SOLVERS = config_choices("solver")


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("scale", ["small", "paper"])
def test_every_scene_and_scale_builds(scene, scale):
    if scene == "arcsim":  # its scene is a file of the user's (tests/test_arcsim_scene.py builds some)
        with pytest.raises(ConfigError, match=r"scene\.params\.conf is required"):
            build_simulation(compose_config(f"scene={scene}", f"scale={scale}"))
        return
    sim, frames = build_simulation(compose_config(f"scene={scene}", f"scale={scale}"))
    assert frames >= 1 and sim.mesh.n_faces > 0
    assert sim.scene.name.split("/")[0] == scene  # a crowd names its character: scene/dancer_00


@pytest.mark.parametrize("scene", SCENES)
def test_a_fixed_camera_by_position_and_target_for_every_scene(scene):
    # conf/camera/fixed.yaml replaces any scene's own camera work (a character scene's shots too)
    cfg = compose_config(f"scene={scene}", "camera=fixed", "camera.position=[1.5,-2.0,1.2]",
                         "camera.target=[0.1,0.2,0.3]", "camera.up=[0,1,0]", "camera.fov_y_deg=25")
    path = build_camera(cfg)
    assert isinstance(path, StaticPath) and path.camera_at(0.0) is path.camera_at(5.0)
    cam = path.camera
    assert cam.position == (1.5, -2.0, 1.2) and cam.look_at == (0.1, 0.2, 0.3)  # look_at follows target
    assert cam.up == (0.0, 1.0, 0.0) and cam.fov_y_deg == 25.0
    assert (cam.width, cam.height) == (1280, 720)
    assert build_camera(compose_config(f"scene={scene}", "camera=fixed")).camera.look_at == (0.0, 0.0, 0.5)


@pytest.mark.parametrize("material", MATERIALS)
@pytest.mark.parametrize("solver", SOLVERS)
def test_every_material_and_solver_builds(material, solver):
    sim, _ = build_simulation(compose_config(f"material={material}", f"solver={solver}"))
    assert sim.scene.material.name == material and sim.solver.method == solver


@pytest.mark.parametrize("override, key", [
    ("scene.params.frame_time=-0.01", "scene.params.frame_time"),
    ("scene.params.steps_per_frame=0", "scene.params.steps_per_frame"),
    ("scene.scales.small.resolution=0", "scene.params.resolution"),
    ("frames=0", "frames"),
    ("material.density=-1", "material.density"),
    ("material.poisson_ratio=0.7", "material.poisson_ratio"),
    ("solver.tolerance=0", "solver.tolerance"),
    ("scale=huge", "scale"),
    ("+scene.params.colour=3", "colour"),
    ("max_speed=-1", "max_speed"),
    ("resolution_factor=0", "resolution_factor"),
    ("resolution_factor=abc", "resolution_factor"),
    ("reference_member=-1", "reference_member"),
    ("reference_member=2", "reference_member"),  # a member is a reference run
    ("reference_check=fine", "reference_check"),  # a check refines the reference
    ("reference_check=coarse", "reference_check"),
])
def test_config_errors_name_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        build_simulation(compose_config(override))


def test_a_reference_check_doubles_the_references_segments_or_its_steps():
    ref, _ = build_simulation(compose_config("reference=true"))
    fine, _ = build_simulation(compose_config("reference=true", "reference_check=fine"))
    half_dt, _ = build_simulation(compose_config("reference=true", "reference_check=half_dt"))
    # sheet_on_sphere: 2 n^2 faces for n cells per side
    assert fine.mesh.n_faces == 4 * ref.mesh.n_faces and half_dt.mesh.n_faces == ref.mesh.n_faces
    assert half_dt.scene.steps_per_frame == 2 * ref.scene.steps_per_frame == 2 * fine.scene.steps_per_frame
    assert half_dt.scene.frame_time == ref.scene.frame_time


def test_resolution_factor_scales_the_fixed_mesh_only():
    base, _ = build_simulation(compose_config("scene=solo_dancer", "mode=nonadaptive"))
    half, _ = build_simulation(compose_config("scene=solo_dancer", "mode=nonadaptive", "resolution_factor=0.5"))
    n = compose_config("scene=solo_dancer").scene.scales.small.resolution
    # the circle skirt's faces grow with the square of its segments around
    assert half.mesh.n_faces < base.mesh.n_faces and round(n * 0.5) == 16
    assert half.mesh.n_faces == pytest.approx(base.mesh.n_faces * (16 / n) ** 2, rel=0.15)
    for extra in (("mode=adaptive",), ("+point=reference",)):
        with pytest.raises(ConfigError, match="resolution_factor: scales the fixed mesh"):
            build_simulation(compose_config("scene=solo_dancer", "resolution_factor=2", *extra))


def test_reference_members_start_from_their_own_jitter():
    """Member K of a reference ensemble is the reference with the scene's seed + 1000 K: a distinct
    initial state for each member, the same for the same member."""
    import numpy as np

    point = {0: "+point=reference", 1: "+point=member/1", 2: "+point=member/2"}
    x = {k: build_simulation(compose_config("scene=solo_dancer", p))[0].mesh.node_x for k, p in point.items()}
    again = build_simulation(compose_config("scene=solo_dancer", "+point=member/1"))[0].mesh.node_x
    assert np.array_equal(x[1], again)
    assert not np.array_equal(x[0], x[1]) and not np.array_equal(x[1], x[2])
    assert np.abs(x[1] - x[0]).max() < 1e-3  # sub-millimetre jitter: the same garment


@pytest.mark.parametrize("override, group", [("scene=nope", "scene"), ("material=silk", "material"),
                                             ("mode=warp", "mode")])
def test_unknown_config_choice_names_the_group(override, group):
    with pytest.raises(MissingConfigException, match=f"'{group}/"):
        compose_config(override)


def _cli(run_dir, *args):
    """`python -m experiments.run` with `args`, its run folder `run_dir`."""
    return run_module("experiments.run", f"hydra.run.dir={run_dir}", *args, timeout=600)


def test_cli_config_error_is_one_clear_message(tmp_path):
    out = _cli(tmp_path / "run", "scene=hanging_sheet", "scene.params.frame_time=-1")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "config error: scene.params.frame_time: must be > 0, got -1"]
    assert not (tmp_path / "run" / "frames.parquet").exists()


@pytest.mark.parametrize("override, message", [
    ("scene=nope", "config error: scene: unknown scene 'nope'; known: "),
    ("material=silk", "config error: material: unknown material 'silk'; known: "),
    ("mode=fast", "config error: mode: unknown mode 'fast'; known: "),
])
def test_cli_unknown_choice_is_one_clear_message(tmp_path, override, message):
    out = _cli(tmp_path / "run", override)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), out.stderr
    assert "cotton" in lines[0] or "sheet_on_sphere" in lines[0] or "adaptive" in lines[0]  # the choices
    assert not (tmp_path / "run").exists()


def test_cli_run_writes_a_complete_run_folder(tmp_path):
    out = _cli(tmp_path, "scene=sheet_on_sphere", "frames=3", "output.progress=false", "output.obj_every=3")
    assert out.returncode == 0, out.stderr
    assert str(tmp_path) in out.stdout and "recording.rrd" in out.stdout
    frames = pd.read_parquet(tmp_path / "frames.parquet")
    assert list(frames["frame"]) == [1, 2, 3]
    for col in ("sim_time_s", "wall_s", "time_sizing_s", "time_remesh_s", "time_physics_s", "time_solve_s",
                "time_collisions_s", "time_io_s", "time_other_s", "nodes", "verts", "faces",
                "solver_iterations", "solver_residual", "kinetic_energy_j", "potential_energy_j",
                "max_speed_m_s", "min_face_quality"):
        assert col in frames.columns, col
    assert (frames["time_collisions_s"] > 0).all() and (frames["time_io_s"] > 0).all()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["frames_completed"] == 3
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["seed"] == 0
    assert (tmp_path / "recording.rrd").stat().st_size > 0
    assert (tmp_path / "config.yaml").exists() and (tmp_path / ".hydra" / "config.yaml").exists()
    assert (tmp_path / "obj" / "frame_00003.obj").exists()


def test_non_finite_state_stops_the_run_at_its_frame_and_keeps_earlier_frames(tmp_path):
    from cloth.runner import run
    from cloth.simulation import SimulationDiverged

    sim, _ = build_simulation(compose_config("scene=hanging_sheet", "output.rerun=false"))
    step = sim.step

    def poisoned_step(timings, stats):  # a NaN appears in the third frame
        if sim.frame == 2:
            sim.mesh.node_v[0, 0] = np.nan
        step(timings, stats)

    sim.step = poisoned_step
    with pytest.raises(SimulationDiverged, match=r"frame 3: non-finite node positions or velocities"):
        run(sim, 10, tmp_path)
    assert list(pd.read_parquet(tmp_path / "frames.parquet")["frame"]) == [1, 2]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "diverged" and "frame 3" in summary["message"]


def test_diverging_run_names_the_frame_and_keeps_earlier_frames(tmp_path):
    from cloth.runner import run
    from cloth.simulation import SimulationDiverged

    sim, _ = build_simulation(compose_config("scene=hanging_sheet", "max_speed=1.0", "output.rerun=false"))
    with pytest.raises(SimulationDiverged, match=r"frame (\d+): node speed") as info:
        run(sim, 60, tmp_path)
    frame = int(info.value.args[0].split()[1].rstrip(":"))
    assert frame > 1  # the sheet starts at rest and takes a few frames to swing past 1 m/s
    frames = pd.read_parquet(tmp_path / "frames.parquet")
    assert list(frames["frame"]) == list(range(1, frame))
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "diverged" and f"frame {frame}" in summary["message"]


def test_mode_defaults_are_arcsims_and_the_papers():
    """conf/mode: ARCSim's remeshing defaults (issue 3) and the paper's view-dependent constants."""
    ad = compose_config("mode=adaptive").mode
    assert (ad.sizing.refine_angle, ad.sizing.refine_compression, ad.sizing.refine_velocity) == (0.3, 0.005, 0.5)
    assert (ad.sizing.size_min, ad.sizing.size_max, ad.sizing.aspect_min, ad.sizing.combine) == (0.01, 0.2, 0.2, "max")
    assert ad.buckling is None
    vd = compose_config("mode=viewdep", "camera=sheet_half").mode
    assert (vd.view.nu_front, vd.view.nu_back, vd.view.nu_out) == (1.0, 0.2, 0.01)
    assert (vd.view.margin, vd.view.anticipation_frames, vd.view.anticipation) == (0.4, 5, True)
    assert vd.sizing == ad.sizing and vd.remesh == ad.remesh  # viewdep is adaptive plus the view
    sim, _ = build_simulation(compose_config("mode=viewdep", "camera=sheet_half"))
    assert sim.buckling is not None and sim.buckling.k == 10 and sim.buckling.mode == "adaptive"
    for scene in ("sheet_on_sphere", "flag"):  # the ARCSim-like scenes: frames of 0.04 s, 8 steps
        s = build_simulation(compose_config(f"scene={scene}"))[0].scene
        assert (s.frame_time, s.steps_per_frame) == (0.04, 8)
