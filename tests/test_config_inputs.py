"""No input silently ignored (issue 32, item 5): every bad value stops the run before any work
with one line naming its key and exit code 2; what the command line says wins over a scene's
scale preset; the run folder's resolved.yaml holds the values the run used."""

import json
import runpy
import sys
import warnings

import numpy as np
import pytest
import yaml
from helpers import MEASURED_JSON, QUIET, compose_config, run_config, run_module, write_material
from omegaconf import OmegaConf

from experiments.build import ConfigError, build, build_simulation, resolved_record
from experiments.launch import RESOLVED

# What Hydra writes into a run folder before the run starts: the config it composed (.hydra/)
# and its log file (empty: nothing is logged before the config is checked).
HYDRA_FILES = {".hydra", ".hydra/config.yaml", ".hydra/hydra.yaml", ".hydra/overrides.yaml", "run.log"}


def _arcsim_with_a_nan(root) -> str:
    """A one-cloth ARCSim folder whose mesh has a NaN coordinate; the path of its conf."""
    for sub in ("conf", "meshes", "materials"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    (root / "meshes" / "square.obj").write_text(
        "v -0.3 -0.3 0.3\nv 0.3 nan 0.3\nv 0.3 0.3 0.3\nv -0.3 0.3 0.3\n"
        "vt 0 0\nvt 0.6 0\nvt 0.6 0.6\nvt 0 0.6\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    write_material(root / "materials" / "knit.json", text=json.dumps(MEASURED_JSON))
    conf = {"frame_time": 0.04, "frame_steps": 4, "end_time": 0.2,
            "cloths": [{"mesh": "meshes/square.obj", "materials": [{"data": "materials/knit.json"}]}]}
    (root / "conf" / "nan.json").write_text(json.dumps(conf))
    return str(root / "conf" / "nan.json")


VIEW = ("mode=viewdep", "camera=sheet_half")
# (overrides, the key the message must name); every case is refused with exit code 2.
BAD = [
    # the cases
    (("scene=solo_dancer", "mode=adaptive", "mode.sizing.size_min=-0.05"), "mode.sizing.size_min"),
    (("scene=solo_dancer", "+scene.params.resolution=0"), "scene.params.resolution"),
    (("output.obj_every=abc",), "output.obj_every"),
    (("seed=-1",), "seed"),
    (("material.youngs_modulus=inf",), "material.youngs_modulus"),
    (("solver.tolerance=abc",), "solver.tolerance"),
    (("solver.max_iterations=abc",), "solver.max_iterations"),
    (("solver.bending_hessian=newton",), "solver.bending_hessian"),
    ((*VIEW, "mode.view.nu_out=abc"), "mode.view.nu_out"),
    (("+scene.params.resolution=2.5",), "scene.params.resolution"),
    (("max_speed=inf",), "max_speed"),
    (("scene=arcsim", "scene.params.conf={arcsim_nan}"), "scene.params.conf"),
    (("hydra.run.dir={tmp}/a_file/run",), "hydra.run.dir"),
    # a clash of the command line with the preset's own key: both named
    (("mode=adaptive", "mode.sizing.size_min=0.03", "scene.scales.small.sizing.size_min=0.04"),
     "scene.scales.small.sizing.size_min"),
    (("+scene.params.resolution=10", "scene.scales.small.resolution=12"), "scene.scales.small.resolution"),
    # top level
    (("+foo=1",), "foo"),
    (("collision.ccd_passes=abc",), "collision.ccd_passes"),
    (("collision.ccd_passes=-1",), "collision.ccd_passes"),
    (("collision.max_zone_passes=2.5",), "collision.max_zone_passes"),
    (("+collision.zone_rounds=4",), "collision.zone_rounds"),
    (("collision=3",), "collision"),
    (("+max_sped=10",), "max_sped"),
    (("+scene.framez=10",), "scene.framez"),
    (("max_speed=-1",), "max_speed"),
    (("max_speed=nan",), "max_speed"),
    (("seed=abc",), "seed"),
    (("seed=1.5",), "seed"),
    (("frames=0",), "frames"),
    (("frames=2.5",), "frames"),
    (("resolution_factor=abc",), "resolution_factor"),
    (("reference=maybe",), "reference"),
    (("reference_member=-1",), "reference_member"),
    (("reference_check=fine",), "reference_check"),
    (("reference=true", "reference_check=twice"), "reference_check"),
    (("scale=huge",), "scale"),
    (("scene=multiple_dancers", "crowd_jobs=0"), "crowd_jobs"),
    # material, solver
    (("material.density=-1",), "material.density"),
    (("material.poisson_ratio=0.7",), "material.poisson_ratio"),
    (("material.bending_stiffness=abc",), "material.bending_stiffness"),
    (("material.damping_mass=nan",), "material.damping_mass"),
    (("solver.tolerance=inf",), "solver.tolerance"),
    (("solver.max_iterations=0",), "solver.max_iterations"),
    (("solver.method=magic",), "solver.method"),
    # scene
    (("scene.params.frame_time=inf",), "scene.params.frame_time"),
    (("scene.params.steps_per_frame=2.5",), "scene.params.steps_per_frame"),
    (("scene=hanging_sheet", "scene.params.size=abc"), "scene.params.size"),
    (("scene.params.jitter=inf",), "scene.params.jitter"),
    (("+scene.params.colour=3",), "scene.params.colour"),
    (("scene=solo_dancer", "scene.params.body=wood"), "scene.params.body"),
    (("scene.effects=[membrane,magic]",), "scene.effects"),
    (("camera=fixed", "camera.fov_y_deg=abc"), "camera.fov_y_deg"),
    # output
    (("output.rerun=maybe",), "output.rerun"),
    (("output.progress=3",), "output.progress"),
    (("output.checkpoint_every=-1",), "output.checkpoint_every"),
    (("output.states_every=abc",), "output.states_every"),
    (("+output.foo=1",), "output.foo"),
    # the remesher
    (("mode=adaptive", "mode.every=0"), "mode.every"),
    (("mode=adaptive", "mode.every=true"), "mode.every"),
    (("mode=adaptive", "mode.sizing.combine=mean"), "mode.sizing.combine"),
    (("mode=adaptive", "mode.sizing.size_min=0.3", "mode.sizing.size_max=0.1"), "mode.sizing.size_min"),
    (("mode=adaptive", "mode.remesh.aspect_min=abc"), "mode.remesh.aspect_min"),
    (("mode=adaptive", "+mode.remesh.max_split_rounds=-3"), "mode.remesh.max_split_rounds"),
    (("mode=adaptive", "mode.pop_filter.regularization=-1"), "mode.pop_filter.regularization"),
    (("mode=adaptive", "+mode.viewz.nu_out=0.1"), "mode.viewz"),
    ((*VIEW, "mode.view.margin=-1"), "mode.view.margin"),
    ((*VIEW, "mode.view.anticipation=maybe"), "mode.view.anticipation"),
    ((*VIEW, "mode.view.samples_per_frame=1.5"), "mode.view.samples_per_frame"),
    ((*VIEW, "mode.buckling.k=0"), "mode.buckling.k"),
    (("mode=viewdep",), "mode.buckling"),  # no camera
]


def _fill(args, tmp_path):
    (tmp_path / "a_file").write_text("not a folder")
    subs = {"tmp": str(tmp_path)}
    if any("{arcsim_nan}" in a for a in args):
        subs["arcsim_nan"] = _arcsim_with_a_nan(tmp_path / "arcsim")
    return [a.format(**subs) for a in args]


def _cli_in_process(argv, monkeypatch, capsys):
    """`python -m experiments.run *argv` in this process: (exit code, stderr)."""
    monkeypatch.setattr(sys, "argv", ["experiments.run", *argv])
    code = 0
    try:
        with warnings.catch_warnings():  # runpy: experiments.run is imported already (by this module)
            warnings.simplefilter("ignore", RuntimeWarning)
            runpy.run_module("experiments.run", run_name="__main__")
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err


def _assert_refused(code, err, key, run_dir):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("config error: "), err
    assert key in lines[0], lines[0]
    if run_dir.exists():  # nothing but what Hydra writes before the run (the config)
        files = {str(p.relative_to(run_dir)) for p in run_dir.rglob("*")}
        assert files <= HYDRA_FILES, files
        assert not (run_dir / "run.log").exists() or (run_dir / "run.log").read_text() == ""


@pytest.mark.slow
@pytest.mark.parametrize("args, key", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_a_bad_input_is_one_line_naming_its_key_exit_2_and_nothing_written(args, key, tmp_path, monkeypatch,
                                                                          capsys):
    run_dir = tmp_path / "run"
    argv = [f"hydra.run.dir={run_dir}", "frames=1", *QUIET, *_fill(args, tmp_path)]
    code, err = _cli_in_process(argv, monkeypatch, capsys)
    _assert_refused(code, err, key, run_dir)


@pytest.mark.slow
@pytest.mark.parametrize("args, key", [BAD[0], BAD[2], BAD[11]], ids=["size_min", "obj_every", "run_dir"])
def test_a_bad_input_in_a_new_process(args, key, tmp_path):
    run_dir = tmp_path / "run"
    out = run_module("experiments.run", f"hydra.run.dir={run_dir}", "frames=1", *QUIET, *_fill(args, tmp_path))
    _assert_refused(out.returncode, out.stderr, key, run_dir)


def test_enough_bad_inputs():
    assert len(BAD) >= 40 and len({a for a, _ in BAD}) == len(BAD)


# ---- the command line wins over the scale preset -------------------------------------------

def test_the_command_line_wins_over_the_scale_preset():
    dancer = ("scene=solo_dancer", "mode=adaptive")
    preset = compose_config(*dancer).scene.scales.small
    assert build_simulation(compose_config(*dancer))[0].remesher.sizing.size_min == preset.sizing.size_min
    assert build_simulation(compose_config(*dancer, "mode.sizing.size_min=0.03"))[0].remesher.sizing.size_min == 0.03
    fixed = build(compose_config("scene=solo_dancer", "+scene.params.resolution=20"))
    assert fixed.scene_params["resolution"] == 20 != preset.resolution
    assert fixed.sim.mesh.n_faces < build(compose_config("scene=solo_dancer")).sim.mesh.n_faces
    # over the reference preset too
    ref = build(compose_config("scene=solo_dancer", "+point=reference", "+scene.params.resolution=40"))
    assert ref.scene_params["resolution"] == 40
    assert build(compose_config("scene=solo_dancer", "+point=reference")).scene_params["resolution"] == \
        preset.reference.resolution


def test_the_recorded_config_builds_what_ran():
    """config.yaml is the config with the preset giving way: building it again (replay, resume,
    a crowd's worker) gives the command line's values, not the preset's."""
    cfg = compose_config("scene=solo_dancer", "mode=adaptive", "mode.sizing.size_min=0.03",
                         "+scene.params.resolution=20")
    again = build(OmegaConf.create(OmegaConf.to_yaml(cfg, resolve=True)))
    assert again.sim.remesher.sizing.size_min == 0.03 and again.scene_params["resolution"] == 20


def test_a_sizing_sweep_of_an_arcsim_conf_sweeps(tmp_path):
    """mode.sizing.K wins over an ARCSim conf's remeshing value too (the conf says 0.01)."""
    conf = tmp_path / "c" / "conf" / "square.json"
    _arcsim_with_a_nan(tmp_path / "c")
    obj = tmp_path / "c" / "meshes" / "square.obj"
    obj.write_text(obj.read_text().replace("nan", "-0.3"))
    spec = json.loads((tmp_path / "c" / "conf" / "nan.json").read_text())
    spec["cloths"][0]["remeshing"] = {"refine_angle": 0.3, "refine_compression": 0.01, "refine_velocity": 1,
                                      "size": [0.05, 0.3], "aspect_min": 0.2}
    conf.write_text(json.dumps(spec))
    base = ("scene=arcsim", f"scene.params.conf={conf}", "mode=adaptive", "scale=paper")
    assert compose_config(*base).mode.sizing.refine_compression == 0.005  # what config.yaml said
    assert build(compose_config(*base)).sim.remesher.sizing.refine_compression == 0.01  # what ran
    swept = build(compose_config(*base, "mode.sizing.refine_compression=0.02"))
    assert swept.sim.remesher.sizing.refine_compression == 0.02
    assert resolved_record(build(compose_config(*base)))["remesher"]["sizing"]["refine_compression"] == 0.01


# ---- resolved.yaml: what ran -------------------------------------------------------------

def _same(recorded, obj, where=""):
    """Every field of the dataclass `obj` equals the recorded mapping's."""
    import dataclasses

    assert set(recorded) == {f.name for f in dataclasses.fields(obj)}, where
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if isinstance(value, np.ndarray):
            assert np.array_equal(np.asarray(recorded[f.name]), value), f"{where}.{f.name}"
        elif isinstance(value, tuple):
            assert recorded[f.name] == list(value), f"{where}.{f.name}"
        else:
            assert recorded[f.name] == value, f"{where}.{f.name}"


def test_resolved_yaml_records_the_built_objects(tmp_path):
    out = tmp_path / "run"
    run_config(out, *QUIET, *VIEW, "scene=hanging_sheet", "frames=1", "mode.sizing.refine_angle=0.4",
               "collision.ccd_passes=7")
    rec = yaml.safe_load((out / RESOLVED).read_text())
    built = build(OmegaConf.load(out / "config.yaml"))
    sim = built.sim
    assert rec["frames"] == built.frames == 1 and rec["max_speed"] == sim.max_speed
    _same(rec["solver"], sim.solver, "solver")
    _same(rec["buckling"], sim.buckling, "buckling")
    _same(rec["collision"], sim.collision, "collision")
    assert rec["collision"]["ccd_passes"] == 7
    _same({k: v for k, v in rec["material"].items() if k != "kind"}, sim.scene.material, "material")
    for key, obj in (("sizing", sim.remesher.sizing), ("remesh", sim.remesher.params),
                     ("pop_filter", sim.remesher.pop), ("view", sim.remesher.view)):
        _same(rec["remesher"][key], obj, f"remesher.{key}")
    assert rec["remesher"]["sizing"]["refine_angle"] == 0.4
    preset = compose_config("scene=hanging_sheet").scene.scales.small
    assert rec["remesher"]["sizing"]["size_min"] == preset.sizing.size_min  # the preset, where nothing overrides it
    assert rec["remesher"]["every"] == sim.remesher.every and rec["remesher"]["frame_time"] == sim.remesher.frame_time
    scene = rec["scene"]
    assert scene["name"] == sim.scene.name and scene["frame_time"] == sim.scene.frame_time
    assert scene["steps_per_frame"] == sim.scene.steps_per_frame and scene["effects"] == sorted(sim.scene.effects)
    assert scene["faces"] == sim.mesh.n_faces
    assert scene["params"]["resolution"] == built.scene_params["resolution"] == preset.resolution
    assert rec == resolved_record(built)


def test_collision_options_reach_the_collision_pass():
    sim = build(compose_config("scene=layered_sheets", "collision.ccd_passes=7", "collision.max_zone_passes=5")).sim
    params = sim.self_collision
    assert (params.ccd_passes, params.max_zone_passes, params.proximity_passes) == (7, 5, 2)


def test_resolution_factor_is_recorded_as_the_resolution_that_ran():
    built = build(compose_config("scene=solo_dancer", "resolution_factor=0.5"))
    assert resolved_record(built)["scene"]["params"]["resolution"] == 16  # round(31 x 0.5)


def test_build_refuses_in_process_too():
    with pytest.raises(ConfigError, match=r"^scene\.params\.resolution: must be an integer, got 2\.5$"):
        build(compose_config("+scene.params.resolution=2.5"))


# ---- experiments.resume: why a checkpoint cannot be read ----------------------------------

@pytest.mark.parametrize("state, says_killed, names", [
    (None, True, "no checkpoint"),                     # missing: killed before its first checkpoint
    (b"not a pickle", False, "cannot be read"),        # damaged
    ("no_sim", False, "'sim'"),                        # of this format, without one of its parts
])
def test_resume_says_why_a_checkpoint_cannot_be_read(state, says_killed, names, tmp_path, capsys):
    import pickle

    from cloth.io.checkpoint import CHECKPOINT_FORMAT, checkpoint_path
    from experiments.resume import main as resume_main

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(compose_config("scene=hanging_sheet", *QUIET),
                                                           resolve=True))
    path = checkpoint_path(run_dir)
    if state is not None:
        path.parent.mkdir(parents=True)
        path.write_bytes(state if isinstance(state, bytes) else
                         pickle.dumps({"format": CHECKPOINT_FORMAT, "rows": [], "frame": 0, "time": 0.0}))
    assert resume_main([str(run_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cannot resume: ") and names in err[0], err
    assert ("killed before its first checkpoint" in err[0]) == says_killed, err
