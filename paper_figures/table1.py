"""Table 1 (faces, vertices, time per frame, speed-up against adaptive) as CSV, Markdown and
LaTeX, with the paper's Table 1 beside it.

    python -m paper_figures.table1 ROOT [ROOT ...] [--out DIR]

Runs: the table1 study's when there are any, else every run (never the fine references); see
experiments.aggregate.table1 for duplicates and the speed-up, experiments.tables for the text.
"""

from __future__ import annotations

import sys
from pathlib import Path

from experiments.aggregate import Problem, table1, table1_runs
from experiments.tables import write_table1

from .common import RunSet, Skip, script_main


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    """Table 1 of the runs: table1.csv, table1_paper.csv, table1.md, table1.tex."""
    t = table1(table1_runs(runset.runs))
    if t.empty:
        raise Skip("no completed run")
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
