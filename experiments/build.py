"""From a composed config to a ready Simulation: the one place where config values are checked.

Hydra composes the config; this module turns it into solver objects and raises
:class:`ConfigError` with a message naming the offending key before any work starts. The checks
it makes on the way (typed checks of values and parameter classes, the keys a run reads, the
command line winning over a scale preset) are in :mod:`experiments.checks`; the record of what a
built config uses (resolved.yaml) in :mod:`experiments.resolved`. ConfigError, command_line_wins
and resolved_record are re-exported here, where the entry points and tests import them.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import inspect
import os
import re
import sys

from omegaconf import DictConfig, OmegaConf

from cloth.collision.selfcollision import CollisionOptions
from cloth.core.material import Material, MaterialError
from cloth.core.mesh import MeshError
from cloth.core.scene import SceneError
from cloth.physics.buckling import BucklingParams
from cloth.physics.linsolve import SolverOptions
from cloth.remeshing.adaptive import AdaptiveRemesher
from cloth.remeshing.popfilter import PopFilterParams
from cloth.remeshing.remesh import RemeshParams
from cloth.remeshing.sizing import SizingParams
from cloth.scenes.arcsim import arcsim_end_frames, arcsim_remesher_overrides
from cloth.scenes.registry import CROWDS, SCENES, build_scene
from cloth.simulation import Simulation
from cloth.view.viewdep import ViewDependentRemesher, ViewParams
from experiments.camerasetup import (  # noqa: F401 - re-exported: where the tools and tests import them
    CAMERA_CONF,
    _crowd_default,
    build_camera,
    camera_config,
    camera_path,
    extra_cameras,
    stage_camera_config,
)
from experiments.checks import (
    MODE_KEYS,
    SCENE_KEYS,
    TOP_LEVEL_KEYS,
    _check_bool,
    _check_fields,
    _check_int,
    _check_positive,
    _finite,
    _hints,
    _int_at_least,
    _is_number,
    _params,
    _plain,
    _require,
    check_output,
)

# Re-exported: where the entry points and tests import them (module docstring).
from experiments.checks import ConfigError as ConfigError
from experiments.checks import command_line_wins as command_line_wins
from experiments.checks import plain_experiment as plain_experiment
from experiments.resolved import resolved_record as resolved_record

IMPLEMENTED_MODES = ("nonadaptive", "adaptive", "viewdep")
REMESHING_MODES = ("adaptive", "viewdep")


MEMBER_SEED_STRIDE = 1000  # scene seed of member K of a reference ensemble: seed + 1000 K
# reference_check: the reference refined by REFERENCE_REFINEMENT in one discretisation parameter,
# the fine one (twice the segments: half the edge, four times the faces) or the half time step (twice
# the implicit steps per frame); the reference measured against each is its own error
REFERENCE_CHECKS = {"fine": "resolution", "half_dt": "steps_per_frame"}
REFERENCE_REFINEMENT = 2


def build_material(cfg: DictConfig):
    """The Material of cfg.material, every value checked; ConfigError names material.<key>."""
    m = _check_fields(Material, OmegaConf.to_container(cfg.material, resolve=True), "material")
    try:
        return Material(**m)
    except TypeError as exc:  # a missing key
        raise ConfigError(f"material: {exc}") from None
    except MaterialError as exc:
        raise ConfigError(f"material.{exc.key}: {exc}") from None


def build_buckling(mode_cfg: DictConfig, camera):
    """BucklingParams from mode.buckling (null: off); it needs a camera (out-of-frustum faces)."""
    b = mode_cfg.get("buckling")
    if b is None:
        return None
    _require(camera is not None, "mode.buckling",
             "buckling compensation acts on faces outside the camera's frustum: choose a camera "
             "(camera=<name>, conf/camera/) or set mode.buckling=null")
    return _params(BucklingParams, OmegaConf.to_container(b, resolve=True), "mode.buckling")


def build_remesher(mode_cfg: DictConfig, sizing_overrides: dict, camera=None, frame_time: float = 0.04,
                   scene_view: dict | None = None):
    """The remesh stage of a remeshing mode (ConfigError names a bad mode.* key)."""
    sizing = dict(OmegaConf.to_container(mode_cfg.sizing, resolve=True))
    sizing.update(sizing_overrides)
    remesh = OmegaConf.to_container(mode_cfg.remesh, resolve=True)
    pop = mode_cfg.get("pop_filter")
    every = _check_int(mode_cfg.get("every", 1), "mode.every", 1, " (frames)")
    common = dict(
        sizing=_params(SizingParams, sizing, "mode.sizing"),
        params=_params(RemeshParams, remesh, "mode.remesh"),
        pop=None if pop is None else _params(PopFilterParams, OmegaConf.to_container(pop, resolve=True),
                                             "mode.pop_filter"),
        every=every,
    )
    if mode_cfg.name != "viewdep":
        return AdaptiveRemesher(**common)
    _require(camera is not None, "camera",
             "mode=viewdep needs a camera path; choose one with camera=<name> (conf/camera/), e.g. camera=sheet_half")
    view_cfg = OmegaConf.to_container(mode_cfg.view, resolve=True)
    view_cfg.update(scene_view or {})  # a scene's own view settings (scene.view) win over the mode's
    view = _params(ViewParams, view_cfg, "mode.view")
    return ViewDependentRemesher(**common, camera=camera, view=view, frame_time=frame_time)


# Where a crowd's characters run (crowd_backend): Ray tasks (a local Ray instance, or the cluster
# at RAY_ADDRESS), local processes (joblib's loky), or auto (the default): Ray when it is
# installed and there is a Ray to use (RAY_ADDRESS set, or this process is itself a Ray task:
# cluster=ray), else local processes. experiments.crowd runs them.
CROWD_BACKENDS = ("auto", "ray", "processes")
# A run config without the key was written before there was a choice: its crowd ran in processes.
LEGACY_CROWD_BACKEND = "processes"
RAY_MISSING = 'ray is not installed (pip install -e ".[ray]")'  # Ray is an extra (pyproject.toml)


def ray_installed() -> bool:
    """Ray can be imported here (the `ray` extra), found without importing it."""
    return importlib.util.find_spec("ray") is not None


def _in_ray() -> bool:
    """This process is connected to Ray already (a Ray task): ray imported and initialised.
    Never imports ray (about a second) to find out."""
    ray = sys.modules.get("ray")
    return ray is not None and bool(getattr(ray, "is_initialized", lambda: False)())


def crowd_backend(cfg: DictConfig) -> str:
    """Where the config's crowd runs, 'ray' or 'processes': crowd_backend checked (one of
    CROWD_BACKENDS, and Ray installed for 'ray') and 'auto' resolved."""
    backend = cfg.get("crowd_backend", LEGACY_CROWD_BACKEND)
    _require(backend in CROWD_BACKENDS, "crowd_backend",
             f"must be one of {', '.join(CROWD_BACKENDS)} (where a crowd's characters run), got {backend!r}")
    if backend == "auto":
        return "ray" if ray_installed() and (os.environ.get("RAY_ADDRESS") or _in_ray()) else "processes"
    if backend == "ray":
        _require(ray_installed(), "crowd_backend", RAY_MISSING)
    return backend


def crowd_size(cfg: DictConfig) -> int | None:
    """Number of characters of a crowd scene (each its own Simulation), None for other scenes;
    checks every crowd key (scene.params.dancers and columns, crowd_jobs, crowd_backend)."""
    if cfg.scene.name not in CROWDS:
        return None
    params = cfg.scene.params
    _require("count" not in params, "scene.params.count",
             "was renamed scene.params.dancers (the number of dancers); set that instead")
    dancers = params.get("dancers", _crowd_default("dancers"))
    _require(_int_at_least(dancers, 1), "scene.params.dancers", f"must be an integer >= 1, got {dancers!r}")
    columns = params.get("columns")
    _require(columns is None or _int_at_least(columns, 1), "scene.params.columns",
             f"must be an integer >= 1, or null (auto: cloth.scenes.crowd.crowd_columns), got {columns!r}")
    jobs = cfg.get("crowd_jobs", 1)
    _require(_int_at_least(jobs, 1), "crowd_jobs", f"must be an integer >= 1, got {jobs!r}")
    crowd_backend(cfg)
    return dancers


@dataclasses.dataclass
class Built:
    """What a config became: the simulation, the frames it runs, and the keyword parameters its
    scene was built with (after the scale preset, the reference preset and resolution_factor)."""

    sim: Simulation
    frames: int
    scene_params: dict


def build_simulation(cfg: DictConfig, character: int | None = None):
    """Return (Simulation, n_frames); raises ConfigError naming the key of a bad value.

    For a crowd scene (cloth.scenes.registry.CROWDS) this is the simulation of one `character` (0 if None).
    """
    built = build(cfg, character)
    return built.sim, built.frames


def _scene_error(exc: Exception, name: str, params: dict) -> ConfigError:
    """A scene builder's SceneError or MeshError as a ConfigError naming the parameter it is about."""
    message = str(exc)
    if re.search(r"unknown effect|effects \[", message):
        return ConfigError(f"scene.effects: {message}")
    named = re.search(r"scene\.params\.(\w+)", message)
    if named:
        return ConfigError(f"scene.params.{named.group(1)}: {message}")
    m = re.match(r"scene '[^']*': (\w+) ", message)
    if m and m.group(1) in params:
        return ConfigError(f"scene.params.{m.group(1)}: {message}")
    if name == "arcsim":  # the ARCSim conf or a file it names
        return ConfigError(f"scene.params.conf: {message}")
    return ConfigError(f"scene.params: {message}")


