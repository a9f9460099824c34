"""Crowds beyond the paper: the view-dependent speed-up over adaptive against the crowd's size.

    python -m paper_figures.crowd_scaling ROOT [ROOT ...] [--out DIR]

Runs: the crowd_scaling study's (conf/experiment/crowd_scaling.yaml: multiple_dancers with 1, 10
and 100 dancers, adaptive and viewdep); each mode with its default settings, never a reference.
A run's crowd size is its number of characters (summary.json). Writes crowd_scaling.csv and .md,
one row per scale and crowd size:

* adaptive_s / viewdep_s: simulation time per frame of the whole crowd (a crowd's frame is the sum
  over its characters, cloth.runner.combine_crowd), as Table 1 computes it: the mean over the
  frames of each run, then the median over the repeats (runs with distinct seeds; of runs with the
  same seed, the latest); ..._per_character_s the same over the number of dancers;
* adaptive_faces / viewdep_faces: mean faces of the crowd per frame, median over the repeats;
* speedup: per seed, adaptive's time per frame / viewdep's; the median over the seeds both modes
  have, speedup_lo / speedup_hi their range;
* speedup_grows: whether the speed-up is larger than at the next smaller crowd (empty for the
  smallest); the Markdown says whether it grows with the crowd over every size.

A size whose runs (both modes) ran other code (commit and uncommitted diff) or other frame counts
is refused: left out, and named in problems.txt.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from cloth.io.manifest import write_text_atomic
from experiments.analysis.aggregate import Problem, disagreement, is_default_variant, latest
from experiments.analysis.tables import md_table

from .common import RunSet, Skip, script_main

STUDY = "crowd_scaling"
SCENE = "multiple_dancers"
MODES = ("adaptive", "viewdep")
COLUMNS = ("scale", "dancers", "frames", "repeats", "adaptive_s", "viewdep_s", "adaptive_per_character_s",
           "viewdep_per_character_s", "adaptive_faces", "viewdep_faces", "speedup", "speedup_lo", "speedup_hi",
           "speedup_grows", "runs")


def scaling_runs(runs: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """The study's runs of each mode with its default settings, the latest per (scale, size, mode,
    seed); and a note per run left out as superseded."""
    if runs.empty or "study" not in runs.columns:
        return runs.iloc[0:0], []
    sel = runs[(runs["study"] == STUDY) & (runs["scene"] == SCENE) & runs["mode"].isin(MODES)
               & ~runs["reference"].astype(bool)]
    sel = sel[sel.apply(is_default_variant, axis=1)] if len(sel) else sel
    if sel.empty:
        return sel, []
    sel = sel.assign(dancers=sel["characters"].astype(int))
    return latest(sel, ("scale", "dancers", "mode", "seed"))


def _grows(speedups: list[float]) -> list:
    """Per size, in increasing order: whether its speed-up is above the previous size's (None for
    the first, or where either is missing)."""
    out = [None]
    for prev, cur in zip(speedups, speedups[1:]):
        out.append(None if math.isnan(prev) or math.isnan(cur) else bool(cur > prev))
    return out


def crowd_scaling_table(runs: pd.DataFrame) -> pd.DataFrame:
    """The table of the module docstring from a runs table (experiments.analysis.aggregate.load_runs);
    `.attrs['notes']` and `.attrs['problems']` as Table 1's, `.attrs['verdict']` per scale: True
    when the speed-up grows from each crowd size to the next, False when it does not, None when
    fewer than two sizes have one."""
    sel, notes = scaling_runs(runs)
    rows, problems = [], []
    for (scale, dancers), g in (sel.groupby(["scale", "dancers"], sort=True) if len(sel) else ()):
        bad = disagreement(g)
        if bad:
            problems.append(f"{STUDY} {scale}/{dancers} dancers: its runs differ in {bad}")
            continue
        row = {"scale": scale, "dancers": int(dancers), "frames": int(g["frames"].iloc[0])}
        by_mode = {m: g[g["mode"] == m] for m in MODES}
        row["repeats"] = int(max(len(r) for r in by_mode.values()))
        for m, r in by_mode.items():
            row[f"{m}_s"] = float(r["time_mean_s"].median()) if len(r) else math.nan
            row[f"{m}_per_character_s"] = row[f"{m}_s"] / int(dancers)
            row[f"{m}_faces"] = float(r["faces_mean"].median()) if len(r) else math.nan
        times = {m: r.set_index("seed")["time_mean_s"] for m, r in by_mode.items()}
        seeds = sorted(set(times["adaptive"].index) & set(times["viewdep"].index))
        ratios = np.array([times["adaptive"][s] / times["viewdep"][s] for s in seeds], dtype=float)
        if not len(ratios):
            missing = [m for m in MODES if by_mode[m].empty]
            notes.append(f"{STUDY} {scale}/{dancers} dancers: no speed-up: "
                         + (f"no {' or '.join(missing)} run" if missing else "no seed that both modes ran"))
        row["speedup"] = float(np.median(ratios)) if len(ratios) else math.nan
        row["speedup_lo"] = float(ratios.min()) if len(ratios) else math.nan
        row["speedup_hi"] = float(ratios.max()) if len(ratios) else math.nan
        row["runs"] = ", ".join(sorted(g["run"]))
        rows.append(row)
    table = pd.DataFrame(rows, columns=[c for c in COLUMNS if c != "speedup_grows"])
    grows, verdict = [], {}
    for scale, t in table.groupby("scale", sort=False):
        g = _grows(t["speedup"].tolist())
        grows += g
        known = [v for v in g[1:] if v is not None]
        verdict[scale] = all(known) if len(known) == len(g) - 1 and known else None
    table.insert(COLUMNS.index("speedup_grows"), "speedup_grows", pd.Series(grows, index=table.index, dtype=object))
    table.attrs.update(notes=notes, problems=problems, verdict=verdict)
    return table


def _num(v, fmt: str) -> str:
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)


def crowd_scaling_markdown(t: pd.DataFrame) -> str:
    """The table as Markdown, with the verdict per scale, the definitions and the notes."""
    out = ["# Crowd scaling: the view-dependent speed-up over adaptive against the crowd's size", ""]
    header = ["scale", "dancers", "frames", "runs", "adaptive s/frame", "view-dep. s/frame", "adaptive s/frame/dancer",
              "view-dep. s/frame/dancer", "adaptive faces", "view-dep. faces", "speed-up (range)", "grows"]
    rows = []
    for r in t.itertuples():
        speed = _num(r.speedup, "{:.2f}×")
        if speed and r.repeats > 1:
            speed += f" ({r.speedup_lo:.2f}–{r.speedup_hi:.2f})"
        grows = "" if r.speedup_grows is None else ("yes" if r.speedup_grows else "no")
        rows.append([str(r.scale), str(r.dancers), str(r.frames), str(r.repeats),
                     _num(r.adaptive_s, "{:.3f}"), _num(r.viewdep_s, "{:.3f}"),
                     _num(r.adaptive_per_character_s, "{:.3f}"),
                     _num(r.viewdep_per_character_s, "{:.3f}"), _num(r.adaptive_faces, "{:,.0f}"),
                     _num(r.viewdep_faces, "{:,.0f}"), speed, grows])
    out += [md_table(header, rows, "ll" + "r" * 10), ""]
    for scale, v in t.attrs.get("verdict", {}).items():
        sizes = t[t["scale"] == scale]
        path = " → ".join(f"{d}: {_num(s, '{:.2f}×') or '?'}" for d, s in zip(sizes["dancers"], sizes["speedup"]))
        said = {True: "grows with the crowd", False: "does not grow with the crowd at every step",
                None: "cannot be told (fewer than two crowd sizes with a speed-up)"}[v]
        out.append(f"At scale={scale} the speed-up {said} ({path}).")
    out += ["", "Time per frame: simulation only (sim_s, I/O apart) of the whole crowd, the sum over its characters; "
            "the mean over the frames of each run, the median over the runs (seeds). Speed-up: per seed, adaptive's "
            "time per frame over the view-dependent one's; the median over the seeds, their range in brackets.", ""]
    out += [f"- note: {n}" for n in t.attrs.get("notes", [])]
    out += [f"- refused: {p}" for p in t.attrs.get("problems", [])]
    return "\n".join(out) + "\n"


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    """crowd_scaling.csv and crowd_scaling.md of the crowd_scaling study's runs."""
    t = crowd_scaling_table(runset.runs)
    for problem in t.attrs["problems"]:
        log(f"crowd_scaling: {problem}")
        runset.problems.append(Problem(Path(out) / "crowd_scaling.md", problem))
    if t.empty:
        raise Skip(f"no completed run of the {STUDY} study")
    out = Path(out)
    files = [out / "crowd_scaling.csv", out / "crowd_scaling.md"]
    write_text_atomic(files[0], t.to_csv(index=False))
    write_text_atomic(files[1], crowd_scaling_markdown(t))
    return files


def main(argv=None) -> int:
    return script_main(make, "crowd_scaling", argv)


if __name__ == "__main__":
    sys.exit(main())
