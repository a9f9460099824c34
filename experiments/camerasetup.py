"""The camera a run looks through, from its config: `camera` (one path of conf/camera/, fitted to a
crowd's stage) and, beyond the paper, `cameras` (more of them: a rig). Every tool that needs a
run's camera builds it here, from the run's config (a DictConfig, or a run folder's config.yaml as
a dict); ConfigError names a bad camera.* or cameras[i] key. Re-exported by experiments.build."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from cloth.scenes.registry import CROWDS, crowd_columns, crowd_placement, multiple_dancers
from cloth.view.camera import ViewError
from cloth.view.paths import CameraRig, fit_shots, path_from_config
from experiments.checks import ConfigError, _int_at_least, _plain, _require

CAMERA_CONF = Path(__file__).resolve().parents[1] / "conf" / "camera"  # the camera configs `cameras` names


def _crowd_default(key: str):
    """multiple_dancers' own default of a parameter (for configs that do not set it)."""
    return inspect.signature(multiple_dancers).parameters[key].default


def stage_camera_config(cam: dict, scene: dict) -> dict:
    """The camera config `cam` (plain dict) fitted to the stage of the crowd `scene` (its plain
    config: name, params), without its `stage_scale` block; as written when it has none or the
    scene is not a crowd.

    `stage_scale: {stage: {dancers, columns, spacing}, front_row_dancer: k}` says which stage the
    shots are written for (conf/camera/crowd_shots.yaml). The scene's stage (its dancers, columns,
    spacing: cloth.scenes.crowd.crowd_placement) against that one gives
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
    (:func:`stage_camera_config`); with `cameras` (beyond the paper) a rig of it and those
    (:func:`extra_cameras`). ConfigError names a bad camera.* or cameras[i] key."""
    try:
        main = camera_path(cfg)
    except (ViewError, KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{_camera_key(cfg, exc)}: {exc}") from None
    more = extra_cameras(cfg)
    if not more:
        return main
    named = ([("main", main)] if main is not None else []) + more
    names = [n for n, _ in named]
    for i, (name, _) in enumerate(more):
        before = names[:len(named) - len(more) + i]
        _require(name not in before, f"cameras[{i}]", f"a second camera named {name!r}; give it another "
                 f"`name` (camera names: {names})")
    return named[0][1] if len(named) == 1 else CameraRig([p for _, p in named], names)


CAMERA_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def extra_cameras(cfg) -> list[tuple[str, object]]:
    """[(name, camera path), ...] of `cameras` (beyond the paper: cameras the view-dependent
    sizing, buckling compensation and the records look at beside `camera`, the main one). Each
    entry is the name of a camera of conf/camera/ (its name is the file's) or a camera config (a
    mapping as those files hold, `type: static` when it has none, `target` read as `look_at`, and
    an optional `name`); each is fitted to a crowd's stage as `camera` is. ConfigError names the
    bad entry (`cameras[i]`)."""
    entries = cfg.get("cameras")
    entries = OmegaConf.to_container(entries, resolve=True) if OmegaConf.is_config(entries) else entries or []
    _require(isinstance(entries, list), "cameras", f"must be a list of camera names or configs, got {entries!r}")
    scene = cfg.get("scene") or {}
    scene = {"name": scene.get("name"), "params": _plain(scene.get("params"))}
    out = []
    for i, entry in enumerate(entries):
        key = f"cameras[{i}]"
        if isinstance(entry, str):
            known = sorted(p.stem for p in CAMERA_CONF.glob("*.yaml") if p.stem != "none")
            _require(entry in known, key, f"no camera {entry!r} in conf/camera/; known: {', '.join(known)}")
            cam, name = OmegaConf.to_container(OmegaConf.load(CAMERA_CONF / f"{entry}.yaml"), resolve=True), entry
        else:
            _require(isinstance(entry, dict), key, f"must be a camera name or a camera config, got {entry!r}")
            cam = dict(entry)
            name = cam.pop("name", f"camera{i + 1}")
            cam.setdefault("type", "static")
            if "target" in cam:
                cam.setdefault("look_at", cam["target"])
        _require(isinstance(name, str) and CAMERA_NAME.fullmatch(name) is not None, f"{key}.name",
                 f"must be a name of letters, digits and _ (it names records: faces_in_view_<name>), got {name!r}")
        try:
            out.append((name, path_from_config(stage_camera_config(cam, scene))))
        except (ViewError, KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(f"{key}: {exc}") from None
    return out


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