def _scene_builder_check(name: str, params: dict) -> dict:
    """The scene's parameters checked against its builder's annotations (a crowd: with the solo
    dancer's, which it passes on)."""
    builder = SCENES[name]
    hints = _hints(builder)
    known = set(inspect.signature(builder).parameters) - {"material", "dancer"}
    if name in CROWDS:
        solo = SCENES["solo_dancer"]
        hints = {**_hints(solo), **hints}
        known |= set(inspect.signature(solo).parameters) - {"material", "position", "phase", "heading"}

    def target():  # the merged annotations, for _check_fields
        pass
    target.__annotations__ = hints
    return _check_fields(target, params, "scene.params", known=known)


def build(cfg: DictConfig, character: int | None = None) -> Built:
    """Every config value checked, then the objects built (:class:`Built`); ConfigError names
    the key of the first bad value. Nothing is simulated or written."""
    for key in cfg:
        _require(key in TOP_LEVEL_KEYS, str(key), f"unknown top-level key; known: {', '.join(sorted(TOP_LEVEL_KEYS))}")
    for key in cfg.get("scene") or {}:
        _require(key in SCENE_KEYS, f"scene.{key}", f"unknown scene key; known: {', '.join(sorted(SCENE_KEYS))}")
    n_frames = run_frames(cfg)
    seed = cfg.get("seed")
    _check_int(seed, "seed", 0, " (it seeds the scene's random choices)")
    max_speed = _check_positive(cfg.get("max_speed", 0), "max_speed",
                                " m/s (a faster node stops the run: the divergence check)")
    check_output(cfg)
    mode = cfg.mode.name
    _require(mode in IMPLEMENTED_MODES, "mode.name",
             f"mode {mode!r} is not implemented yet; implemented: {list(IMPLEMENTED_MODES)}")
    # a key no mode reads is refused; one another mode reads is allowed: a study's preset sets
    # mode.view for all of its points, the nonadaptive and adaptive ones too
    every_mode = set().union(*MODE_KEYS.values())
    for key in cfg.mode:
        _require(key in every_mode, f"mode.{key}",
                 f"no mode reads it (mode={mode} reads {', '.join(sorted(MODE_KEYS[mode]))})")
    name = cfg.scene.name
    _require(name in SCENES, "scene.name", f"unknown scene {name!r}; known: {sorted(SCENES)}")
    if name in CROWDS:  # the crowd's own keys first (scene.params.count: renamed, not unknown)
        crowd_size(cfg)
    scales = cfg.scene.get("scales") or {}
    _require(cfg.scale in scales, "scale", f"scene {name!r} has no scale {cfg.scale!r}; available: {sorted(scales)}")
    reference_run = cfg.get("reference", False)
    _check_bool(reference_run, "reference")
    params = dict(OmegaConf.to_container(cfg.scene.params, resolve=True))
    params.update(OmegaConf.to_container(scales[cfg.scale], resolve=True))
    reference = params.pop("reference", None)
    if reference_run:  # the fine nonadaptive run that accuracy is measured against
        _require(mode == "nonadaptive", "reference",
                 f"a reference run is nonadaptive (mode=nonadaptive), got mode={mode}")
        _require(isinstance(reference, dict), "reference",
                 f"scene {name!r} has no reference preset at scale {cfg.scale!r} (scene.scales.{cfg.scale}.reference)")
        params.update(reference)
    check = cfg.get("reference_check", None)
    if check is not None:  # the reference made finer in space or in time, to measure the reference's own error
        _require(check in REFERENCE_CHECKS, "reference_check",
                 f"one of {', '.join(REFERENCE_CHECKS)} or null, got {_plain(check)!r}")
        _require(reference_run and cfg.get("reference_member", 0) == 0, "reference_check",
                 "refines the reference (member 0): set reference=true (+point=reference_check/NAME sets both)")
        key = REFERENCE_CHECKS[check]
        _require(_is_number(params.get(key)), f"scene.params.{key}",
                 f"reference_check={check} refines it: must be an integer, got {params.get(key)!r}")
        params[key] = int(params[key]) * REFERENCE_REFINEMENT
    sizing_overrides = params.pop("sizing", None) or {}
    _require(isinstance(sizing_overrides, dict), f"scene.scales.{cfg.scale}.sizing",
             f"must be a mapping of mode.sizing keys, got {sizing_overrides!r}")
    pop_filter = True
    if name == "arcsim":
        sizing_overrides, pop_filter = _arcsim_mode(cfg, params, mode, sizing_overrides)
    factor = cfg.get("resolution_factor", 1.0)
    _check_positive(factor, "resolution_factor")
    if factor != 1.0:
        _require(mode == "nonadaptive" and not reference_run, "resolution_factor",
                 f"scales the fixed mesh of the preset; mode={mode}{' (reference)' if reference_run else ''} "
                 f"has none to scale")
        _require("resolution" in params, "resolution_factor", f"scene {name!r} has no resolution to scale")
        _require(_is_number(params["resolution"]), "scene.params.resolution",
                 f"must be an integer, got {params['resolution']!r}")
        params["resolution"] = max(int(round(params["resolution"] * factor)), 1)
    checked = _scene_builder_check(name, params)  # the values as given are named in the messages
    for key in ("frame_time", "steps_per_frame", "resolution"):
        if key in params:
            v = params[key]
            _require(_finite(v) and v > 0, f"scene.params.{key}", f"must be > 0, got {v!r}")
    _require(isinstance(params.get("steps_per_frame", 1), int), "scene.params.steps_per_frame",
             f"must be an integer, got {params.get('steps_per_frame')!r}")
    params = checked
    effects = cfg.scene.get("effects")
    _require(effects is not None and not isinstance(effects, str)
             and all(isinstance(e, str) for e in effects), "scene.effects",
             f"must be a list of effect names, got {_plain(effects)!r}")
    params["effects"] = tuple(effects)
    member = cfg.get("reference_member", 0)
    _check_int(member, "reference_member", 0)
    _require(member == 0 or reference_run, "reference_member",
             "members of a reference ensemble are reference runs (+point=member/K sets both)")
    # member K of the ensemble of seed s: the scene's seed s + MEMBER_SEED_STRIDE K (distinct from
    # every run's own seed below the stride)
    params["seed"] = int(seed) + MEMBER_SEED_STRIDE * int(member)
    if name in CROWDS:
        crowd_size(cfg)
        params["character"] = int(character or 0)
    material = build_material(cfg)
    solver = _params(SolverOptions, OmegaConf.to_container(cfg.solver, resolve=True), "solver")
    collision = cfg.get("collision")
    _require(isinstance(collision, DictConfig), "collision",
             f"must be a mapping of {', '.join(f.name for f in dataclasses.fields(CollisionOptions))}, "
             f"got {_plain(collision)!r}")
    collision = _params(CollisionOptions, OmegaConf.to_container(collision, resolve=True), "collision")
    camera = build_camera(cfg)
    _require(cfg.output.get("stills_every", 0) == 0 or camera is not None, "output.stills_every",
             "stills are drawn from the camera: choose one with camera=<name> (conf/camera/)")
    buckling = build_buckling(cfg.mode, camera)
    scene_view = cfg.scene.get("view")
    scene_view = OmegaConf.to_container(scene_view, resolve=True) if scene_view is not None else None
    if mode in REMESHING_MODES:  # its parameters checked before the scene is built (the slow part)
        build_remesher(cfg.mode, sizing_overrides, camera, float(params.get("frame_time", 0.04)), scene_view)
    try:
        scene = build_scene(name, material, **params)
    except (SceneError, MeshError) as exc:
        raise _scene_error(exc, name, params) from None
    scene.camera = camera
    remesher = (build_remesher(cfg.mode, sizing_overrides, camera, scene.frame_time, scene_view)
                if mode in REMESHING_MODES else None)
    if remesher is not None and not pop_filter:
        remesher.pop = None
    sim = Simulation(scene, solver=solver, remesher=remesher, max_speed=max_speed, buckling=buckling,
                     collision=collision)
    return Built(sim=sim, frames=int(n_frames), scene_params=params)


