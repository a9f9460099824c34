"""What the figure scripts share: the Agg backend, colours, atomic saving, the paper's per-frame
timings, run selection and the command line of a single script."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from cloth.io.manifest import atomic_write, write_text_atomic  # noqa: E402
from experiments.analysis.aggregate import latest, report_problems  # noqa: E402
from experiments.analysis.runs import AggregateError, RunSet, check_roots, load_runs  # noqa: E402
from experiments.analysis.tables import md_table  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = REPO_ROOT / "results" / "paper_figures"
DEFAULT_PAPER_TIMINGS = REPO_ROOT.parent / "shared" / "paper-timings"  # beside the clone in CI; optional
MODE_COLORS = {"nonadaptive": "tab:gray", "adaptive": "tab:blue", "viewdep": "tab:orange"}
MODE_MARKERS = {"nonadaptive": "s", "adaptive": "o", "viewdep": "^"}
MODE_NAMES = {"nonadaptive": "non-adaptive", "adaptive": "adaptive", "viewdep": "view-dependent"}
FIGURE_FORMATS = ("png", "pdf")  # PDF as well: line plots are cheap to write as vectors
DPI = 150

# The paper's per-frame records (../shared/paper-timings, see its README): (scene, mode) -> files;
# several files are one crowd (one per dancer), summed per frame.
PAPER_TIMING_FILES = {
    ("karate", "nonadaptive"): ("karate_hires.csv",),
    ("karate", "adaptive"): ("karate_rahuls.csv",),
    ("karate", "viewdep"): ("karate_vd.csv",),
    ("solo_dancer", "nonadaptive"): ("solo_hires_1.csv",),
    ("solo_dancer", "adaptive"): ("solo_rahuls_1.csv",),
    ("solo_dancer", "viewdep"): ("solo_vd_1.csv",),
    ("multiple_dancers", "viewdep"): tuple(f"crowd_vd_{i}.csv" for i in range(10)),
}
# The paper's Time/Frame is the sum of its simulation phases: our sim_s (cloth.core.records.SIM_PHASES).
PAPER_TIMING_COLUMNS = {"FrameNum": "frame", "Time/Frame": "sim_s", "Faces": "faces", "Verts": "verts"}


class Skip(Exception):
    """A figure or table that cannot be made from the runs at hand; the message says why."""


def color(mode: str) -> str:
    return MODE_COLORS.get(mode, "tab:purple")


def save_figure(fig, out_dir, stem: str) -> list[Path]:
    """Save `fig` as <stem>.png and .pdf in out_dir, each atomically (temporary file, then rename)."""
    out_dir = Path(out_dir)
    files = []
    for ext in FIGURE_FORMATS:
        target = out_dir / f"{stem}.{ext}"
        with atomic_write(target) as tmp:
            fig.savefig(tmp, format=ext, dpi=DPI, bbox_inches="tight")
        files.append(target)
    plt.close(fig)
    return files


def write_table(df: pd.DataFrame, out_dir, stem: str, title: str, floatfmt: str = "{:.4g}") -> list[Path]:
    """<stem>.csv (raw values) and <stem>.md (a Markdown table under `title`), atomically."""
    out_dir = Path(out_dir)

    def cell(v):
        if isinstance(v, (bool, np.bool_)):
            return "yes" if v else "no"
        if isinstance(v, (float, np.floating)):
            return "" if math.isnan(v) else floatfmt.format(v)
        return str(v)

    rows = [[cell(v) for v in row] for row in df.itertuples(index=False)]
    lines = [f"# {title}", "", md_table(list(df.columns), rows)]
    csv, md = out_dir / f"{stem}.csv", out_dir / f"{stem}.md"
    write_text_atomic(csv, df.to_csv(index=False))
    write_text_atomic(md, "\n".join(lines) + "\n")
    return [csv, md]


def place_labels(ax, xs, ys, texts, fontsize: float = 7, pad_px: float = 2.0, max_moves: int = 500) -> list:
    """Label the points (xs, ys) of `ax` with `texts` so that no label is drawn over another: each
    label starts just above right of its point and, taken from the lowest point up, moves up
    past every label already placed that it would overlap, with a thin leader line back to its
    point. Call it once the figure's layout is final (after tight_layout): it measures the labels
    as drawn. Returns the annotations."""
    fig = ax.figure
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    anchors = [ax.transData.transform((float(x), float(y))) for x, y in zip(xs, ys)]
    order = sorted(range(len(anchors)), key=lambda i: (anchors[i][1], anchors[i][0]))
    placed, anns = [], [None] * len(anchors)
    for i in order:
        dy = 3.0  # points above the point
        ann = ax.annotate(str(texts[i]), (float(xs[i]), float(ys[i])), xytext=(4, dy), textcoords="offset points",
                          fontsize=fontsize, annotation_clip=False,
                          arrowprops=dict(arrowstyle="-", lw=0.4, color="0.5", shrinkA=0, shrinkB=2))
        for _ in range(max_moves):
            box = _text_box(ann, renderer)
            clash = [b for b in placed if b.overlaps(box)]
            if not clash:
                break
            dy += (max(b.y1 for b in clash) - box.y0 + pad_px) * 72.0 / fig.dpi
            ann.set_position((4, dy))
        placed.append(_text_box(ann, renderer))
        anns[i] = ann
    return anns


def _text_box(ann, renderer):
    """The label's own box, without its leader line (an Annotation's extent includes the line)."""
    from matplotlib.text import Text  # noqa: PLC0415

    return Text.get_window_extent(ann, renderer)


def resolve_paper_timings(path) -> Path | None:
    """The paper-timings folder: `path` when given (AggregateError if it is not a folder), else
    DEFAULT_PAPER_TIMINGS when it exists, else None."""
    if path is None:
        return DEFAULT_PAPER_TIMINGS if DEFAULT_PAPER_TIMINGS.is_dir() else None
    p = Path(path)
    if not p.is_dir():
        raise AggregateError(f"--paper-timings {str(path)!r} is not a folder")
    return p


def read_paper_timings(folder) -> dict[tuple[str, str], pd.DataFrame]:
    """The paper's per-frame records: (scene, mode) -> frame, sim_s, faces, verts (a crowd's
    dancers summed per frame). A (scene, mode) whose files are absent or unreadable is left out."""
    out = {}
    if folder is None:
        return out
    folder = Path(folder)
    for key, names in PAPER_TIMING_FILES.items():
        try:
            tables = [pd.read_csv(folder / n, usecols=list(PAPER_TIMING_COLUMNS)).rename(columns=PAPER_TIMING_COLUMNS)
                      .set_index("frame") for n in names]
        except (OSError, ValueError):
            continue
        total = tables[0]
        for t in tables[1:]:
            total = total.add(t, fill_value=None).dropna()
        out[key] = total.reset_index()
    return out


def frame_times(frames: pd.DataFrame, frame_time_s: float) -> np.ndarray:
    """Simulated time (s) of each frame: sim_time_s, else frame x frame time, else the frame number."""
    if "sim_time_s" in frames.columns and frames["sim_time_s"].notna().all():
        return frames["sim_time_s"].to_numpy(float)
    if np.isfinite(frame_time_s):
        return frames["frame"].to_numpy(float) * frame_time_s
    return frames["frame"].to_numpy(float)


def time_unit(total_s: float) -> tuple[float, str]:
    """(divisor, unit) to show a cumulative time readably."""
    if total_s > 3 * 3600:
        return 3600.0, "h"
    if total_s > 180:
        return 60.0, "min"
    return 1.0, "s"


def study_or_all(runs: pd.DataFrame, *studies: str) -> pd.DataFrame:
    """The runs of the first of `studies` that has any, else all runs; never the fine references."""
    if runs.empty:
        return runs
    runs = runs[~runs["reference"].astype(bool)]
    for study in studies:
        s = runs[runs["study"] == study]
        if len(s):
            return s
    return runs


def _key(v):
    return "none" if v is None or (isinstance(v, float) and math.isnan(v)) else v


def one_factor(runs: pd.DataFrame, factor: str, others, refused: list | None = None) -> pd.DataFrame:
    """The runs among `runs` in which only `factor` varies: grouped by the `others` columns, the
    group with the most distinct values of `factor` (at least two), the latest run per value;
    empty when no group varies `factor`. With a list `refused`, every other run of `runs` is
    appended to it as (run, reason): the columns in which it differs from the chosen points, or
    the later run of its value that superseded it."""
    if runs.empty:
        return runs
    others = [c for c in others if c in runs.columns]  # a runs table of older code may lack some
    keys = runs[list(others)].apply(lambda r: tuple(_key(v) for v in r), axis=1)
    best, best_n, best_key = None, 1, None
    for k in keys.drop_duplicates():
        group = runs[keys == k]
        n = group[factor].map(_key).nunique()
        if n > best_n:
            best, best_n, best_key = group, n, k
    if best is None:
        if refused is not None:
            refused.extend((r.run, f"no other run varies only {factor}") for r in runs.itertuples())
        return runs.iloc[0:0]
    best = best.assign(_f=best[factor].map(_key))
    chosen, _ = latest(best, ("_f",))
    if refused is not None:
        for i, r in runs.iterrows():
            if i in chosen.index:
                continue
            if keys[i] == best_key:
                refused.append((r["run"], f"superseded by a later run of the same {factor}"))
                continue
            differ = [f"{c} {r[c]!r} (the points: {v!r})" for c, v, own in zip(others, best_key, keys[i]) if own != v]
            refused.append((r["run"], f"differs from the {factor} sweep's points in " + ", ".join(differ)))
    return chosen.drop(columns="_f")


def parse_and_load(prog: str, description: str, argv=None, extra=None):
    """The shared command line ROOT [ROOT ...] [--out DIR] [--paper-timings PATH] (and what
    `extra(parser)` adds): parse it, check the roots and the timings, load the runs and report the
    broken folders. Returns (args, paper timings or None, RunSet), or None after one message naming
    a bad argument."""
    ap = argparse.ArgumentParser(prog=f"python -m {prog}", description=description)
    if extra is not None:
        extra(ap)
    ap.add_argument("roots", nargs="+", type=Path, help="folders searched for run folders")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
    ap.add_argument("--paper-timings", type=Path, default=None,
                    help=f"the paper's per-frame records for Fig. 8 (default {DEFAULT_PAPER_TIMINGS}, if present)")
    args = ap.parse_args(argv)
    try:
        check_roots(args.roots)
        timings = resolve_paper_timings(args.paper_timings)
    except AggregateError as exc:
        print(f"{prog.rsplit('.', 1)[-1]}: {exc}", file=sys.stderr)
        return None
    runset = load_runs(args.roots, warn=False)
    report_problems(runset.problems)
    return args, timings, runset


def script_main(make, name: str, argv=None) -> int:
    """The command line of one figure script: ROOT [ROOT ...] [--out DIR] [--paper-timings PATH]."""
    loaded = parse_and_load(f"paper_figures.{name}", (make.__doc__ or "").split("\n")[0], argv)
    if loaded is None:
        return 2
    args, timings, runset = loaded
    try:
        files = make(runset, args.out, paper_timings=timings, log=print)
    except Skip as exc:
        print(f"{name}: skipped: {exc}")
        return 0
    for f in files:
        print(f"wrote {f}")
    return 0


__all__ = ["RunSet", "Skip", "place_labels", "save_figure", "write_table", "read_paper_timings",
           "resolve_paper_timings",
           "one_factor", "study_or_all", "parse_and_load", "script_main", "frame_times", "time_unit", "color"]
