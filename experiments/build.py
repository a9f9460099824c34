"""From a composed config to a ready Simulation: the one place where config values are checked.

Hydra composes the config; this module turns it into solver objects and raises
:class:`ConfigError` with a message naming the offending key before any work starts.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib.util
import inspect
import math
import os
import re
import sys
import types
import typing

import numpy as np
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
from cloth.scenes.arcsim import arcsim_end_frames, arcsim_remesher_overrides
from cloth.scenes.registry import CROWDS, SCENES, build_scene, crowd_columns, crowd_placement, multiple_dancers
from cloth.simulation import Simulation
from cloth.view.camera import ViewError
from cloth.view.paths import fit_shots, path_from_config
from cloth.view.viewdep import ViewDependentRemesher, ViewParams

IMPLEMENTED_MODES = ("nonadaptive", "adaptive", "viewdep")
REMESHING_MODES = ("adaptive", "viewdep")


MEMBER_SEED_STRIDE = 1000  # scene seed of member K of a reference ensemble: seed + 1000 K


class ConfigError(ValueError):
    """A bad config value; the message names the key."""


def _require(cond: bool, key: str, msg: str) -> None:
    if not cond:
        raise ConfigError(f"{key}: {msg}")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _finite(v) -> bool:
    return _is_number(v) and math.isfinite(v)


def _int_at_least(v, low: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= low


def _check_int(v, key: str, low: int, what: str = "") -> int:
    _require(_int_at_least(v, low), key, f"must be an integer >= {low}{what}, got {v!r}")
    return int(v)


def _check_positive(v, key: str, unit: str = "") -> float:
    _require(_finite(v) and v > 0, key, f"must be a finite number > 0{unit}, got {v!r}")
    return float(v)


def _check_bool(v, key: str) -> bool:
    _require(isinstance(v, bool), key, f"must be true or false, got {v!r}")
    return v


def _type_problem(value, hint) -> str | None:
    """What is wrong with `value` for the annotation `hint` (None: nothing). float: a finite
    number (an integer is one); int: an integer (not a bool, not 2.5); bool: true or false; str: a
    string; X | None: null or an X. Other annotations (tuples, paths, objects) are not checked here."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        problems = [_type_problem(value, a) for a in args if a is not type(None)]
        if any(p is None for p in problems):
            return None
        return problems[0] + (" or null" if type(None) in args else "")
    if hint is float:
        return None if _finite(value) else "must be a finite number"
    if hint is int:
        return None if isinstance(value, int) and not isinstance(value, bool) else "must be an integer"
    if hint is bool:
        return None if isinstance(value, bool) else "must be true or false"
    if hint is str:
        return None if isinstance(value, str) else "must be a string"
    return None


def _hints(target) -> dict:
    """The annotations of a dataclass's fields or a function's parameters (resolved)."""
    try:
        hints = typing.get_type_hints(target)
    except (NameError, TypeError):  # an annotation that does not resolve: not checked
        hints = {}
    hints.pop("return", None)
    return hints


def _check_fields(target, values: dict, key: str, known=None) -> dict:
    """`values` checked against the annotations of `target` (a dataclass: its fields, a function:
    its parameters), every key known; returns them with the integers of float fields as floats.
    ConfigError names `key`.<field>."""
    hints = _hints(target)
    if known is None:
        known = ({f.name for f in dataclasses.fields(target)} if dataclasses.is_dataclass(target)
                 else set(inspect.signature(target).parameters))
    for name, value in values.items():
        _require(name in known, f"{key}.{name}", f"unknown key; known: {', '.join(sorted(known))}")
        problem = _type_problem(value, hints.get(name))
        _require(problem is None, f"{key}.{name}", f"{problem}, got {value!r}")
    return {k: float(v) if hints.get(k) is float and _is_number(v) else v for k, v in values.items()}


def _value_error_key(message: str, key: str, names) -> str:
    """`key: message` for a parameter class's ValueError, naming the field it starts with
    (`size_min must be > 0` -> `mode.sizing.size_min: must be > 0`, `view.nu_out must be ...` ->
    `mode.view.nu_out: must be ...`)."""
    last = key.rsplit(".", 1)[-1] + "."
    if message.startswith(last):  # a message that names its own group (view.l_min_px ...)
        message = message[len(last):]
    m = re.match(r"(\w+)", message)
    if m and m.group(1) in names:
        rest = message[m.end():].lstrip()
        return f"{key}.{m.group(1)}: {rest if rest.startswith('must') else message}"
    return f"{key}: {message}"


