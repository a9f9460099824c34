"""ARCSim's output beside a run of this project on the same scene, frame by frame: faces, time
per frame, and how far apart the two cloths are.

    python -m experiments.compare_arcsim ARCSIM_OUT RUN_DIR [--out DIR] [--cloth 0|all] [--frames a:b]
                                         [--spacing M]

ARCSIM_OUT is the folder of ``arcsim simulate conf.json ARCSIM_OUT`` (cloth.io.arcsim_output reads it);
RUN_DIR a run folder of ``python -m experiments.run`` (run it with ``output.states_every=1`` for
the cloth's shape at every frame; without, only the last frame, ``final_state.npz``, and any
``output.obj_every`` frames have one).

**Frames.** ARCSim frame k is matched with run frame k. Frame 0 is the initial state on both
sides: ARCSim's ``0000_CC.obj`` after its set-up (initial remesh and relaxation), before the
first step; the run's ``states/frame_00000.npz`` before its first step (the run has no record
for frame 0). Frame k >= 1 is the state after k frames on both (time k x frame_time; the two
frame times are compared and a difference is noted). Only frames that both have are compared;
``--frames a:b`` (inclusive; ``a:``, ``:b`` or ``k``) narrows them.

**Per frame** (compare.csv): faces of each (ARCSim: the triangles of the file; the run: its
record's ``faces``, or its state's at frame 0); time per frame of each: ARCSim's from its
``timing`` file (the sum of its module columns, also given one by one as ``arcsim_<module>_s``;
blank at frame 0 and without the file), the run's ``sim_s`` (its simulation time without I/O;
blank at frame 0); the shape difference where the run has a shape: two-sided mean and maximum
surface distance, point to triangle, sampled on both surfaces (cloth.eval.surface: vertices and
the centroids of each triangle cut into n^2 equal parts, n = ceil(longest edge / h), h =
``--spacing`` or the smaller median edge length of the two meshes; area-weighted mean, the
average of the two directions; maximum over every sample of both), each direction apart, and the
difference of the axis-aligned bounding boxes, run minus ARCSim, per axis for the lower
(``bbox_min_d*``) and upper (``bbox_max_d*``) corners and the largest in magnitude; the material
area of each (from ``vt`` and the run's material coordinates: the same cloth has the same).
Frame 1's times include each simulator's start-up (ARCSim's first timing line its set-up; a run
with a cold numba cache its compilation): read the medians.

**Writes** into ``--out`` (default RUN_DIR/compare_arcsim): ``compare.csv``, ``summary.json``
(median, mean and max over the frames of every column, the frames compared, what was missing:
frames on one side only, frames without a time or a shape, and notes) and ``compare.png`` (faces,
time per frame, and mean and maximum distance against frame), and prints the table.

A bad input (a folder missing, no ``NNNN_CC.obj``, a run folder without frames, no frame in both)
stops before any work with one message naming it (exit code 2).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from cloth.eval.surface import (  # noqa: E402
    DEFAULT_SPACING_RULE,
    SURFACE_DEFINITION,
    bounding_box_difference,
    material_area,
    surface_distance,
)
from cloth.io import arcsim_output as arcsim  # noqa: E402
from cloth.io.checkpoint import FINAL_STATE_FILE, CheckpointError, load_final_state  # noqa: E402
from cloth.io.manifest import atomic_write, write_json_atomic, write_text_atomic  # noqa: E402
from cloth.io.obj import ObjError, load_obj  # noqa: E402
from cloth.io.states import StateError, load_state, merge_states  # noqa: E402
from cloth.runner import JOURNAL_FILE, read_journal  # noqa: E402
from experiments.analysis.accuracy import state_files  # noqa: E402
from experiments.analysis.runs import with_sim_seconds  # noqa: E402

DEFAULT_OUT = "compare_arcsim"  # --out: this sub-folder of the run folder
FRAME_TIME_RTOL = 1e-6  # two frame times are "the same" to this relative difference (both are config values)
AREA_RTOL = 0.01  # material areas further apart than 1 % are not the same cloth (remeshing keeps the area)
STAT_COLUMNS = ("arcsim_faces", "run_faces", "faces_ratio", "arcsim_s", "run_sim_s", "time_ratio", "dist_mean_m",
                "dist_max_m", "bbox_largest_m")  # the printed summary; summary.json has every column
PRINTED = ("frame", "arcsim_faces", "run_faces", "arcsim_s", "run_sim_s", "dist_mean_m", "dist_max_m",
           "bbox_largest_m")
DPI = 150


class CompareError(ValueError):
    """A bad input; the message names it."""


@dataclass
class Shape:
    """A cloth at one frame: node_x (N, 3) float64 m, face_nodes (F, 3) int64, and its material
    area (m^2; NaN when its source has no material coordinates)."""
    node_x: np.ndarray
    face_nodes: np.ndarray
    material_area_m2: float


@dataclass
class Inputs:
    """What the comparison reads, found and checked before any work."""
    arcsim_frames: dict  # frame -> [paths of the cloths compared]
    timing: arcsim.ArcsimTiming | None
    arcsim_frame_time: float | None
    records: pd.DataFrame  # the run's per-frame records (frame, faces, sim_s, ...), maybe empty
    run_shapes: dict  # frame -> ('states', [paths]) | ('obj', path) | ('final', path)
    frames: list  # the frames compared
    arcsim_available: set  # every frame of each side within --frames (what was missing is their difference)
    run_available: set
    notes: list


# ---- reading both sides ---------------------------------------------------------------------

def parse_frames(text: str | None) -> tuple[int, float]:
    """(first, last) of ``--frames``: ``a:b`` inclusive, ``a:``, ``:b`` or ``k``."""
    if text is None:
        return 0, math.inf
    a, sep, b = text.partition(":")
    try:
        first = int(a) if a.strip() else 0
        last = (int(b) if b.strip() else math.inf) if sep else first
    except ValueError:
        raise CompareError(f"--frames: expected a:b, a:, :b or k (frame numbers), got {text!r}") from None
    if first < 0 or last < first:
        raise CompareError(f"--frames: {text!r} selects no frame (0 <= a <= b)")
    return first, last


def ranges(frames) -> str:
    """Frame numbers as compact ranges: [0, 2, 3, 4, 7] -> '0, 2-4, 7' ('' for none)."""
    frames = sorted(int(f) for f in frames)
    out, start = [], None
    for i, f in enumerate(frames):
        if start is None:
            start = f
        if i + 1 == len(frames) or frames[i + 1] != f + 1:
            out.append(str(start) if start == f else f"{start}-{f}")
            start = None
    return ", ".join(out)


def arcsim_cloth_frames(out_dir: Path, cloth: str) -> dict[int, list[Path]]:
    """frame -> the OBJ files of the cloth(s) compared (`cloth`: an index or 'all')."""
    if not out_dir.is_dir():
        raise CompareError(f"ARCSim output {out_dir}: no such folder")
    files = arcsim.frame_files(out_dir)
    if cloth == "all":
        picked = {k: [c[i] for i in sorted(c)] for k, c in files.items()}
    else:
        picked = {k: [c[int(cloth)]] for k, c in files.items() if int(cloth) in c}
    if not picked:
        there = sorted({i for c in files.values() for i in c})
        raise CompareError(f"ARCSim output {out_dir}: no NNNN_{'CC' if cloth == 'all' else f'{int(cloth):02d}'}.obj "
                           f"frame files (ARCSim's `arcsim simulate conf.json OUT` writes them)"
                           + (f"; it has cloths {', '.join(f'{i:02d}' for i in there)} (--cloth)" if there else ""))
    return picked


def run_records(run_dir: Path) -> pd.DataFrame:
    """The run's per-frame records: frames.parquet, or a killed run's frames.jsonl; empty if neither."""
    try:
        if (run_dir / "frames.parquet").is_file():
            frames = pd.read_parquet(run_dir / "frames.parquet")
        elif (run_dir / JOURNAL_FILE).is_file():
            frames = read_journal(run_dir / JOURNAL_FILE)
        else:
            frames = pd.DataFrame()
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several kinds for a broken file
        raise CompareError(f"run folder {run_dir}: its frame records cannot be read ({type(exc).__name__})") from None
    if "frame" not in frames.columns:  # an empty journal: no frame finished
        return pd.DataFrame({"frame": pd.Series(dtype=int)})
    return with_sim_seconds(frames)


def run_shape_sources(run_dir: Path) -> dict[int, tuple]:
    """frame -> where the run's cloth shape of that frame is: its states (one per character of a
    crowd), else its OBJ frame, else final_state.npz (the last frame of a completed run)."""
    out: dict[int, tuple] = {}
    final = run_dir / FINAL_STATE_FILE
    if final.is_file():
        try:
            out[int(load_final_state(final)["frame"])] = ("final", final)
        except (CheckpointError, KeyError) as exc:
            raise CompareError(f"run folder {run_dir}: {exc}") from None
    for p in sorted((run_dir / "obj").glob("frame_*.obj")):
        try:
            out[int(p.stem.split("_")[1])] = ("obj", p)
        except (IndexError, ValueError):
            continue
    out.update({k: ("states", paths) for k, paths in state_files(run_dir).items()})
    return dict(sorted(out.items()))


def check_inputs(arcsim_out: Path, run_dir: Path, cloth: str, frames: str | None) -> Inputs:
    """Find and check both sides and the frames to compare; CompareError names the first problem."""
    first, last = parse_frames(frames)
    if cloth != "all" and not (cloth.isdigit() and int(cloth) < 100):
        raise CompareError(f"--cloth: expected a cloth index 0-99 or 'all', got {cloth!r}")
    a_frames = arcsim_cloth_frames(arcsim_out, cloth)
    if not run_dir.is_dir():
        raise CompareError(f"run folder {run_dir}: no such folder")
    records = run_records(run_dir)
    shapes = run_shape_sources(run_dir)
    run_frames = set(records["frame"].astype(int)) | set(shapes)
    if not run_frames:
        raise CompareError(f"run folder {run_dir}: no frames (no frames.parquet, frames.jsonl, states/, obj/ or "
                           f"{FINAL_STATE_FILE}): not a folder of python -m experiments.run, or its run wrote no frame")
    both = sorted(k for k in set(a_frames) & run_frames if first <= k <= last)
    if not both:
        window = "" if frames is None else f" within --frames {frames}"
        raise CompareError(f"no frame in both{window}: ARCSim has {ranges(a_frames)}, the run has {ranges(run_frames)}")
    notes = []
    timing = None
    if (arcsim_out / arcsim.TIMING_FILE).is_file():
        timing = arcsim.read_timing(arcsim_out / arcsim.TIMING_FILE, last_frame=max(a_frames))
        if timing.note:
            notes.append(f"ARCSim times left blank: {timing.note}")
    a_dt = None
    if (arcsim_out / arcsim.CONF_FILE).is_file():
        try:
            a_dt = arcsim.conf_frame_time(arcsim.read_conf(arcsim_out / arcsim.CONF_FILE))
        except arcsim.ArcsimError as exc:
            notes.append(f"frame time of ARCSim unknown: {exc}")
    window = lambda frames: {k for k in frames if first <= k <= last}  # noqa: E731
    return Inputs(arcsim_frames={k: a_frames[k] for k in both}, timing=timing, arcsim_frame_time=a_dt,
                  records=records, run_shapes={k: shapes[k] for k in both if k in shapes}, frames=both,
                  arcsim_available=window(a_frames), run_available=window(run_frames), notes=notes)


def run_frame_time(records: pd.DataFrame) -> float | None:
    """The run's seconds per frame, from its records' sim_time_s (None without them)."""
    if "sim_time_s" not in records.columns or not (records["frame"] > 0).any():
        return None
    r = records[records["frame"] > 0]
    return float(np.median(r["sim_time_s"] / r["frame"]))


def arcsim_shape(paths: list[Path]) -> Shape:
    f = arcsim.concatenate([arcsim.read_cloth_obj(p) for p in paths])
    return Shape(f.node_x, f.face_nodes, material_area(f.vert_u, f.face_verts))


def run_shape(source: tuple) -> Shape:
    """The run's cloth at one frame, through the project's own readers."""
    kind, where = source
    try:
        if kind == "states":
            s = merge_states([load_state(p) for p in where])
            area = material_area(s["vert_u"], s["face_verts"]) if s["restart"] else math.nan
            return Shape(s["node_x"], s["face_nodes"], area)
        if kind == "obj":
            mesh = load_obj(where)
            return Shape(mesh.node_x, mesh.vert_node[mesh.face_verts], material_area(mesh.vert_u, mesh.face_verts))
        s = load_final_state(where)
        return Shape(s["node_x"], s["vert_node"][s["face_verts"]], material_area(s["vert_u"], s["face_verts"]))
    except (StateError, ObjError, CheckpointError) as exc:
        raise CompareError(str(exc)) from None


# ---- the comparison -------------------------------------------------------------------------

def compare_frame(a: Shape, r: Shape, spacing: float | None) -> dict:
    """The shape columns of one frame: surface distance (A = ARCSim, B = the run) and boxes."""
    d = surface_distance(a.node_x, a.face_nodes, r.node_x, r.face_nodes, spacing)
    box = bounding_box_difference(a.node_x[np.unique(a.face_nodes)], r.node_x[np.unique(r.face_nodes)])
    out = {"dist_mean_m": d["mean_m"], "dist_max_m": d["max_m"],
           "dist_mean_arcsim_to_run_m": d["mean_a_to_b_m"], "dist_mean_run_to_arcsim_m": d["mean_b_to_a_m"],
           "dist_max_arcsim_to_run_m": d["max_a_to_b_m"], "dist_max_run_to_arcsim_m": d["max_b_to_a_m"]}
    out.update({f"bbox_{k}": v for k, v in box.items()})
    out.update(spacing_m=d["spacing_m"], samples_arcsim=d["samples_a"], samples_run=d["samples_b"])
    return out


def compare(inputs: Inputs, spacing: float | None = None) -> pd.DataFrame:
    """compare.csv's table: one row per frame of `inputs.frames` (see the module docstring)."""
    records = inputs.records.set_index(inputs.records["frame"].astype(int)) if len(inputs.records) else None
    per_frame = inputs.timing.frame_seconds() if inputs.timing is not None else {}
    modules = inputs.timing.modules if inputs.timing is not None else ()
    dt = run_frame_time(inputs.records)
    rows = []
    for k in inputs.frames:
        a = arcsim_shape(inputs.arcsim_frames[k])
        row = {"frame": k, "time_s": k * dt if dt is not None else math.nan, "arcsim_faces": a.face_nodes.shape[0],
               "run_faces": math.nan, "arcsim_s": math.nan, "run_sim_s": math.nan}
        if k in per_frame:
            row["arcsim_s"] = float(per_frame[k].sum())
            row.update({f"arcsim_{m}_s": float(v) for m, v in zip(modules, per_frame[k])})
        if records is not None and k in records.index and k > 0:
            rec = records.loc[k]
            row["run_faces"], row["run_sim_s"] = float(rec.get("faces", math.nan)), float(rec.get("sim_s", math.nan))
        row["arcsim_material_area_m2"], row["run_material_area_m2"] = a.material_area_m2, math.nan
        if k in inputs.run_shapes:
            r = run_shape(inputs.run_shapes[k])
            if math.isnan(row["run_faces"]):
                row["run_faces"] = float(r.face_nodes.shape[0])
            row["run_material_area_m2"] = r.material_area_m2
            row.update(compare_frame(a, r, spacing))
        rows.append(row)
    table = pd.DataFrame(rows)
    table["faces_ratio"] = table["run_faces"] / table["arcsim_faces"]
    table["time_ratio"] = table["run_sim_s"] / table["arcsim_s"]
    for col in ("run_faces", "samples_arcsim", "samples_run"):  # counts, blank where there is none
        if col in table:
            table[col] = table[col].astype("Int64")
    first = ["frame", "time_s", "arcsim_faces", "run_faces", "faces_ratio", "arcsim_s", "run_sim_s", "time_ratio"]
    return table[first + [c for c in table.columns if c not in first]]


