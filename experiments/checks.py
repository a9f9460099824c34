"""The checks of a composed config: typed checks of single values and of parameter classes, the
keys a run reads (any other is refused), and the command line winning over a scale preset.

:mod:`experiments.build` turns a config into solver objects and checks every value on the way,
with these functions; each check raises :class:`ConfigError` with a message naming the offending
key before any work starts. What is here knows no scene and no solver object (only Hydra's config
nodes and the annotations of the classes it is handed), so the checks of a value are written once
and read the same for every group. The names with an underscore are experiments.build's, not a
public interface.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib.util
import inspect
import math
import re
import types
import typing

from omegaconf import DictConfig, OmegaConf


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


def _plain(node):
    """A config node as plain Python (dicts, lists), resolved; a plain value as it is."""
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else node


# The keys each mode reads (conf/mode/); any other is refused, not ignored.
MODE_KEYS = {"nonadaptive": {"name", "buckling"},
             "adaptive": {"name", "every", "sizing", "remesh", "pop_filter", "buckling"},
             "viewdep": {"name", "every", "sizing", "remesh", "pop_filter", "buckling", "view"}}
# The top-level keys a run reads or records (conf/config.yaml, its groups, and what the study
# presets of conf/experiment and conf/point set: `points`, `baseline`); any other is refused,
# never silently ignored (`+foo=1`, a key mistyped with a `+`).
TOP_LEVEL_KEYS = frozenset({"camera", "cameras", "scene", "mode", "material", "solver", "collision", "output", "frames",
                            "seed", "repeats", "scale", "resolution_factor", "crowd_jobs", "crowd_backend", "max_speed",
                            "study", "reference", "reference_member", "reference_check", "variant", "drape_mesh",
                            "points", "baseline", "baseline_factor"})
# The keys of a scene (conf/scene/*.yaml): the others are refused.
SCENE_KEYS = frozenset({"name", "effects", "frames", "params", "scales", "view"})
# output.* (conf/output/default.yaml): what each is, checked before any run.
OUTPUT_INTS = ("obj_every", "stills_every", "states_every", "checkpoint_every", "usd_every")  # frames, 0: never
OUTPUT_BOOLS = ("rerun", "progress", "resume")


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
    if out.get("usd_every") and importlib.util.find_spec("pxr") is None:
        raise ConfigError("output.usd_every: writing a USD stage needs the usd-core package "
                          "(pip install -e '.[usd]'), which is not installed")


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


def plain_experiment(overrides) -> list[str]:
    """`overrides` with ``+experiment=NAME`` and ``++experiment=NAME`` written ``experiment=NAME``.
    conf/config.yaml lists the experiment group (``experiment: null``), so that
    ``experiment=NAME`` picks a study preset; Hydra refuses to append (+) a group the defaults
    list already holds, and the appending form is how studies were run before (the README's
    ``-m +experiment=NAME``): both forms keep working."""
    return [re.sub(r"^\+{1,2}(experiment=)", r"\1", str(a)) for a in overrides]


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
