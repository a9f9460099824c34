"""Table 1 (faces, vertices, time per frame, speed-up against adaptive) as CSV, Markdown and
LaTeX, with the paper's Table 1 beside it.

    python -m paper_figures.table1 ROOT [ROOT ...] [--out DIR]

Runs: the table1 study's when there are any, else every run (never the fine references); see
experiments.analysis.aggregate.table1 for duplicates and the speed-up, experiments.analysis.tables for the text.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from experiments.analysis.aggregate import Problem, table1, table1_runs
from experiments.analysis.tables import write_table1

from .common import RunSet, Skip, script_main
from .pareto import pareto_table


def baseline_notes(runs, t) -> list[str]:
    """Where the runs hold an accuracy study, the fixed mesh of adaptive's quality (the paper's
    baseline: paper_figures.pareto's equal_quality) named with its resolution and error, and
    whether Table 1's non-adaptive rows of that scene are that mesh."""
    notes = []
    pareto = pareto_table(runs)
    if pareto.empty:
        return notes
    for r in pareto[pareto["equal_quality"]].itertuples():
        group = pareto[(pareto["scene"] == r.scene) & (pareto["scale"] == r.scale)]
        ad = group[(group["mode"] == "adaptive") & group["variant"].isin(["adaptive"])]
        rows = t[(t["scene"] == r.scene) & (t["scale"] == r.scale) & (t["mode"] == "nonadaptive")]
        used = sorted({str(v) or "nonadaptive" for v in rows["variant"]}) if "variant" in rows.columns else []
        interval = (f" ({r.error_lo_px:.3g}-{r.error_hi_px:.3g})" if np.isfinite(r.error_lo_px) else "")
        adaptive = (f" against adaptive's {ad['error_px'].iloc[0]:.3g} px" if len(ad) else "")
        notes.append(
            f"the paper's baseline on {r.scene} ({r.scale}): the coarsest fixed mesh whose {r.error} is not told apart "
            f"as worse than adaptive's is {r.variant} ({r.faces_mean:,.0f} faces, {r.error_px:.3g} px{interval}"
            f"{adaptive}); Table 1's non-adaptive row{'s' if len(used) > 1 else ''} of {r.scene}: "
            f"{', '.join(used) if used else 'none'}")
    return notes


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    """Table 1 of the runs: table1.csv, table1_paper.csv, table1.md, table1.tex."""
    t = table1(table1_runs(runset.runs))
    if t.empty:
        raise Skip("no completed run")
    t.attrs["notes"] = [*t.attrs.get("notes", []), *baseline_notes(runset.runs, t)]
    for note in t.attrs.get("notes", []):
        log(f"table1: note: {note}")
    for problem in t.attrs.get("problems", []):  # rows refused: into problems.txt with the folders'
        log(f"table1: {problem}")
        runset.problems.append(Problem(Path(out) / "table1.md", problem))
    return write_table1(t, out)


def main(argv=None) -> int:
    return script_main(make, "table1", argv)


if __name__ == "__main__":
    sys.exit(main())
