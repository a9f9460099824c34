"""Re-synchronised short-horizon error: what coarsening costs on screen, with chaos taken out.

    python -m experiments.sync RUN_DIR [RUN_DIR ...] --reference REF_DIR [REF_DIR ...] [--every 10] [--horizon 8]
                               [--before-cut 5] [--resolution-scale 0.5]
                               [--restart reference_mesh|own_mesh] [--per-frame]

A swirling skirt is chaotic: two runs that differ by round-off follow unrelated trajectories
within about a second, so the error of a whole run against a reference soon measures "two
different skirts" for every mode alike. Here every run instead restarts, at each *sync frame*,
from the reference's own state (positions, velocities, material coordinates:
cloth.simulation.Simulation.restart_from; a remeshing mode remeshes it on its first frame, a
fixed mesh takes it by interpolation in material space), runs ``--horizon`` H frames with its
own mode and settings, and is compared with the reference's own continuation from that state
(the reference run's state H frames later) by material correspondence: where the run puts the
cloth the reference shows (cloth.eval.correspondence). The sync frames are 0, every, 2 every, ...
and ``--before-cut`` frames before each camera cut (what anticipation is for), as long as the
window ends within the run.

``--restart`` says on which mesh a remeshing mode restarts. ``reference_mesh`` (the default): on
the reference's own fine mesh, which it coarsens on its first frame. ``own_mesh`` (the symmetric
restart): on the mesh its own run had at the sync frame (the run's saved state of that frame),
with positions and velocities transferred from the reference by material coordinates exactly as
a fixed mesh takes them on its own mesh, so that every mode starts from its own mesh at the same
kind of distance from the truth; the run then needs its own states with restart data at every
sync frame (output.states_every=1). A fixed mesh restarts on its own mesh either way. Every
window also records ``sync_error_h0_px``: the error right after the restart, before any step
(what the transfer alone costs).

The run folder's config.yaml says how to build the run (its mode and settings); with
``--restart reference_mesh`` nothing of the run's own trajectory is used, so a run of any length
can be evaluated. The reference needs
per-frame states with restart data (written by this code's runner with output.states_every=1)
at every sync frame and every window's end. Writes into each RUN_DIR:

* ``sync.parquet``: one row per window: member (with several ``--reference`` folders, the
  members of an ensemble: every window is restarted from each member's state and compared with
  that member's continuation, so the windows multiply and pair member by member), sync_frame,
  frame (its end), shot (the camera path's shot at its end: 0, 1, ... after each cut), before_cut (a window
  ending just after a cut's lead), sync_error_px, sync_error_p90_px, sync_error_mm,
  sync_error_p90_mm, sync_error_px1080 (cloth.eval.correspondence), sync_samples,
  sync_error_h0_px and sync_error_h0_mm (at the window's start, right after the restart), faces_mean
  (the run's faces over the window's frames), sim_s (its simulation time per frame) and
  diverged (the window stopped: its error is NaN);
* ``sync.json``: for each of MEASURES (px, mm, px1080), ``<measure>_mean`` with its 90 % BCa
  bootstrap interval over the windows (scipy.stats.bootstrap) (``<measure>_lo`` / ``_hi``,
  BOOTSTRAP resamples, seeded) and ``<measure>_cut_mean`` (windows before a cut); ``sim_s_mean``,
  ``faces_mean``, ``windows``, ``every``, ``horizon``, ``before_cut``, ``reference``,
  ``resolution_scale``, ``restart``, ``sync_error_h0_px_mean``, ``sync_error_px_by_shot`` and
  ``sync_error_mm_by_shot`` (the mean of the windows that end in each shot) and ``definition``;
* with ``--per-frame``, also ``sync_frames.parquet``: one row per frame of every window
  (sync_frame, h = 1 ... H, frame, the error measures against the reference's state of that
  frame, faces, sim_s), so that how the error grows within a window is seen, not only its value
  at H; and in sync.json ``sync_error_px_by_h`` (the mean over windows at each h). The reference
  then needs its states at every frame of every window.

Refused before any work, with one message (exit code 2): a run of another scene, camera or
frame time than the reference, a crowd, a reference without restart states where they are needed.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from cloth.eval import correspondence
from cloth.eval.correspondence import ERROR_KEYS, correspondence_error
from cloth.eval.perceptual import flip_error, render_shaded
from cloth.eval.screenspace import render_state
from cloth.io.manifest import write_json_atomic, write_parquet_atomic
from cloth.io.states import StateError, load_state, require_restart
from cloth.simulation import SimulationDiverged
from experiments.analysis.accuracy import BOOTSTRAP, AccuracyError, check_configs, shot_index, state_files
from experiments.analysis.accuracy import bootstrap_mean_interval as bootstrap_interval  # over windows here
from experiments.build import ConfigError, build_simulation, camera_path, crowd_size, extra_cameras

EVERY, HORIZON, BEFORE_CUT = 10, 8, 5  # frames: the defaults
RESTARTS = ("reference_mesh", "own_mesh")  # on which mesh a remeshing mode restarts (module docstring)
RESOLUTION_SCALE = 0.5  # rendered image / camera image: samples every 2 camera pixels (distances stay in camera px)
COLUMNS = ("member", "sync_frame", "frame", "shot", "before_cut", *ERROR_KEYS, "sync_samples",
           "sync_error_h0_px", "sync_error_h0_mm", "faces_mean", "sim_s", "diverged",
           "flip")  # FLIP at the window's end (perceptual=True; NaN otherwise)
# the summaries' measures: the camera's pixels, millimetres on the cloth, pixels of a 1080p image
MEASURES = ("sync_error_px", "sync_error_mm", "sync_error_px1080")
FRAME_COLUMNS = ("member", "sync_frame", "h", "frame", *MEASURES, "faces", "sim_s")  # sync_frames.parquet (--per-frame)


def definition() -> str:
    doc = correspondence.__doc__
    start = doc.index("Definition (version")
    return doc[start:].strip().replace(":data:`DEFINITION_VERSION`", correspondence.DEFINITION_VERSION)


def sync_frames(frames: int, every: int, horizon: int, cut_frames=(), before_cut: int = BEFORE_CUT):
    """[(sync frame, before_cut)] of a run of `frames` frames: 0, every, 2 every, ... and
    `before_cut` frames before each cut frame, each with its window [s, s + horizon] within the run."""
    out = {s: False for s in range(0, frames - horizon + 1, every)}
    for c in cut_frames:
        s = int(c) - before_cut
        if 0 <= s and s + horizon <= frames:
            out[s] = True
    return sorted(out.items())


def _cut_frames(path, frame_time: float) -> list[int]:
    return [int(round(c / frame_time)) for c in getattr(path, "cuts", ())]


def plan(run_dir: Path, ref_dir: Path, every: int, horizon: int, before_cut: int, restart: str = "reference_mesh",
         per_frame: bool = False):
    """(config, camera path, [(sync frame, before_cut)]) of a run; AccuracyError names what is wrong.
    `per_frame`: the reference's states of every frame of every window are needed too."""
    check_configs(run_dir, ref_dir)
    cfg = OmegaConf.load(run_dir / "config.yaml")
    if crowd_size(cfg) is not None:
        raise AccuracyError(f"{run_dir}: a crowd run; the re-synchronised error restarts one character "
                            f"(run it on solo_dancer or karate)")
    path = camera_path(cfg)
    ref_cfg = OmegaConf.load(ref_dir / "config.yaml")
    frames = min(int(cfg.frames), int(ref_cfg.frames))
    sim, _ = build_simulation(cfg)  # every config check, before any work
    windows = sync_frames(frames, every, horizon, _cut_frames(path, sim.scene.frame_time), before_cut)
    if not windows:
        raise AccuracyError(f"{run_dir}: no window of {horizon} frames fits in {frames} frames")
    states = state_files(ref_dir)
    need = sorted({s for s, _ in windows} | {s + horizon for s, _ in windows}
                  | ({s + h for s, _ in windows for h in range(1, horizon)} if per_frame else set()))
    missing = [f for f in need if f not in states]
    if missing:
        raise AccuracyError(f"{ref_dir}: the reference has no state for frames {missing[:5]} "
                            f"({len(missing)} of the {len(need)} the windows need); run it with output.states_every=1")
    for f in need:  # the starts to restart from, the frames to compare with (material coordinates)
        try:
            require_restart(load_state(states[f][0]), states[f][0])
        except StateError as exc:
            raise AccuracyError(str(exc)) from None
    if restart == "own_mesh" and sim.remesher is not None:  # its own mesh at every sync frame
        own = state_files(run_dir)
        missing = [s for s, _ in windows if s not in own]
        if missing:
            raise AccuracyError(f"{run_dir}: --restart own_mesh needs the run's own state at every sync frame; it has "
                                f"none for frames {missing[:5]}; run it with output.states_every=1")
        for s, _ in windows:
            try:
                require_restart(load_state(own[s][0]), own[s][0])
            except StateError as exc:
                raise AccuracyError(str(exc)) from None
    return cfg, path, windows


