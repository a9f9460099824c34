"""Where the time goes: Table 1's runs phase by phase (what turns faces saved into time saved).

    python -m paper_figures.phases ROOT [ROOT ...] [--out DIR]

Runs: the table1 study's (never the fine references). Writes phases.csv and .md, one row per scene,
scale and variant: the runs' seeds, mean faces and implicit steps per frame, and for each phase of
the simulation time (sizing, remesh, physics, solve, collisions, and the collisions in their parts:
contacts, projection, the collision pass, untangling) its mean seconds per frame, the median over
the seeds; then for each phase its share of the frame, microseconds per face per step (the phase's
time over faces x steps, the benchmark's unit) and, beside the adaptive row of the same scene, the
ratio adaptive / this (above 1: cheaper than adaptive). The face ratio is in the same row: a
phase whose time ratio falls short of it does not shrink with the faces.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from cloth.core.records import COLLISION_PARTS, SIM_PHASES
from experiments.analysis.aggregate import latest

from .common import RunSet, Skip, script_main, write_table

STUDY = "table1"
PARTS = (*SIM_PHASES, *(f"collisions_{p}" for p in COLLISION_PARTS))


def per_run(frames: pd.DataFrame) -> dict:
    """One run's means per frame: faces, steps, sim_s and each of PARTS (seconds)."""
    out = {"faces": float(frames["faces"].mean()), "sim_s": float(frames["sim_s"].mean()),
           "steps": float(frames["steps"].mean()) if "steps" in frames.columns else np.nan}
    for p in PARTS:
        col = f"time_{p}_s"
        out[p] = float(frames[col].mean()) if col in frames.columns else np.nan
    return out


def phase_table(runset: RunSet) -> pd.DataFrame:
    """The table of the module docstring (empty without table1 runs)."""
    runs = runset.runs
    if runs.empty or "study" not in runs.columns:
        return pd.DataFrame()
    sel = runs[(runs["study"] == STUDY) & ~runs["reference"].astype(bool)]
    if sel.empty:
        return pd.DataFrame()
    sel, _ = latest(sel, ("scene", "scale", "variant", "seed"))
    frames = runset.frames
    stats = {r: per_run(frames[frames["run"] == r]) for r in sel["run"]}
    rows = []
    for (scene, scale, variant), g in sel.groupby(["scene", "scale", "variant"], sort=False):
        per = pd.DataFrame([stats[r] for r in g["run"]])
        med = per.median()
        row = {"scene": scene, "scale": scale, "variant": variant or g["mode"].iloc[0], "mode": g["mode"].iloc[0],
               "seeds": int(len(g)), "faces": med["faces"], "steps": med["steps"], "sim_s": med["sim_s"]}
        for p in PARTS:
            row[f"{p}_s"] = med[p]
            row[f"{p}_share"] = med[p] / med["sim_s"] if med["sim_s"] > 0 else np.nan
            row[f"{p}_us_per_face_step"] = 1e6 * med[p] / (med["faces"] * med["steps"])
        rows.append(row)
    table = pd.DataFrame(rows)
    for _, g in table.groupby(["scene", "scale"], sort=False):
        ad = g[g["mode"] == "adaptive"]
        if ad.empty:
            continue
        a = ad.iloc[0]
        table.loc[g.index, "faces_vs_adaptive"] = a["faces"] / g["faces"]
        for p in ("sim", *PARTS):
            table.loc[g.index, f"{p}_vs_adaptive"] = a[f"{p}_s"] / g[f"{p}_s"]
    return table


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    table = phase_table(runset)
    if table.empty:
        raise Skip("phases: no table1 runs")
    for _, r in table[table["mode"] == "viewdep"].iterrows():
        slow = [p for p in SIM_PHASES if r.get(f"{p}_vs_adaptive", np.nan) < r.get("faces_vs_adaptive", np.nan)]
        if slow:
            ratios = ", ".join(f"{p} {r[f'{p}_vs_adaptive']:.2f}x" for p in slow)
            log(f"phases: {r['scene']} ({r['scale']}) {r['variant']}: {r['faces_vs_adaptive']:.2f}x fewer faces than "
                f"adaptive, but only {ratios} cheaper")
    return write_table(table, out, "phases",
                       "Where the time goes: Table 1's runs phase by phase, seconds per frame (medians over the "
                       "seeds), share of the frame, microseconds per face per step, and adaptive's over each "
                       "row's (above 1: cheaper than adaptive; faces_vs_adaptive: the face ratio)")


def main(argv=None) -> int:
    return script_main(make, "phases", argv)


if __name__ == "__main__":
    sys.exit(main())
