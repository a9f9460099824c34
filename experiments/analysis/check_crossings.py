"""Whether a run's saved cloth states cross themselves or their obstacles: the check behind "nothing
left intersecting", from the run's own files, without re-simulating.

    python -m experiments.check_crossings RUN_DIR [RUN_DIR ...] [--out DIR] [--frames a:b]
                                          [--report docs/crossings.md]

RUN_DIR is a run folder of ``python -m experiments.run`` with per-frame states
(``output.states_every=N``; a crowd's ``dancer_*/states`` are checked character by character).

**Per state** (crossings.csv), on the positions the state holds (cloth.io.states):

* ``self_pairs``, ``self_length_m``: cloth face pairs that cross each other (a triangle's edge
  through the other triangle; faces sharing a node excluded), and the total length of their
  intersection segments (cloth.collision.untangle.find_intersections, the test the untangling
  stage itself uses);
* ``obstacle_pairs``, ``obstacle_length_m``: cloth faces crossing a triangle of a mesh obstacle
  (a body mesh, a ground plane's square), the same test;
* ``nodes_inside``: cloth nodes inside a capsule obstacle (a capsule body, a sphere), and
  ``deepest_m`` the deepest of them (0 when none); a capsule is tested against the nodes only;
* ``faces_pierced``: cloth faces a capsule's axis passes through (the bone of a body part through
  the cloth), whether or not a node of the face is inside: what the simulation's contact with
  capsules, which holds the nodes out, cannot see. Reported, not in the verdict (a face can lie
  over a capsule with its middle inside by the chord's sagitta and no axis through it; the count
  is of faces the body went through);
* ``clearance_m``: the distance from the cloth's nodes to the nearest obstacle surface (the
  exact point-to-triangle distance to mesh obstacles, the distance to the capsules' surfaces);
  blank for a scene without obstacles.

**The records** (frames.parquet, or a killed run's frames.jsonl) say more of the frames without
a state: a frame whose untangling left crossings (``intersections_left`` > 0: the steps after it
cannot remove them, so the frame ends crossing) counts against the verdict like a crossing
state; the frames with a step whose collision pass gave up (``self_collisions_left`` or
``obstacle_collisions_left`` > 0, untangled before the next step) are listed.

**Frame 0** is the state before the first step, and so before the start state's untangling (a
scene's start mesh may cross its obstacles; the first frame removes that): it is listed, and the
verdict covers the frames after it.

**Writes** into ``--out`` (default RUN_DIR/check_crossings): ``crossings.csv`` and
``summary.json`` (states checked, frames with crossings as ranges, largest counts, smallest
clearance, the records' frames), and prints the frames that cross, or that none does. Exit code 0
when no state after frame 0 crosses and no record says crossings were left, 1 otherwise, 2 for a
bad input (a folder without states, an unreadable state
file, ``--frames`` selecting none), named before any work. With several RUN_DIRs each is checked in
turn (the exit code is the worst); ``--report PATH`` also writes one Markdown page of every run's
verdict with its scene, seed, faces, rejected steps and commit.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from numba import njit

from cloth.collision.ccd import edge_triangle_crossing
from cloth.collision.nearest import point_mesh_distance
from cloth.collision.obstacles import CapsuleUnion
from cloth.collision.untangle import find_intersections
from cloth.io.manifest import write_json_atomic, write_text_atomic
from cloth.io.states import StateError, load_state
from experiments.analysis.accuracy import state_files
from experiments.analysis.compare_arcsim import CompareError, parse_frames, ranges, run_records
from experiments.analysis.tables import md_table

DEFAULT_OUT = "check_crossings"
COLUMNS = ("frame", "time_s", "faces", "self_pairs", "self_length_m", "obstacle_pairs", "obstacle_length_m",
           "nodes_inside", "deepest_m", "faces_pierced", "clearance_m")


@njit(cache=True)
def faces_pierced(x: np.ndarray, faces: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """(F,) bool: whether any capsule axis (ends (K, 2, 3), its segment a -> b) passes through the
    face (cloth.collision.ccd.edge_triangle_crossing; a sphere, a = b, has no axis)."""
    hit = np.zeros(faces.shape[0], np.bool_)
    for f in range(faces.shape[0]):
        a, b, c = x[faces[f, 0]], x[faces[f, 1]], x[faces[f, 2]]
        for k in range(ends.shape[0]):
            if edge_triangle_crossing(ends[k, 0], ends[k, 1], a, b, c)[0]:
                hit[f] = True
                break
    return hit
    p0 = x[faces[:, 0]]
    e1, e2 = x[faces[:, 1]] - p0, x[faces[:, 2]] - p0
    for a, b in np.asarray(ends, float).reshape(-1, 2, 3):
        d = b - a
        if not np.any(d):  # a sphere: a point, no axis
            continue
        pvec = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pvec)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = a - p0
        u = np.einsum("ij,ij->i", tvec, pvec) * inv
        qvec = np.cross(tvec, e1)
        v = (qvec @ d) * inv
        t = np.einsum("ij,ij->i", qvec, e2) * inv
        hit |= ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)
    return hit


class CheckError(ValueError):
    """A bad input of the check; the message names it."""


def check_state(state: dict) -> dict:
    """The crossings of one state (load_state's arrays): the columns of crossings.csv but frame
    and time."""
    x, faces = state["node_x"], state["face_nodes"]
    self_pairs, self_length, _ = find_intersections(faces, x)
    ox, of = state["obstacle_x"], state["obstacle_faces"]
    obstacle_pairs, obstacle_length = 0, 0.0
    clearance = math.inf
    if of.shape[0]:
        pairs, length, _ = find_intersections(np.vstack([faces, of + x.shape[0]]), np.vstack([x, ox]),
                                              n_fixed_faces=of.shape[0])
        obstacle_pairs, obstacle_length = len(pairs), float(length.sum())
        clearance = float(point_mesh_distance(x, ox, of).min()) if x.shape[0] else math.inf
    inside, deepest, pierced = 0, 0.0, 0
    if state["capsule_radii"].shape[0] and x.shape[0]:
        pierced = int(faces_pierced(x, np.ascontiguousarray(faces, np.int64),
                                     np.ascontiguousarray(state["capsule_ends"], np.float64)).sum())
        capsules = CapsuleUnion(state["capsule_ends"], state["capsule_radii"])
        phi = capsules.query(x)[0]
        inside = int(np.sum(phi < 0.0))
        deepest = float(max(0.0, -phi.min()))
        clearance = min(clearance, float(max(phi.min(), 0.0)))
    return {"faces": int(faces.shape[0]), "self_pairs": len(self_pairs), "self_length_m": float(self_length.sum()),
            "obstacle_pairs": obstacle_pairs, "obstacle_length_m": obstacle_length, "nodes_inside": inside,
            "deepest_m": deepest, "faces_pierced": pierced,
            "clearance_m": clearance if math.isfinite(clearance) else None}


def check_run(run_dir: Path, frames: str | None = None) -> pd.DataFrame:
    """One row per saved state of `run_dir` within `frames` (a crowd: its characters' counts
    summed, the smallest clearance); CheckError names a bad input."""
    if not run_dir.is_dir():
        raise CheckError(f"run folder {run_dir} does not exist")
    try:
        first, last = parse_frames(frames)
    except CompareError as exc:
        raise CheckError(str(exc)) from None
    available = state_files(run_dir)
    if not available:
        raise CheckError(f"{run_dir} has no states/frame_NNNNN.npz: run it with output.states_every=N")
    chosen = {k: v for k, v in available.items() if first <= k <= last}
    if not chosen:
        raise CheckError(f"--frames {frames}: none of the saved states ({ranges(available)}) is in it")
    rows = []
    for frame, paths in chosen.items():
        parts = []
        for path in paths:
            try:
                state = load_state(path)
            except StateError as exc:
                raise CheckError(str(exc)) from None
            parts.append(check_state(state))
        row = {"frame": frame, "time_s": state["time"]}
        for key in COLUMNS[2:]:
            values = [p[key] for p in parts if p[key] is not None]
            if key == "clearance_m":
                row[key] = min(values) if values else None
            elif key == "deepest_m":
                row[key] = max(values)
            else:
                row[key] = sum(values)
        rows.append(row)
    return pd.DataFrame(rows, columns=list(COLUMNS))


def frame_list(frames) -> str:
    """Frame numbers compactly: evenly spaced ones as 'a-b every n' (states saved every n frames),
    others as ranges ('0, 2-4, 7'); '' for none."""
    frames = sorted(int(f) for f in frames)
    steps = set(np.diff(frames).tolist())
    if len(frames) > 2 and len(steps) == 1 and steps != {1}:
        return f"{frames[0]}-{frames[-1]} every {steps.pop()}"
    return ranges(frames)


def crossing_frames(table: pd.DataFrame) -> list[int]:
    """The frames after frame 0 whose state crosses itself or an obstacle."""
    bad = (table["self_pairs"] > 0) | (table["obstacle_pairs"] > 0) | (table["nodes_inside"] > 0)
    return [int(f) for f in table.loc[bad & (table["frame"] > 0), "frame"]]


def record_frames(run_dir: Path, frames: str | None = None) -> dict:
    """From the run's records within `frames`: 'left' (frames whose untangling left crossings)
    and 'gave_up' (frames with a step whose collision pass left collisions); {} without records."""
    try:
        records = run_records(run_dir)
    except CompareError as exc:
        raise CheckError(str(exc)) from None
    first, last = parse_frames(frames)
    records = records[(records["frame"] >= first) & (records["frame"] <= last)]
    if records.empty:
        return {}
    column = lambda name: records[name] if name in records else pd.Series(0, index=records.index)  # noqa: E731
    gave_up = (column("self_collisions_left") > 0) | (column("obstacle_collisions_left") > 0)
    return {"records": len(records),
            "left": [int(f) for f in records.loc[column("intersections_left") > 0, "frame"]],
            "gave_up": [int(f) for f in records.loc[gave_up, "frame"]]}


def summarize(table: pd.DataFrame, run_dir: Path, records: dict | None = None) -> dict:
    records = records or {}
    crossing = crossing_frames(table)
    start = table[table["frame"] == 0]
    clearance = table["clearance_m"].dropna()
    return {
        "run_dir": str(run_dir),
        "states_checked": len(table),
        "frames": frame_list(table["frame"]),
        "frames_crossing": frame_list(crossing),
        "clean": not crossing and not records.get("left"),
        "records": records.get("records", 0),
        "records_left_crossings": frame_list(records.get("left", [])),
        "records_collisions_gave_up": frame_list(records.get("gave_up", [])),
        "start_state": None if start.empty else {k: int(start.iloc[0][k]) for k in
                                                 ("self_pairs", "obstacle_pairs", "nodes_inside")},
        "max_self_pairs": int(table["self_pairs"].max()),
        "max_obstacle_pairs": int(table["obstacle_pairs"].max()),
        "max_nodes_inside": int(table["nodes_inside"].max()),
        "max_faces_pierced": int(table["faces_pierced"].max()),
        "frames_pierced": frame_list(table.loc[table["faces_pierced"] > 0, "frame"]),
        "min_clearance_m": float(clearance.min()) if len(clearance) else None,
    }


REPORT_COLUMNS = ("run", "scene", "mode", "seed", "status", "frames", "faces_mean", "faces_max", "steps_rejected",
                  "states_checked", "frames_crossing", "records_left_crossings", "collisions_gave_up", "clean",
                  "commit")


def report_row(run_dir: Path) -> dict:
    """One run's line of the report: what ran (config, manifest), how it ended (summary.json) and the
    verdict of its check (RUN_DIR/check_crossings/summary.json)."""
    run_dir = Path(run_dir)
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    end = json.loads((run_dir / "summary.json").read_text())
    check = json.loads((run_dir / DEFAULT_OUT / "summary.json").read_text())
    manifest = json.loads((run_dir / "manifest.json").read_text())
    params = (cfg["scene"].get("params") or {})
    scene = Path(params["conf"]).stem if params.get("conf") else cfg["scene"]["name"]
    return {"run": run_dir.name, "scene": scene, "mode": cfg["mode"]["name"], "seed": cfg.get("seed"),
            "status": end.get("status"), "frames": end.get("frames_completed"),
            "faces_mean": round(float(end.get("faces_mean", float("nan")))),
            "faces_max": int(end.get("faces_max", 0)), "steps_rejected": end.get("steps_rejected_total", 0),
            "states_checked": check["states_checked"], "frames_crossing": check["frames_crossing"] or "none",
            "records_left_crossings": check.get("records_left_crossings") or "none",
            "collisions_gave_up": check.get("records_collisions_gave_up") or "none", "clean": check["clean"],
            "commit": str(manifest.get("git_commit"))[:10] + ("+dirty" if manifest.get("git_dirty") else "")}


def write_report(path: Path, run_dirs, command: str) -> None:
    """A Markdown page of the runs' checks (one row per run), stamped with the date and command."""
    rows = pd.DataFrame([report_row(d) for d in run_dirs], columns=list(REPORT_COLUMNS))
    table = md_table(list(rows.columns), rows.itertuples(index=False)) + "\n"
    clean = int(rows["clean"].sum())
    text = (f"# Crossing checks\n\n{datetime.now():%Y-%m-%d}: `{command}`\n\n"
            f"{clean} of {len(rows)} runs clean: no saved state after frame 0 with cloth crossing itself or an "
            "obstacle, and no frame whose records say crossings were left (experiments.check_crossings).\n\n"
            + table)
    write_text_atomic(Path(path), text)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.check_crossings",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("run_dirs", type=Path, nargs="+", metavar="RUN_DIR",
                        help="run folders of python -m experiments.run (each checked in turn)")
    parser.add_argument("--out", type=Path, default=None,
                        help=f"output folder of a single RUN_DIR (default RUN_DIR/{DEFAULT_OUT})")
    parser.add_argument("--frames", default=None, help="frames a:b (inclusive; a:, :b, k)")
    parser.add_argument("--report", type=Path, default=None,
                        help="also write a Markdown page of every RUN_DIR's verdict (e.g. docs/crossings.md)")
    args = parser.parse_args(argv)
    if args.out is not None and len(args.run_dirs) > 1:
        parser.error("--out: only with a single RUN_DIR (each run's check goes into RUN_DIR/check_crossings)")
    codes = [check_one(d, args.out, args.frames) for d in args.run_dirs]
    if args.report is not None and 2 not in codes:
        argv_text = " ".join(argv if argv is not None else sys.argv[1:])
        write_report(args.report, args.run_dirs, f"python -m experiments.check_crossings {argv_text}")
        print(f"report: {args.report}")
    return max(codes)