def _params(cls, values: dict, key: str):
    """cls(**values), every value checked (:func:`_check_fields`, then the class's own checks);
    ConfigError names the key."""
    given = dict(values)
    checked = _check_fields(cls, given, key)
    try:
        cls(**given)  # the class's own checks, its messages naming the values as given
    except TypeError as exc:  # a missing key
        raise ConfigError(f"{key}: {exc}") from None
    except ValueError as exc:
        raise ConfigError(_value_error_key(str(exc), key, {f.name for f in dataclasses.fields(cls)})) from None
    return cls(**checked)


def build_material(cfg: DictConfig):
    """The Material of cfg.material, every value checked; ConfigError names material.<key>."""
    m = _check_fields(Material, OmegaConf.to_container(cfg.material, resolve=True), "material")
    try:
        return Material(**m)
    except TypeError as exc:  # a missing key
        raise ConfigError(f"material: {exc}") from None
    except MaterialError as exc:
        raise ConfigError(f"material.{exc.key}: {exc}") from None


def _plain(node):
    """A config node as plain Python (dicts, lists), resolved; a plain value as it is."""
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else node


def _crowd_default(key: str):
    """multiple_dancers' own default of a parameter (for configs that do not set it)."""
    return inspect.signature(multiple_dancers).parameters[key].default


def stage_camera_config(cam: dict, scene: dict) -> dict:
    """The camera config `cam` (plain dict) fitted to the stage of the crowd `scene` (its plain
    config: name, params), without its `stage_scale` block; as written when it has none or the
    scene is not a crowd.

    `stage_scale: {stage: {dancers, columns, spacing}, front_row_dancer: k}` says which stage the
    shots are written for (conf/camera/crowd_shots.yaml). The scene's stage (its dancers, columns,
    spacing: cloth.scenes.registry.crowd_placement) against that one gives
    (cloth.view.paths.fit_shots):

    * scale = max(1, R / R_written), R a stage's radius: the largest horizontal distance of a
      dancer from the stage's centre (the origin). `fit: stage` cameras go that many times as far
      from their look-at point, as does the far plane; a smaller stage keeps the written shot;
    * shift = where dancer k of the front row (row 0; the row's last when it is shorter) stands
      on the scene's stage - where it stands on the written stage. `fit: dancer` cameras move by it.

    On the written stage scale is 1 and shift 0: the camera is exactly as written. ConfigError
    names a bad camera.stage_scale key."""
    fit = cam.get("stage_scale")
    cam = {k: v for k, v in cam.items() if k != "stage_scale"}
    if fit is None or scene.get("name") not in CROWDS:
        return cam
    key = "camera.stage_scale"
    _require(isinstance(fit, dict), key, f"must be a mapping {{stage, front_row_dancer}}, got {fit!r}")
    unknown = set(fit) - {"stage", "front_row_dancer"}
    _require(not unknown, key, f"unknown key(s) {sorted(unknown)}; known: front_row_dancer, stage")
    stage = fit.get("stage")
    _require(isinstance(stage, dict) and set(stage) <= {"dancers", "columns", "spacing"}, f"{key}.stage",
             f"must be a mapping of dancers, columns, spacing (the stage the shots are written for), got {stage!r}")
    for name, ok, what in (("dancers", _int_at_least(stage.get("dancers"), 2), "an integer >= 2"),
                           ("columns", stage.get("columns") is None or _int_at_least(stage.get("columns"), 1),
                            "an integer >= 1 or null (auto)"),
                           ("spacing", isinstance(stage.get("spacing"), (int, float))
                            and not isinstance(stage.get("spacing"), bool) and stage.get("spacing") > 0,
                            "a number > 0 (m)")):
        _require(ok, f"{key}.stage.{name}", f"must be {what}, got {stage.get(name)!r}")
    front = fit.get("front_row_dancer", 0)
    _require(_int_at_least(front, 0), f"{key}.front_row_dancer", f"must be an integer >= 0, got {front!r}")
    params = scene.get("params") or {}
    written = (stage["dancers"], stage["spacing"], stage.get("columns"))
    actual = tuple(params.get(k, _crowd_default(k)) for k in ("dancers", "spacing", "columns"))
    (ref, _, _), (pos, _, _) = (crowd_placement(n, sp, c, 0.0, 0.0) for n, sp, c in (written, actual))
    ref_radius = float(np.max(np.linalg.norm(ref[:, :2], axis=1)))
    radius = float(np.max(np.linalg.norm(pos[:, :2], axis=1)))
    scale = max(1.0, radius / ref_radius)

    def front_row(dancers, columns):  # the dancer of the dancer shots: k of the front row, or its last
        return min(front, min(int(dancers), crowd_columns(dancers, columns)) - 1)

    shift = pos[front_row(actual[0], actual[2])] - ref[front_row(written[0], written[2])]
    return fit_shots(cam, scale, shift)


