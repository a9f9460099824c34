"""Run a simulation for N frames and write its records into a run folder (no Hydra here).

A run folder holds ``frames.parquet`` (one row per frame, written atomically when the run ends,
also when it fails, so that it keeps the frames it finished), ``summary.json`` (written at the
end, also when the run fails, with the failure message), the Rerun recording and optional OBJ
frames. While the run goes on, each finished frame's record is appended to ``frames.jsonl`` (one
JSON line, flushed: a constant cost per frame, whatever the run's length); a run killed outright
keeps there every frame it finished, and loses at most the line it was writing
(:func:`read_journal` skips it). The journal is removed once frames.parquet holds the frames.
The caller writes the resolved config and the environment manifest. With
`checkpoint_every` the run keeps its latest complete state in ``checkpoint/state.pkl`` (removed
when it completes), from which experiments.resume continues a killed run; a completed run
leaves ``final_state.npz`` (float64 positions) for experiments.replay (cloth.io.checkpoint).
"""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from cloth.core.records import COLLISION_PARTS, PHASES, STEP_CHECKS
from cloth.io.checkpoint import CHECKPOINT_DIR, FINAL_STATE_FILE, remove_checkpoint, save_checkpoint, save_final_state
from cloth.io.manifest import remove_stale_temp_files, write_json_atomic, write_parquet_atomic, write_text_atomic
from cloth.io.obj import save_obj
from cloth.io.recorder import Recorder
from cloth.io.states import save_state
from cloth.io.stills import OBSTACLE_RGB, mesh_triangles, obstacle_triangles, render_still
from cloth.physics.linsolve import resolve_method
from cloth.signals import Terminated, sigterm_interrupts
from cloth.simulation import Simulation, SimulationDiverged
from cloth.view.factors import face_geometry, face_view_data, spatial_view_factor
from cloth.view.paths import rig_paths
from cloth.view.viewdep import ViewParams

JOURNAL_FILE = "frames.jsonl"  # the records of the frames finished so far, while a run goes on


def _json_value(v):
    """JSON for numpy scalars in a record (numbers stay numbers; NaN as JSON's NaN)."""
    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(f"record value {v!r} ({type(v).__name__}) is not JSON")


def open_journal(path: Path, rows: list):
    """The frames journal, started over with `rows` (the frames a resumed run already has) and
    open for appending."""
    text = "".join(json.dumps(r, default=_json_value) + "\n" for r in rows)
    write_text_atomic(path, text)
    return open(path, "a", encoding="utf-8")


def append_journal(journal, row: dict) -> None:
    """One frame's record as one line, flushed to the OS: what a kill cannot take back."""
    journal.write(json.dumps(row, default=_json_value) + "\n")
    journal.flush()


def read_journal(path) -> pd.DataFrame:
    """The records in a frames journal (a killed run's), without a last line cut off mid-write."""
    rows = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:  # the line a kill interrupted: only ever the last
            break
    return pd.DataFrame(rows)


def summarize(frames: pd.DataFrame) -> dict:
    """Min/max/mean of faces, verts and time per frame, as in the paper's Table 1."""
    if frames.empty:
        return {"frames_completed": 0}
    out = {"frames_completed": int(len(frames))}
    for col in ("faces", "verts", "nodes", "sim_s", "wall_s"):
        out[f"{col}_min"] = float(frames[col].min())
        out[f"{col}_max"] = float(frames[col].max())
        out[f"{col}_mean"] = float(frames[col].mean())
    out["sim_total_s"] = float(frames["sim_s"].sum())
    out["wall_total_s"] = float(frames["wall_s"].sum())
    for p in PHASES:
        out[f"time_{p}_total_s"] = float(frames[f"time_{p}_s"].sum())
    for part in COLLISION_PARTS:  # absent in the records of code before the collision phase's parts
        if f"time_collisions_{part}_s" in frames.columns:
            out[f"time_collisions_{part}_total_s"] = float(frames[f"time_collisions_{part}_s"].sum())
    out["solver_iterations_total"] = int(frames["solver_iterations"].sum())
    if "solves_capped" in frames.columns:
        out["solves_capped_total"] = int(frames["solves_capped"].sum())
        out["frames_with_capped_solves"] = int((frames["solves_capped"] > 0).sum())
    if "steps_rejected" in frames.columns:  # step control (cloth.stepcontrol: MAX_STEP_HALVINGS)
        rejected = frames["steps_rejected"].fillna(0).astype(int)
        out["steps_rejected_total"] = int(rejected.sum())
        for check in STEP_CHECKS:
            col = f"steps_rejected_{check}"
            if col in frames.columns:
                out[f"{col}_total"] = int(frames[col].fillna(0).sum())
        out["frames_with_rejected_steps"] = [int(f) for f in frames.loc[rejected > 0, "frame"]]
        out["dt_min_s"] = float(frames["dt_min_s"].min())
    return out


