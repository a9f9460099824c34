"""Several cameras at once (beyond the paper): what a second camera costs, and what each camera sees.

    python -m paper_figures.cameras ROOT [ROOT ...] [--out DIR]

Runs: the cameras study's (conf/experiment/cameras.yaml: solo_dancer, adaptive, the paper's method
with the scene's camera, and with the side camera as well, conf/point/cameras/two.yaml; against the
fine reference) and the cameras_crowd study's (multiple_dancers, the same points, no reference: a
crowd's windows cannot be restarted one character at a time). Writes cameras.csv and .md, one row
per scene, scale and point:

* faces_mean, time_mean_s: the runs' mean faces and simulation time per frame, medians over seeds;
  faces_vs_adaptive, time_vs_adaptive: adaptive's over the point's (above 1: fewer, faster);
* sync_error_px_mean (lo, hi): the re-synchronised error seen from the scene's own camera, and
  sync_error_px_view_<name>_mean (lo, hi): from each further view the study measures (the
  callback's sync.views), mean over the windows of every seed with its 90 % BCa interval (each
  seed's windows restart from its own reference: the windows of all seeds are one sample).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.analysis.accuracy import bootstrap_mean_interval
from experiments.analysis.aggregate import latest
from experiments.analysis.sync import read_windows

from .common import RunSet, Skip, script_main, write_table

STUDIES = ("cameras", "cameras_crowd")


def camera_table(runs: pd.DataFrame) -> pd.DataFrame:
    """The table of the module docstring from a runs table (empty without the studies' runs)."""
    if runs.empty or "study" not in runs.columns:
        return pd.DataFrame()
    sel = runs[runs["study"].isin(STUDIES) & ~runs["reference"].astype(bool)]
    if sel.empty:
        return pd.DataFrame()
    sel, _ = latest(sel, ("scene", "scale", "variant", "seed"))
    views = sorted(c[: -len("_mean")] for c in sel.columns
                   if c.startswith("sync_error_px_view_") and c.endswith("_mean"))
    rows = []
    for (scene, scale), g in sel.groupby(["scene", "scale"], sort=False):
        base = g[g["mode"] == "adaptive"]
        base_faces = float(base["faces_mean"].median()) if len(base) else np.nan
        base_time = float(base["time_mean_s"].median()) if len(base) else np.nan
        for variant, h in g.groupby("variant", sort=False):
            first = h.sort_values("seed").iloc[0]
            faces, time = float(h["faces_mean"].median()), float(h["time_mean_s"].median())
            row = {"scene": scene, "scale": scale, "variant": variant, "mode": first["mode"], "seeds": int(len(h)),
                   "faces_mean": faces, "time_mean_s": time, "faces_vs_adaptive": base_faces / faces,
                   "time_vs_adaptive": base_time / time}
            for col in ("sync_error_px", *views):
                row.update(_pooled_error(h, col, first))
            rows.append(row)
    return pd.DataFrame(rows)


def _pooled_error(h: pd.DataFrame, col: str, first) -> dict:
    """{col_mean, col_lo, col_hi}: the windows of every seed's run (sync.parquet) as one sample, its
    mean and 90 % BCa interval; a run folder without windows falls back to the first seed's summary."""
    parts = [read_windows(p, col) for p in h["path"]] if "path" in h.columns else []
    if parts and all(w is not None for w in parts):
        err = np.concatenate([w.to_numpy(float) for w in parts])
        err = err[np.isfinite(err)]
        lo, hi = bootstrap_mean_interval(err)
        return {f"{col}_mean": float(err.mean()) if err.size else np.nan, f"{col}_lo": lo, f"{col}_hi": hi}
    return {f"{col}_{part}": float(first[f"{col}_{part}"]) if f"{col}_{part}" in h.columns
            and pd.notna(first.get(f"{col}_{part}")) else np.nan for part in ("mean", "lo", "hi")}


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    table = camera_table(runset.runs)
    if table.empty:
        raise Skip("cameras: no runs of the cameras studies")
    return write_table(table, out, "cameras",
                       "Several cameras at once: faces and simulation time per frame (medians over seeds) and "
                       "their ratios to adaptive's, and the re-synchronised error (px, 90 % BCa interval over the "
                       "windows of every seed) seen from the scene's camera and from each further view")


def main(argv=None) -> int:
    return script_main(make, "cameras", argv)


if __name__ == "__main__":
    sys.exit(main())
