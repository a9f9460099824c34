"""Run folders and the runs table (never re-simulating): finding run folders under roots,
loading each (config.yaml, frames.parquet, summary.json and, when present, accuracy.json /
accuracy.parquet, sync.json), and the runs table, the per-frame table and the accuracy table of
every usable run (:func:`load_runs`). experiments.aggregate makes Table 1 from them.

Run folders. A directory is a run folder when it holds ``config.yaml``, or both
``frames.parquet`` and ``summary.json`` (hidden directories such as Hydra's ``.hydra/`` are
never looked into). The search does not descend into a run folder, so the characters of a crowd
(``dancer_NN/``) are never counted as runs: the crowd is its top-level folder (per-frame sums).
A folder is reported by name with its reason and skipped when its config, frames or summary is
missing or unreadable, a required column (:data:`REQUIRED_FRAME_COLUMNS`) is missing or holds
NaN, its status is not ``completed`` or it has fewer frames than requested. An unreadable
accuracy.json/accuracy.parquet is reported too; the run is kept without accuracy.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import yaml

from cloth.core.records import SIM_PHASES
from experiments.analysis.tables import (
    PAPER_TABLE1 as PAPER_TABLE1,  # re-exported: the paper's numbers, also found here
)

REQUIRED_FRAME_COLUMNS = ("frame", "faces", "verts", "sim_s")  # what Table 1 and Fig. 8 are made of
RUN_MARKERS = ("config.yaml", "frames.parquet", "summary.json")
MODES = ("nonadaptive", "adaptive", "viewdep")
# Swept parameters: runs-table column -> dotted config key (present in mode viewdep / when set).
SWEPT = {"nu_out": "mode.view.nu_out", "margin": "mode.view.margin", "T": "mode.view.anticipation_frames",
         "anticipation": "mode.view.anticipation", "l_min_px": "mode.view.l_min_px"}
# View settings that are not swept but that a sweep's points must share (a point of a sweep differs
# from the others in its parameter only): the occlusion test (bool) and the contact floor (m; NaN
# when off). NaN outside mode=viewdep.
VIEW_HELD = {"occlusion": "mode.view.occlusion", "contact_size": "mode.view.contact_size",
             "lookahead": "mode.view.lookahead"}
VIEW_HELD_BOOLS = {"occlusion": None, "lookahead": True}  # bool columns: the value of a config without the key
SWEPT_COLUMNS = ("nu_out", "margin", "T", "anticipation", "l_min_px", "buckling_k", "buckling_mode",
                 "resolution_factor")
ACCURACY_KEYS = ("error_px_mean", "error_px_max", "silhouette_px_mean", "surface_px_mean", "iou_mean",
                 "offscreen_distance_m_mean", "popping_px_mean", "popping_remesh_px_mean", "popping_still_px_mean",
                 "floor_px_mean", "error_ratio_mean", "error_ratio_before_saturation_mean", "floor_saturation_frame",
                 "visible_distance_mean", "visible_area_px_distance_mean", "silhouette_length_px_distance_mean",
                 "wrinkle_energy_px2_distance_mean", "hem_radius_m_distance_mean", "hem_height_m_distance_mean")
# sync.json (experiments.sync, the re-synchronised error) -> runs table column
SYNC_KEYS = {**{f"{m}_{s}": f"{m}_{s}" for m in ("sync_error_px", "sync_error_mm", "sync_error_px1080")
                for s in ("mean", "lo", "hi", "cut_mean")},
             "windows": "sync_windows", "horizon": "sync_horizon", "members": "sync_members",
             "sim_s_mean": "sync_sim_s_mean", "faces_mean": "sync_faces_mean",  # the windows' own cost
             **{f"flip_{s}": f"sync_flip_{s}" for s in ("mean", "lo", "hi")}}  # FLIP (sync.perceptual)
# The reference's own error (experiments.callbacks.reference_error), on a reference's row:
# <file>.json's sync_error_px_mean / sync_error_mm_mean -> <column>_px / <column>_mm
REFERENCE_ERROR_FILES = {"sync_fine": "reference_error_fine", "sync_half_dt": "reference_error_half_dt",
                         "sync_floor": "reference_floor"}
# Per-frame measures a scene declares (cloth.core.scene.Scene.probes) or the view gives, taken at
# equilibrium: the mean over the last EQUILIBRIUM_FRAMES frames -> runs-table column <name>_final.
SCENE_MEASURES = ("drape_coefficient", "folds", "hem_radius_mean_m", "compressive_energy_out_j",
                  "overhang_elements")
EQUILIBRIUM_FRAMES = 10
# and how far each still moves over those frames (max - min): <name>_drift, what the ablations'
# settling criterion reads (paper_figures.ablations: SETTLED_DRAPE_COEFFICIENT, SETTLED_HEM_M)
STAT_COLUMNS = {"faces": "faces", "verts": "verts", "sim_s": "time"}  # frames column -> Table 1 name


class AggregateError(ValueError):
    """Bad input to the aggregation (a root that does not exist ...); the message names it."""


class RunFolderWarning(UserWarning):
    """A run folder that is reported and skipped (or kept without its accuracy)."""


@dataclass(frozen=True)
class Problem:
    """A run folder that could not be used (or only in part), and why."""
    path: Path
    reason: str

    def __str__(self) -> str:
        return f"{self.path}: {self.reason}"


@dataclass
class RunSet:
    """What load_runs found: one row per usable run, their frames, and the folders it skipped.

    runs:      one row per run (see :func:`load_run` for the columns), ordered by path.
    frames:    every frame of every run: the run's ``run``, scene, mode, scale, study, variant, then
               the frames.parquet columns.
    accuracy:  every frame of accuracy.parquet of the runs that have one (``run`` + its columns).
    problems:  the folders skipped (or kept without accuracy), each with its reason.
    """
    runs: pd.DataFrame
    frames: pd.DataFrame
    accuracy: pd.DataFrame
    problems: list[Problem] = field(default_factory=list)


class _Bad(Exception):
    """Internal: a run folder that cannot be used; the message is the reason."""


# ---- finding and loading run folders -----------------------------------------------------------

def check_roots(roots) -> list[Path]:
    """The roots as Paths; AggregateError naming the first that is not a directory."""
    out = []
    for r in roots:
        p = Path(r)
        if not p.is_dir():
            raise AggregateError(f"root {str(r)!r} is not a directory" if p.exists() else
                                 f"root {str(r)!r} does not exist")
        out.append(p)
    if not out:
        raise AggregateError("no root given (the folders to search for run folders)")
    return out


def is_run_folder(path: Path) -> bool:
    """A run folder holds config.yaml, or both frames.parquet and summary.json."""
    return (path / "config.yaml").is_file() or ((path / "frames.parquet").is_file()
                                                 and (path / "summary.json").is_file())


def find_run_folders(roots) -> list[Path]:
    """Every run folder under the roots (a root may be a run folder), sorted, without duplicates.
    Hidden directories are skipped and the search stops at a run folder (crowd characters and
    states/ sub-folders belong to their run)."""
    found: set[Path] = set()
    for root in check_roots(roots):
        for dirpath, dirnames, _ in os.walk(root):
            here = Path(dirpath)
            if is_run_folder(here):
                found.add(here.resolve())
                dirnames[:] = []
                continue
            dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
    return sorted(found)


def _get(cfg: dict, dotted: str, default=None):
    node = cfg
    for key in dotted.split("."):
        if not isinstance(node, dict) or key not in node:
            return default
        node = node[key]
    return node


def _read_yaml(path: Path) -> dict:
    if not path.is_file():
        raise _Bad(f"no {path.name} (half-written run folder?)")
    try:
        cfg = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise _Bad(f"{path.name} unreadable: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") \
            from None
    if not isinstance(cfg, dict):
        raise _Bad(f"{path.name} is not a mapping")
    return cfg


def _read_json(path: Path, what: str) -> dict:
    if not path.is_file():
        raise _Bad(f"no {path.name} ({what})")
    try:
        obj = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise _Bad(f"{path.name} unreadable: {type(exc).__name__}: {exc}") from None
    if not isinstance(obj, dict):
        raise _Bad(f"{path.name} is not a JSON object")
    return obj


def _read_parquet(path: Path) -> pd.DataFrame:
    if not path.is_file():
        raise _Bad(f"no {path.name} (the run wrote no frame?)")
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several kinds for a broken file
        raise _Bad(f"{path.name} unreadable: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") \
            from None


def _timestamp(path: Path) -> str:
    """When the run started: the manifest's timestamp_utc, else the config's modification time."""
    try:
        ts = json.loads((path / "manifest.json").read_text()).get("timestamp_utc")
        if ts:
            return str(pd.Timestamp(ts).tz_convert("UTC").isoformat())
    except (OSError, ValueError, TypeError, AttributeError):
        pass
    f = path / "config.yaml"
    t = f.stat().st_mtime if f.exists() else path.stat().st_mtime
    return pd.Timestamp(t, unit="s", tz="UTC").isoformat()


def _manifest(path: Path) -> dict:
    """manifest.json of a run folder ({} when absent or unreadable: runs made by other tools)."""
    try:
        m = json.loads((path / "manifest.json").read_text())
    except (OSError, ValueError):
        return {}
    return m if isinstance(m, dict) else {}


def code_label(manifest: dict) -> str:
    """The code a run ran: its commit (12 hex digits), with ``+diff:<sha1 8>`` when the work tree
    had uncommitted changes; '' when the manifest does not say."""
    commit = str(manifest.get("git_commit") or "")[:12]
    if commit and manifest.get("git_dirty"):
        commit += f"+diff:{str(manifest.get('git_diff_sha1') or '?')[:8]}"
    return commit


def _camera_cuts(cfg: dict) -> tuple:
    """Times (s) of the camera's jump cuts: the start of every shot after the first."""
    cam = cfg.get("camera") or {}
    if not isinstance(cam, dict) or cam.get("type") != "cuts":
        return ()
    shots = cam.get("shots") or []
    return tuple(float(s["start"]) for s in shots[1:] if isinstance(s, dict) and "start" in s)