def missing_frames(inputs: Inputs, table: pd.DataFrame) -> dict:
    """What was missing, as frame ranges (summary.json's ``missing``): frames of one side only
    (within --frames), and compared frames without ARCSim's time, the run's time or the run's shape."""
    a_all, run_all = inputs.arcsim_available, inputs.run_available
    blank = lambda col: ranges(table.loc[table[col].isna(), "frame"]) if col in table else ranges(table["frame"])  # noqa: E731
    return {"arcsim_frames_not_in_run": ranges(a_all - run_all), "run_frames_not_in_arcsim": ranges(run_all - a_all),
            "arcsim_time": blank("arcsim_s") + ("" if inputs.timing is not None else " (no timing file)"),
            "run_time": blank("run_sim_s"), "run_shape": blank("dist_mean_m")}


def summarize(table: pd.DataFrame, inputs: Inputs, args, arcsim_out: Path, run_dir: Path) -> dict:
    """summary.json: median, mean and max over the frames of every column, the frames, what was missing."""
    stats = {}
    for col in table.columns:
        if col == "frame":
            continue
        v = table[col].dropna()
        stats[col] = ({"median": float(v.median()), "mean": float(v.mean()), "max": float(v.max()),
                       "frames": int(len(v))} if len(v) else {"median": None, "mean": None, "max": None, "frames": 0})
    notes = list(inputs.notes)
    run_dt = run_frame_time(inputs.records)
    if inputs.arcsim_frame_time is not None and run_dt is not None and not math.isclose(
            inputs.arcsim_frame_time, run_dt, rel_tol=FRAME_TIME_RTOL):
        notes.append(f"the frame times differ (ARCSim {inputs.arcsim_frame_time:g} s, the run {run_dt:g} s): "
                     f"frame k is not the same instant on both sides")
    areas = table[["arcsim_material_area_m2", "run_material_area_m2"]].dropna()
    if len(areas):
        a, r = areas.iloc[0]
        if not math.isclose(a, r, rel_tol=AREA_RTOL):
            notes.append(f"the material areas differ (ARCSim {a:.4g} m^2, the run {r:.4g} m^2): not the same cloth, "
                         f"or other units")
    missing = missing_frames(inputs, table)
    if missing["run_shape"]:
        notes.append(f"no run shape at frames {missing['run_shape']}: distances blank there (run with "
                     f"output.states_every=1 for every frame)")
    return {"arcsim_out": str(arcsim_out), "run_dir": str(run_dir), "cloth": args.cloth,
            "frames_compared": int(len(table)), "first_frame": int(table["frame"].min()),
            "last_frame": int(table["frame"].max()), "frames_option": args.frames,
            "frame_matching": "ARCSim frame k with run frame k; 0: the initial state of each, k >= 1: after k frames",
            "frame_time_s": {"arcsim": inputs.arcsim_frame_time, "run": run_dt},
            "timing_modules": list(inputs.timing.modules) if inputs.timing is not None else [],
            "distance": {"definition": SURFACE_DEFINITION, "spacing_m": args.spacing,
                         "spacing_rule": DEFAULT_SPACING_RULE if args.spacing is None else "--spacing",
                         "sampling": "vertices, and the centroids of each triangle cut into n^2 equal parts, "
                                     "n = ceil(longest edge / spacing); area-weighted mean of each direction, "
                                     "averaged; maximum over both", "bbox": "run minus ARCSim"},
            "statistics": stats, "missing": missing, "notes": notes}


