"""Re-run a run from its saved config and check that it reproduces: ``python -m experiments.replay RUN_DIR``.

    python -m experiments.replay RUN_DIR [--out DIR] [--frames N] [--tolerance RTOL]

Reads RUN_DIR/config.yaml (the resolved config), runs it again into ``--out`` (default
``RUN_DIR/replay_<YYYYmmdd-HHMMSS>``: inside the run folder, so that tools that list the run
folders of a sweep do not take it for a run) and compares:

* frames.parquet, column by column and frame by frame, over every deterministic column: all
  except the wall-clock columns ``time_*``, ``wall_*`` and ``sim_s`` (time per phase, per frame),
  which depend on the machine and its load. Counts, energies, speeds, solver iterations and
  residuals, remesh and view-factor statistics must be identical;
* the final node positions (final_state.npz, float64), when the replay covers the whole
  original run and the original completed;
* for a crowd, the combined records and every character's own records and final state.

By default it replays as many frames as RUN_DIR/frames.parquet holds (all of them for a
completed run, up to where it stopped otherwise); ``--frames N`` replays and compares the first
N. The replay writes no recording, OBJ, stills, states or checkpoints: they never feed back into
the simulation.

Threads: the numba kernels with ``parallel=True`` (cloth/membrane.py, cloth/bending.py) write
one output slot per element and every sum over elements is serial, and the CG solver's dot
products are serial numba loops, so the results do not depend on the thread count: measured
bit-identical with NUMBA_NUM_THREADS=1 and 2 (and OPENBLAS_NUM_THREADS=1 and 2) on every scene
tried, at both scales. So identity is demanded whatever the thread counts (the report states
them, from both manifests). ``--tolerance RTOL`` (default REPLAY_RTOL = 0, identity) accepts
differences up to RTOL times each column's largest magnitude over the compared frames, and final
positions that differ by at most RTOL times the cloth's bounding-box diagonal, and reports a
"tolerance match": for a replay on another CPU or with other library versions, where floating
point may legitimately differ.

The report (printed, and written to ``<out>/replay_report.json``) says: match, tolerance match
or mismatch; for a mismatch the first frame and the columns that differ there, by how much,
and the largest difference per column; whether the final positions are identical and the
largest distance between them; and what differs between the two environments (commit,
uncommitted changes, versions, CPU, threads). Exit code 0 on a match, 1 on a mismatch, 2 on
bad input (not a run folder, no records, bad option, or a config the current code rejects).
"""

from __future__ import annotations

import argparse
import json
import sys
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from cloth.io.checkpoint import FINAL_STATE_FILE, CheckpointError, load_final_state
from cloth.io.manifest import write_json_atomic
from cloth.simulation import SimulationDiverged
from experiments.build import ConfigError, build_simulation, crowd_size
from experiments.launch import run_from_config

# Relative difference a replay accepts by default: none (bit-identical; see the module docstring).
REPLAY_RTOL = 0.0
MAX_COLUMNS_SHOWN = 6  # differing columns listed for the first differing frame
ENV_KEYS = ("git_commit", "git_dirty", "git_diff_sha1", "python", "cpu_model", "numba_threads", "blas")


class ReplayError(ValueError):
    """Bad input to a replay; the message names the problem."""


def machine_dependent(column: str) -> bool:
    """Wall-clock columns (time per phase ``time_*``, per frame ``wall_*``, simulation time per frame
    ``sim_s``): excluded from comparison."""
    return column.startswith(("time_", "wall_")) or column == "sim_s"


def _equal(a: np.ndarray, b: np.ndarray, rtol: float) -> np.ndarray:
    """Element-wise: equal (NaN equals NaN), or, if rtol > 0, differing by at most `rtol` times
    the column's largest magnitude (so that values near zero are judged on the column's scale)."""
    if a.dtype.kind in "biuf" and b.dtype.kind in "biuf":
        a, b = a.astype(np.float64), b.astype(np.float64)
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        if rtol > 0 and a.size:
            with np.errstate(invalid="ignore"):
                scale = np.nanmax(np.abs(np.concatenate([a, b])), initial=0.0)
                same |= np.abs(a - b) <= rtol * scale
        return same
    return np.array([x == y or (x != x and y != y) for x, y in zip(a, b)], dtype=bool)


def _diff(a, b) -> float | None:
    try:
        return float(abs(float(a) - float(b)))
    except (TypeError, ValueError):
        return None


