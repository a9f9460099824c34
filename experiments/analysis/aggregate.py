"""Aggregate run folders into tables (never re-simulating): the runs table, the per-frame table and
the paper's Table 1.

    python -m experiments.aggregate ROOT [ROOT ...] [--out DIR]

Finds every run folder under the roots, loads each (config.yaml, frames.parquet, summary.json and,
when present, accuracy.json / accuracy.parquet), prints Table 1 and a warning for every folder
that cannot be used; with ``--out`` it writes ``runs.csv``, ``frames.parquet`` (every frame of
every run), ``table1.csv``/``.md``/``.tex``, ``table1_paper.csv`` and ``problems.txt`` there.

Run folders, and what makes a folder one that is skipped: experiments.analysis.runs (whose names are
re-exported here).

Table 1 (:func:`table1`). One row per (scene, scale, mode, variant), made of its repeats: the
runs of that key with distinct seeds (``repeats=N`` runs each cell N times); of runs that share a
seed the latest is used (the manifest's ``timestamp_utc``, else the config's modification time)
and the others are listed in the table's notes as superseded; the fine reference runs
(``reference: true``) are left out. Every number is the median over the repeats of the per-run
value, with the range of the per-run mean times. Speed-up, per seed = mean time per frame of the
``adaptive`` run (default variant, same scene and scale) / this row's; the table gives the median
and range over the seeds. A row whose runs ran other code (commit and uncommitted diff, from
manifest.json) or other frames is refused and named in problems.txt, as is a speed-up against a
baseline that did. Time per frame is the frame's simulation time ``sim_s`` (sizing, remesh,
physics, solve, collisions: the paper's Time/Frame, cloth.core.records.SIM_PHASES; for runs
recorded before that column, the sum of those phase columns); I/O is its own column
(``io_mean_s``), never inside it.
The Markdown and LaTeX of the tables are made by experiments.analysis.tables.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import pandas as pd

from cloth.io.manifest import write_parquet_atomic, write_text_atomic
from experiments.analysis.runs import (
    ACCURACY_KEYS,
    EQUILIBRIUM_FRAMES,
    MODES,
    REQUIRED_FRAME_COLUMNS,
    RUN_MARKERS,
    SCENE_MEASURES,
    STAT_COLUMNS,
    SWEPT,
    SWEPT_COLUMNS,
    SYNC_KEYS,
    AggregateError,
    Problem,
    RunFolderWarning,
    RunSet,
    check_roots,
    code_label,
    effective_view_setting,
    find_run_folders,
    is_run_folder,
    load_run,
    load_runs,
    with_sim_seconds,
)
from experiments.analysis.tables import PAPER_SCENES, table1_markdown, write_table1
from experiments.analysis.tables import (
    PAPER_TABLE1 as PAPER_TABLE1,  # re-exported: the paper's numbers, also found here
)

TABLE1_COLUMNS = ("scene", "scale", "mode", "variant", "frames", "faces_min", "faces_max", "faces_mean",
                  "verts_min", "verts_max", "verts_mean", "time_min_s", "time_max_s", "time_mean_s", "io_mean_s",
                  "time_mean_lo_s", "time_mean_hi_s", "repeats", "seeds", "speedup", "speedup_lo", "speedup_hi",
                  "code", "baseline", "run")

__all__ = ["ACCURACY_KEYS", "EQUILIBRIUM_FRAMES", "MODES", "PAPER_TABLE1", "REQUIRED_FRAME_COLUMNS", "RUN_MARKERS",
           "SCENE_MEASURES", "STAT_COLUMNS", "SWEPT", "SWEPT_COLUMNS", "SYNC_KEYS", "TABLE1_COLUMNS", "AggregateError",
           "Problem", "RunFolderWarning", "RunSet", "baseline_for", "check_roots", "code_label", "disagreement",
           "effective_view_setting", "find_run_folders", "is_default_variant", "is_run_folder", "latest",
           "load_run", "load_runs", "main", "report_problems", "table1", "table1_runs", "with_sim_seconds",
           "write_runs"]



# ---- selecting runs ------------------------------------------------------------------------------

def latest(runs: pd.DataFrame, keys) -> tuple[pd.DataFrame, list[str]]:
    """The latest run (timestamp, then path) of each group of `keys`; and a note per run left out."""
    if runs.empty:
        return runs, []
    ordered = runs.sort_values(["timestamp", "path"])
    keep = ordered.groupby(list(keys), dropna=False, sort=False).tail(1)
    dropped = ordered.drop(keep.index)
    notes = [f"{r.run}: superseded by a later run of the same {'/'.join(keys)}" for r in dropped.itertuples()]
    return keep.sort_index(), notes


def is_default_variant(row) -> bool:
    """A run that stands for its mode with default settings (variant empty or the mode's name)."""
    return row["variant"] in ("", row["mode"])


# Studies whose runs are never Table 1's, even among runs without a table1 study: crowd_scaling's
# crowds of 1 to 100 dancers would make one row of several crowd sizes.
NOT_TABLE1_STUDIES = ("crowd_scaling",)


def table1_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """The runs Table 1 is made of: the table1 study's when there are any, else all but those of
    NOT_TABLE1_STUDIES; never the fine reference runs."""
    if runs.empty:
        return runs
    runs = runs[~runs["reference"].astype(bool)]
    study = runs[runs["study"] == "table1"]
    return study if len(study) else runs[~runs["study"].isin(NOT_TABLE1_STUDIES)]


def baseline_for(runs: pd.DataFrame, scene: str, scale: str, seed=None) -> pd.Series | None:
    """The adaptive run of a scene and scale that speed-ups are measured against: the only one,
    else the latest of the default variant; None when there is none or it is ambiguous. With a
    `seed`, only the adaptive runs of that seed (the same repeat) are candidates."""
    cand = runs[(runs["scene"] == scene) & (runs["scale"] == scale) & (runs["mode"] == "adaptive")
                & ~runs["reference"].astype(bool)]
    if seed is not None and "seed" in cand.columns:
        cand = cand[cand["seed"] == seed]
    if len(cand) > 1:
        cand = cand[cand.apply(is_default_variant, axis=1)]
        cand, _ = latest(cand, ("scene",))
    return cand.iloc[0] if len(cand) == 1 else None


def _order(df: pd.DataFrame) -> pd.DataFrame:
    scene_rank = {s: i for i, s in enumerate(PAPER_SCENES)}
    mode_rank = {m: i for i, m in enumerate(MODES)}
    return (df.assign(_s=df["scene"].map(lambda s: (scene_rank.get(s, len(scene_rank)), s)),
                      _m=df["mode"].map(lambda m: mode_rank.get(m, len(mode_rank))))
            .sort_values(["_s", "scale", "_m", "variant"]).drop(columns=["_s", "_m"]).reset_index(drop=True))


# ---- Table 1 -------------------------------------------------------------------------------------

ROW_KEY = ("scene", "scale", "mode", "variant")
# What the runs of one Table 1 row, and a row and its adaptive baseline, must share: the code
# they ran (commit and uncommitted diff) and the frames they simulated (the scale is in ROW_KEY).
MUST_AGREE = {"code": "commit", "frames": "frames", "scale": "scale"}


def disagreement(runs: pd.DataFrame) -> str:
    """'' when the runs agree on MUST_AGREE, else what differs and the values."""
    parts = []
    for col, what in MUST_AGREE.items():
        if col in runs.columns and runs[col].astype(str).nunique() > 1:
            parts.append(f"{what} ({', '.join(sorted(runs[col].astype(str).unique()))})")
    return ", ".join(parts)


def _label(key) -> str:
    scene, scale, mode, variant = key
    return f"{scene}/{scale or 'no scale'}/{mode}" + (f"/{variant}" if variant and variant != mode else "")


def table1(runs: pd.DataFrame) -> pd.DataFrame:
    """The paper's Table 1 of any set of runs: one row per (scene, scale, mode, variant), made of
    that cell's repeats (its runs with distinct seeds; of runs with the same seed, the latest).

    Every statistic (faces, vertices, time per frame: min, max, mean) is the median over the
    repeats of the per-run value; ``time_mean_lo_s``/``time_mean_hi_s`` are the smallest and
    largest per-run means. Speed-up: per seed, the adaptive run's mean time per frame (default
    variant, same scene and scale) over this row's run of that seed; ``speedup`` is the median over
    the seeds both have, ``speedup_lo``/``speedup_hi`` their range. A row whose repeats differ in
    commit (code, with the uncommitted diff), frames or scale is refused: it is left out and named
    in ``.attrs['problems']``, as is a speed-up whose baseline ran other code or other frames.
    Notes (superseded runs, missing baselines) are in ``.attrs['notes']``."""
    runs = runs[~runs["reference"].astype(bool)] if len(runs) else runs
    if runs.empty:
        out = pd.DataFrame(columns=list(TABLE1_COLUMNS))
        out.attrs["notes"], out.attrs["problems"] = [], []
        return out
    if "seed" not in runs.columns:
        runs = runs.assign(seed=0)
    runs = runs.assign(seed=runs["seed"].fillna(0).astype(int),
                       code=runs["code"].fillna("") if "code" in runs.columns else "")
    chosen, notes = latest(runs, (*ROW_KEY, "seed"))
    problems: list[str] = []
    groups = {}
    for key, g in chosen.groupby(list(ROW_KEY), sort=False, dropna=False):
        bad = disagreement(g)
        if bad:
            problems.append(f"Table 1 row {_label(key)} refused: its runs differ in {bad} "
                            f"({', '.join(sorted(g['run']))})")
            continue
        groups[key] = g.sort_values("seed")
    rows = []
    for key, g in groups.items():
        scene, scale, mode, variant = key
        base = None
        for bkey in ((scene, scale, "adaptive", ""), (scene, scale, "adaptive", "adaptive")):
            if bkey in groups:
                base = groups[bkey]
        speed = {}
        if base is None:
            notes.append(f"{_label(key)}: no adaptive run of {scene} ({scale or 'no scale'}) in the table: "
                         "speed-up left out")
        elif disagreement(pd.concat([g, base])):
            problems.append(f"Table 1 row {_label(key)}: speed-up refused: its adaptive baseline differs in "
                            f"{disagreement(pd.concat([g, base]))}")
        else:
            b = base.set_index("seed")["time_mean_s"]
            speed = {s: b[s] / t for s, t in zip(g["seed"], g["time_mean_s"]) if s in b.index}
            if not speed:
                notes.append(f"{_label(key)}: no seed in common with its adaptive runs: speed-up left out")
        ratios = pd.Series(list(speed.values()), dtype=float)
        rows.append({"scene": scene, "scale": scale, "mode": mode, "variant": variant,
                     "frames": int(g["frames"].iloc[0]),
                     **{c: float(g[c].median()) for c in TABLE1_COLUMNS[5:15]},
                     "time_mean_lo_s": float(g["time_mean_s"].min()), "time_mean_hi_s": float(g["time_mean_s"].max()),
                     "repeats": len(g), "seeds": " ".join(str(s) for s in g["seed"]),
                     "speedup": float(ratios.median()) if len(ratios) else math.nan,
                     "speedup_lo": float(ratios.min()) if len(ratios) else math.nan,
                     "speedup_hi": float(ratios.max()) if len(ratios) else math.nan,
                     "code": str(g["code"].iloc[0]),
                     "baseline": " ".join(base["run"]) if speed else "", "run": " ".join(g["run"])})
    out = _order(pd.DataFrame(rows, columns=list(TABLE1_COLUMNS)))
    out.attrs["notes"] = sorted(set(notes))
    out.attrs["problems"] = problems
    return out


def write_runs(runset: RunSet, out_dir) -> list[Path]:
    """runs.csv, frames.parquet (every frame of every run), accuracy_frames.parquet (when any),
    problems.txt, atomically."""
    out_dir = Path(out_dir)
    files = [out_dir / "runs.csv", out_dir / "frames.parquet", out_dir / "problems.txt"]
    write_text_atomic(files[0], runset.runs.to_csv(index=False))
    write_parquet_atomic(files[1], runset.frames)
    write_text_atomic(files[2], "".join(f"{p}\n" for p in runset.problems))
    if len(runset.accuracy):
        files.append(out_dir / "accuracy_frames.parquet")
        write_parquet_atomic(files[-1], runset.accuracy)
    return files


# ---- command line ----------------------------------------------------------------------------------

def report_problems(problems, stream=None) -> None:
    stream = stream or sys.stderr
    for p in problems:
        print(f"warning: {p}", file=stream)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.aggregate",
                                 description="Tables of run folders (never re-simulating): runs, frames, Table 1.")
    ap.add_argument("roots", nargs="+", type=Path, help="folders searched for run folders")
    ap.add_argument("--out", type=Path, default=None,
                    help="write runs.csv, frames.parquet, table1.{csv,md,tex}, table1_paper.csv, problems.txt here "
                         "(default: print Table 1 only)")
    args = ap.parse_args(argv)
    try:
        check_roots(args.roots)
    except AggregateError as exc:
        print(f"aggregate: {exc}", file=sys.stderr)
        return 2
    runset = load_runs(args.roots, warn=False)
    report_problems(runset.problems)
    print(f"{len(runset.runs)} run(s) loaded, {sum(p.reason.startswith('skipped') for p in runset.problems)} "
          f"folder(s) skipped")
    if runset.runs.empty:
        print("aggregate: no usable run folder under " + ", ".join(map(str, args.roots)), file=sys.stderr)
        return 1
    t1 = table1(table1_runs(runset.runs))
    refused = [Problem(Path(args.out or ".") / "table1.md", p) for p in t1.attrs["problems"]]
    report_problems(refused)
    runset.problems.extend(refused)
    print(table1_markdown(t1))
    if args.out is not None:
        files = write_runs(runset, args.out) + write_table1(t1, args.out)
        for f in files:
            print(f"wrote {f}")
    return 0

