"""Make every figure and table from the run folders under the roots:

    python -m paper_figures ROOT [ROOT ...] [--out DIR] [--paper-timings PATH]
                            [--report DIR] [--docs DIR [--readme PATH]] [--command TEXT]

Loads the runs once (experiments.aggregate: broken folders are reported by name and skipped),
then runs every script of paper_figures.FIGURES into DIR (default results/paper_figures/); a
figure whose runs are absent is skipped with a one-line note. Also writes runs.csv (one row per
run used) and problems.txt (the folders skipped, and why). Prints where every file went. Exit
Then writes the study report, REPORT/index.html (paper_figures.report; default ROOT/report/).
With --docs, also writes the measurement pages into DIR and the README's headline table
(paper_figures.docs: each page stamped with the runs' commit, machine and command). Exit
status: 0, or 1 when a script failed (the others still run), 2 on bad arguments.
"""

from __future__ import annotations

import importlib
import sys
import traceback
from pathlib import Path

from cloth.io.manifest import write_text_atomic

from . import FIGURES, docs, report
from .common import REPO_ROOT, Skip, parse_and_load


def _docs_args(ap) -> None:
    ap.add_argument("--docs", type=Path, default=None, metavar="DIR",
                    help="also write the measurement pages into DIR (docs/results) and the README's headline table")
    ap.add_argument("--readme", type=Path, default=REPO_ROOT / "README.md",
                    help="the README whose headline-table block --docs rewrites (default: the repository's)")
    ap.add_argument("--report", type=Path, default=None, metavar="DIR",
                    help="where the study report goes (index.html and its images; default: ROOT/report)")
    ap.add_argument("--pages", nargs="+", default=None, metavar="PAGE", choices=list(docs.PAGES),
                    help=f"with --docs: only these pages (of {', '.join(docs.PAGES)}); default every page "
                         "whose tables exist")
    ap.add_argument("--command", default=None,
                    help="the command that ran the runs, for the pages' stamp (default: ROOT/command.txt, "
                         "which python -m experiments.paper writes)")


def _job_command(roots) -> str | None:
    for root in roots:
        f = Path(root) / "command.txt"
        if f.is_file():
            return f.read_text().strip()
    return None


def main(argv=None) -> int:
    loaded = parse_and_load("paper_figures", __doc__.split("\n")[0], argv, extra=_docs_args)
    if loaded is None:
        return 2
    args, timings, runset = loaded
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
    write_text_atomic(files[1], "".join(f"{p}\n" for p in runset.problems))  # with what the figures refused
    command = args.command or _job_command(args.roots)
    files.append(report.write_report(args.out, runset.runs, args.report or args.roots[0] / "report", command=command))
    if args.docs is not None:
        page_command = "python -m paper_figures " + " ".join(sys.argv[1:] if argv is None else argv)
        files += docs.write_pages(args.out, runset.runs, args.docs, command=command, page_command=page_command,
                                  problems=runset.problems, pages=args.pages)
        if docs.update_readme(args.readme, args.out, runset.runs, args.docs, command, page_command):
            files.append(args.readme)
    print(f"\nfiles written ({len(files)}):")
    for f in files:
        print(f"  {f}")
    if failed:
        print(f"paper_figures: failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