def compare_frames(original: pd.DataFrame, replay: pd.DataFrame, n_frames: int, rtol: float = REPLAY_RTOL) -> dict:
    """Compare the first `n_frames` rows of two frames tables over their deterministic columns.

    Returns {identical, within_tolerance, frames_compared, columns_compared, columns_excluded,
    columns_missing, first_difference (frame, columns: {column: (original, replay, abs diff)}),
    max_abs_diff {column: value}, problems [text]}.
    """
    problems = []
    det_a = [c for c in original.columns if not machine_dependent(c)]
    det_b = [c for c in replay.columns if not machine_dependent(c)]
    missing = sorted(set(det_a) ^ set(det_b))
    if missing:
        problems.append(f"columns in only one of the tables: {missing}")
    cols = [c for c in det_a if c in set(det_b)]
    n = min(n_frames, len(original), len(replay))
    if len(original) < n_frames or len(replay) < n_frames:
        problems.append(f"frames: original has {len(original)}, replay {len(replay)}, expected {n_frames}")
    a, b = original.iloc[:n], replay.iloc[:n]
    exact = np.ones((n, len(cols)), dtype=bool)
    close = np.ones((n, len(cols)), dtype=bool)
    max_abs = {}
    for j, c in enumerate(cols):
        x, y = a[c].to_numpy(), b[c].to_numpy()
        exact[:, j] = _equal(x, y, 0.0)
        close[:, j] = _equal(x, y, rtol) if rtol > 0 else exact[:, j]
        if not exact[:, j].all():
            d = [_diff(x[i], y[i]) for i in np.flatnonzero(~exact[:, j])]
            d = [v for v in d if v is not None]
            max_abs[c] = max(d) if d else float("nan")
    first = None
    bad_rows = np.flatnonzero(~exact.all(axis=1))
    if bad_rows.size:
        i = int(bad_rows[0])
        frame = int(a["frame"].iloc[i]) if "frame" in a.columns else i + 1
        shown = {}
        for j in np.flatnonzero(~exact[i])[:MAX_COLUMNS_SHOWN]:
            c = cols[j]
            x, y = a[c].iloc[i], b[c].iloc[i]
            shown[c] = (_py(x), _py(y), _diff(x, y))
        first = {"frame": frame, "row": i, "columns_differing": int((~exact[i]).sum()), "columns": shown}
    return {"identical": not problems and bool(exact.all()), "within_tolerance": not problems and bool(close.all()),
            "frames_compared": int(n), "columns_compared": cols,
            "columns_excluded": [c for c in original.columns if machine_dependent(c)],
            "columns_missing": missing, "first_difference": first, "max_abs_diff": max_abs, "problems": problems}


def _py(v):
    return v.item() if isinstance(v, np.generic) else v


def compare_final_states(original_dir: Path, replay_dir: Path, rtol: float = REPLAY_RTOL) -> dict:
    """Compare final_state.npz of two run folders: node positions (and counts, frame)."""
    try:
        a = load_final_state(original_dir / FINAL_STATE_FILE)
    except CheckpointError as exc:
        return {"compared": False, "reason": f"original: {exc}"}
    try:
        b = load_final_state(replay_dir / FINAL_STATE_FILE)
    except CheckpointError as exc:
        return {"compared": False, "reason": f"replay: {exc}"}
    if int(a["frame"]) != int(b["frame"]):
        return {"compared": False,
                "reason": f"final frames differ: original {int(a['frame'])}, replay {int(b['frame'])}"}
    out = {"compared": True, "frame": int(a["frame"]), "nodes": [int(len(a["node_x"])), int(len(b["node_x"]))]}
    if a["node_x"].shape != b["node_x"].shape or not np.array_equal(a["face_verts"], b["face_verts"]):
        out.update(identical=False, within_tolerance=False,
                   reason=f"different meshes: {a['node_x'].shape[0]} and {b['node_x'].shape[0]} nodes, "
                          f"{a['face_verts'].shape[0]} and {b['face_verts'].shape[0]} faces")
        return out
    d = np.linalg.norm(a["node_x"] - b["node_x"], axis=1)
    out["identical"] = bool(np.array_equal(a["node_x"], b["node_x"]) and np.array_equal(a["node_v"], b["node_v"]))
    out["max_distance_m"] = float(d.max()) if d.size else 0.0
    size = float(np.linalg.norm(np.ptp(a["node_x"], axis=0))) if d.size else 0.0  # bounding-box diagonal, m
    out["within_tolerance"] = out["identical"] or (rtol > 0 and out["max_distance_m"] <= rtol * size)
    return out