def camera_config(cfg) -> dict | None:
    """The camera config of a run's config (a DictConfig, or a run folder's config.yaml as a
    dict) as plain dicts, fitted to its crowd's stage (:func:`stage_camera_config`); None for
    camera=none. Every tool that needs a run's camera path builds it from this."""
    cam = cfg.get("camera")
    if cam is None or cam.get("type") in (None, "none"):
        return None
    scene = cfg.get("scene") or {}
    return stage_camera_config(dict(_plain(cam)), {"name": scene.get("name"), "params": _plain(scene.get("params"))})


def camera_path(cfg):
    """The camera path of a run's config (:func:`camera_config`), None for camera=none; ViewError,
    KeyError ... for a bad camera, ConfigError for a bad camera.stage_scale."""
    cam = camera_config(cfg)
    return None if cam is None else path_from_config(cam)


def build_camera(cfg: DictConfig):
    """The camera path of `cfg.camera` (None for camera=none), fitted to a crowd's stage
    (:func:`stage_camera_config`); ConfigError names a bad camera.* key."""
    try:
        return camera_path(cfg)
    except (ViewError, KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{_camera_key(cfg, exc)}: {exc}") from None


def _camera_key(cfg, exc: Exception) -> str:
    """The camera.* key a camera error is about: the one holding the value a conversion refused
    (`could not convert string to float: 'abc'`), the key a KeyError names, or camera."""
    m = re.search(r"could not convert string to float: '(.*)'|invalid literal for int\(\) with base 10: '(.*)'",
                  str(exc))
    wanted = (m.group(1) if m.group(1) is not None else m.group(2)) if m else None

    def find(node, at):
        if isinstance(node, dict):
            for k, v in node.items():
                if isinstance(exc, KeyError) and k == exc.args[0] and wanted is None:
                    return f"{at}.{k}"
                found = find(v, f"{at}.{k}")
                if found:
                    return found
        elif isinstance(node, list):
            for i, v in enumerate(node):
                found = find(v, f"{at}[{i}]")
                if found:
                    return found
        elif wanted is not None and isinstance(node, str) and node == wanted:
            return at
        return None

    if isinstance(exc, KeyError) and wanted is None:
        return f"camera.{exc.args[0]}" if exc.args else "camera"
    return (find(_plain(cfg.get("camera")), "camera") if wanted is not None else None) or "camera"


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
             f"must be an integer >= 1, or null (auto: cloth.scenes.registry.crowd_columns), got {columns!r}")
    jobs = cfg.get("crowd_jobs", 1)
    _require(_int_at_least(jobs, 1), "crowd_jobs", f"must be an integer >= 1, got {jobs!r}")
    crowd_backend(cfg)
    return dancers


_OVERRIDE = re.compile(r"(\+\+|\+|~)?([A-Za-z_][\w.]*)(?:@[\w.]*)?(=.*)?")


def override_keys(overrides) -> list[str]:
    """The config keys that command-line overrides (Hydra's syntax: key=value, +key=value,
    ++key=value) set, in order; deletions (~key) and group choices count as set too."""
    keys = []
    for arg in overrides or ():
        m = _OVERRIDE.fullmatch(str(arg))
        if m and m.group(2) not in keys:
            keys.append(m.group(2))
    return keys


def command_line_wins(cfg: DictConfig, overrides) -> DictConfig:
    """`cfg` with the scale preset (scene.scales.<scale>, and its reference preset) giving way to
    what the command line (`overrides`, HydraConfig's overrides.task) sets:

    * scene.params.K: the preset's K (and its reference's) is dropped, so the command line's value
      is the scene's;
    * mode.sizing.K: the preset's sizing.K becomes the command line's value (a preset's sizing and
      an ARCSim conf's remeshing sizes are applied over mode.sizing: this way the command line
      wins over both).

    Both a key and the preset's own key on the command line (mode.sizing.size_min and
    scene.scales.small.sizing.size_min) are refused, naming both. The config a run records
    (config.yaml) is this one: a replay or resume builds what ran. A copy; `cfg` is unchanged."""
    keys = override_keys(overrides)
    scale = cfg.get("scale")
    presets = cfg.scene.get("scales") if "scene" in cfg else None
    if not isinstance(scale, str) or presets is None or scale not in presets:
        return cfg  # build() names the bad scale
    cfg = copy.deepcopy(cfg)
    OmegaConf.set_struct(cfg, False)
    preset = cfg.scene.scales[scale]
    at = f"scene.scales.{scale}"
    for key in keys:
        parts = key.split(".")
        if len(parts) == 3 and parts[:2] == ["scene", "params"]:
            k = parts[2]
            for where, node in ((at, preset), (f"{at}.reference", preset.get("reference"))):
                if isinstance(node, DictConfig) and k in node:
                    _require(f"{where}.{k}" not in keys, key,
                             f"both {key} and {where}.{k} are set on the command line: set one")
                    del node[k]
        elif len(parts) == 3 and parts[:2] == ["mode", "sizing"] and "sizing" in cfg.mode:
            k = parts[2]
            _require(f"{at}.sizing.{k}" not in keys, key,
                     f"both {key} and {at}.sizing.{k} are set on the command line: set one")
            if k in cfg.mode.sizing:
                if not isinstance(preset.get("sizing"), DictConfig):
                    preset.sizing = {}
                preset.sizing[k] = cfg.mode.sizing[k]
    return cfg


