"""Table 1 as the paper prints it, and as text: the paper's own numbers, Markdown and LaTeX
(booktabs) of the Table 1 that experiments.aggregate computes, and the files they go to.

Nothing here reads run folders: the functions take our table (experiments.analysis.aggregate.table1:
the columns of experiments.analysis.aggregate.TABLE1_COLUMNS, notes in ``.attrs['notes']``) and the
paper's (:func:`paper_table1`). Numbers: counts with thousands separators, times with the paper's
2 decimals (more when our times per frame are short, see :func:`_time_digits`), speed-ups as
``2.39×``; an empty cell for a missing value (NaN).
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from cloth.io.manifest import write_text_atomic

PAPER_SCENES = {"karate": "Karate", "solo_dancer": "Solo Dancer", "multiple_dancers": "Multiple Dancers"}

# The paper's Table 1 (Koh, Narain, O'Brien 2015, TVCG; 4 threads of a Xeon E5-2680 v2), as printed:
# scene -> mode -> (faces min, max, mean, vertices min, max, mean, s/frame min, max, mean, speed-up).
PAPER_TABLE1 = {
    "karate": {
        "nonadaptive": (123790, 123790, 123790, 63889, 63889, 63889, 136.47, 288.01, 161.44, 0.49),
        "adaptive": (25785, 71142, 41973, 14135, 37199, 22358, 31.41, 184.39, 79.04, 1.0),
        "viewdep": (5223, 39139, 21501, 3142, 20770, 11670, 5.52, 83.29, 33.02, 2.39),
    },
    "solo_dancer": {
        "nonadaptive": (43710, 43710, 43710, 22736, 22736, 22736, 27.31, 58.09, 29.27, 0.54),
        "adaptive": (12030, 21763, 18041, 6593, 11535, 9659, 7.78, 22.00, 15.80, 1.0),
        "viewdep": (730, 15951, 9638, 560, 8599, 5314, 0.83, 13.81, 7.55, 2.09),
    },
    "multiple_dancers": {
        "nonadaptive": (437100, 437100, 437100, 227360, 227360, 227360, 273.13, 580.85, 292.73, 0.47),
        "adaptive": (119515, 184340, 161028, 65505, 98630, 86897, 79.97, 178.24, 136.99, 1.0),
        "viewdep": (11216, 102945, 36339, 7619, 56285, 21228, 12.02, 82.54, 30.76, 4.45),
    },
}
PAPER_COLUMNS = ("faces_min", "faces_max", "faces_mean", "verts_min", "verts_max", "verts_mean", "time_min_s",
                 "time_max_s", "time_mean_s", "speedup")
PAPER_SOURCE = "Koh, Narain, O'Brien 2015, Table 1"
MODE_LABELS = {"nonadaptive": "Non-adaptive", "adaptive": "Adaptive", "viewdep": "View-dependent"}


def paper_table1() -> pd.DataFrame:
    """The paper's Table 1 as printed (PAPER_TABLE1), one row per scene and mode."""
    rows = [{"scene": s, "paper_scene": PAPER_SCENES[s], "mode": m, **dict(zip(PAPER_COLUMNS, v))}
            for s, modes in PAPER_TABLE1.items() for m, v in modes.items()]
    return pd.DataFrame(rows)


def side_by_side(ours: pd.DataFrame, paper: pd.DataFrame | None = None) -> pd.DataFrame:
    """Our rows of the paper's scenes (default variants, the view-dependent mode without the
    contact floor, the paper's method as published, and every fixed mesh: Table 1's is the one of
    adaptive's quality, e.g. 'fixed x1.14') paired with the paper's row of the same scene and mode:
    faces mean, time per frame mean and speed-up, ours and the paper's."""
    paper = paper_table1() if paper is None else paper
    mine = ours[ours["scene"].isin(list(PAPER_SCENES))
                & (ours["variant"].isin(["", "viewdep_nofloor"]) | (ours["variant"] == ours["mode"])
                   | (ours["mode"] == "nonadaptive"))]
    merged = mine.merge(paper, on=["scene", "mode"], how="inner", suffixes=("", "_paper"))
    return merged[["scene", "scale", "mode", "variant", "faces_mean", "faces_mean_paper", "time_mean_s",
                   "time_mean_s_paper", "speedup", "speedup_paper"]]