def count_diverged_frame(summary: dict, exc: SimulationDiverged) -> None:
    """Add the steps rejected in the frame a run diverged in (it has no record) to `summary`'s
    totals (:func:`summarize`)."""
    n = int(exc.rejected.get("steps_rejected", 0))
    summary["steps_rejected_total"] = summary.get("steps_rejected_total", 0) + n
    for check in STEP_CHECKS:
        key = f"steps_rejected_{check}_total"
        summary[key] = summary.get(key, 0) + int(exc.rejected.get(f"steps_rejected_{check}", 0))
    if n:
        summary["frames_with_rejected_steps"] = [*summary.get("frames_with_rejected_steps", []), int(exc.frame)]
    summary["dt_min_s"] = min(summary.get("dt_min_s", float("inf")), exc.rejected.get("dt_min_s", float("inf")))


def rejected_steps_note(summary: dict) -> str | None:
    """The run's note when step control took any step again at half its length (None if none)."""
    n = summary.get("steps_rejected_total", 0)
    if not n:
        return None
    kinds = ", ".join(f"{summary[f'steps_rejected_{c}_total']} {c}" for c in STEP_CHECKS
                      if summary.get(f"steps_rejected_{c}_total"))
    frames = summary["frames_with_rejected_steps"]
    return (f"{n} step(s) in {len(frames)} frame(s) failed a check ({kinds}) and were taken again at half the length, "
            f"down to {summary['dt_min_s']:.3g} s (steps_rejected in frames.parquet)")


def capped_solves_note(summary: dict, max_iterations: int) -> str | None:
    """The run's note when any implicit step stopped at the solver's iteration cap (None if none)."""
    n = summary.get("solves_capped_total", 0)
    if not n:
        return None
    return (f"{n} implicit step(s) in {summary['frames_with_capped_solves']} frame(s) stopped at the solver's "
            f"iteration cap (solver.max_iterations = {max_iterations}) with the residual above solver.tolerance: "
            f"those steps are inexact (solves_capped in frames.parquet)")


# Per-frame columns that add up over the characters of a crowd (everything else is per character).
CROWD_SUM_COLUMNS = ("faces", "verts", "nodes", "sim_s", "wall_s", "solver_iterations", "solves_capped", "contacts",
                     "steps_rejected", *(f"steps_rejected_{c}" for c in STEP_CHECKS),
                     "faces_in_view",
                     "faces_back_facing", "faces_out_of_frame", "faces_compensated", "kinetic_energy_j", "remeshed",
                     "faces_sized", "faces_at_size_min", "faces_at_size_max", "faces_occluded")


CHARACTERS_FILE = "characters.csv"  # a crowd's per-character table, in its run folder
CHARACTER_COLUMNS = ("character", "status", "frames", "sim_s_mean", "sim_total_s", "faces_mean", "wall_s_mean",
                     "in_view_fraction", "frames_out_of_view", "sim_s_out_of_view_mean", "sim_s_in_view_mean",
                     "out_of_view_cost_ratio")


