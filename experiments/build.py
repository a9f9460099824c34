"""From a composed config to a ready Simulation: the one place where config values are checked.

Hydra composes the config; this module turns it into solver objects and raises
:class:`ConfigError` with a message naming the offending key before any work starts.
"""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from cloth.core.material import Material, MaterialError
from cloth.core.mesh import MeshError
from cloth.core.scene import SceneError
from cloth.physics.buckling import BucklingParams
from cloth.physics.linsolve import SolverOptions
from cloth.remeshing.adaptive import AdaptiveRemesher
from cloth.remeshing.popfilter import PopFilterParams
from cloth.remeshing.remesh import RemeshParams
from cloth.remeshing.sizing import SizingParams
from cloth.scenes.registry import CROWDS, SCENES, build_scene
from cloth.simulation import Simulation
from cloth.view.camera import ViewError
from cloth.view.paths import path_from_config
from cloth.view.viewdep import ViewDependentRemesher, ViewParams

IMPLEMENTED_MODES = ("nonadaptive", "adaptive", "viewdep")
REMESHING_MODES = ("adaptive", "viewdep")


MEMBER_SEED_STRIDE = 1000  # scene seed of member K of a reference ensemble: seed + 1000 K


class ConfigError(ValueError):
    """A bad config value; the message names the key."""


def _require(cond: bool, key: str, msg: str) -> None:
    if not cond:
        raise ConfigError(f"{key}: {msg}")


def build_material(cfg: DictConfig):
    m = OmegaConf.to_container(cfg.material, resolve=True)
    try:
        return Material(**m)
    except TypeError as exc:
        raise ConfigError(f"material: {exc}") from None
    except MaterialError as exc:
        raise ConfigError(f"material.{exc.key}: {exc}") from None


def _params(cls, values: dict, key: str):
    try:
        return cls(**values)
    except TypeError as exc:  # an unknown key
        raise ConfigError(f"{key}: {exc}") from None
    except ValueError as exc:
        raise ConfigError(f"{key}.{exc}") from None


def build_camera(cfg: DictConfig):
    """The camera path of `cfg.camera` (None for camera=none); ConfigError names a bad camera.* key."""
    cam = cfg.get("camera")
    if cam is None or cam.get("type") in (None, "none"):
        return None
    try:
        return path_from_config(OmegaConf.to_container(cam, resolve=True))
    except (ViewError, KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"camera: {exc}") from None


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
    every = mode_cfg.get("every", 1)
    _require(isinstance(every, int) and every >= 1, "mode.every", f"must be an integer >= 1, got {every!r}")
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


def crowd_size(cfg: DictConfig) -> int | None:
    """Number of characters of a crowd scene (each its own Simulation), None for other scenes."""
    if cfg.scene.name not in CROWDS:
        return None
    count = cfg.scene.params.get("count", 10)
    _require(isinstance(count, int) and count >= 1, "scene.params.count", f"must be an integer >= 1, got {count!r}")
    jobs = cfg.get("crowd_jobs", 1)
    _require(isinstance(jobs, int) and jobs >= 1, "crowd_jobs", f"must be an integer >= 1, got {jobs!r}")
    return count