def _environment_differences(original_dir: Path, replay_dir: Path) -> dict:
    def load(d):
        try:
            return json.loads((d / "manifest.json").read_text())
        except (OSError, ValueError):
            return {}
    a, b = load(original_dir), load(replay_dir)
    diff = {k: [a.get(k), b.get(k)] for k in ENV_KEYS if a.get(k) != b.get(k)}
    pa, pb = a.get("packages", {}), b.get("packages", {})
    diff.update({f"package {p}": [pa.get(p), pb.get(p)] for p in sorted(set(pa) | set(pb)) if pa.get(p) != pb.get(p)})
    threads = {"original": {"numba_threads": a.get("numba_threads"), **(a.get("env") or {})},
               "replay": {"numba_threads": b.get("numba_threads"), **(b.get("env") or {})}}
    return {"differences": diff, "threads": threads}


def _check_inputs(run_dir: Path, out: Path | None, frames: int | None, rtol: float):
    if not run_dir.is_dir():
        raise ReplayError(f"{run_dir}: no such folder")
    if not (run_dir / "config.yaml").is_file():
        raise ReplayError(f"{run_dir}: not a run folder (no config.yaml)")
    if not (run_dir / "frames.parquet").is_file():
        raise ReplayError(f"{run_dir}: has no frames.parquet (the run recorded no frame): nothing to compare")
    if frames is not None and frames < 1:
        raise ReplayError(f"--frames must be >= 1, got {frames}")
    if not (rtol >= 0):
        raise ReplayError(f"--tolerance must be >= 0, got {rtol}")
    if out is not None:
        if out.resolve() == run_dir.resolve():
            raise ReplayError(f"--out {out} is the run folder itself; choose a new folder")
        if out.exists() and any(out.iterdir()):
            raise ReplayError(f"--out {out} exists and is not empty; choose a new folder")
    original = pd.read_parquet(run_dir / "frames.parquet")
    if original.empty:
        raise ReplayError(f"{run_dir}/frames.parquet has no rows: nothing to compare")
    if frames is not None and frames > len(original):
        raise ReplayError(f"--frames {frames}: the original recorded only {len(original)} frames")
    return original


def replay(run_dir, out=None, frames: int | None = None, rtol: float = REPLAY_RTOL) -> dict:
    """Replay `run_dir` into `out` and compare; returns the report (see the module docstring).

    Raises ReplayError (before any work) on bad input or a config the current code rejects.
    """
    run_dir = Path(run_dir)
    out = Path(out) if out is not None else None
    original = _check_inputs(run_dir, out, frames, rtol)
    if out is None:
        out = run_dir / f"replay_{datetime.now().strftime('%Y%m%d-%H%M%S')}"
        k = 1
        while out.exists():
            out = run_dir / f"replay_{datetime.now().strftime('%Y%m%d-%H%M%S')}_{k}"
            k += 1
    cfg = OmegaConf.load(run_dir / "config.yaml")
    n = int(frames) if frames is not None else len(original)
    cfg.frames = n
    # no output that does not feed back into the simulation
    for key, value in (("rerun", False), ("obj_every", 0), ("stills_every", 0), ("states_every", 0),
                       ("checkpoint_every", 0), ("progress", False)):
        cfg.output[key] = value
    try:
        dancers = crowd_size(cfg)
        build_simulation(cfg, character=0 if dancers is not None else None)
    except ConfigError as exc:
        raise ReplayError(f"{run_dir}/config.yaml is rejected by the current code: {exc}") from None
    stopped = None
    try:
        run_from_config(cfg, out)
    except SimulationDiverged as exc:  # the original may have diverged at the same frame
        stopped = str(exc)
    report = {"run_dir": str(run_dir), "replay_dir": str(out), "frames_replayed": n,
              "frames_original": int(len(original)), "tolerance_rtol": rtol, "replay_stopped": stopped}
    units = [("", run_dir, out)]
    if dancers is not None:
        units += [(f"dancer_{i:02d}", run_dir / f"dancer_{i:02d}", out / f"dancer_{i:02d}") for i in range(dancers)]
    checks = []
    for label, a_dir, b_dir in units:
        a = pd.read_parquet(a_dir / "frames.parquet") if (a_dir / "frames.parquet").is_file() else pd.DataFrame()
        b = pd.read_parquet(b_dir / "frames.parquet") if (b_dir / "frames.parquet").is_file() else pd.DataFrame()
        # a crowd's characters may have stopped at different frames (the combined table has the shortest)
        unit = label or ("crowd" if dancers is not None else "run")
        item = {"unit": unit, "frames": compare_frames(a, b, min(n, len(a)) if label else n, rtol)}
        if dancers is not None and not label:
            item["final_state"] = {"compared": False, "reason": "a crowd's final positions are its characters'"}
        elif n >= len(a):
            item["final_state"] = compare_final_states(a_dir, b_dir, rtol)
        else:
            item["final_state"] = {"compared": False,
                                   "reason": f"the replay covers {n} of the original's {len(a)} frames"}
        checks.append(item)
    report["checks"] = checks
    report["environment"] = _environment_differences(run_dir, out)
    frames_ok = all(c["frames"]["identical"] for c in checks)
    states = [c["final_state"] for c in checks if c["final_state"].get("compared")]
    states_ok = all(s["identical"] for s in states)
    if frames_ok and states_ok:
        verdict = "match"
    elif (rtol > 0 and all(c["frames"]["within_tolerance"] for c in checks)
          and all(s["within_tolerance"] for s in states)):
        verdict = "tolerance match"
    else:
        verdict = "mismatch"
    report["verdict"] = verdict
    report["final_states_compared"] = len(states)
    write_json_atomic(out / "replay_report.json", report)
    return report