def _error(sim, path, ref: dict, resolution_scale: float) -> dict:
    """correspondence_error of the simulation's cloth now against the reference state `ref`."""
    camera = path.camera_at(ref["time"])
    image = render_state(camera, ref, resolution_scale)
    mesh = sim.mesh
    run = {"node_x": mesh.node_x, "vert_u": mesh.vert_u, "vert_node": mesh.vert_node, "face_verts": mesh.face_verts}
    return correspondence_error(camera, image, ref, run)


def _flip(sim, path, ref: dict, resolution_scale: float) -> float:
    """FLIP between shaded renders of the reference state `ref` and of the simulation's cloth now
    (with the reference's obstacles, at the same time), from the camera at that time."""
    camera = path.camera_at(ref["time"])
    run = {**ref, "node_x": sim.mesh.node_x, "face_nodes": sim.mesh.face_nodes}
    return flip_error(render_shaded(camera, ref, resolution_scale), render_shaded(camera, run, resolution_scale))


def _members(ref_dir) -> list[Path]:
    """The reference folders of `ref_dir`: one folder, or a list (the members of an ensemble, member 0 first)."""
    dirs = [Path(ref_dir)] if isinstance(ref_dir, (str, Path)) else [Path(d) for d in ref_dir]
    if not dirs:
        raise AccuracyError("no reference given")
    return dirs


