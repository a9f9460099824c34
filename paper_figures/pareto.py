"""What accuracy costs in time: error against mean simulation time per frame over every run that
has accuracy (all modes and sweep settings), coloured by mode, labelled by variant, the Pareto
front marked; one panel per scene and scale (errors of different scenes are not comparable).

The error is the re-synchronised error (``sync_error_px_mean``, experiments.sync: every run
restarted from the reference's states, H frames later, with its 90 % bootstrap interval over the
windows as error bars) where the runs have it, else the whole-run screen-space error
(``error_px_mean``, experiments.accuracy; no interval), which chaos swamps after about a second.

    python -m paper_figures.pareto ROOT [ROOT ...] [--out DIR]

Writes pareto.png/.pdf and pareto.csv/.md (every point; ``error`` names the measure). on_front
marks the front: no other run of the same scene and scale is at least as fast and at least as
accurate, and better in one; and its extra time buys an error that is told apart from every
faster run's: with the runs' windows (sync.parquet), the 90 % bootstrap interval of the mean
difference over the windows both have (the same restarts: paired) lies below 0; else, with
intervals, its interval lies wholly below the faster run's; and, where the study measured the
reference's own error (its restart from a reference twice as fine and from one with half the time
step: experiments.callbacks.reference_error), by at least RANK_FACTOR times that error, which the
equal-quality choice respects too.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from experiments.analysis.aggregate import MODES, baseline_for
from experiments.analysis.sync import paired_difference_interval, read_windows

from .common import MODE_MARKERS, MODE_NAMES, RunSet, Skip, color, place_labels, save_figure, script_main, write_table


def pareto_front(time_s, error, lo=None, hi=None, better=None, min_difference: float = 0.0) -> np.ndarray:
    """on_front[i]: no point j has time_j <= time_i and error_j <= error_i with one of them <; and
    for every j with time_j < time_i, i's error is told apart as lower: better[i, j] when given
    (a paired test), else hi_i < lo_j when intervals (lo, hi) are given; and in any case by at
    least `min_difference` (the reference's own error times RANK_FACTOR: below it the reference
    cannot rank two points)."""
    t, e = np.asarray(time_s, float), np.asarray(error, float)
    dominated = ((t[None, :] <= t[:, None]) & (e[None, :] <= e[:, None])
                 & ((t[None, :] < t[:, None]) | (e[None, :] < e[:, None])))
    front = ~dominated.any(axis=1)
    faster = t[None, :] < t[:, None]  # [i, j]: j is faster than i
    if min_difference > 0:
        front &= ~(faster & ~(e[None, :] - e[:, None] >= min_difference)).any(axis=1)
    if better is not None:
        front &= ~(faster & ~np.asarray(better, bool)).any(axis=1)
    elif lo is not None and hi is not None:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        apart = hi[:, None] < lo[None, :]  # [i, j]: i's interval wholly below j's
        front &= ~(faster & ~apart).any(axis=1)
    return front


def paired_better(paths) -> np.ndarray | None:
    """[i, j]: run i's re-synchronised error is lower than run j's, told apart by the 90 % bootstrap
    interval of their difference over the windows both have (experiments.sync: the same restarts);
    None unless every run has its windows."""
    windows = [read_windows(p) for p in paths]
    if any(w is None for w in windows):
        return None
    n = len(windows)
    out = np.zeros((n, n), dtype=bool)
    for i in range(n):
        for j in range(n):
            if i != j:
                _, hi = paired_difference_interval(windows[i], windows[j])
                out[i, j] = bool(hi < 0)
    return out


def _error_columns(g: pd.DataFrame) -> tuple[str, pd.Series, pd.Series | None, pd.Series | None]:
    """(measure, error, lo, hi) of a scene's runs: the re-synchronised error with its interval when
    every run has it, else the whole-run error without one."""
    if "sync_error_px_mean" in g.columns and g["sync_error_px_mean"].notna().all():
        return "sync_error_px", g["sync_error_px_mean"], g["sync_error_px_lo"], g["sync_error_px_hi"]
    return "error_px", g["error_px_mean"], None, None


# Two points whose errors differ by less than this many times the reference's own error are not
# ranked: the reference itself is that far from the truth, so it cannot tell which is closer.
RANK_FACTOR = 3.0


def reference_error(runs: pd.DataFrame, scene: str, scale: str) -> tuple[float, float]:
    """(own error, floor) in px of the references of a scene and scale: the largest of their errors
    against their checks (twice as fine, half the time step: experiments.callbacks.reference_error)
    and the largest perturbed-restart floor; NaN where not measured."""
    if runs.empty or "reference_error_fine_px" not in runs.columns:
        return math.nan, math.nan
    refs = runs[runs["reference"].astype(bool) & (runs["scene"] == scene) & (runs["scale"] == scale)]
    own = refs[["reference_error_fine_px", "reference_error_half_dt_px"]].to_numpy(float)
    floor = refs["reference_floor_px"].to_numpy(float)
    big = lambda a: float(np.nanmax(a)) if np.isfinite(a).any() else math.nan  # noqa: E731
    return big(own), big(floor)


def equal_quality_fixed(g: pd.DataFrame, measure: str, err: pd.Series, lo, hi,
                        min_difference: float = 0.0) -> str | None:
    """The run of the coarsest fixed mesh (fewest faces) whose error is not told apart as worse than
    the adaptive run's (the default adaptive run of the group): with windows, the 90 % interval of
    their paired difference does not lie above 0; with intervals only, its interval does not lie
    wholly above adaptive's; without either, its mean error is not above adaptive's. The paper's
    baseline: a fixed mesh "selected to match the visual quality of the adaptive simulations"
    (its Table 1 caption). A fixed mesh less than `min_difference` worse (RANK_FACTOR times the
    reference's own error) is never told apart as worse. None without an adaptive run or a fixed
    mesh that qualifies."""
    g = g.assign(_err=err.to_numpy(float), _lo=(lo.to_numpy(float) if lo is not None else np.nan),
                 _hi=(hi.to_numpy(float) if hi is not None else np.nan))
    ad = g[(g["mode"] == "adaptive") & g["variant"].isin(["", "adaptive"])]
    fixed = g[g["mode"] == "nonadaptive"].sort_values("faces_mean")
    if ad.empty or fixed.empty:
        return None
    a = ad.iloc[-1]
    fixed = same_solver(fixed, a)
    wa = read_windows(a["path"]) if measure == "sync_error_px" and "path" in g.columns else None
    for _, f in fixed.iterrows():
        wf = read_windows(f["path"]) if wa is not None else None
        if wa is not None and wf is not None:
            lo_d, _ = paired_difference_interval(wf, wa)
            worse = lo_d > 0
        elif np.isfinite(f["_lo"]) and np.isfinite(a["_hi"]):
            worse = f["_lo"] > a["_hi"]
        else:
            worse = f["_err"] > a["_err"]
        worse = worse and f["_err"] - a["_err"] >= min_difference
        if not worse:
            return f["run"]
    return None


# How a point integrates (the solver's bending and membrane Hessians, the implicit steps per frame; a
# setting missing from an older run's config is its default then, projected): a fixed mesh
# is judged against the adaptive run that integrates as it does.
INTEGRATION = {"bending_hessian": "projected", "membrane_hessian": "projected", "steps_per_frame": math.nan}


def _setting(v, default) -> str:
    """An integration setting as text, a missing one (NaN, None, '') as its default."""
    missing = v is None or v == "" or (isinstance(v, float) and math.isnan(v))
    return str(default if missing else v)


def same_solver(runs: pd.DataFrame, other) -> pd.DataFrame:
    """The runs that integrate as `other` does (INTEGRATION: bending Hessian and steps per frame;
    a column missing from a table written before it is not compared)."""
    keep = pd.Series(True, index=runs.index)
    for col, default in INTEGRATION.items():
        if col in runs.columns and col in other:
            keep &= runs[col].map(lambda v, d=default: _setting(v, d)) == _setting(other[col], default)
    return runs[keep]


# A point that integrates otherwise names it in its variant after this (conf/point/bending/,
# conf/point/steps/): "adaptive, bending gauss_newton" and "adaptive, 4 steps" are compared with
# the study's "adaptive".
OPTION_SEPARATOR = ", "


def integration_table(g: pd.DataFrame) -> pd.DataFrame:
    """Each run of `g` (one scene and scale's runs table with paths) whose variant names an
    integration option ("<base>, <option>") against the run of its base variant and mode: the
    paired difference other - base of sync_error_mm over the windows both have with its 90 % BCa
    interval, and both runs' simulation time per frame (free runs, and their windows). not_worse:
    the interval does not lie above 0 (the Gauss-Newton bending Hessian becomes the default only
    if so, issue 34). Columns variant, base, option, bending_hessian, membrane_hessian, steps_per_frame,
    diff_mm, lo_mm, hi_mm, windows, not_worse, time_s, base_time_s, speedup (base over other), window_time_s,
    base_window_time_s."""
    cols = ["variant", "base", "option", "bending_hessian", "membrane_hessian", "steps_per_frame", "diff_mm", "lo_mm",
            "hi_mm",
            "windows", "not_worse", "time_s", "base_time_s", "speedup", "window_time_s", "base_window_time_s"]
    rows = []
    variants = g["variant"].fillna("")
    if "path" not in g.columns:
        return pd.DataFrame(rows, columns=cols)
    for _, r in g[variants.str.contains(OPTION_SEPARATOR, regex=False)].iterrows():
        base_name, option = r["variant"].split(OPTION_SEPARATOR, 1)
        base = g[(variants == base_name) & (g["mode"] == r["mode"])]
        if base.empty:
            continue
        b = base.iloc[-1]
        wr, wb = read_windows(r["path"], "sync_error_mm"), read_windows(b["path"], "sync_error_mm")
        if wr is None or wb is None:
            continue
        x, y = wr.align(wb, join="inner")
        d = (x - y).to_numpy(float)
        d = d[np.isfinite(d)]
        lo, hi = paired_difference_interval(wr, wb)
        get = lambda row, key: float(row.get(key, np.nan))  # noqa: E731
        rows.append({"variant": r["variant"], "base": base_name, "option": option,
                     "bending_hessian": r.get("bending_hessian", ""), "membrane_hessian": r.get("membrane_hessian", ""),
                     "steps_per_frame": get(r, "steps_per_frame"),
                     "diff_mm": float(d.mean()) if d.size else np.nan, "lo_mm": lo, "hi_mm": hi,
                     "windows": int(d.size), "not_worse": bool(lo <= 0.0),
                     "time_s": get(r, "time_mean_s"), "base_time_s": get(b, "time_mean_s"),
                     "speedup": get(b, "time_mean_s") / get(r, "time_mean_s"),
                     "window_time_s": get(r, "sync_sim_s_mean"), "base_window_time_s": get(b, "sync_sim_s_mean")})
    return pd.DataFrame(rows, columns=cols)


def _other_units(r, measure: str) -> dict:
    """The re-synchronised error in millimetres on the cloth (error_mm, with its interval) and in
    pixels of a 1080p image (error_px1080): NaN for the whole-run measure or an older evaluation."""
    sync = measure == "sync_error_px"
    get = lambda key: float(getattr(r, key, np.nan)) if sync else np.nan  # noqa: E731
    return {"error_mm": get("sync_error_mm_mean"), "error_lo_mm": get("sync_error_mm_lo"),
            "error_hi_mm": get("sync_error_mm_hi"), "error_px1080": get("sync_error_px1080_mean")}


def _window_cost(r, measure: str) -> dict:
    """The re-synchronised windows' own cost: window_time_s (simulation time per frame), window_faces
    and windows (their number); NaN for the whole-run measure or an older evaluation."""
    sync = measure == "sync_error_px"
    get = lambda key: float(getattr(r, key, np.nan)) if sync else np.nan  # noqa: E731
    return {"window_time_s": get("sync_sim_s_mean"), "window_faces": get("sync_faces_mean"),
            "windows": get("sync_windows")}


# The equivalence margin for "equal quality": two errors within 5 mm on the cloth count as the same
# quality. 5 mm is a tenth of the small scale's finest edge (the dancer's size_min, 5 cm), so a
# difference below it is far inside one element of any mesh the study judges; it is also about
# 1.7 pixels of a 1080p image in the study's wide shot (2.9 mm per 1080p pixel there).
EQUIVALENCE_MARGIN_MM = 5.0


def equivalence_table(g: pd.DataFrame, margin_mm: float = EQUIVALENCE_MARGIN_MM) -> pd.DataFrame:
    """Each fixed mesh of a scene's runs `g` (a runs table of one scene and scale with paths) against
    its default adaptive run, by two one-sided tests at 5 % each: the 90 % BCa interval (lo_mm, hi_mm)
    of the paired difference fixed - adaptive of sync_error_mm over the windows both have; within
    the margin (equivalent) when -margin < lo and hi < margin, and not worse than adaptive by more
    than the margin (not_worse: the one-sided test at 5 %) when hi < margin, however much better.
    Columns run, variant, faces_mean, resolution_factor, diff_mm, lo_mm, hi_mm, windows, equivalent,
    not_worse; sorted by faces, coarsest first.
    Empty without an adaptive run or millimetre windows."""
    ad = g[(g["mode"] == "adaptive") & g["variant"].fillna("").isin(["", "adaptive"])]
    fixed = g[g["mode"] == "nonadaptive"].sort_values("faces_mean")
    fixed = same_solver(fixed, ad.iloc[-1]) if len(ad) else fixed
    wa = read_windows(ad.iloc[-1]["path"], "sync_error_mm") if len(ad) and "path" in g.columns else None
    rows = []
    for _, f in fixed.iterrows() if wa is not None else ():
        wf = read_windows(f["path"], "sync_error_mm")
        if wf is None:
            continue
        a, b = wf.align(wa, join="inner")
        d = (a - b).to_numpy(float)
        d = d[np.isfinite(d)]
        lo, hi = paired_difference_interval(wf, wa)
        rows.append({"run": f["run"], "variant": f["variant"] or "nonadaptive", "faces_mean": float(f["faces_mean"]),
                     "resolution_factor": float(f.get("resolution_factor", np.nan)),
                     "diff_mm": float(d.mean()) if d.size else np.nan, "lo_mm": lo, "hi_mm": hi,
                     "windows": int(d.size), "equivalent": bool(-margin_mm < lo and hi < margin_mm),
                     "not_worse": bool(hi < margin_mm)})
    return pd.DataFrame(rows, columns=["run", "variant", "faces_mean", "resolution_factor", "diff_mm", "lo_mm",
                                       "hi_mm", "windows", "equivalent", "not_worse"])


def equivalent_resolution(table: pd.DataFrame, margin_mm: float = EQUIVALENCE_MARGIN_MM) -> dict | None:
    """The fixed mesh of adaptive's quality from an :func:`equivalence_table`: the coarsest run not
    worse than adaptive by more than the margin (not_worse: a finer mesh much better than adaptive
    still qualifies, since a fixed mesh of adaptive's quality is the coarsest that is at least as
    good), and where the next coarser one is worse by more than the margin (hi_mm > margin), the
    resolution factor at which hi_mm reaches the margin, linear in log(resolution factor) between
    the two (the sweep brackets it). None when no fixed mesh qualifies."""
    col = "not_worse" if "not_worse" in table.columns else "equivalent"  # a table written before the column
    eq = table[table[col].astype(bool)]
    if eq.empty:
        return None
    best = eq.iloc[0]
    out = {"run": best["run"], "variant": best["variant"], "resolution_factor": best["resolution_factor"],
           "faces_mean": best["faces_mean"], "interpolated_factor": best["resolution_factor"], "bracketed": False}
    coarser = table[table["faces_mean"] < best["faces_mean"]]
    if len(coarser):
        c = coarser.iloc[-1]
        if c["hi_mm"] > margin_mm > best["hi_mm"] and c["resolution_factor"] > 0 and best["resolution_factor"] > 0:
            w = (c["hi_mm"] - margin_mm) / (c["hi_mm"] - best["hi_mm"])
            log_f = (1 - w) * np.log(c["resolution_factor"]) + w * np.log(best["resolution_factor"])
            out.update(interpolated_factor=float(np.exp(log_f)), bracketed=True)
    return out


def pareto_table(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per run with accuracy (never a reference): scene, scale, mode, variant, run, time_mean_s,
    error (the measure: sync_error_px or error_px), error_px (its mean), error_lo_px / error_hi_px
    (its 90 % interval; NaN for error_px), error_mm / error_lo_mm / error_hi_mm and error_px1080
    (the re-synchronised error in mm on the cloth and in 1080p pixels), faces_mean, window_time_s,
    window_faces and windows (the re-synchronised windows' own simulation time per frame and faces,
    and their number; NaN for the whole-run measure), speedup (against
    the adaptive run of the scene in the same study and seed: a study's runs share a commit and a
    machine; NaN when that study has none), on_front, equal_quality (the coarsest fixed mesh whose
    error is not told apart as worse than adaptive's: :func:`equal_quality_fixed`),
    reference_error_px and reference_floor_px (:func:`reference_error`: no two points closer than
    RANK_FACTOR times the first are ranked, on the front or for equal quality), floor_px (the
    reference ensemble's chaos floor over the whole run; NaN with one reference) and
    visible_distance (the statistics of visible cloth per shot, in spreads of the ensemble:
    cloth.eval.visible; NaN with one reference)."""
    if runs.empty:
        return pd.DataFrame()
    pts = runs[~runs["reference"].astype(bool) & runs["error_px_mean"].notna() & runs["time_mean_s"].notna()]
    rows = []
    for (scene, scale), g in pts.groupby(["scene", "scale"], sort=True):
        measure, err, lo, hi = _error_columns(g)
        own, floor = reference_error(runs, scene, scale) if measure == "sync_error_px" else (math.nan, math.nan)
        min_diff = RANK_FACTOR * own if np.isfinite(own) else 0.0
        better = paired_better(g["path"]) if measure == "sync_error_px" and "path" in g.columns else None
        front = pareto_front(g["time_mean_s"], err, lo, hi, better, min_diff)
        baseline = equal_quality_fixed(g, measure, err, lo, hi, min_diff)
        for i, (r, on) in enumerate(zip(g.itertuples(), front)):
            base = baseline_for(runs[runs["study"] == r.study], scene, scale, seed=r.seed)
            rows.append({"scene": scene, "scale": scale, "mode": r.mode, "variant": r.variant or r.mode, "run": r.run,
                         "time_mean_s": r.time_mean_s, "error": measure, "error_px": float(err.iloc[i]),
                         "error_lo_px": float(lo.iloc[i]) if lo is not None else np.nan,
                         "error_hi_px": float(hi.iloc[i]) if hi is not None else np.nan,
                         **_other_units(r, measure), "faces_mean": r.faces_mean,
                         **_window_cost(r, measure),
                         "speedup": base["time_mean_s"] / r.time_mean_s if base is not None else np.nan,
                         "on_front": bool(on), "equal_quality": r.run == baseline,
                         "reference_error_px": own, "reference_floor_px": floor,
                         "floor_px": getattr(r, "floor_px_mean", np.nan),
                         "visible_distance": getattr(r, "visible_distance_mean", np.nan)})
    out = pd.DataFrame(rows)
    return out.sort_values(["scene", "scale", "time_mean_s"]).reset_index(drop=True) if len(out) else out


def flip_figure(runs: pd.DataFrame, table: pd.DataFrame, out) -> list[Path]:
    """pareto_flip.png/.csv: the Pareto table's points with their perceptual error (FLIP between
    shaded renders at the windows' ends, the accuracy study's sync.perceptual) against time; []
    when no point has it."""
    if "sync_flip_mean" not in runs.columns or table.empty:
        return []
    flip = runs.set_index("run")[["sync_flip_mean", "sync_flip_lo", "sync_flip_hi"]]
    pts = table.join(flip[~flip.index.duplicated()], on="run")
    pts = pts[pts["sync_flip_mean"].notna()]
    if pts.empty:
        return []
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for mode in sorted(pts["mode"].unique(), key=lambda m: MODES.index(m) if m in MODES else 9):
        m = pts[pts["mode"] == mode]
        ax.errorbar(m["time_mean_s"], m["sync_flip_mean"], yerr=[m["sync_flip_mean"] - m["sync_flip_lo"],
                                                                 m["sync_flip_hi"] - m["sync_flip_mean"]],
                    fmt=MODE_MARKERS.get(mode, "D"), color=color(mode), label=MODE_NAMES.get(mode, mode), capsize=2)
    ax.set_xlabel("simulation time per frame, mean (s)")
    ax.set_ylabel("FLIP at the windows' ends, mean (90% interval)")
    ax.set_title("Perceptual error against time (lower left is better)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    place_labels(ax, pts["time_mean_s"], pts["sync_flip_mean"], pts["variant"])
    cols = ["scene", "scale", "mode", "variant", "run", "faces_mean", "time_mean_s", "error_px",
            "sync_flip_mean", "sync_flip_lo", "sync_flip_hi"]
    return save_figure(fig, out, "pareto_flip") + write_table(
        pts[[c for c in cols if c in pts.columns]], out, "pareto_flip",
        "Perceptual error against time: FLIP between shaded renders of each run's cloth and the reference's at "
        "the ends of the re-synchronised windows (cloth/eval/perceptual.py), mean with its 90 % BCa interval")


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    """pareto.png/.pdf and pareto.csv/.md."""
    table = pareto_table(runset.runs)
    if table.empty:
        raise Skip("no run with accuracy (experiments.accuracy against a reference)")
    groups = list(table.groupby(["scene", "scale"], sort=True))
    cols = min(len(groups), 3)
    rows = math.ceil(len(groups) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 4.5 * rows), squeeze=False)
    for ax, ((scene, scale), g) in zip(axes.flat, groups):
        for mode in sorted(g["mode"].unique(), key=lambda m: MODES.index(m) if m in MODES else 9):
            m = g[g["mode"] == mode]
            if m["error_lo_px"].notna().any():
                ax.errorbar(m["time_mean_s"], m["error_px"], yerr=[m["error_px"] - m["error_lo_px"],
                                                                   m["error_hi_px"] - m["error_px"]],
                            fmt="none", ecolor=color(mode), elinewidth=0.8, capsize=2, zorder=2)
            ax.scatter(m["time_mean_s"], m["error_px"], color=color(mode), marker=MODE_MARKERS.get(mode, "D"),
                       s=36, label=MODE_NAMES.get(mode, mode), zorder=3)
        f = g[g["on_front"]].sort_values("time_mean_s")
        ax.scatter(f["time_mean_s"], f["error_px"], s=110, facecolors="none", edgecolors="k", lw=1.0, zorder=4)
        ax.step(f["time_mean_s"], f["error_px"], where="post", color="k", lw=1.0, ls="--", label="Pareto front",
                zorder=2)
        ax.set_xlabel("simulation time per frame, mean (s)")
        ax.set_ylabel("re-synchronised error, mean (px; 90% interval)" if g["error"].iloc[0] == "sync_error_px"
                      else "screen-space error over the whole run, mean (px)")
        ax.set_title(f"{scene} ({scale})" if scale else scene)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(groups):]:
        ax.axis("off")
    fig.suptitle("Accuracy against time per frame (lower left is better)")
    fig.tight_layout()
    for ax, (_, g) in zip(axes.flat, groups):  # labels last: they are placed as the final layout draws them
        place_labels(ax, g["time_mean_s"], g["error_px"], g["variant"])
    for (scene, scale), g in groups:
        if "reference_error_px" not in g.columns:
            continue
        own, floor = g["reference_error_px"].iloc[0], g["reference_floor_px"].iloc[0]
        if np.isfinite(own):
            log(f"pareto: {scene} ({scale}): the reference's own error {own:.3g} px (floor {floor:.3g} px): "
                f"points closer than {RANK_FACTOR * own:.3g} px are not ranked")
    for r in table[table["equal_quality"]].itertuples():
        ad = table[(table["scene"] == r.scene) & (table["scale"] == r.scale) & (table["mode"] == "adaptive")]
        t_ad = float(ad["time_mean_s"].iloc[0]) if len(ad) else np.nan
        log(f"pareto: {r.scene} ({r.scale}): the fixed mesh of adaptive's quality is {r.variant} "
            f"({r.faces_mean:.0f} faces, {r.error_px:.3g} px, {r.time_mean_s:.3g} s/frame; adaptive "
            f"{t_ad:.3g} s/frame)")
    written = save_figure(fig, out, "pareto") + write_table(
        table, out, "pareto", "Accuracy against time: every run with accuracy; on_front = on the Pareto front; "
        "equal_quality = the coarsest fixed mesh whose error is not told apart as worse than adaptive's "
        "(the paper's baseline)")
    eq, chosen = _equivalence(runset.runs, log)
    if len(eq):
        written += write_table(eq, out, "equivalence", "Equal quality by equivalence: each fixed mesh against "
                               f"adaptive, the 90 % paired interval of their difference in mm on the cloth; "
                               f"equivalent = inside +-{EQUIVALENCE_MARGIN_MM:g} mm (two one-sided tests at 5 %); "
                               f"not_worse = below +{EQUIVALENCE_MARGIN_MM:g} mm (one-sided at 5 %)")
        if len(chosen):
            written += write_table(chosen, out, "equal_quality", "The fixed mesh of adaptive's quality per scene: the "
                                   f"coarsest not worse than adaptive by more than {EQUIVALENCE_MARGIN_MM:g} mm at "
                                   "90 %, its resolution factor interpolated in log where the sweep brackets the "
                                   "margin (Table 1's non-adaptive row in the main job)")
    written += flip_figure(runset.runs, table, out)
    options = _per_scene(runset.runs, integration_table)
    if len(options):
        written += write_table(options, out, "integration", "The study's points integrated otherwise (the "
                               "bending Hessian, solver.bending_hessian; the implicit steps per frame) against the "
                               "point they vary: the paired difference of the re-synchronised error in mm (other - "
                               "base) with its 90 % interval; not_worse = the interval does not lie above 0; "
                               "speedup = the base's simulation time per frame over the other's")
        for r in options.itertuples():
            log(f"pareto: {r.variant}: {r.diff_mm:+.3g} mm ({r.lo_mm:+.3g} to {r.hi_mm:+.3g}, {r.windows} windows) "
                f"against {r.base}, {r.speedup:.3g}x its speed: {'not worse' if r.not_worse else 'worse'}")
    return written


def _per_scene(runs: pd.DataFrame, table) -> pd.DataFrame:
    """`table` of each scene and scale's points with windows (never a reference), with scene and scale
    first; empty when none gives a row."""
    if runs.empty or not {"scene", "scale"} <= set(runs.columns):
        return pd.DataFrame()
    pts = runs[~runs["reference"].astype(bool)] if "reference" in runs else runs
    if "sync_error_px_mean" in pts.columns:
        pts = pts[pts["sync_error_px_mean"].notna()]
    parts = [table(g).assign(scene=scene, scale=scale) for (scene, scale), g in pts.groupby(["scene", "scale"])]
    parts = [p for p in parts if len(p)]
    if not parts:
        return pd.DataFrame()
    t = pd.concat(parts, ignore_index=True)
    return t[["scene", "scale", *[c for c in t.columns if c not in ("scene", "scale")]]]


def _equivalence(runs: pd.DataFrame, log=print) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(equivalence_table of every scene and scale whose runs have millimetre windows, the fixed
    mesh of adaptive's quality of each: equivalent_resolution's fields with scene and scale), with
    a log line naming it (interpolated where the sweep brackets it)."""
    if runs.empty or not {"scene", "scale"} <= set(runs.columns):
        return pd.DataFrame(), pd.DataFrame()
    pts = runs[~runs["reference"].astype(bool)] if "reference" in runs else runs
    if "sync_error_px_mean" in pts.columns:  # the runs with windows (another study's adaptive run has none)
        pts = pts[pts["sync_error_px_mean"].notna()]
    parts, chosen = [], []
    for (scene, scale), g in pts.groupby(["scene", "scale"], sort=True):
        t = equivalence_table(g)
        if t.empty:
            continue
        parts.append(t.assign(scene=scene, scale=scale))
        best = equivalent_resolution(t)
        if best is not None:
            chosen.append({"scene": scene, "scale": scale, **best})
        log(f"pareto: {scene} ({scale}): " + (
            f"no fixed mesh is within {EQUIVALENCE_MARGIN_MM:g} mm of adaptive's error or better" if best is None else
            f"equal quality (not worse than adaptive by more than {EQUIVALENCE_MARGIN_MM:g} mm): {best['variant']} "
            f"(x{best['interpolated_factor']:.3g} {'interpolated' if best['bracketed'] else 'as run'})"))
    if not parts:
        return pd.DataFrame(), pd.DataFrame()
    t = pd.concat(parts, ignore_index=True)
    return t[["scene", "scale", *[c for c in t.columns if c not in ("scene", "scale")]]], pd.DataFrame(chosen)


def main(argv=None) -> int:
    return script_main(make, "pareto", argv)


if __name__ == "__main__":
    sys.exit(main())