def format_report(report: dict) -> str:
    lines = [f"replay of {report['run_dir']}", f"  into {report['replay_dir']}: {report['frames_replayed']} frames "
             f"(original recorded {report['frames_original']})"]
    if report.get("replay_stopped"):
        lines.append(f"  the replay stopped: {report['replay_stopped']}")
    for c in report["checks"]:
        f = c["frames"]
        head = f"  {c['unit']}: frames.parquet, {f['frames_compared']} frames x {len(f['columns_compared'])} columns"
        if f["identical"]:
            lines.append(f"{head}: identical")
        else:
            lines.append(f"{head}: {'within tolerance' if f['within_tolerance'] else 'DIFFERENT'}")
            for p in f["problems"]:
                lines.append(f"    {p}")
            d = f["first_difference"]
            if d:
                k = d["columns_differing"]
                lines.append(f"    first difference at frame {d['frame']} ({k} column{'s' if k > 1 else ''}):")
                for col, (x, y, ad) in d["columns"].items():
                    by = f", |diff| {ad:.3g}" if ad is not None else ""
                    lines.append(f"      {col}: original {x!r}, replay {y!r}{by}")
                largest = sorted(f["max_abs_diff"].items(), key=lambda kv: -np.nan_to_num(kv[1]))
                worst = ", ".join(f"{col} {v:.3g}" for col, v in largest[:MAX_COLUMNS_SHOWN])
                lines.append(f"    largest |diff| over all frames: {worst}")
        s = c["final_state"]
        if not s.get("compared"):
            lines.append(f"  {c['unit']}: final positions not compared ({s.get('reason')})")
        elif s["identical"]:
            lines.append(f"  {c['unit']}: final positions (frame {s['frame']}, {s['nodes'][0]} nodes): identical")
        else:
            extra = f", max distance {s['max_distance_m']:.3g} m" if "max_distance_m" in s else f" ({s.get('reason')})"
            lines.append(f"  {c['unit']}: final positions (frame {s['frame']}): "
                         f"{'within tolerance' if s['within_tolerance'] else 'DIFFERENT'}{extra}")
    lines.append(f"  excluded (wall-clock) columns: {', '.join(report['checks'][0]['frames']['columns_excluded'])}")
    env = report["environment"]
    t = env["threads"]
    lines.append(f"  threads: original numba {t['original'].get('numba_threads')} (NUMBA_NUM_THREADS="
                 f"{t['original'].get('NUMBA_NUM_THREADS')}), replay numba {t['replay'].get('numba_threads')} "
                 f"(NUMBA_NUM_THREADS={t['replay'].get('NUMBA_NUM_THREADS')}); results do not depend on the "
                 f"thread count, identity is required either way")
    if env["differences"]:
        lines.append("  environment differences (original -> replay): " +
                     "; ".join(f"{k}: {a} -> {b}" for k, (a, b) in env["differences"].items()))
    verdict = report["verdict"]
    if verdict == "tolerance match":
        verdict += f" (relative tolerance {report['tolerance_rtol']:g})"
    lines.append(f"verdict: {verdict.upper()}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.replay", description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path, help="a run folder (config.yaml, frames.parquet)")
    parser.add_argument("--out", type=Path, default=None,
                        help="new folder for the replay (default RUN_DIR/replay_<time>)")
    parser.add_argument("--frames", type=int, default=None, help="replay and compare only the first N frames")
    parser.add_argument("--tolerance", type=float, default=REPLAY_RTOL,
                        help=f"accepted relative difference (default {REPLAY_RTOL:g}: bit-identical)")
    args = parser.parse_args(argv)
    try:
        report = replay(args.run_dir, args.out, args.frames, args.tolerance)
    except ReplayError as exc:
        print(f"cannot replay: {exc}", file=sys.stderr)
        return 2
    print(format_report(report))
    return 0 if report["verdict"] in ("match", "tolerance match") else 1


if __name__ == "__main__":
    sys.exit(main())