def view_columns(name: str) -> tuple[str, str]:
    """The window table's columns of the error seen from the extra view `name` (px, mm)."""
    return f"sync_error_px_view_{name}", f"sync_error_mm_view_{name}"


def evaluate_run(run_dir, ref_dir, every: int = EVERY, horizon: int = HORIZON, before_cut: int = BEFORE_CUT,
                 resolution_scale: float = RESOLUTION_SCALE, log=None, restart: str = "reference_mesh",
                 per_frame: bool = False, perturb_m: float = 0.0, views=(), perceptual: bool = False) -> pd.DataFrame:
    """The windows of one run against the reference (COLUMNS, one row per window); writes nothing.
    `ref_dir`: the reference's folder, or a list of the folders of a reference ensemble's members:
    then every window is restarted from each member's state and compared with that member's own
    continuation (column ``member``: its place in the list), so that the windows multiply by the
    members and pair up, member by member, between runs.
    `restart`: one of RESTARTS (module docstring). `per_frame`: also the error at every frame of
    every window, as ``.attrs["per_frame"]`` (FRAME_COLUMNS, one row per window and frame).
    `perturb_m` > 0: every free node of the restart state is first moved `perturb_m` metres in a
    seeded random direction (:func:`perturbed`): the reference restarted so against itself gives the
    floor that chaos alone sets within a window.
    `views`: names of cameras of conf/camera/ (or camera configs, as `cameras` takes them) from which
    the window's end is also measured (several cameras, beyond the paper): columns
    :func:`view_columns` per view, beside the run's own camera's.
    `perceptual`: also FLIP between shaded renders of the reference's and the run's cloth at the
    window's end (cloth.eval.perceptual; column ``flip``, needs the flip-evaluator package)."""
    run_dir, members = Path(run_dir), _members(ref_dir)
    if restart not in RESTARTS:
        raise AccuracyError(f"--restart must be one of {', '.join(RESTARTS)}, got {restart!r}")
    planned = [plan(run_dir, m, every, horizon, before_cut, restart, per_frame) for m in members]  # all, before work
    own = state_files(run_dir) if restart == "own_mesh" else {}
    cfg0 = planned[0][0]
    try:
        view_paths = extra_cameras({"cameras": list(views), "scene": OmegaConf.to_container(cfg0.scene, resolve=True)})
    except ConfigError as exc:
        raise AccuracyError(f"sync views: {exc}") from None
    rows, frame_rows = [], []
    for k, (member, (cfg, path, windows)) in enumerate(zip(members, planned)):
        states = state_files(member)
        for s, cut in windows:
            t0 = time.perf_counter()
            sim, _ = build_simulation(cfg)
            start = load_state(states[s][0])
            if perturb_m > 0:
                start = perturbed(start, perturb_m, seed=s + 1000 * k)
            own_mesh = load_state(own[s][0]) if sim.remesher is not None and s in own else None
            sim.restart_from(start, own_mesh=own_mesh)
            h0 = _error(sim, path, start, resolution_scale)
            faces, sim_s, diverged = [], 0.0, False
            try:
                for h in range(1, horizon + 1):
                    rec = sim.advance_frame()
                    faces.append(rec["faces"])
                    sim_s += rec["sim_s"]
                    if per_frame:
                        e = _error(sim, path, load_state(states[s + h][0]), resolution_scale)
                        frame_rows.append({"member": k, "sync_frame": s, "h": h, "frame": s + h,
                                           **{m: e[m] for m in MEASURES}, "faces": rec["faces"], "sim_s": rec["sim_s"]})
            except SimulationDiverged:
                diverged = True
            row = {"member": k, "sync_frame": s, "frame": s + horizon,
                   "shot": shot_index(path, (s + horizon) * sim.scene.frame_time), "before_cut": cut,
                   "faces_mean": float(np.mean(faces or [0])), "sim_s": sim_s / max(len(faces), 1),
                   "diverged": diverged, "sync_error_h0_px": h0["sync_error_px"],
                   "sync_error_h0_mm": h0["sync_error_mm"],
                   **dict.fromkeys(ERROR_KEYS, math.nan), "sync_samples": 0}
            row["flip"] = math.nan
            for name, _ in view_paths:
                row.update(dict.fromkeys(view_columns(name), math.nan))
            if not diverged:
                end = load_state(states[s + horizon][0])
                row.update(_error(sim, path, end, resolution_scale))
                if perceptual:
                    row["flip"] = _flip(sim, path, end, resolution_scale)
                for name, view in view_paths:
                    e = _error(sim, view, end, resolution_scale)
                    px, mm = view_columns(name)
                    row[px], row[mm] = e["sync_error_px"], e["sync_error_mm"]
            rows.append(row)
            if log:
                log(f"  {run_dir.name}: {f'member {k}, ' if len(members) > 1 else ''}window {s}..{s + horizon}"
                    f"{' (before a cut)' if cut else ''}: {row['sync_error_px']:.2f} px "
                    f"({row['sync_error_mm']:.2f} mm), {row['faces_mean']:.0f} faces, {time.perf_counter() - t0:.1f} s")
    table = pd.DataFrame(rows, columns=list(COLUMNS) + [c for name, _ in view_paths for c in view_columns(name)])
    if per_frame:
        table.attrs["per_frame"] = pd.DataFrame(frame_rows, columns=list(FRAME_COLUMNS))
    return table