# The keys each mode reads (conf/mode/); any other is refused, not ignored.
MODE_KEYS = {"nonadaptive": {"name", "buckling"},
             "adaptive": {"name", "every", "sizing", "remesh", "pop_filter", "buckling"},
             "viewdep": {"name", "every", "sizing", "remesh", "pop_filter", "buckling", "view"}}
# The top-level keys a run reads or records (conf/config.yaml, its groups, and what the study
# presets of conf/experiment and conf/point set: `points`, `baseline`); any other is refused,
# never silently ignored (`+foo=1`, a key mistyped with a `+`).
TOP_LEVEL_KEYS = frozenset({"camera", "scene", "mode", "material", "solver", "output", "frames", "seed", "repeats",
                            "scale", "resolution_factor", "crowd_jobs", "crowd_backend", "max_speed", "study",
                            "reference", "reference_member", "variant", "drape_mesh", "points", "baseline"})
# The keys of a scene (conf/scene/*.yaml): the others are refused.
SCENE_KEYS = frozenset({"name", "effects", "frames", "params", "scales", "view"})
# output.* (conf/output/default.yaml): what each is, checked before any run.
OUTPUT_INTS = ("obj_every", "stills_every", "states_every", "checkpoint_every")  # frames, 0: never
OUTPUT_BOOLS = ("rerun", "progress")


def check_output(cfg: DictConfig) -> None:
    """Every output.* key (conf/output/default.yaml), ConfigError naming a bad one."""
    out = _plain(cfg.get("output")) or {}
    _require(isinstance(out, dict), "output", f"must be a mapping, got {out!r}")
    known = set(OUTPUT_INTS) | set(OUTPUT_BOOLS)
    for key, value in out.items():
        _require(key in known, f"output.{key}", f"unknown key; known: {', '.join(sorted(known))}")
        if key in OUTPUT_BOOLS:
            _check_bool(value, f"output.{key}")
        else:
            _check_int(value, f"output.{key}", 0, " (frames; 0: never)")


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
    sim = Simulation(scene, solver=solver, remesher=remesher, max_speed=max_speed, buckling=buckling)
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


def _record_value(v):
    """A built value as plain YAML data (dataclasses as mappings, tuples and arrays as lists)."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {f.name: _record_value(getattr(v, f.name)) for f in dataclasses.fields(v)}
    if isinstance(v, dict):
        return {str(k): _record_value(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, set, frozenset)):
        items = sorted(v) if isinstance(v, (set, frozenset)) else v
        return [_record_value(x) for x in items]
    if isinstance(v, np.ndarray):
        return _record_value(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    return str(v)


def resolved_record(built: Built) -> dict:
    """The values a run uses, read from the built objects (what a run folder's resolved.yaml
    holds): the frames, the scene (its builder's parameters and what the scene became), the
    material, the solver's options, the remesher's (sizing, remesh, pop filter, view), the
    buckling compensation's and max_speed. config.yaml says what was asked; this, what ran (an
    ARCSim conf's remeshing sizes, a scale preset, resolution_factor are applied here)."""
    sim = built.sim
    scene, remesher = sim.scene, sim.remesher
    remesh = None
    if remesher is not None:
        remesh = {"kind": type(remesher).__name__, "every": remesher.every,
                  "sizing": _record_value(remesher.sizing), "remesh": _record_value(remesher.params),
                  "pop_filter": _record_value(remesher.pop)}
        if hasattr(remesher, "view"):
            remesh["view"] = _record_value(remesher.view)
            remesh["frame_time"] = float(remesher.frame_time)
    return {
        "frames": int(built.frames),
        "max_speed": float(sim.max_speed),
        "scene": {"name": scene.name, "params": _record_value(built.scene_params),
                  "frame_time": float(scene.frame_time), "steps_per_frame": int(scene.steps_per_frame),
                  "effects": _record_value(scene.effects), "thickness": float(scene.thickness),
                  "friction": float(scene.friction), "faces": int(sim.mesh.n_faces),
                  "camera": None if scene.camera is None else type(scene.camera).__name__},
        "material": {"kind": type(scene.material).__name__, **_record_value(scene.material)},
        "solver": _record_value(sim.solver),
        "remesher": remesh,
        "buckling": _record_value(sim.buckling),
    }