def _column_stat(frames: pd.DataFrame, col: str, stat: str) -> float:
    """frames[col]'s mean or sum as a float; NaN when the column is absent or the frames empty."""
    if col not in frames.columns or frames.empty:
        return float("nan")
    return float(getattr(frames[col].astype(float), stat)())


def characters_table(frames: list, summaries: list) -> pd.DataFrame:
    """One row per character of a crowd (CHARACTER_COLUMNS): its index, status, frames completed,
    mean simulation time per frame sim_s_mean (s) and its total sim_total_s, mean faces, mean
    wall time per frame, and in_view_fraction: the fraction of its frames with any face in the
    camera's view (faces_in_view > 0; NaN without a camera). NaN where a character wrote no frame.
    And what a character costs out of view: its frames wholly out of view (mode=viewdep's
    character_out_of_view), their mean sim_s, the mean sim_s of its frames with a face in view, and
    the ratio of the two (NaN unless the character has frames of both kinds)."""
    rows = []
    for i, (f, s) in enumerate(zip(frames, summaries)):
        in_view = f["faces_in_view"].astype(float) if "faces_in_view" in f.columns else pd.Series(dtype=float)
        in_view = in_view.dropna()
        out = (f["character_out_of_view"].fillna(0) > 0 if "character_out_of_view" in f.columns
               else pd.Series(False, index=f.index))
        seen = f["faces_in_view"].fillna(0) > 0 if "faces_in_view" in f.columns else pd.Series(False, index=f.index)
        t_out = _column_stat(f[out], "sim_s", "mean")
        t_in = _column_stat(f[seen], "sim_s", "mean")
        rows.append({"character": i, "status": s.get("status", "missing"), "frames": int(len(f)),
                     "sim_s_mean": _column_stat(f, "sim_s", "mean"), "sim_total_s": _column_stat(f, "sim_s", "sum"),
                     "faces_mean": _column_stat(f, "faces", "mean"), "wall_s_mean": _column_stat(f, "wall_s", "mean"),
                     "in_view_fraction": float((in_view > 0).mean()) if len(in_view) else float("nan"),
                     "frames_out_of_view": int(out.sum()), "sim_s_out_of_view_mean": t_out, "sim_s_in_view_mean": t_in,
                     "out_of_view_cost_ratio": t_out / t_in if t_in > 0 else float("nan")})
    return pd.DataFrame(rows, columns=list(CHARACTER_COLUMNS))


