"""From a composed config to a ready Simulation: the one place where config values are checked.

Hydra composes the config; this module turns it into solver objects and raises
:class:`ConfigError` with a message naming the offending key before any work starts.
"""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

IMPLEMENTED_MODES = ("nonadaptive",)


class ConfigError(ValueError):
    """A bad config value; the message names the key."""


def _require(cond: bool, key: str, msg: str) -> None:
    if not cond:
        raise ConfigError(f"{key}: {msg}")


def build_material(cfg: DictConfig):
    from cloth.material import Material, MaterialError

    m = OmegaConf.to_container(cfg.material, resolve=True)
    try:
        return Material(**m)
    except TypeError as exc:
        raise ConfigError(f"material: {exc}") from None
    except MaterialError as exc:
        raise ConfigError(f"material.{exc.key}: {exc}") from None


def build_simulation(cfg: DictConfig):
    """Return (Simulation, n_frames); raises ConfigError naming the key of a bad value."""
    from cloth.linsolve import SolverOptions
    from cloth.mesh import MeshError
    from cloth.scene import SceneError
    from cloth.scenes import SCENES, build_scene
    from cloth.simulation import Simulation

    _require(isinstance(cfg.get("frames"), int) and cfg.frames >= 1, "frames", f"must be an integer >= 1, got {cfg.get('frames')!r}")
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
    for key in ("frame_time", "steps_per_frame", "resolution"):
        if key in params:
            v = params[key]
            _require(isinstance(v, (int, float)) and v > 0, f"scene.params.{key}", f"must be > 0, got {v!r}")
    _require(isinstance(params.get("steps_per_frame", 1), int), "scene.params.steps_per_frame",
             f"must be an integer, got {params.get('steps_per_frame')!r}")
    params["effects"] = tuple(cfg.scene.effects)
    params["seed"] = int(cfg.seed)
    material = build_material(cfg)
    try:
        solver = SolverOptions(method=cfg.solver.method, tolerance=float(cfg.solver.tolerance),
                               max_iterations=int(cfg.solver.max_iterations))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    _require(int(cfg.output.obj_every) >= 0, "output.obj_every", f"must be >= 0, got {cfg.output.obj_every}")
    try:
        scene = build_scene(name, material, **params)
    except (SceneError, MeshError) as exc:
        raise ConfigError(f"scene: {exc}") from None
    return Simulation(scene, solver=solver, max_speed=float(cfg.max_speed)), int(cfg.frames)