def build_simulation(cfg: DictConfig, character: int | None = None):
    """Return (Simulation, n_frames); raises ConfigError naming the key of a bad value.

    For a crowd scene (cloth.scenes.registry.CROWDS) this is the simulation of one `character` (0 if None).
    """
    _require(isinstance(cfg.get("frames"), int) and cfg.frames >= 1, "frames",
             f"must be an integer >= 1, got {cfg.get('frames')!r}")
    _require(isinstance(cfg.get("seed"), int), "seed", f"must be an integer, got {cfg.get('seed')!r}")
    _require(cfg.get("max_speed", 0) > 0, "max_speed", f"must be > 0 m/s, got {cfg.get('max_speed')!r}")
    mode = cfg.mode.name
    _require(mode in IMPLEMENTED_MODES, "mode.name",
             f"mode {mode!r} is not implemented yet; implemented: {list(IMPLEMENTED_MODES)}")
    name = cfg.scene.name
    _require(name in SCENES, "scene.name", f"unknown scene {name!r}; known: {sorted(SCENES)}")
    scales = cfg.scene.get("scales") or {}
    _require(cfg.scale in scales, "scale", f"scene {name!r} has no scale {cfg.scale!r}; available: {sorted(scales)}")
    params = dict(OmegaConf.to_container(cfg.scene.params, resolve=True))
    params.update(OmegaConf.to_container(scales[cfg.scale], resolve=True))
    reference = params.pop("reference", None)
    if cfg.get("reference", False):  # the fine nonadaptive run that accuracy is measured against
        _require(mode == "nonadaptive", "reference",
                 f"a reference run is nonadaptive (mode=nonadaptive), got mode={mode}")
        _require(isinstance(reference, dict), "reference",
                 f"scene {name!r} has no reference preset at scale {cfg.scale!r} (scene.scales.{cfg.scale}.reference)")
        params.update(reference)
    sizing_overrides = params.pop("sizing", None) or {}
    factor = cfg.get("resolution_factor", 1.0)
    _require(isinstance(factor, (int, float)) and not isinstance(factor, bool) and factor > 0, "resolution_factor",
             f"must be a number > 0, got {factor!r}")
    if factor != 1.0:
        _require(mode == "nonadaptive" and not cfg.get("reference", False), "resolution_factor",
                 f"scales the fixed mesh of the preset; mode={mode}{' (reference)' if cfg.get('reference') else ''} "
                 f"has none to scale")
        _require("resolution" in params, "resolution_factor", f"scene {name!r} has no resolution to scale")
        params["resolution"] = max(int(round(params["resolution"] * factor)), 1)
    for key in ("frame_time", "steps_per_frame", "resolution"):
        if key in params:
            v = params[key]
            _require(isinstance(v, (int, float)) and v > 0, f"scene.params.{key}", f"must be > 0, got {v!r}")
    _require(isinstance(params.get("steps_per_frame", 1), int), "scene.params.steps_per_frame",
             f"must be an integer, got {params.get('steps_per_frame')!r}")
    params["effects"] = tuple(cfg.scene.effects)
    member = cfg.get("reference_member", 0)
    _require(isinstance(member, int) and not isinstance(member, bool) and member >= 0, "reference_member",
             f"must be an integer >= 0, got {member!r}")
    _require(member == 0 or cfg.get("reference", False), "reference_member",
             "members of a reference ensemble are reference runs (+point=member/K sets both)")
    # member K of the ensemble of seed s: the scene's seed s + MEMBER_SEED_STRIDE K (distinct from
    # every run's own seed below the stride)
    params["seed"] = int(cfg.seed) + MEMBER_SEED_STRIDE * int(member)
    if name in CROWDS:
        crowd_size(cfg)
        params["character"] = int(character or 0)
    material = build_material(cfg)
    try:
        solver = SolverOptions(method=cfg.solver.method, tolerance=float(cfg.solver.tolerance),
                               max_iterations=int(cfg.solver.max_iterations))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    _require(int(cfg.output.obj_every) >= 0, "output.obj_every", f"must be >= 0, got {cfg.output.obj_every}")
    camera = build_camera(cfg)
    stills = cfg.output.get("stills_every", 0)
    _require(isinstance(stills, int) and stills >= 0, "output.stills_every", f"must be an integer >= 0, got {stills!r}")
    states = cfg.output.get("states_every", 1)
    _require(isinstance(states, int) and states >= 0, "output.states_every", f"must be an integer >= 0, got {states!r}")
    _require(stills == 0 or camera is not None, "output.stills_every",
             "stills are drawn from the camera: choose one with camera=<name> (conf/camera/)")
    buckling = build_buckling(cfg.mode, camera)
    try:
        scene = build_scene(name, material, **params)
    except (SceneError, MeshError) as exc:
        raise ConfigError(f"scene: {exc}") from None
    scene.camera = camera
    scene_view = cfg.scene.get("view")
    scene_view = OmegaConf.to_container(scene_view, resolve=True) if scene_view is not None else None
    remesher = (build_remesher(cfg.mode, sizing_overrides, camera, scene.frame_time, scene_view)
                if mode in REMESHING_MODES else None)
    return (Simulation(scene, solver=solver, remesher=remesher, max_speed=float(cfg.max_speed), buckling=buckling),
            int(cfg.frames))
