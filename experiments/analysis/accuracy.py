"""Screen-space accuracy of runs against a fine reference of the same scene and camera.

    python -m experiments.accuracy RUN_DIR [RUN_DIR ...] --reference REF_DIR [REF_DIR ...] [--resolution-scale 1.0]

Reads the per-frame states (``states/frame_NNNNN.npz``, written by the runner with
``output.states_every``) of every run and of the reference, rebuilds the camera path from the
run's ``config.yaml``, renders both at every frame they both have (cloth.eval.screenspace) and writes
into each RUN_DIR:

* ``accuracy.parquet``: one row per frame, columns frame, error_px, silhouette_px, surface_px,
  cloth_px_run, cloth_px_ref, iou, offscreen_distance_m (definitions: cloth.eval.screenspace),
  and error_lo_px, error_hi_px, floor_px, error_ratio, members (a reference ensemble, below),
  popping_px (the run against itself: popping within a shot, cloth.eval.screenspace);
  and the run's statistics of visible cloth (cloth.eval.visible: visible_area_px,
  silhouette_length_px, wrinkle_energy_px2, hem_radius_m, hem_height_m);
* ``visible.parquet``: per camera shot and statistic, the run's mean over the shot's frames, the
  reference members' mean and spread (standard deviation over the members' own shot means) and
  the run's distance from them in spreads (cloth.eval.visible.spread_distance: about 1 or below,
  the run looks as much like the reference as one member like another; NaN with one member);
* ``accuracy.json``: ``<column>_mean`` and ``<column>_max`` of every numeric column (NaN frames
  left out; null when a column has no value), ``<statistic>_distance_mean`` (over the shots) and
  ``visible_distance_mean`` (over shots and statistics), ``reference`` (the reference folder),
  ``frames`` (frames evaluated), ``resolution`` ([width, height] of the rendered images),
  ``resolution_scale`` and ``definition`` (the definitions, with their versions).

**A reference ensemble** (several REF_DIRs: runs of the reference config that differ only in
their seed, the members): every column is the mean over the members; error_lo_px / error_hi_px
the 90 % bootstrap interval of error_px over them; floor_px, the *chaos floor*, the median of
error_px between pairs of members (two equally good runs that chaos has parted); error_ratio =
error_px / floor_px (about 1: the run is as far from the reference as chaos alone puts it).
accuracy.json then also gives floor_saturation_frame, the first frame where the floor reaches
FLOOR_SATURATION of its largest value, and error_ratio_before_saturation_mean.

Every run is checked against the reference before any work (same scene and scene parameters
apart from the mesh resolution, same camera config, same frame time, states for every frame of
the run); a mismatch stops with one message naming it. A crowd run (one sub-folder per
character) is rendered as one image: all characters' cloth and bodies under the one camera.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import OmegaConf
from scipy import stats
from tqdm import tqdm

from cloth.eval import screenspace, visible
from cloth.eval.screenspace import frame_errors, offscreen_distance, popping, render_state
from cloth.io.manifest import write_json_atomic, write_parquet_atomic
from cloth.io.states import load_state, merge_states
from cloth.view.camera import ViewError
from experiments.build import ConfigError, camera_path

# With an ensemble of reference members: the bootstrap interval of error_px over the members, the
# chaos floor (median error between pairs of members; NaN with one member), error / floor, members.
ENSEMBLE_COLUMNS = ("error_lo_px", "error_hi_px", "floor_px", "error_ratio", "members")
COLUMNS = ("frame", "error_px", "silhouette_px", "surface_px", "cloth_px_run", "cloth_px_ref", "iou",
           "offscreen_distance_m", *ENSEMBLE_COLUMNS, "popping_px", *visible.STATISTICS)
VISIBLE_COLUMNS = ("shot", "statistic", "frames", "run", "members_mean", "members_spread", "distance")
BOOTSTRAP = 2000  # resamples for the 90 % intervals (seeded: the same numbers every time)
# Values within this relative spread are one value to the bootstrap (round-off of a constant difference:
# (x + 0.9) - (x + 1.0) differs from -0.1 in the last bits, by x)
SAME_VALUES_REL = 1e-12
# The floor has saturated at the first frame where it reaches this fraction of its largest value:
# from there on, two members of the ensemble are as different as two unrelated runs of the scene.
FLOOR_SATURATION = 0.9
# Frame times of a run and its reference are equal if they agree to this many seconds (config
# values pass through YAML; the times of states are multiples of the frame time).
TIME_TOL_S = 1e-9
# A progress bar redraws at most this often (seconds): a log file gets a line per interval, not per frame.
PROGRESS_INTERVAL_S = 10.0
# Scene parameters that may differ between a run and its reference: the discretisation, in space
# (the mesh resolution and the presets that set it: the reference is finer by design) and in time
# (the implicit steps per frame: a reference with half the time step, a sweep of the steps).
RESOLUTION_KEYS = ("resolution", "sizing", "reference", "steps_per_frame")


class AccuracyError(ValueError):
    """A run folder that cannot be evaluated against the reference; the message names why."""


def definition() -> str:
    """The definitions of the columns, with their version (cloth.eval.screenspace's docstring)."""
    parts = []
    for module in (screenspace, visible):
        doc = module.__doc__
        start = doc.index("Definitions (version") if "Definitions (version" in doc else 0
        parts.append(doc[start:].strip().replace(":data:`DEFINITION_VERSION`", module.DEFINITION_VERSION))
    return "\n\n".join(parts)


# ---- reading run folders -----------------------------------------------------------------------

def _config(run_dir: Path) -> dict:
    f = run_dir / "config.yaml"
    if not f.is_file():
        raise AccuracyError(f"{run_dir}: no config.yaml (is it a run folder of experiments.run?)")
    return OmegaConf.to_container(OmegaConf.load(f), resolve=True)


def _scene_params(cfg: dict) -> dict:
    """The scene parameters the run used: scene.params, its scale preset, the reference preset
    of a reference run (as experiments.build does)."""
    scene = cfg.get("scene") or {}
    params = dict(scene.get("params") or {})
    preset = dict((scene.get("scales") or {}).get(cfg.get("scale"), {}) or {})
    ref = preset.pop("reference", None)
    params.update(preset)
    if cfg.get("reference") and isinstance(ref, dict):
        params.update(ref)
    return params


def state_files(run_dir: Path) -> dict[int, list[Path]]:
    """frame -> state files of that frame (one per character of a crowd); {} without states."""
    dirs = [run_dir / "states"] if (run_dir / "states").is_dir() else sorted(
        d / "states" for d in run_dir.glob("dancer_*") if (d / "states").is_dir())
    per_dir = []
    for d in dirs:
        files = {}
        for f in d.glob("frame_*.npz"):
            try:
                files[int(f.stem.split("_")[1])] = f
            except (IndexError, ValueError):
                continue
        per_dir.append(files)
    if not per_dir:
        return {}
    frames = set(per_dir[0]).intersection(*per_dir[1:])  # a crowd: frames every character has
    return {k: [files[k] for files in per_dir] for k in sorted(frames)}


def _first_difference(a, b, key: str):
    """(key path, value in a, value in b) of the first difference of two nested configs, or None."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b), key=str):
            d = _first_difference(a.get(k), b.get(k), f"{key}.{k}")
            if d is not None:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            d = _first_difference(x, y, f"{key}[{i}]")
            if d is not None:
                return d
        return None
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return None if float(a) == float(b) else (key, a, b)
    return None if a == b else (key, a, b)


def check_configs(run_dir, ref_dir) -> None:
    """A run and its reference are of the same scene (parameters apart from the discretisation:
    RESOLUTION_KEYS), camera and frame time; AccuracyError names the first mismatch."""
    run_dir, ref_dir = Path(run_dir), Path(ref_dir)
    for d in (run_dir, ref_dir):
        if not d.is_dir():
            raise AccuracyError(f"{d}: no such folder")
    run_cfg, ref_cfg = _config(run_dir), _config(ref_dir)
    name = lambda c: (c.get("scene") or {}).get("name")  # noqa: E731
    if name(run_cfg) != name(ref_cfg):
        raise AccuracyError(f"{run_dir}: scene {name(run_cfg)!r} differs from the reference's {name(ref_cfg)!r} "
                            f"({ref_dir})")
    cam = run_cfg.get("camera")
    if not cam or cam.get("type") in (None, "none"):
        raise AccuracyError(f"{run_dir}: the run has no camera (camera: none); screen-space accuracy needs one")
    diff = _first_difference(cam, ref_cfg.get("camera"), "camera")
    if diff is not None:
        raise AccuracyError(f"{run_dir}: camera config differs from the reference's at {diff[0]}: "
                            f"run {diff[1]!r}, reference {diff[2]!r} ({ref_dir})")
    pr, pf = _scene_params(run_cfg), _scene_params(ref_cfg)
    tr, tf = pr.get("frame_time"), pf.get("frame_time")
    if tr is None or tf is None or abs(float(tr) - float(tf)) > TIME_TOL_S:
        raise AccuracyError(f"{run_dir}: frame time {tr} s differs from the reference's {tf} s ({ref_dir})")
    for k in RESOLUTION_KEYS:
        pr.pop(k, None)
        pf.pop(k, None)
    diff = _first_difference(pr, pf, "scene.params")
    if diff is not None:
        raise AccuracyError(f"{run_dir}: {diff[0]} differs from the reference's: run {diff[1]!r}, "
                            f"reference {diff[2]!r} ({ref_dir})")


def check_pair(run_dir, ref_dir) -> list[int]:
    """The frames to evaluate (every frame the run has a state for); AccuracyError names a mismatch."""
    run_dir, ref_dir = Path(run_dir), Path(ref_dir)
    check_configs(run_dir, ref_dir)
    ref_cfg = _config(ref_dir)
    run_states, ref_states = state_files(run_dir), state_files(ref_dir)
    for d, states in ((run_dir, run_states), (ref_dir, ref_states)):
        if not states:
            raise AccuracyError(f"{d}: no per-frame states (states/frame_NNNNN.npz); run it again with "
                                f"output.states_every=1")
    missing = sorted(set(run_states) - set(ref_states))
    if missing:
        have = sorted(ref_states)
        raise AccuracyError(
            f"{run_dir}: the reference has no state for {len(missing)} of the run's {len(run_states)} frames "
            f"(first {missing[:5]}); the reference has frames {have[0]}..{have[-1]} ({len(have)} states, {ref_dir}): "
            f"run the reference for at least {max(run_states)} frames with output.states_every=1")
    if not isinstance(ref_cfg.get("mode"), dict) or ref_cfg["mode"].get("name") != "nonadaptive":
        print(f"note: the reference {ref_dir} is not a nonadaptive run", file=sys.stderr)
    return sorted(run_states)


def _load(files: list[Path]) -> dict:
    return merge_states([load_state(f) for f in files])


# ---- evaluation --------------------------------------------------------------------------------

def _ref_list(ref_dir) -> list[Path]:
    """The members of a reference: one folder, or a list of folders (an ensemble)."""
    refs = [Path(ref_dir)] if isinstance(ref_dir, (str, Path)) else [Path(r) for r in ref_dir]
    if not refs:
        raise AccuracyError("no reference run given")
    return refs


def shot_index(path, t: float) -> int:
    """Index of the shot of a camera path at time t (the number of cuts at or before it)."""
    return sum(1 for c in getattr(path, "cuts", ()) if c <= t + TIME_TOL_S)


def bootstrap_mean_interval(values, resamples: int = BOOTSTRAP, seed: int = 0) -> tuple[float, float]:
    """90 % BCa bootstrap interval of the mean of `values` (scipy.stats.bootstrap, seeded; NaN left
    out; (nan, nan) if none). Values that all agree to SAME_VALUES_REL (one value, or the
    window-by-window differences of two runs a constant apart) give (mean, mean): BCa's
    acceleration is undefined there, and every resample has that mean."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan
    mean = float(v.mean())
    if np.ptp(v) <= SAME_VALUES_REL * max(1.0, abs(mean)):
        return mean, mean
    res = stats.bootstrap((v,), np.mean, confidence_level=0.9, n_resamples=resamples, method="BCa",
                          random_state=np.random.default_rng(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def evaluate_runs(run_dirs, ref_dir, resolution_scale: float = 1.0) -> list[pd.DataFrame]:
    """One accuracy table per run (the columns of COLUMNS, one row per frame); every run is checked
    before any work. `ref_dir`: the reference run, or the members of a reference ensemble (runs of
    the reference config with different seeds): each column is then the mean over the members,
    error_lo_px / error_hi_px the 90 % bootstrap interval of error_px over them, floor_px the
    chaos floor (the median error_px between pairs of members) and error_ratio = error_px /
    floor_px. The references are rendered once per frame and camera for all runs."""
    if not (isinstance(resolution_scale, (int, float)) and math.isfinite(resolution_scale) and resolution_scale > 0):
        raise AccuracyError(f"--resolution-scale must be a number > 0, got {resolution_scale!r}")
    refs = _ref_list(ref_dir)
    run_dirs = [Path(d) for d in run_dirs]
    frames = []
    for d in run_dirs:  # every run against every member, before any work; its frames from the first
        frames.append(check_pair(d, refs[0]))
        for r in refs[1:]:
            check_pair(d, r)
    for r in refs[1:]:  # members of one ensemble: the same scene, camera and frame time
        check_configs(r, refs[0])
    ref_states = [state_files(r) for r in refs]
    run_states = [state_files(d) for d in run_dirs]
    try:
        paths = [camera_path(_config(d)) for d in run_dirs]  # a crowd's: fitted to its stage
    except (ViewError, ConfigError, KeyError, TypeError, ValueError) as exc:
        raise AccuracyError(f"camera config cannot be built: {exc}") from None
    rows = [[] for _ in run_dirs]
    recent = [[] for _ in run_dirs]  # each run's last two (frame, shot, image): popping needs three
    seen = [[] for _ in run_dirs]  # each run's (shot, its statistics, the members' statistics) per frame
    numeric = [c for c in COLUMNS if c not in ("frame", "popping_px", *ENSEMBLE_COLUMNS, *visible.STATISTICS)]
    # a bar on stderr: a study's evaluation of its runs takes minutes (issue: never a silent minute)
    for frame in tqdm(sorted(set().union(*frames)), desc=f"accuracy: {len(run_dirs)} run(s), frames", unit="frame",
                      mininterval=PROGRESS_INTERVAL_S):
        members = [_load(states[frame]) for states in ref_states]
        ref_img = {}  # the members' images under each distinct camera (runs share one path)
        ref_stats = {}  # and their statistics of visible cloth
        floor = {}
        for i, d in enumerate(run_dirs):
            if frame not in run_states[i]:
                continue
            run = _load(run_states[i][frame])
            if abs(run["time"] - members[0]["time"]) > TIME_TOL_S:
                raise AccuracyError(f"{d}: frame {frame} is at t = {run['time']} s, the reference's at "
                                    f"t = {members[0]['time']} s ({refs[0]})")
            camera = paths[i].camera_at(members[0]["time"])
            if camera not in ref_img:
                ref_img[camera] = [render_state(camera, m, resolution_scale) for m in members]
                pairs = [frame_errors(a, b)["error_px"] for k, a in enumerate(ref_img[camera])
                         for b in ref_img[camera][k + 1:]]
                floor[camera] = float(np.median(pairs)) if pairs else math.nan
                ref_stats[camera] = [visible.frame_statistics(img, m) for img, m in zip(ref_img[camera], members)]
            run_img = render_state(camera, run, resolution_scale)
            shot = shot_index(paths[i], members[0]["time"])
            stats = visible.frame_statistics(run_img, run)
            seen[i].append((shot, stats, ref_stats[camera]))
            if len(recent[i]) == 2:
                (f0, s0, im0), (f1, s1, im1) = recent[i]
                if (f0, f1) == (frame - 2, frame - 1) and s0 == s1 == shot:
                    rows[i][-1]["popping_px"] = popping(im0, im1, run_img)
            recent[i] = [*recent[i][-1:], (frame, shot, run_img)]
            per_member = []
            for m, img in zip(members, ref_img[camera]):
                off, _ = offscreen_distance(camera, run["node_x"], m["node_x"], m["face_nodes"])
                per_member.append({**frame_errors(run_img, img), "offscreen_distance_m": off})
            row = {"frame": frame}
            for c in numeric:
                v = np.array([e[c] for e in per_member], dtype=np.float64)
                row[c] = float(np.nanmean(v)) if np.isfinite(v).any() else math.nan
            lo, hi = bootstrap_mean_interval([e["error_px"] for e in per_member], seed=frame)
            f = floor[camera]
            row.update(error_lo_px=lo, error_hi_px=hi, floor_px=f, members=len(members),
                       error_ratio=row["error_px"] / f if f > 0 else math.nan, popping_px=math.nan, **stats)
            rows[i].append(row)
    tables = []
    for r, frames_seen in zip(rows, seen):
        table = pd.DataFrame(r, columns=list(COLUMNS)).astype({"frame": np.int64})
        table.attrs["visible"] = visible_by_shot(frames_seen)
        tables.append(table)
    return tables


def visible_by_shot(frames_seen) -> pd.DataFrame:
    """visible.parquet's table (VISIBLE_COLUMNS) from a run's frames: (shot, the run's statistics,
    the members' statistics) each. Per shot and statistic, the run's mean over the shot's frames
    and each member's, then the run's distance from the members in their spread."""
    out = []
    for shot in sorted({f[0] for f in frames_seen}):
        in_shot = [f for f in frames_seen if f[0] == shot]
        n_members = len(in_shot[0][2])
        for name in visible.STATISTICS:
            run = np.array([f[1][name] for f in in_shot], dtype=np.float64)
            members = np.array([[f[2][k][name] for f in in_shot] for k in range(n_members)], dtype=np.float64)
            run_mean = float(np.nanmean(run)) if np.isfinite(run).any() else math.nan
            member_means = [float(np.nanmean(m)) if np.isfinite(m).any() else math.nan for m in members]
            dist, mean, spread = visible.spread_distance(run_mean, member_means)
            out.append({"shot": shot, "statistic": name, "frames": len(in_shot), "run": run_mean,
                        "members_mean": mean, "members_spread": spread, "distance": dist})
    return pd.DataFrame(out, columns=list(VISIBLE_COLUMNS))


def evaluate_run(run_dir, ref_dir, resolution_scale: float = 1.0) -> pd.DataFrame:
    """The accuracy table of one run against a reference (see evaluate_runs); writes nothing."""
    return evaluate_runs([run_dir], ref_dir, resolution_scale)[0]


def _stat(values: pd.Series, fn) -> float | None:
    v = values.to_numpy(dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(fn(v)) if v.size else None


def floor_saturation_frame(table: pd.DataFrame) -> int | None:
    """The first frame whose chaos floor reaches FLOOR_SATURATION x its largest value (None without
    a floor: a single reference, or a floor that stays 0)."""
    f = table["floor_px"].to_numpy(dtype=np.float64) if "floor_px" in table.columns else np.zeros(0)
    ok = np.isfinite(f)
    if not ok.any() or not np.nanmax(f) > 0:
        return None
    k = np.flatnonzero(ok & (f >= FLOOR_SATURATION * np.nanmax(f)))[0]
    return int(table["frame"].iloc[k])


def summarize(table: pd.DataFrame, ref_dir, resolution, resolution_scale: float, remeshed=None) -> dict:
    """accuracy.json: <column>_mean and <column>_max of every numeric column, reference (the folder,
    or the list of an ensemble's members), members, floor_saturation_frame, error_ratio_before_saturation_mean
    (the mean ratio over the frames before it: where the floor is not yet "two different skirts"),
    popping_remesh_px_mean / popping_still_px_mean (popping over the frames whose remesh changed
    the mesh and over the others, from `remeshed`: frame -> count of the run's records; None
    without), frames, resolution, resolution_scale, definition."""
    out = {}
    for c in table.columns:
        if pd.api.types.is_numeric_dtype(table[c]):
            out[f"{c}_mean"] = _stat(table[c], np.mean)
            out[f"{c}_max"] = _stat(table[c], np.max)
    refs = _ref_list(ref_dir)
    sat = floor_saturation_frame(table)
    out["floor_saturation_frame"] = sat
    out["error_ratio_before_saturation_mean"] = (
        _stat(table["error_ratio"][(table["frame"] < sat).to_numpy()], np.mean) if sat is not None else None)
    out["popping_remesh_px_mean"] = out["popping_still_px_mean"] = None
    if remeshed is not None and "popping_px" in table.columns:
        changed = table["frame"].map(remeshed).fillna(0).to_numpy() > 0
        out["popping_remesh_px_mean"] = _stat(table["popping_px"][changed], np.mean)
        out["popping_still_px_mean"] = _stat(table["popping_px"][~changed], np.mean)
    shots = table.attrs.get("visible")
    if shots is not None and len(shots):
        for name in visible.STATISTICS:
            out[f"{name}_distance_mean"] = _stat(shots["distance"][shots["statistic"] == name], np.mean)
        out["visible_distance_mean"] = _stat(shots["distance"], np.mean)
    out.update(reference=str(refs[0].resolve()) if len(refs) == 1 else [str(r.resolve()) for r in refs],
               members=len(refs), frames=int(len(table)),
               resolution=[int(resolution[0]), int(resolution[1])], resolution_scale=float(resolution_scale),
               definition=definition())
    return out


def image_resolution(run_dir, resolution_scale: float) -> tuple[int, int]:
    """[width, height] of the images rendered for a run (its camera's image times the scale)."""
    cam = camera_path(_config(Path(run_dir))).camera_at(0.0)
    h = max(int(round(cam.height * resolution_scale)), 1)
    return max(int(round(cam.width * resolution_scale)), 1), h


def write_accuracy(run_dir, table: pd.DataFrame, ref_dir, resolution_scale: float = 1.0) -> dict:
    """Write accuracy.parquet and accuracy.json into `run_dir` (atomically); returns the summary."""
    run_dir = Path(run_dir)
    remeshed = None
    try:
        rec = pd.read_parquet(run_dir / "frames.parquet", columns=["frame", "remeshed"])
        remeshed = dict(zip(rec["frame"].astype(int), rec["remeshed"]))
    except Exception:  # noqa: BLE001 - no records, or records without remeshing: popping is not split
        remeshed = None
    summary = summarize(table, ref_dir, image_resolution(run_dir, resolution_scale), resolution_scale, remeshed)
    shots = table.attrs.get("visible")
    plain = table.copy()
    plain.attrs = {}  # parquet keeps a frame's attrs as JSON: the per-shot table goes to its own file
    write_parquet_atomic(run_dir / "accuracy.parquet", plain)
    if shots is not None:
        write_parquet_atomic(run_dir / "visible.parquet", shots)
    write_json_atomic(run_dir / "accuracy.json", summary)
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.accuracy", description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folders to evaluate")
    parser.add_argument("--reference", required=True, nargs="+", metavar="REF_DIR",
                        help="the fine nonadaptive reference run of the same scene and camera, or the members of "
                             "a reference ensemble (the reference config with different seeds: mean, interval, floor)")
    parser.add_argument("--resolution-scale", type=float, default=1.0,
                        help="render at this times the camera's image size (distances stay in camera pixels)")
    args = parser.parse_args(argv)
    try:
        tables = evaluate_runs(args.runs, args.reference, args.resolution_scale)
    except AccuracyError as exc:
        print(f"accuracy error: {exc}", file=sys.stderr)
        return 2
    for run_dir, table in zip(args.runs, tables):
        s = write_accuracy(run_dir, table, args.reference, args.resolution_scale)
        fmt = lambda v, u: "n/a" if v is None else f"{v:.3g} {u}"  # noqa: E731
        print(f"{run_dir}: {s['frames']} frames  error {fmt(s['error_px_mean'], 'px')} mean, "
              f"{fmt(s['error_px_max'], 'px')} max  iou {fmt(s['iou_mean'], '')} "
              f"off-screen {fmt(s['offscreen_distance_m_mean'], 'm')}"
              + (f"  floor {fmt(s['floor_px_mean'], 'px')} mean, saturated at frame {s['floor_saturation_frame']}"
                 if s["members"] > 1 else "")
              + (f"  visible statistics {fmt(s.get('visible_distance_mean'), 'spreads')} from the ensemble"
                 if s["members"] > 1 else "")
              + f"  -> {Path(run_dir) / 'accuracy.parquet'}")
    return 0