# ---- outputs --------------------------------------------------------------------------------

def plot(table: pd.DataFrame, path: Path) -> None:
    """compare.png: faces, time per frame, and mean / max surface distance against frame."""
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    f = table["frame"]
    axes[0].plot(f, table["arcsim_faces"], "o-", ms=3, label="ARCSim")
    axes[0].plot(f, table["run_faces"], "s-", ms=3, label="this run")
    axes[0].set_ylabel("faces")
    axes[1].plot(f, table["arcsim_s"], "o-", ms=3, label="ARCSim (timing)")
    axes[1].plot(f, table["run_sim_s"], "s-", ms=3, label="this run (sim_s)")
    axes[1].set_ylabel("time per frame (s)")
    if "dist_mean_m" in table:
        axes[2].plot(f, table["dist_mean_m"], "o-", ms=3, label="mean (two-sided)")
        axes[2].plot(f, table["dist_max_m"], "^-", ms=3, label="max (two-sided)")
    axes[2].set_ylabel("surface distance (m)")
    axes[2].set_ylim(bottom=0)
    axes[2].ticklabel_format(axis="y", useOffset=False)
    axes[2].set_xlabel("frame")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.has_data():
            ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    plt.close(fig)


def printed_tables(table: pd.DataFrame, summary: dict) -> str:
    """The per-frame table (long ones cut in the middle) and the summary over frames, as text."""
    cols = [c for c in PRINTED if c in table.columns]
    stats = pd.DataFrame({c: summary["statistics"][c] for c in STAT_COLUMNS if c in summary["statistics"]}).T
    with pd.option_context("display.float_format", "{:.4g}".format, "display.width", 160):
        text = table[cols].to_string(index=False, max_rows=20, na_rep="")
        text += f"\n\nover {summary['frames_compared']} frames ({summary['first_frame']}-{summary['last_frame']}):\n"
        text += stats.to_string(na_rep="")
    return text


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.compare_arcsim", description=__doc__.split("\n")[0])
    parser.add_argument("arcsim_out", type=Path, metavar="ARCSIM_OUT", help="ARCSim's output folder")
    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a run folder of python -m experiments.run")
    parser.add_argument("--out", type=Path, default=None, help=f"output folder (default RUN_DIR/{DEFAULT_OUT})")
    parser.add_argument("--cloth", default="0", help="ARCSim's cloth: an index (NNNN_CC.obj) or 'all' (default 0)")
    parser.add_argument("--frames", default=None, help="frames a:b (inclusive; a:, :b, k)")
    parser.add_argument("--spacing", type=float, default=None,
                        help=f"surface sampling spacing h (m; default {DEFAULT_SPACING_RULE})")
    args = parser.parse_args(argv)
    try:
        if args.spacing is not None and not (math.isfinite(args.spacing) and args.spacing > 0):
            raise CompareError(f"--spacing: must be a length > 0 (m), got {args.spacing}")
        inputs = check_inputs(args.arcsim_out, args.run_dir, args.cloth, args.frames)
        table = compare(inputs, args.spacing)
    except (CompareError, arcsim.ArcsimError) as exc:
        print(f"compare_arcsim error: {exc}", file=sys.stderr)
        return 2
    out = args.out if args.out is not None else args.run_dir / DEFAULT_OUT
    summary = summarize(table, inputs, args, args.arcsim_out, args.run_dir)
    write_text_atomic(out / "compare.csv", table.to_csv(index=False))
    write_json_atomic(out / "summary.json", summary)
    plot(table, out / "compare.png")
    print(printed_tables(table, summary))
    missing = {k: v for k, v in summary["missing"].items() if v}
    if missing:
        print("missing (frames): " + "; ".join(f"{k} {v}" for k, v in missing.items()))
    for note in summary["notes"]:
        print(f"note: {note}")
    print(f"written: {out / 'compare.csv'}, {out / 'summary.json'}, {out / 'compare.png'}")
    return 0

