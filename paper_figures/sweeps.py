"""Sweep figures: speed-up against adaptive and screen-space error against each parameter of the
view-dependent method (nu_out, buckling k, anticipation window T, margin).

    python -m paper_figures.sweeps ROOT [ROOT ...] [--out DIR]

Writes sweep_<param>.png/.pdf per parameter that varies and sweeps.csv/.md (every point). Runs
of a parameter: its study's (sweep_<param>) when present, else all; within each scene and scale,
the viewdep runs of one study in which only that parameter varies (experiments of one factor: the
other view settings, the occlusion test and the contact floor equal), the latest per value.
Speed-up = mean time per frame of the adaptive run of the point's study and seed / the point's;
error = the re-synchronised error (sync_error_px_mean, experiments.sync) where it was measured,
else the whole-run error_px_mean of accuracy.json (column `error` says which; absent points are
left out of that panel). The paper's value of each parameter is marked by a dashed line.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from experiments.analysis.aggregate import Problem, baseline_for

from .common import RunSet, Skip, one_factor, save_figure, script_main, study_or_all, write_table

# parameter -> (runs-table column, axis label, log axis, the paper's value)
PARAMETERS = {
    "nu_out": ("nu_out", r"$\nu_{out}$ (view factor far out of view)", True, 0.01),
    "k": ("buckling_k", "buckling exponent k (eq 11)", True, 10.0),
    "T": ("T", "anticipation window T (frames, eq 4)", False, 5.0),
    "margin": ("margin", "margin m (metres, eq 3)", False, 0.4),
}
# what a sweep's points must share besides the swept parameter: the other view settings, the
# occlusion test and contact floor, and the study (a sweep is of one study's runs, never mixed)
OTHERS = ("nu_out", "margin", "T", "anticipation", "l_min_px", "buckling_k", "buckling_mode", "occlusion",
          "contact_size", "study")


def sweep_points(runs: pd.DataFrame, param: str, refused: list | None = None) -> pd.DataFrame:
    """The points of one parameter's sweep: scene, scale, value, run, variant, faces_mean,
    time_mean_s, speedup, error_px_mean (one row per value per scene and scale). With a list
    `refused`, the view-dependent runs of the points' study that are not points go into it as
    (run, reason) (:func:`paper_figures.common.one_factor`)."""
    col = PARAMETERS[param][0]
    cand = study_or_all(runs, f"sweep_{param}")
    if cand.empty:
        return pd.DataFrame()
    vd = cand[(cand["mode"] == "viewdep") & cand[col].notna()]
    if param == "k":
        vd = vd[vd["buckling_mode"] == "adaptive"]
    rows = []
    for (scene, scale), group in vd.groupby(["scene", "scale"], sort=True):
        left: list = []
        pts = one_factor(group, col, [c for c in OTHERS if c != col], left)
        if pts.empty:
            continue
        if refused is not None:  # the runs of the points' own study left out (other studies' are not this sweep's)
            own = set(group.loc[group["study"] == pts["study"].iloc[0], "run"])
            refused.extend((run, why) for run, why in left if run in own)
        for r in pts.sort_values(col).itertuples():
            # the adaptive run of the point's own study and repeat (seed), never another study's
            base = baseline_for(cand[cand["study"] == r.study], scene, scale, seed=r.seed)
            sync = getattr(r, "sync_error_px_mean", np.nan)
            measure, error = ("sync_error_px", sync) if pd.notna(sync) else ("error_px_mean", r.error_px_mean)
            rows.append({"parameter": param, "scene": scene, "scale": scale, "value": float(getattr(r, col)),
                         "study": r.study, "run": r.run, "variant": r.variant, "faces_mean": r.faces_mean,
                         "time_mean_s": r.time_mean_s,
                         "speedup": base["time_mean_s"] / r.time_mean_s if base is not None else np.nan,
                         "baseline": base["run"] if base is not None else "", "error": measure, "error_px": error})
    return pd.DataFrame(rows)


def _figure(points: pd.DataFrame, param: str):
    _, label, log, paper_value = PARAMETERS[param]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for (scene, scale), g in points.groupby(["scene", "scale"], sort=True):
        name = f"{scene} ({scale})" if scale else scene
        axes[0].plot(g["value"], g["speedup"], "o-", label=name)
        axes[1].plot(g["value"], g["error_px"], "o-", label=name)
    axes[0].set_ylabel("speed-up against adaptive (x)")
    axes[0].axhline(1.0, color="0.5", lw=0.8)
    measures = set(points["error"].dropna())
    axes[1].set_ylabel("re-synchronised error (px)" if measures == {"sync_error_px"} else "screen-space error (px)")
    for ax, col in zip(axes, ("speedup", "error_px")):
        ax.set_xlabel(label)
        if log and (points["value"] > 0).all():
            ax.set_xscale("log")
        ax.axvline(paper_value, color="0.3", ls="--", lw=0.8, label="paper's value")
        ax.grid(alpha=0.3)
        if not points[col].notna().any():
            ax.text(0.5, 0.5, "not measured" if col == "error_px" else "no adaptive run",
                    transform=ax.transAxes, ha="center", va="center", color="0.4")
        ax.legend(fontsize=8)
    fig.suptitle(f"Sweep of {param}: what it buys in time and costs in accuracy")
    fig.tight_layout()
    return fig


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    """sweep_<param>.png/.pdf for every parameter swept in the runs, and sweeps.csv/.md."""
    files, tables, absent = [], [], []
    for param in PARAMETERS:
        refused: list = []
        pts = sweep_points(runset.runs, param, refused)
        for run, reason in refused:  # a run of the sweep that is not one of its points, named
            runset.problems.append(Problem(Path(out) / "sweeps.md", f"sweep of {param}: {run}: {reason}"))
        if pts.empty:
            absent.append(param)
            continue
        tables.append(pts)
        files += save_figure(_figure(pts, param), out, f"sweep_{param}")
    if not tables:
        raise Skip(f"no viewdep runs that vary only one of {', '.join(PARAMETERS)}")
    if absent:
        log(f"sweeps: no sweep of {', '.join(absent)} (no viewdep runs that vary only it)")
    files += write_table(pd.concat(tables, ignore_index=True), out, "sweeps",
                         "Sweeps: speed-up against adaptive and screen-space error per parameter value")
    return files


def main(argv=None) -> int:
    return script_main(make, "sweeps", argv)


if __name__ == "__main__":
    sys.exit(main())