def face_ratios(ours: pd.DataFrame, paper: pd.DataFrame | None = None) -> pd.DataFrame:
    """Mean faces of every row over the adaptive row's (same scene and scale), ours and, for the
    paper's scenes and modes, the paper's: how much finer or coarser each mode's mesh is (the
    paper's fixed meshes have 2.4-2.9x the adaptive mean faces)."""
    paper = paper_table1() if paper is None else paper
    pf = paper.set_index(["scene", "mode"])["faces_mean"]
    rows = []
    for (scene, scale), g in ours.groupby(["scene", "scale"], sort=False):
        base = g[(g["mode"] == "adaptive") & g["variant"].isin(["", "adaptive"])]
        if len(base) != 1:
            continue
        for r in g.itertuples():
            p = (pf.get((scene, r.mode), math.nan) / pf.get((scene, "adaptive"), math.nan)
                 if (scene, "adaptive") in pf.index and (r.variant in ("", r.mode, "viewdep_nofloor")
                                                          or r.mode == "nonadaptive") else math.nan)
            rows.append({"scene": scene, "scale": scale, "mode": r.mode, "variant": r.variant,
                         "faces_ratio": r.faces_mean / base["faces_mean"].iloc[0], "faces_ratio_paper": p})
    return pd.DataFrame(rows, columns=["scene", "scale", "mode", "variant", "faces_ratio", "faces_ratio_paper"])


def _int(v) -> str:
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{int(round(v)):,}"


def _sec(v, digits: int) -> str:
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def _x(v) -> str:
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.2f}×"


def _time_digits(t: pd.DataFrame) -> int:
    """Decimals for times: the paper's 2, more when our times are short (small scale)."""
    m = t["time_min_s"].min() if len(t) else 1.0
    return 2 if m >= 1 else 3 if m >= 0.01 else 4


def md_table(header: list[str], rows, align: str = "") -> str:
    """The one Markdown table writer of the harness: `header`, then `rows` (lists of cells, made
    strings here), columns aligned by `align` ('l' or 'r' per column; left where it is short).
    No trailing newline."""
    align = align.ljust(len(header), "l")
    lines = ["| " + " | ".join(str(h) for h in header) + " |",
             "| " + " | ".join("---:" if a == "r" else "---" for a in align[:len(header)]) + " |"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def markdown(t: pd.DataFrame) -> str:
    """A DataFrame as a Markdown table (md_table), floats to 3 significant digits (the stability
    suite's and compare_modes' tables)."""
    fmt = lambda v: f"{v:.3g}" if isinstance(v, float) else str(v)  # noqa: E731
    return md_table(list(t.columns), [[fmt(v) for v in row] for row in t.itertuples(index=False)]) + "\n"


def _with_range(v: str, lo: str, hi: str, repeats) -> str:
    """`v (lo–hi)` for a row of several repeats, else `v`."""
    return f"{v} ({lo}–{hi})" if v and _n(repeats) > 1 else v


def _n(v) -> int:
    try:
        return 0 if v is None or (isinstance(v, float) and math.isnan(v)) else int(v)
    except (TypeError, ValueError):
        return 0


def _ours_cells(t: pd.DataFrame) -> tuple[list[str], list[list[str]], str]:
    d = _time_digits(t)
    header = ["scene", "scale", "mode", "variant", "frames", "runs", "faces min", "faces max", "faces mean",
              "verts min", "verts max", "verts mean", "s/frame min", "s/frame max", "s/frame mean (range)",
              "I/O s/frame", "speed-up (range)"]
    rows = []
    for r in t.itertuples():
        reps = getattr(r, "repeats", 1)
        time_mean = _with_range(_sec(r.time_mean_s, d), _sec(getattr(r, "time_mean_lo_s", math.nan), d),
                                _sec(getattr(r, "time_mean_hi_s", math.nan), d), reps)
        lo, hi = getattr(r, "speedup_lo", math.nan), getattr(r, "speedup_hi", math.nan)
        speed = _with_range(_x(r.speedup), _x(lo)[:-1], _x(hi)[:-1], reps)
        rows.append([r.scene, r.scale, MODE_LABELS.get(r.mode, r.mode), r.variant if r.variant != r.mode else "",
                     str(r.frames), str(_n(reps) or 1), _int(r.faces_min), _int(r.faces_max), _int(r.faces_mean),
                     _int(r.verts_min), _int(r.verts_max), _int(r.verts_mean), _sec(r.time_min_s, d),
                     _sec(r.time_max_s, d), time_mean, _sec(r.io_mean_s, d), speed])
    return header, rows, "llllrrrrrrrrrrrrr"


def _paper_cells(p: pd.DataFrame) -> tuple[list[str], list[list[str]], str]:
    header = ["scene", "mode", "faces min", "faces max", "faces mean", "verts min", "verts max", "verts mean",
              "s/frame min", "s/frame max", "s/frame mean", "speed-up"]
    rows = [[r.paper_scene, MODE_LABELS[r.mode], _int(r.faces_min), _int(r.faces_max), _int(r.faces_mean),
             _int(r.verts_min), _int(r.verts_max), _int(r.verts_mean), _sec(r.time_min_s, 2), _sec(r.time_max_s, 2),
             _sec(r.time_mean_s, 2), _x(r.speedup)] for r in p.itertuples()]
    return header, rows, "llrrrrrrrrrr"


def table1_markdown(ours: pd.DataFrame, paper: pd.DataFrame | None = None) -> str:
    """Our Table 1, the paper's beside it, and the two side by side where scenes match."""
    paper = paper_table1() if paper is None else paper
    out = ["## Table 1: this project", ""]
    if len(ours):
        out.append(md_table(*_ours_cells(ours)))
    else:
        out.append("(no runs)")
    out += ["", "Time per frame in seconds of simulation (sizing, remeshing, physics, solve, collisions: the "
            "paper's Time/Frame), I/O apart. With several runs (repeats with distinct seeds) every number is the "
            "median over the runs of the per-run value, the mean's range in brackets the smallest and largest "
            "per-run mean. Speed-up = per seed, the adaptive run's mean time per frame (same scene and scale) / "
            "this row's; the median over the seeds, their range in brackets.", ""]
    for n in ours.attrs.get("notes", []):
        out.append(f"- note: {n}")
    for n in ours.attrs.get("problems", []):
        out.append(f"- refused: {n}")
    out += ["", f"## Table 1: the paper ({PAPER_SOURCE}; 4 threads of a Xeon E5-2680 v2)", "",
            md_table(*_paper_cells(paper)), ""]
    sbs = side_by_side(ours, paper)
    if len(sbs):
        d = _time_digits(ours)
        rows = [[r.scene, r.scale, MODE_LABELS.get(r.mode, r.mode) + (f" ({r.variant})" if r.variant not in
                 ("", r.mode) else ""), _int(r.faces_mean), _int(r.faces_mean_paper),
                 _sec(r.time_mean_s, d), _sec(r.time_mean_s_paper, 2), _x(r.speedup), _x(r.speedup_paper)]
                for r in sbs.itertuples()]
        out += ["## Side by side (means)", "", md_table(
            ["scene", "scale", "mode", "faces (ours)", "faces (paper)", "s/frame (ours)", "s/frame (paper)",
             "speed-up (ours)", "speed-up (paper)"], rows, "lllrrrrrr"), ""]
    ratios = face_ratios(ours, paper)
    if len(ratios):
        rows = [[r.scene, r.scale, MODE_LABELS.get(r.mode, r.mode) + (f" ({r.variant})" if r.variant not in
                ("", r.mode) else ""), f"{r.faces_ratio:.2f}", "" if math.isnan(r.faces_ratio_paper) else
                f"{r.faces_ratio_paper:.2f}"] for r in ratios.itertuples()]
        out += ["## Mean faces over the adaptive run's (nonadaptive : adaptive : view-dependent)", "",
                md_table(["scene", "scale", "mode", "ours", "paper"], rows, "lllrr"), ""]
    return "\n".join(out) + "\n"


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{",
        "}": r"\}", "×": r"$\times$", ",": "{,}"}


def _tex_escape(s: str) -> str:
    """LaTeX-safe text (a thousands comma as {,} so that it is not followed by a space)."""
    return "".join(_TEX.get(c, c) for c in s)


def _tex_table(header, rows, align, caption: str) -> str:
    lines = [r"\begin{table}[t]", r"\centering", rf"\caption{{{_tex_escape(caption).replace('{,}', ',')}}}",
             rf"\begin{{tabular}}{{{align}}}", r"\toprule", " & ".join(_tex_escape(h) for h in header) + r" \\",
             r"\midrule"]
    lines += [" & ".join(_tex_escape(c) for c in r) + r" \\" for r in rows]
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines)