def perturbed(state: dict, distance_m: float, seed: int = 0) -> dict:
    """A copy of a restart state whose free (unpinned) nodes are each moved `distance_m` metres in a
    random direction (seeded: the same seed, the same perturbation); velocities unchanged."""
    rng = np.random.default_rng(seed)
    x = np.array(state["node_x"], dtype=np.float64)
    free = ~np.asarray(state["node_pinned"], dtype=bool)
    d = rng.normal(size=(int(free.sum()), 3))
    x[free] += distance_m * d / np.linalg.norm(d, axis=1, keepdims=True)
    return {**state, "node_x": x}


def paired_difference_interval(a, b, resamples: int = BOOTSTRAP, seed: int = 0) -> tuple[float, float]:
    """90 % BCa bootstrap interval (paired: of the mean of a - b) over windows both have (pandas Series indexed
    by window, as :func:`read_windows` gives, or arrays of equal length): two runs restarted from the same states are
    compared window by window, so the phase of the dance (which sets how large every run's error
    is) cancels. (nan, nan) without a common finite window."""
    if isinstance(a, pd.Series) and isinstance(b, pd.Series):
        a, b = a.align(b, join="inner")
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    return bootstrap_interval(d, resamples, seed)


def read_windows(run_dir, measure: str = "sync_error_px") -> pd.Series | None:
    """`measure` (a column of COLUMNS) of a run folder's sync.parquet indexed by (member, sync_frame)
    (member 0 for an evaluation from before the column), so that two runs pair window by window;
    None without one, or without that column (an evaluation older than it)."""
    f = Path(run_dir) / "sync.parquet"
    if not f.is_file():
        return None
    try:
        t = pd.read_parquet(f)
    except (OSError, ValueError):
        return None
    if measure not in t.columns or "sync_frame" not in t.columns:
        return None
    if "member" not in t.columns:
        t = t.assign(member=0)
    return t.set_index(["member", "sync_frame"])[measure].astype(float)


