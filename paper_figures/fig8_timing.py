"""The paper's Fig. 8 for every scene: time per frame and cumulative time against the frame, one
curve per mode; the paper's own curves of the same scene beside ours when its per-frame records
(--paper-timings) are available.

    python -m paper_figures.fig8_timing ROOT [ROOT ...] [--out DIR] [--paper-timings PATH]

Writes fig8_<scene>_<scale>.png/.pdf. Runs: those of Table 1 (the table1 study's when present),
each mode with its default settings (variant empty or the mode's name), the latest per scene,
scale and mode.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from experiments.analysis.aggregate import MODES, is_default_variant, latest, table1_runs
from experiments.analysis.tables import PAPER_SCENES

from .common import MODE_NAMES, RunSet, Skip, color, read_paper_timings, save_figure, script_main, time_unit


def _curves(ax_frame, ax_cum, series: dict, title: str) -> None:
    """series: mode -> (frame numbers, seconds per frame)."""
    total = max((float(np.sum(t)) for _, t in series.values()), default=0.0)
    div, unit = time_unit(total)
    for mode, (f, t) in series.items():
        ax_frame.plot(f, t, color=color(mode), lw=0.9, label=MODE_NAMES.get(mode, mode))
        ax_cum.plot(f, np.cumsum(t) / div, color=color(mode), lw=1.2, label=MODE_NAMES.get(mode, mode))
    ax_frame.set_title(title)
    ax_frame.set_ylabel("time per frame (s)")
    ax_cum.set_ylabel(f"cumulative time ({unit})")
    ax_cum.set_xlabel("frame")
    ax_frame.set_ylim(bottom=0)
    ax_cum.set_ylim(bottom=0)
    for ax in (ax_frame, ax_cum):
        ax.grid(alpha=0.3)
    ax_frame.legend(fontsize=8)


def _mode_order(m: str) -> int:
    return MODES.index(m) if m in MODES else len(MODES)


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    """Fig. 8 per scene and scale: fig8_<scene>_<scale>.png/.pdf."""
    runs = table1_runs(runset.runs)
    if len(runs):
        # Table 1's fixed mesh is its baseline at whatever resolution the main job chose (the fixed
        # mesh of adaptive's quality, variant "fixed x1.4"); elsewhere a mode's default settings
        baseline = (runs["mode"] == "nonadaptive") & (runs["study"] == "table1")
        runs = runs[runs.apply(is_default_variant, axis=1) | baseline]
    if runs.empty:
        raise Skip("no run of a mode with its default settings")
    runs, _ = latest(runs, ("scene", "scale", "mode"))
    paper = read_paper_timings(paper_timings)
    files = []
    for (scene, scale), group in runs.groupby(["scene", "scale"], sort=True):
        ours = {}
        for r in sorted(group.itertuples(), key=lambda r: _mode_order(r.mode)):
            fr = runset.frames[runset.frames["run"] == r.run]
            ours[r.mode] = (fr["frame"].to_numpy(), fr["sim_s"].to_numpy(float))
        theirs = {m: (d["frame"].to_numpy(), d["sim_s"].to_numpy(float))
                  for m in MODES for (s, m2), d in paper.items() if s == scene and m2 == m}
        cols = 2 if theirs else 1
        fig, axes = plt.subplots(2, cols, figsize=(5.5 * cols, 6), squeeze=False, sharex="col")
        _curves(axes[0, 0], axes[1, 0], ours, f"{scene} ({scale or 'no scale'}): this project")
        if theirs:
            _curves(axes[0, 1], axes[1, 1], theirs, f"{PAPER_SCENES[scene]}: the paper (Koh et al. 2015)")
        fig.suptitle("Time per frame and cumulative time (the paper's Fig. 8)")
        fig.tight_layout()
        files += save_figure(fig, out, f"fig8_{scene}_{scale or 'none'}")
    return files


def main(argv=None) -> int:
    return script_main(make, "fig8_timing", argv)


if __name__ == "__main__":
    sys.exit(main())