def _text(v) -> str:
    return "" if v is None else str(v)


def _float(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def effective_view_setting(cfg: dict, key: str):
    """The value a run used for the view setting `key` ('mode.view.<name>'): the scene's own
    (scene.view.<name>, which experiments.build lets win over the mode's), else the mode's."""
    scene_value = _get(cfg, "scene.view." + key.rsplit(".", 1)[-1])
    return scene_value if scene_value is not None else _get(cfg, key)


def with_sim_seconds(frames: pd.DataFrame) -> pd.DataFrame:
    """`frames` with its sim_s column: as recorded, or for runs recorded before it, the sum of the
    simulation phases' columns (cloth.core.records.SIM_PHASES). Without either, unchanged (the
    caller names the missing column)."""
    if "sim_s" in frames.columns:
        return frames
    phases = [f"time_{p}_s" for p in SIM_PHASES]
    if not all(c in frames.columns for c in phases):
        return frames
    return frames.assign(sim_s=frames[phases].sum(axis=1))


def load_run(path) -> tuple[dict, pd.DataFrame, pd.DataFrame | None, list[str]]:
    """One run folder: (row of the runs table, frames, accuracy frames or None, notes about parts
    left out). Raises _Bad with the reason when the folder cannot be used.

    Row: path, scene, mode, scale, study, variant, reference, seed, timestamp, the swept
    parameters (nu_out, margin, T, anticipation, l_min_px, buckling_k, buckling_mode,
    resolution_factor; NaN/'' where the mode has none), frame_time_s, camera_cuts_s, status, frames,
    frames_requested, characters,
    faces/verts/time min/max/mean (time_*_s from sim_s), time_total_s, io_mean_s and wall_mean_s
    (I/O and the whole frame, beside the simulation time), time_<phase>_mean_s,
    drape_mesh (ablation_buckling's mesh, '' elsewhere), <measure>_final of SCENE_MEASURES (mean
    over the last EQUILIBRIUM_FRAMES frames; NaN where a run does not record it) and <measure>_drift
    (its range over them),
    size_min_fraction_mean / size_max_fraction_mean (faces at a sizing bound over faces, mean over
    the frames that remeshed) and edge_at_size_min_m (median over those frames; NaN without them),
    and accuracy.json's ACCURACY_KEYS plus accuracy_frames (NaN without accuracy), and sync.json's
    SYNC_KEYS (the re-synchronised error; NaN without it), and on a reference the columns of
    REFERENCE_ERROR_FILES (its own error against its checks, and its floor; NaN without them).
    """
    path = Path(path)
    cfg = _read_yaml(path / "config.yaml")
    scene, mode = _get(cfg, "scene.name"), _get(cfg, "mode.name")
    if not scene or not mode:
        raise _Bad("config.yaml has no scene.name or mode.name (not a resolved run config?)")
    summary = _read_json(path / "summary.json", "half-written: the run did not finish, or is still running")
    status = summary.get("status")
    if status != "completed":
        msg = summary.get("message") or ""
        raise _Bad(f"status {status!r}, not 'completed'" + (f" ({msg})" if msg else ""))
    frames = with_sim_seconds(_read_parquet(path / "frames.parquet"))
    missing = [c for c in REQUIRED_FRAME_COLUMNS if c not in frames.columns]
    if missing:
        raise _Bad(f"frames.parquet lacks column(s) {', '.join(missing)}")
    nan = [c for c in REQUIRED_FRAME_COLUMNS if frames[c].isna().any()]
    if nan:
        raise _Bad(f"frames.parquet has NaN in {', '.join(nan)}")
    requested = [int(v) for v in (cfg.get("frames"), summary.get("frames_requested")) if isinstance(v, (int, float))]
    if requested and len(frames) < max(requested):
        raise _Bad(f"{len(frames)} frames of {max(requested)} requested")
    if "frames_completed" in summary and int(summary["frames_completed"]) != len(frames):
        raise _Bad(f"summary.json says {summary['frames_completed']} frames, frames.parquet has {len(frames)}")
    frames = frames.sort_values("frame").reset_index(drop=True)

    buckling = _get(cfg, "mode.buckling")
    row = {"path": str(path), "scene": str(scene), "mode": str(mode), "scale": _text(cfg.get("scale")),
           "study": _text(cfg.get("study")), "variant": _text(cfg.get("variant")),
           "reference": bool(cfg.get("reference") or False), "reference_check": _text(cfg.get("reference_check")),
           "seed": cfg.get("seed"), "timestamp": _timestamp(path)}
    manifest = _manifest(path)
    row["code"] = code_label(manifest)
    row["numba_threads"] = _float(manifest.get("numba_threads"))
    for col, key in SWEPT.items():
        v = effective_view_setting(cfg, key)
        row[col] = (math.nan if v is None else bool(v)) if col == "anticipation" else _float(v)
    row["anticipation"] = row["anticipation"] if mode == "viewdep" else math.nan
    for col, key in VIEW_HELD.items():
        v = effective_view_setting(cfg, key) if mode == "viewdep" else None
        if v is None and mode == "viewdep":
            v = VIEW_HELD_BOOLS.get(col)  # lookahead: runs from before the key looked ahead
        row[col] = math.nan if v is None else (bool(v) if col in VIEW_HELD_BOOLS else _float(v))
    row["resolution_factor"] = _float(cfg.get("resolution_factor", 1.0)) if mode == "nonadaptive" else math.nan
    row["bending_hessian"] = _text(_get(cfg, "solver.bending_hessian")) or "projected"
    row["membrane_hessian"] = _text(_get(cfg, "solver.membrane_hessian")) or "projected"
    row["steps_per_frame"] = _float(_get(cfg, "scene.params.steps_per_frame"))
    row["buckling_k"] = _float(buckling.get("k")) if isinstance(buckling, dict) else math.nan
    row["buckling_mode"] = (str(buckling.get("mode", "adaptive")) if isinstance(buckling, dict) else "none")
    row["frame_time_s"] = _float(_get(cfg, "scene.params.frame_time"))
    row["camera_cuts_s"] = _camera_cuts(cfg)
    row.update(status=status, frames=int(len(frames)), frames_requested=max(requested) if requested else len(frames),
               characters=int(summary.get("characters", 1)))
    for col, name in STAT_COLUMNS.items():
        unit = "_s" if name == "time" else ""
        row[f"{name}_min{unit}"] = float(frames[col].min())
        row[f"{name}_max{unit}"] = float(frames[col].max())
        row[f"{name}_mean{unit}"] = float(frames[col].mean())
    # step control (cloth.stepcontrol): steps undone and retried at half the step; NaN for runs recorded before it
    row["steps_rejected"] = float(frames["steps_rejected"].sum()) if "steps_rejected" in frames.columns else math.nan
    row["drape_mesh"] = _text(cfg.get("drape_mesh"))
    for name in SCENE_MEASURES:
        v = frames[name].astype(float).tail(EQUILIBRIUM_FRAMES) if name in frames.columns else pd.Series(dtype=float)
        row[f"{name}_final"] = float(v.mean()) if v.notna().any() else math.nan
        row[f"{name}_drift"] = float(v.max() - v.min()) if v.notna().any() else math.nan
    row["time_total_s"] = float(frames["sim_s"].sum())
    row["io_mean_s"] = float(frames["time_io_s"].mean()) if "time_io_s" in frames.columns else math.nan
    row["wall_mean_s"] = float(frames["wall_s"].mean()) if "wall_s" in frames.columns else math.nan
    for c in frames.columns:
        if c.startswith("time_") and c.endswith("_s"):
            row[f"{c[:-2]}_mean_s"] = float(frames[c].mean())
    # room the sizing had (remeshing modes): the share of faces held at each bound, over the frames
    # that remeshed, and the median realised edge of the faces at size_min (a fixed mesh of the
    # same resolution uses it: iso-resolution)
    remeshed = frames[frames["remeshed"] > 0] if "remeshed" in frames.columns else frames.iloc[0:0]
    for bound in ("min", "max"):
        col = f"faces_at_size_{bound}"
        sized = remeshed["faces_sized"] if "faces_sized" in remeshed.columns else remeshed["faces"]
        row[f"size_{bound}_fraction_mean"] = (float((remeshed[col] / sized).mean())
                                              if col in remeshed.columns and len(remeshed) else math.nan)
    row["edge_at_size_min_m"] = (float(remeshed["edge_at_size_min_m"].median())
                                 if "edge_at_size_min_m" in remeshed.columns and len(remeshed) else math.nan)

    notes: list[str] = []
    acc_frames = None
    for k in ACCURACY_KEYS:
        row[k] = math.nan
    row["accuracy_frames"] = math.nan
    if (path / "accuracy.json").exists():
        try:
            acc = _read_json(path / "accuracy.json", "accuracy")
            for k in ACCURACY_KEYS:
                row[k] = _float(acc.get(k))
            row["accuracy_frames"] = _float(acc.get("frames"))
        except _Bad as exc:
            notes.append(f"{exc}; the run is kept without accuracy")
    for col in SYNC_KEYS.values():
        row[col] = math.nan
    if (path / "sync.json").exists():
        try:
            sync = _read_json(path / "sync.json", "sync")
            for k, col in SYNC_KEYS.items():
                row[col] = _float(sync.get(k))
            for k in sync:  # seen from further cameras (the callback's sync.views): as named
                if k.startswith(("sync_error_px_view_", "sync_error_mm_view_")):
                    row[k] = _float(sync.get(k))
        except _Bad as exc:
            notes.append(f"{exc}; the run is kept without its re-synchronised error")
    for stem, col in REFERENCE_ERROR_FILES.items():
        row[f"{col}_px"] = row[f"{col}_mm"] = math.nan
        if (path / f"{stem}.json").exists():
            try:
                own = _read_json(path / f"{stem}.json", stem)
                row[f"{col}_px"], row[f"{col}_mm"] = _float(own.get("sync_error_px_mean")), \
                    _float(own.get("sync_error_mm_mean"))
            except _Bad as exc:
                notes.append(f"{exc}; the reference is kept without its own error ({stem})")
    if (path / "accuracy.parquet").exists():
        try:
            acc_frames = _read_parquet(path / "accuracy.parquet")
            if "frame" not in acc_frames.columns:
                raise _Bad("accuracy.parquet has no frame column")
        except _Bad as exc:
            acc_frames = None
            notes.append(f"{exc}; the run is kept without per-frame accuracy")
    return row, frames, acc_frames, notes


def _run_ids(paths: list[Path]) -> list[str]:
    """Short names: each path relative to the common parent of all (the folder name when alone)."""
    if not paths:
        return []
    if len(paths) == 1:
        return [paths[0].name]
    base = Path(os.path.commonpath([str(p.parent) for p in paths]))
    return [str(p.relative_to(base)) for p in paths]


def load_runs(roots, warn: bool = True) -> RunSet:
    """Load every run folder under the roots; unusable ones go to ``problems`` (and, with `warn`,
    a RunFolderWarning each), never into the tables."""
    paths = find_run_folders(roots)
    rows, frames, accs, problems, kept = [], [], [], [], []
    for p in paths:
        try:
            row, fr, acc, notes = load_run(p)
        except _Bad as exc:
            problems.append(Problem(p, f"skipped: {exc}"))
            continue
        problems.extend(Problem(p, n) for n in notes)
        kept.append(p)
        rows.append(row)
        frames.append(fr)
        accs.append(acc)
    ids = _run_ids(kept)
    runs = pd.DataFrame(rows)
    if len(runs):
        runs.insert(0, "run", ids)
    else:
        runs = pd.DataFrame(columns=["run", "path", "scene", "mode", "scale", "study", "variant", "reference"])
    key = ("scene", "mode", "scale", "study", "variant")
    per_frame = [f.assign(run=rid, **{k: r[k] for k in key}) for rid, r, f in zip(ids, rows, frames)]
    frames_all = pd.concat(per_frame, ignore_index=True) if per_frame else pd.DataFrame(columns=["run", *key])
    frames_all = frames_all[["run", *key] + [c for c in frames_all.columns if c not in ("run", *key)]]
    acc_all = [a.assign(run=rid) for rid, a in zip(ids, accs) if a is not None]
    acc_all = pd.concat(acc_all, ignore_index=True) if acc_all else pd.DataFrame(columns=["run", "frame"])
    acc_all = acc_all[["run"] + [c for c in acc_all.columns if c != "run"]]
    if warn:
        for pr in problems:
            warnings.warn(str(pr), RunFolderWarning, stacklevel=2)
    return RunSet(runs=runs, frames=frames_all, accuracy=acc_all, problems=problems)