def summarize(table: pd.DataFrame, ref_dir, every, horizon, before_cut, resolution_scale,
              restart: str = "reference_mesh") -> dict:
    nan_or = lambda a: float(np.mean(a)) if a.size else None  # noqa: E731
    out = {}
    for measure in MEASURES:
        if measure not in table.columns:
            continue
        err = table[measure].to_numpy(dtype=np.float64)
        ok = np.isfinite(err)
        lo, hi = bootstrap_interval(err)
        cut = table["before_cut"].to_numpy(bool) & ok
        out.update({f"{measure}_mean": nan_or(err[ok]), f"{measure}_lo": None if math.isnan(lo) else lo,
                    f"{measure}_hi": None if math.isnan(hi) else hi, f"{measure}_cut_mean": nan_or(err[cut])})
    for col in [c for c in table.columns if c.startswith(("sync_error_px_view_", "sync_error_mm_view_"))
                or (c == "flip" and table[c].notna().any())]:
        err = table[col].to_numpy(dtype=np.float64)
        ok = np.isfinite(err)
        lo, hi = bootstrap_interval(err)
        out.update({f"{col}_mean": nan_or(err[ok]), f"{col}_lo": None if math.isnan(lo) else lo,
                    f"{col}_hi": None if math.isnan(hi) else hi})
    h0 = table["sync_error_h0_px"].to_numpy(float) if "sync_error_h0_px" in table.columns else np.zeros(0)
    return {**out,
            "sim_s_mean": nan_or(table["sim_s"].to_numpy(float)),
            "faces_mean": nan_or(table["faces_mean"].to_numpy(float)),
            "windows": int(len(table)), "windows_diverged": int(table["diverged"].sum()),
            "every": int(every), "horizon": int(horizon), "before_cut": int(before_cut),
            "reference": str(_members(ref_dir)[0].resolve()), "members": len(_members(ref_dir)),
            "resolution_scale": float(resolution_scale),
            "restart": restart,
            "sync_error_h0_px_mean": nan_or(h0[np.isfinite(h0)]),
            **_by_h(table.attrs.get("per_frame")), **_by_shot(table),
            "definition": definition()}


def _by_shot(table: pd.DataFrame) -> dict:
    """sync_error_px_by_shot and sync_error_mm_by_shot: the mean over the windows that end in each
    shot of the camera path (a close-up and a wide shot put a millimetre on different pixels)."""
    if "shot" not in table.columns or table.empty:
        return {}
    out = {}
    for measure in ("sync_error_px", "sync_error_mm"):
        by = table.groupby("shot")[measure].mean()
        out[f"{measure}_by_shot"] = {int(k): (None if math.isnan(v) else float(v)) for k, v in by.items()}
    return out


def _by_h(per_frame: pd.DataFrame | None) -> dict:
    """sync_error_px_by_h: the mean over windows of the error at each frame h = 1 ... H of a
    window (h = 0: sync_error_h0_px); {} without per-frame errors."""
    if per_frame is None or per_frame.empty:
        return {}
    by_h = per_frame.groupby("h")["sync_error_px"].mean()
    return {"sync_error_px_by_h": {int(h): (None if math.isnan(v) else float(v)) for h, v in by_h.items()}}