def combine_crowd(character_dirs: list, out_dir: Path, errors: dict | None = None,
                  extra: dict | None = None) -> tuple[pd.DataFrame, dict]:
    """The records of a crowd from its characters' run folders (never re-simulating).

    frames.parquet: per frame, the sum over the characters of CROWD_SUM_COLUMNS and of every
    time_*_s column, the largest max_speed_m_s and the smallest min_face_quality, over the frames
    that every character completed (and the median over the characters of edge_at_size_min_m).
    characters.csv: one row per character (:func:`characters_table`).
    summary.json: the Table 1 statistics of those sums, the worst status of the characters, the
    characters' messages (`errors`: character index -> what happened to it, for a character
    whose own summary has no message, e.g. a worker that died), the per-character table
    (character_table), each character's own summary, and `extra` (how the characters ran).
    """
    out_dir = Path(out_dir)
    frames, summaries = [], []
    for d in character_dirs:
        d = Path(d)
        f = d / "frames.parquet"
        frames.append(pd.read_parquet(f) if f.exists() else pd.DataFrame())
        s = d / "summary.json"
        summaries.append(json.loads(s.read_text()) if s.exists() else {"status": "missing"})
    for i, message in (errors or {}).items():
        if not summaries[i].get("message"):
            summaries[i] = {**summaries[i], "message": message}
    n = min(len(f) for f in frames)
    rows = pd.DataFrame({"frame": frames[0]["frame"].iloc[:n].to_numpy()} if n else {})
    if n:
        cols = [c for c in frames[0].columns if c in CROWD_SUM_COLUMNS or (c.startswith("time_") and c.endswith("_s"))]
        for c in cols:
            rows[c] = sum(f[c].iloc[:n].to_numpy() for f in frames)
        rows["sim_time_s"] = frames[0]["sim_time_s"].iloc[:n].to_numpy()
        rows["max_speed_m_s"] = np.max([f["max_speed_m_s"].iloc[:n].to_numpy() for f in frames], axis=0)
        rows["min_face_quality"] = np.min([f["min_face_quality"].iloc[:n].to_numpy() for f in frames], axis=0)
        if "dt_min_s" in frames[0].columns:
            rows["dt_min_s"] = np.min([f["dt_min_s"].iloc[:n].to_numpy() for f in frames], axis=0)
        if "edge_at_size_min_m" in frames[0].columns:  # the characters' median realised edges: their median
            edges = np.array([f["edge_at_size_min_m"].iloc[:n].to_numpy(dtype=float) for f in frames])
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a frame where no character remeshed
                rows["edge_at_size_min_m"] = np.nanmedian(edges, axis=0)
        rows["characters"] = len(frames)
        write_parquet_atomic(out_dir / "frames.parquet", rows)
    table = characters_table(frames, summaries)
    write_text_atomic(out_dir / CHARACTERS_FILE, table.to_csv(index=False))
    ratios = table["out_of_view_cost_ratio"].dropna()
    order = ("completed", "interrupted", "diverged", "failed", "missing")
    status = max((s.get("status", "missing") for s in summaries), key=lambda x: order.index(x) if x in order else 9)
    summary = {"status": status, "characters": len(frames), **summarize(rows),
               "message": "; ".join(f"character {i}: {s['message']}" for i, s in enumerate(summaries)
                                    if s.get("message")),
               # the scene's notes (the same for every character) and each character's own, once each
               "notes": list(dict.fromkeys(n for s in summaries for n in s.get("notes", []))),
               **(extra or {}),
               # a character wholly out of view against the same character in view (its frames of
               # each kind, in this run): the median and the largest ratio over the characters
               "out_of_view_cost_ratio_median": float(ratios.median()) if len(ratios) else None,
               "out_of_view_cost_ratio_max": float(ratios.max()) if len(ratios) else None,
               # NaN (no camera, no frame) as null: summary.json stays strict JSON
               "character_table": [{k: (None if isinstance(v, float) and np.isnan(v) else v) for k, v in r.items()}
                                   for r in table.to_dict(orient="records")],
               "character_summaries": summaries}
    write_json_atomic(out_dir / "summary.json", summary)
    return rows, summary


VISIBLE_RGB = np.array([0.15, 0.35, 0.95])  # the paper's Fig. 1: visible faces blue
HIDDEN_RGB = np.array([0.9, 0.15, 0.1])  # not visible: red, lighter where the view factor is lower


def _more_cameras(sim) -> dict:
    """{name: camera now} of the cameras beside the main one (a CameraRig; {} otherwise)."""
    return {name: path.camera_at(sim.time) for name, path in rig_paths(sim.scene.camera)[1:]}


def _view(sim):
    """(camera now, per-face RGB by view factor, per-face spatial view factor) or (None, None, None)
    without a camera."""
    if sim.scene.camera is None:
        return None, None, None
    cam = sim.scene.camera.camera_at(sim.time)
    p = getattr(sim.remesher, "view", None) or ViewParams()
    geometry = face_geometry(sim.mesh)
    nu, visible = None, None
    for _, path in rig_paths(sim.scene.camera):  # several cameras: the largest factor, visible in any
        d, front = face_view_data(path.camera_at(sim.time), *geometry)
        nu_c = spatial_view_factor(d, front, p.nu_front, p.nu_back, p.nu_out, p.margin)
        nu = nu_c if nu is None else np.maximum(nu, nu_c)
        visible = (d == 0) & front if visible is None else visible | ((d == 0) & front)
    shade = HIDDEN_RGB * (0.4 + 0.6 * nu[:, None]) + 0.6 * (1 - nu[:, None]) * np.array([1.0, 0.8, 0.8])
    colors = np.where(visible[:, None], VISIBLE_RGB, np.clip(shade, 0, 1))
    return cam, colors, nu


