"""Make every figure and table from the run folders under the roots:

    python -m paper_figures ROOT [ROOT ...] [--out DIR] [--paper-timings PATH]

Loads the runs once (experiments.aggregate: broken folders are reported by name and skipped),
then runs every script of paper_figures.FIGURES into DIR (default results/paper_figures/); a
figure whose runs are absent is skipped with a one-line note. Also writes runs.csv (one row per
run used) and problems.txt (the folders skipped, and why). Prints where every file went. Exit
status: 0, or 1 when a script failed (the others still run), 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback
from pathlib import Path

from cloth.io.manifest import write_text_atomic
from experiments.aggregate import AggregateError, check_roots, load_runs, report_problems

from . import FIGURES
from .common import DEFAULT_OUT, DEFAULT_PAPER_TIMINGS, Skip, resolve_paper_timings


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m paper_figures", description=__doc__.split("\n")[0])
    ap.add_argument("roots", nargs="+", type=Path, help="folders searched for run folders")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
    ap.add_argument("--paper-timings", type=Path, default=None,
                    help=f"the paper's per-frame records for Fig. 8 (default {DEFAULT_PAPER_TIMINGS}, if present)")
    args = ap.parse_args(argv)
    try:
        check_roots(args.roots)
        timings = resolve_paper_timings(args.paper_timings)
    except AggregateError as exc:
        print(f"paper_figures: {exc}", file=sys.stderr)
        return 2
    runset = load_runs(args.roots, warn=False)
    report_problems(runset.problems)
    print(f"paper_figures: {len(runset.runs)} run(s) from {', '.join(map(str, args.roots))}"
          + (f"; the paper's timings from {timings}" if timings else "; no paper timings"))
    files = [args.out / "runs.csv", args.out / "problems.txt"]
    write_text_atomic(files[0], runset.runs.to_csv(index=False))
    write_text_atomic(files[1], "".join(f"{p}\n" for p in runset.problems))
    failed = []
    for name in FIGURES:
        module = importlib.import_module(f"paper_figures.{name}")
        try:
            files += module.make(runset, args.out, paper_timings=timings, log=print)
        except Skip as exc:
            print(f"{name}: skipped: {exc}")
        except Exception:  # noqa: BLE001 - one broken figure does not stop the others; say which
            failed.append(name)
            print(f"{name}: FAILED\n{traceback.format_exc()}", file=sys.stderr)
    print(f"\nfiles written ({len(files)}):")
    for f in files:
        print(f"  {f}")
    if failed:
        print(f"paper_figures: failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