def check_one(run_dir: Path, out: Path | None, frames: str | None) -> int:
    """Check one run folder, write its crossings.csv and summary.json, print the verdict; the exit code."""
    args = argparse.Namespace(run_dir=run_dir, out=out, frames=frames)
    try:
        table = check_run(args.run_dir, args.frames)
        records = record_frames(args.run_dir, args.frames)
    except CheckError as exc:
        print(f"check_crossings error: {exc}", file=sys.stderr)
        return 2
    out = args.out if args.out is not None else args.run_dir / DEFAULT_OUT
    summary = summarize(table, args.run_dir, records)
    write_text_atomic(out / "crossings.csv", table.to_csv(index=False))
    write_json_atomic(out / "summary.json", summary)
    print(f"{summary['states_checked']} states checked (frames {summary['frames']})")
    if summary["start_state"] and any(summary["start_state"].values()):
        s = summary["start_state"]
        print(f"frame 0 (before the start state's untangling): {s['self_pairs']} self pairs, "
              f"{s['obstacle_pairs']} obstacle pairs, {s['nodes_inside']} nodes inside")
    if summary["frames_crossing"]:
        bad = table[table["frame"].isin(crossing_frames(table))]
        with pd.option_context("display.float_format", "{:.4g}".format, "display.width", 160):
            print(bad.to_string(index=False, max_rows=20, na_rep=""))
        print(f"crossing in frames {summary['frames_crossing']}")
    else:
        print("no state after frame 0 has cloth crossing itself or an obstacle")
    if summary["records"]:
        print(f"records of {summary['records']} frames: "
              f"untangling left crossings in frames {summary['records_left_crossings'] or 'none'}; "
              f"a collision pass gave up in frames {summary['records_collisions_gave_up'] or 'none'}")
    if summary["frames_pierced"]:
        print(f"a capsule's axis through the cloth (not in the verdict: the contact holds nodes only) in frames "
              f"{summary['frames_pierced']}, up to {summary['max_faces_pierced']} faces")
    if summary["min_clearance_m"] is not None:
        print(f"nearest node to an obstacle: {summary['min_clearance_m']:.4g} m")
    print(f"written: {out / 'crossings.csv'}, {out / 'summary.json'}")
    return 0 if summary["clean"] else 1