def table1_latex(ours: pd.DataFrame, paper: pd.DataFrame | None = None) -> str:
    """Two booktabs tables: ours and the paper's."""
    paper = paper_table1() if paper is None else paper
    parts = ["% Table 1 of this project and of the paper (needs \\usepackage{booktabs})"]
    if len(ours):
        parts.append(_tex_table(*_ours_cells(ours), "Table 1, this project: faces, vertices and simulation time "
                                "per frame (s), I/O apart; speed-up against adaptive on the same scene."))
    parts.append(_tex_table(*_paper_cells(paper), f"Table 1 of the paper ({PAPER_SOURCE})."))
    return "\n\n".join(parts) + "\n"


def write_table1(ours: pd.DataFrame, out_dir, stem: str = "table1") -> list[Path]:
    """table1.csv (ours), table1_paper.csv, table1.md and table1.tex (both tables), atomically."""
    out_dir = Path(out_dir)
    paper = paper_table1()
    files = [out_dir / f"{stem}.csv", out_dir / f"{stem}_paper.csv", out_dir / f"{stem}.md", out_dir / f"{stem}.tex"]
    write_text_atomic(files[0], ours.to_csv(index=False))
    write_text_atomic(files[1], paper.assign(source=PAPER_SOURCE).to_csv(index=False))
    write_text_atomic(files[2], table1_markdown(ours, paper))
    write_text_atomic(files[3], table1_latex(ours, paper))
    return files