def write_still(sim, path: Path) -> Path:
    """stills/frame_NNNNN.png: the camera's view coloured by view factor and an outside view
    with the frustum (cloth.io.stills); the scene must have a camera."""
    camera, colors, _ = _view(sim)
    obstacles = sim.obstacle_set.obstacles if sim.contact is not None else ()
    extra = [(obstacle_triangles(ob), OBSTACLE_RGB) for ob in obstacles if ob.name != "plane"]
    return render_still(path, camera, mesh_triangles(sim.mesh), colors, extra=extra,
                        title=f"{sim.scene.name}  frame {sim.frame}  t = {sim.time:.2f} s  {sim.mesh.n_faces} faces")


def remove_stale_temp_files_of_run(out_dir) -> list[Path]:
    """The temporary files that writers killed outright (SIGKILL) left in a run folder and the
    sub-folders a run writes (cloth.io.manifest.remove_stale_temp_files); returns those removed."""
    out_dir = Path(out_dir)
    return [p for d in (out_dir, out_dir / CHECKPOINT_DIR, out_dir / "states", out_dir / "stills", out_dir / "obj")
            for p in remove_stale_temp_files(d)]


@sigterm_interrupts()  # SIGTERM (a scheduler's time limit) stops a run as Ctrl-C does: its records are written
def run(sim: Simulation, n_frames: int, out_dir: Path, recorder: Recorder | None = None,
        obj_every: int = 0, progress: bool = False, stills_every: int = 0, states_every: int = 1,
        checkpoint_every: int = 0, rows: list | None = None) -> dict:
    """Simulate `n_frames` frames, writing records into `out_dir`; returns the summary.

    `states_every` N > 0 writes states/frame_NNNNN.npz (cloth.io.states.save_state: node
    positions, triangles, obstacles, for the accuracy measures; velocities, material coordinates
    and handle anchors, for a restart from it) at frame 0 and every N-th frame.
    `checkpoint_every` N > 0 saves the whole state and the records so far to checkpoint/state.pkl
    every N-th frame (only the latest is kept; its time counts in time_io_s, except in the
    checkpoint's own copy of that frame's record). To continue from a checkpoint pass its
    simulation and its `rows` (records of the frames already done): the run goes on to frame
    `n_frames` and its records are those of an uninterrupted run.
    A diverged run (non-finite state or a node above the speed limit) stops at the frame where
    it happened; its summary has status 'diverged' and the message, and the exception is
    re-raised after everything is written. Ctrl-C and SIGTERM (a scheduler's time limit:
    cloth.signals, in the main thread) stop it with status 'interrupted', also written, and the
    KeyboardInterrupt (Terminated) goes on; the run continues from its last checkpoint.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_stale_temp_files_of_run(out_dir)  # of a writer that a SIGKILL stopped (a killed run, now resumed)
    recorder = recorder or Recorder()
    rows: list[dict] = list(rows or [])  # continuing from a checkpoint: its records
    status, message, error = "interrupted", "", None
    journal = open_journal(out_dir / JOURNAL_FILE, rows)
    scene = sim.scene
    obstacles = sim.obstacle_set.obstacles if sim.contact is not None else ()
    camera, colors, nu = _view(sim)
    recorder.log_frame(sim.frame, sim.time, sim.mesh, face_colors=colors, obstacles=obstacles, camera=camera,
                       view_factor=nu, more_cameras=_more_cameras(sim))
    if states_every > 0 and sim.frame % states_every == 0:
        save_state(out_dir / "states" / f"frame_{sim.frame:05d}.npz", sim.mesh, sim.frame, sim.time, obstacles,
                   scene.handles, restart=True)
    bar = None
    if progress:
        bar = tqdm(total=n_frames, initial=len(rows), desc=f"{scene.name}", unit="frame")
    try:
        for _ in range(n_frames - len(rows)):
            row = sim.advance_frame()
            t0 = time.perf_counter()
            camera, colors, nu = _view(sim)
            recorder.log_frame(sim.frame, sim.time, sim.mesh, face_colors=colors, obstacles=obstacles, camera=camera,
                               view_factor=nu, more_cameras=_more_cameras(sim))
            if obj_every > 0 and sim.frame % obj_every == 0:
                save_obj(out_dir / "obj" / f"frame_{sim.frame:05d}.obj", sim.mesh)
            if states_every > 0 and sim.frame % states_every == 0:
                save_state(out_dir / "states" / f"frame_{sim.frame:05d}.npz", sim.mesh, sim.frame, sim.time, obstacles,
                   scene.handles, restart=True)
            if stills_every > 0 and sim.frame % stills_every == 0:
                write_still(sim, out_dir / "stills" / f"frame_{sim.frame:05d}.png")
            rows.append(row)
            append_journal(journal, row)
            io = time.perf_counter() - t0
            row["time_io_s"] = io
            row["wall_s"] += io
            if checkpoint_every > 0 and sim.frame % checkpoint_every == 0:
                t0 = time.perf_counter()
                save_checkpoint(out_dir, sim, rows)
                io = time.perf_counter() - t0
                row["time_io_s"] += io
                row["wall_s"] += io
            if bar is not None:
                bar.update(1)
                bar.set_postfix(faces=row["faces"], s_per_frame=f"{row['wall_s']:.3f}")
        if rows:  # the state a replay compares positions with (float64)
            t0 = time.perf_counter()
            save_final_state(out_dir / FINAL_STATE_FILE, sim)
            io = time.perf_counter() - t0
            rows[-1]["time_io_s"] += io
            rows[-1]["wall_s"] += io
        status = "completed"
    except SimulationDiverged as exc:
        status, message, error = "diverged", str(exc), exc
    except KeyboardInterrupt as exc:  # status 'interrupted', resumable from the last checkpoint
        message = f"stopped by {exc}" if isinstance(exc, Terminated) else "stopped by Ctrl-C (KeyboardInterrupt)"
        raise
    except Exception as exc:  # keep what was written, say what happened, then re-raise
        status, message = "failed", f"{type(exc).__name__}: {exc}"
        raise
    finally:
        if bar is not None:
            bar.close()
        journal.close()
        frames = pd.DataFrame(rows)
        if rows:
            write_parquet_atomic(out_dir / "frames.parquet", frames)
        (out_dir / JOURNAL_FILE).unlink(missing_ok=True)  # frames.parquet holds every frame now
        summary = {"status": status, "message": message, "scene": scene.name, "notes": list(scene.notes),
                   "stages": sim.stages.names(), "solver_method": resolve_method(sim.solver.method),
                   "frames_requested": int(n_frames), **summarize(frames)}
        if isinstance(error, SimulationDiverged) and error.rejected:
            count_diverged_frame(summary, error)
        capped = capped_solves_note(summary, sim.solver.max_iterations)
        if capped is not None:  # never silent: the summary's notes, which the run prints
            summary["notes"].append(capped)
        rejected = rejected_steps_note(summary)
        if rejected is not None:
            summary["notes"].append(rejected)
        if rows:
            summary["final_max_speed_m_s"] = float(rows[-1]["max_speed_m_s"])
            summary["final_kinetic_energy_j"] = float(rows[-1]["kinetic_energy_j"])
        summary["finite"] = bool(np.all(np.isfinite(sim.mesh.node_x)))
        write_json_atomic(out_dir / "summary.json", summary)
        if status == "completed":  # after the summary: a kill in between still leaves a resumable run
            remove_checkpoint(out_dir)
        remove_stale_temp_files_of_run(out_dir)
        recorder.close()
    if error is not None:
        raise error
    return summary