def run_frames(cfg: DictConfig) -> int:
    """The frames a run simulates: `frames`, or with scene=arcsim and frames=null the conf's end."""
    n_frames = cfg.get("frames")
    if n_frames is None and cfg.scene.name == "arcsim":  # the ARCSim conf's own end
        n_frames = _arcsim_frames(cfg)
    _require(isinstance(n_frames, int) and not isinstance(n_frames, bool) and n_frames >= 1, "frames",
             f"must be an integer >= 1, got {n_frames!r}")
    return int(n_frames)


def _arcsim_frames(cfg: DictConfig) -> int:
    """frames=null with scene=arcsim: the conf's end_frame, or its end time in frames."""
    params = OmegaConf.to_container(cfg.scene.params, resolve=True)
    try:
        n = arcsim_end_frames(params.get("conf"), params.get("root"))
    except SceneError as exc:
        raise _scene_error(exc, "arcsim", params) from None
    _require(n is not None, "frames", f"the ARCSim conf {params.get('conf')} has no end: give frames=N")
    return n


def _arcsim_mode(cfg: DictConfig, params: dict, mode: str, scale_sizing: dict) -> tuple[dict, bool]:
    """An ARCSim scene's part in the mode: the conf's remeshing sizes (x the scale's size_factor)
    as sizing overrides, its fixed mesh for mode=nonadaptive, and whether it keeps the pop filter."""
    factor = params.get("size_factor", 1.0)
    _check_positive(factor, "scene.params.size_factor")
    try:
        wants = arcsim_remesher_overrides(params.get("conf"), params.get("root"), float(factor))
    except SceneError as exc:
        raise _scene_error(exc, "arcsim", params) from None
    if mode in REMESHING_MODES:
        _require(wants["remeshing"], "mode", f"the ARCSim conf {params.get('conf')} disables remeshing: "
                                             "run it with mode=nonadaptive")
    else:
        params["mode_mesh"] = "uniform"
    return {**wants["sizing"], **scale_sizing}, wants["pop_filter"]