def write_sync(run_dir, table: pd.DataFrame, ref_dir, every=EVERY, horizon=HORIZON, before_cut=BEFORE_CUT,
               resolution_scale=RESOLUTION_SCALE, restart: str = "reference_mesh", stem: str = "sync") -> dict:
    """<stem>.parquet and <stem>.json into `run_dir` (atomically), and <stem>_frames.parquet when the
    table carries per-frame errors (evaluate_run's `per_frame`); returns the summary. Another
    `stem` keeps a second evaluation of the same run apart (the reference against its checks)."""
    summary = summarize(table, ref_dir, every, horizon, before_cut, resolution_scale, restart)
    per_frame = table.attrs.get("per_frame")
    if per_frame is not None:
        write_parquet_atomic(Path(run_dir) / f"{stem}_frames.parquet", per_frame)
        table = table.copy()
        table.attrs = {}  # the per-frame table has its own file
    write_parquet_atomic(Path(run_dir) / f"{stem}.parquet", table)
    write_json_atomic(Path(run_dir) / f"{stem}.json", summary)
    return summary


def check_options(every: int, horizon: int, before_cut: int, resolution_scale: float) -> None:
    for name, v, lo in (("every", every, 1), ("horizon", horizon, 1), ("before-cut", before_cut, 0)):
        if not (isinstance(v, int) and v >= lo):
            raise AccuracyError(f"--{name} must be an integer >= {lo}, got {v!r}")
    if not (isinstance(resolution_scale, (int, float)) and math.isfinite(resolution_scale) and resolution_scale > 0):
        raise AccuracyError(f"--resolution-scale must be a number > 0, got {resolution_scale!r}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.sync", description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folders to evaluate (their config.yaml)")
    ap.add_argument("--reference", required=True, metavar="REF_DIR", nargs="+",
                    help="the reference run (states with restart data); several: the members of an ensemble, "
                         "member 0 first, every window restarted from each")
    ap.add_argument("--every", type=int, default=EVERY, help="frames between sync frames")
    ap.add_argument("--horizon", type=int, default=HORIZON, help="frames simulated from each sync frame (H)")
    ap.add_argument("--before-cut", type=int, default=BEFORE_CUT, help="a sync frame this many frames before each cut")
    ap.add_argument("--resolution-scale", type=float, default=RESOLUTION_SCALE,
                    help="rendered image / camera image (distances stay in camera pixels)")
    ap.add_argument("--restart", choices=RESTARTS, default="reference_mesh",
                    help="a remeshing mode restarts on the reference's mesh, or on its own run's mesh (symmetric)")
    ap.add_argument("--per-frame", action="store_true",
                    help="also the error at every frame of every window (sync_frames.parquet)")
    args = ap.parse_args(argv)
    try:
        check_options(args.every, args.horizon, args.before_cut, args.resolution_scale)
        for d in args.runs:  # every run checked against every member before any work
            for m in args.reference:
                plan(Path(d), Path(m), args.every, args.horizon, args.before_cut, args.restart, args.per_frame)
    except (AccuracyError, ConfigError) as exc:
        print(f"sync error: {exc}", file=sys.stderr)
        return 2
    for d in args.runs:
        table = evaluate_run(d, args.reference, args.every, args.horizon, args.before_cut, args.resolution_scale,
                             log=print, restart=args.restart, per_frame=args.per_frame)
        s = write_sync(d, table, args.reference, args.every, args.horizon, args.before_cut, args.resolution_scale,
                       args.restart)
        fmt = lambda v: "n/a" if v is None else f"{v:.3g}"  # noqa: E731
        print(f"{d}: {s['windows']} windows  sync error {fmt(s['sync_error_px_mean'])} px "
              f"(90% {fmt(s['sync_error_px_lo'])}-{fmt(s['sync_error_px_hi'])})  sim {fmt(s['sim_s_mean'])} s/frame "
              f"-> {Path(d) / 'sync.parquet'}")
    return 0

