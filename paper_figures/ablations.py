"""Ablation figures: buckling compensation (the paper's Fig. 6) and temporal anticipation of
camera cuts (the paper's Fig. 3).

    python -m paper_figures.ablations ROOT [ROOT ...] [--out DIR]

Buckling: viewdep runs that differ only in their compensation (none; uniform: compression removed
on every out-of-frustum face; adaptive with its k), the ablation_buckling study's when present:
faces, ballooning of out-of-view cloth (offscreen_distance_m of accuracy.json, metres) and time
per frame per variant, and ballooning over time when accuracy.parquet is there.
-> ablation_buckling.png/.pdf, ablation_buckling.csv/.md.

Anticipation: viewdep runs that differ only in their anticipation (off, or on with its window T;
the ablation_anticipation study's when present, else the accuracy study's, whose 70 frames hold
the first cut, else every run): faces, faces in view, screen-space error and
popping over time with the camera cuts marked; per variant the mean error and popping over the
CUT_WINDOW_FRAMES frames from each cut, and the re-synchronised error of the windows that start
before a cut and end after it (sync_error_px_cut_mean of sync.json: what refining before the
cut buys on screen), beside faces and simulation time per frame (what it costs). With several
seeds (repeats), each seed's runs are compared among themselves and the table gives the medians
over the seeds, the cut windows' error with its interval, and its paired difference from the run
without anticipation of the same seed; the plots show the first seed.
-> ablation_anticipation.png/.pdf, ablation_anticipation.csv/.md, ablation_anticipation_seeds.csv/.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from experiments.analysis.accuracy import bootstrap_mean_interval
from experiments.analysis.sync import paired_difference_interval

from .common import (
    RunSet,
    Skip,
    frame_times,
    latest,
    one_factor,
    save_figure,
    script_main,
    study_or_all,
    write_table,
)

CUT_WINDOW_FRAMES = 10  # frames from a cut over which 'error after the cut' is averaged (T = 5 frames, twice)
# what the runs an ablation compares must share (besides what it ablates): the view settings, the
# occlusion test, the contact floor and the study
BUCKLING_OTHERS = ("nu_out", "margin", "T", "anticipation", "l_min_px", "occlusion", "contact_size", "study")
ANTICIPATION_OTHERS = ("nu_out", "margin", "l_min_px", "buckling_k", "buckling_mode", "occlusion", "contact_size",
                       "study")
BUCKLING_ORDER = ("none", "uniform", "adaptive")
BUCKLING_COLORS = {"none": "tab:red", "uniform": "tab:gray", "adaptive": "tab:green"}


def buckling_label(row) -> str:
    if row["buckling_mode"] == "adaptive":
        return f"adaptive k={row['buckling_k']:g}"
    return str(row["buckling_mode"])


def _per_frame(runset: RunSet, run: str, column: str):
    """(simulated time, values) of a frames.parquet or accuracy.parquet column of a run, or None."""
    fr = runset.frames[runset.frames["run"] == run]
    if column in fr.columns:
        return fr, fr[column].to_numpy(float)
    acc = runset.accuracy[runset.accuracy["run"] == run] if len(runset.accuracy) else runset.accuracy
    if len(acc) and column in acc.columns:
        merged = acc.merge(fr[["frame"] + (["sim_time_s"] if "sim_time_s" in fr.columns else [])], on="frame",
                           how="left")
        return merged, merged[column].to_numpy(float)
    return None


def _plot_over_time(ax, runset, runs: pd.DataFrame, column: str, labels, ylabel: str, colors=None) -> bool:
    drawn = False
    colors = list(colors) if colors is not None else [None] * len(runs)
    for (_, r), label, c in zip(runs.iterrows(), labels, colors):
        got = _per_frame(runset, r["run"], column)
        if got is None:
            continue
        fr, values = got
        ax.plot(frame_times(fr, r["frame_time_s"]), values, lw=1.0, label=label, color=c)
        drawn = True
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if drawn:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "not recorded", transform=ax.transAxes, ha="center", va="center", color="0.4")
    return drawn


DRAPE_MESHES = ("fine", "coarse", "view-coarsened")
# Settled (the measures are read at equilibrium, the last EQUILIBRIUM_FRAMES frames): over them the
# drape coefficient moves by less than SETTLED_DRAPE_COEFFICIENT (a hundredth of its 0-1 range, a
# tenth of the smallest difference the drape table discusses) and the hem's radius by less than
# SETTLED_HEM_M (5 mm: under a tenth of the small scale's 5 cm edge), in every seed.
SETTLED_DRAPE_COEFFICIENT = 0.01
SETTLED_HEM_M = 0.005


def _settled(g: pd.DataFrame) -> bool:
    """Every run of `g` settled by the criterion above (False when a run has no drift recorded)."""
    dc = g["drape_coefficient_drift"].to_numpy(float) if "drape_coefficient_drift" in g else np.array([np.nan])
    hem = g["hem_radius_mean_m_drift"].to_numpy(float) if "hem_radius_mean_m_drift" in g else np.array([np.nan])
    return bool(np.all(dc < SETTLED_DRAPE_COEFFICIENT) and np.all(hem < SETTLED_HEM_M))


def _drape_runs(runset: RunSet) -> pd.DataFrame:
    runs = study_or_all(runset.runs, "ablation_buckling")
    if runs.empty or "drape_coefficient_final" not in runs.columns:
        return runs.iloc[0:0]
    return runs[runs["drape_coefficient_final"].notna() & (runs["drape_mesh"] != "")]


def drape(runset: RunSet, out) -> list[Path]:
    """ablation_drape.*: buckling compensation on the drape test, per mesh and compensation: the
    measures at equilibrium, and whether compensation moves each mesh's drape coefficient toward
    the fine mesh's without compensation."""
    runs = _drape_runs(runset)
    if runs.empty:
        raise Skip("drape: no runs of the drape test (scene cusick_drape, ablation_buckling)")
    runs, _ = latest(runs.assign(compensation=runs.apply(_compensation_label, axis=1)),
                     ("scene", "scale", "drape_mesh", "compensation", "seed"))
    rows = []
    for (scene, scale), g in runs.groupby(["scene", "scale"], sort=True):
        med = g.groupby(["drape_mesh", "compensation"], sort=False).agg(
            runs=("run", "size"), faces_mean=("faces_mean", "median"), time_mean_s=("time_mean_s", "median"),
            drape_coefficient=("drape_coefficient_final", "median"), folds=("folds_final", "median"),
            hem_radius_m=("hem_radius_mean_m_final", "median"),
            compressive_energy_j=("compressive_energy_out_j_final", "median"),
            **({"overhang_elements": ("overhang_elements_final", "median")}
               if "overhang_elements_final" in g else {})).reset_index()
        med["settled"] = [_settled(s) for _, s in g.groupby(["drape_mesh", "compensation"], sort=False)]
        fine = med[(med["drape_mesh"] == "fine") & (med["compensation"] == "none")]
        dc_fine = float(fine["drape_coefficient"].iloc[0]) if len(fine) else np.nan
        for _, r in med.iterrows():
            base = med[(med["drape_mesh"] == r["drape_mesh"]) & (med["compensation"] == "none")]
            dc0 = float(base["drape_coefficient"].iloc[0]) if len(base) else np.nan
            d, d0 = abs(r["drape_coefficient"] - dc_fine), abs(dc0 - dc_fine)
            toward = bool(d < d0) if r["compensation"] != "none" and np.isfinite(d + d0) else None
            rows.append({"scene": scene, "scale": scale, **r.to_dict(),
                         "dc_minus_fine": r["drape_coefficient"] - dc_fine, "toward_fine": toward})
    table = pd.DataFrame(rows)
    order = {m: i for i, m in enumerate(DRAPE_MESHES)}
    comp_order = {c: i for i, c in enumerate(COMPENSATIONS)}
    table = table.sort_values(["scene", "scale", "drape_mesh", "compensation"],
                              key=lambda c: c.map(order) if c.name == "drape_mesh" else
                              (c.map(comp_order) if c.name == "compensation" else c)).reset_index(drop=True)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    comps = [c for c in COMPENSATIONS if c in set(table["compensation"])]
    x = np.arange(len(comps))
    for m, mark in zip(DRAPE_MESHES, ("o", "s", "^")):
        t = table[table["drape_mesh"] == m].set_index("compensation").reindex(comps)
        for ax, col in zip(axes, ("drape_coefficient", "folds", "compressive_energy_j")):
            ax.plot(x, t[col].to_numpy(float), marker=mark, label=m)
    if np.isfinite(dc_fine):
        axes[0].axhline(dc_fine, color="0.3", ls="--", lw=1, label="fine, no compensation")
    axes[2].set_yscale("log")  # from round-off-sized compression to whole folds held flat
    for ax, ylabel in zip(axes, ("drape coefficient at equilibrium", "folds at equilibrium",
                                 "compressive membrane energy out of view (J)")):
        ax.set_xticks(x, comps)
        ax.set_xlabel("compensation")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Buckling compensation on the Cusick drape test (specimen out of the frustum)")
    fig.tight_layout()
    return save_figure(fig, out, "ablation_drape") + write_table(
        table, out, "ablation_drape",
        "Buckling compensation on the drape test, at equilibrium (last 10 frames; medians over seeds): "
        "toward_fine = compensation brings the mesh's drape coefficient closer to the fine mesh's without it; "
        "overhang_elements = elements across the overhang; settled = in every seed the drape coefficient "
        f"moved by less than {SETTLED_DRAPE_COEFFICIENT:g} and the hem by less than {SETTLED_HEM_M * 1000:g} mm "
        "over those frames")


def standing(runset: RunSet, out) -> list[Path]:
    """ablation_buckling_dancer.*: the standing dancer with her skirt out of view, per run: faces,
    time, and at equilibrium the hem's radius, its folds, the skirt's drape coefficient about the
    waist and the compressive membrane energy out of view, and the hem's radius beside the fine
    reference's (the fixed mesh's when the study has no reference)."""
    runs = runset.runs
    runs = runs[runs["study"] == "ablation_buckling_dancer"] if len(runs) else runs
    if runs.empty or "hem_radius_mean_m_final" not in runs.columns:
        raise Skip("standing dancer: no runs of ablation_buckling_dancer")
    runs, _ = latest(runs, ("scene", "scale", "variant", "seed"))
    cols = {"hem_radius_mean_m_final": "hem_radius_m", "folds_final": "folds",
            "drape_coefficient_final": "drape_coefficient", "compressive_energy_out_j_final": "compressive_energy_j"}
    table = runs.groupby(["scene", "scale", "mode", "variant"], sort=False).agg(
        runs=("run", "size"), nu_out=("nu_out", "median"), faces_mean=("faces_mean", "median"),
        time_mean_s=("time_mean_s", "median"), **{v: (k, "median") for k, v in cols.items()}).reset_index()
    table["settled"] = [_settled(s) for _, s in runs.groupby(["scene", "scale", "mode", "variant"], sort=False)]
    # the comparison: the fine reference when the study has it, else the preset's fixed mesh
    fine = table[table["variant"] == "reference"]
    fine = fine if len(fine) else table[table["mode"] == "nonadaptive"]
    hem_fine = float(fine["hem_radius_m"].iloc[0]) if len(fine) else np.nan
    table["hem_minus_fine_m"] = table["hem_radius_m"] - hem_fine
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    x = np.arange(len(table))
    for ax, col, ylabel in zip(axes, ("hem_radius_m", "folds", "faces_mean"),
                               ("hem radius at equilibrium (m)", "folds at equilibrium", "faces, mean")):
        ax.bar(x, table[col].to_numpy(float), color="tab:blue")
        ax.set_xticks(x, table["variant"], fontsize=8, rotation=20)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle("Buckling compensation on the standing dancer, skirt out of view")
    fig.tight_layout()
    return save_figure(fig, out, "ablation_buckling_dancer") + write_table(
        table, out, "ablation_buckling_dancer",
        "The standing dancer, skirt out of view: measures at equilibrium (last 10 frames; medians over seeds); "
        "hem_minus_fine_m = hem radius minus the fine reference's (the preset's fixed mesh's without one; "
        f"ballooning > 0); settled = in every seed the hem moved by less than {SETTLED_HEM_M * 1000:g} mm and the "
        f"drape coefficient by less than {SETTLED_DRAPE_COEFFICIENT:g} over those frames")


COMPENSATIONS = ("none", "uniform", "k=1", "k=3", "k=10", "k=50")


def _compensation_label(row) -> str:
    if row["buckling_mode"] == "none" or not isinstance(row["buckling_mode"], str):
        return "none"
    return "uniform" if row["buckling_mode"] == "uniform" else f"k={row['buckling_k']:g}"


def buckling(runset: RunSet, out) -> list[Path]:
    runs = study_or_all(runset.runs, "ablation_buckling")
    drape_runs = _drape_runs(runset)
    if len(drape_runs):  # the drape test's runs have their own table (drape)
        runs = runs[~runs["run"].isin(drape_runs["run"])]
    vd = runs[runs["mode"] == "viewdep"] if len(runs) else runs
    if vd.empty:
        raise Skip("buckling: no viewdep runs")
    vd = vd.assign(compensation=vd.apply(buckling_label, axis=1))
    pts = pd.concat([one_factor(g, "compensation", BUCKLING_OTHERS) for _, g in vd.groupby(["scene", "scale"])])
    if pts.empty:
        raise Skip("buckling: no viewdep runs that differ only in their buckling compensation")
    pts = pts.assign(_o=pts["buckling_mode"].map(lambda m: BUCKLING_ORDER.index(m) if m in BUCKLING_ORDER else 9))
    pts = pts.sort_values(["scene", "scale", "_o", "buckling_k"]).drop(columns="_o")
    table = pts[["scene", "scale", "compensation", "run", "faces_mean", "offscreen_distance_m_mean", "time_mean_s",
                 "error_px_mean"]].reset_index(drop=True)
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.6))
    names = [f"{r.compensation}\n{r.scene}" if table["scene"].nunique() > 1 else r.compensation
             for r in table.itertuples()]
    x = np.arange(len(table))
    for ax, col, ylabel in zip(axes[:3], ("faces_mean", "offscreen_distance_m_mean", "time_mean_s"),
                               ("faces, mean", "out-of-view ballooning, mean (m)", "time per frame, mean (s)")):
        ax.bar(x, table[col].to_numpy(float), color=[BUCKLING_COLORS.get(m, "tab:olive") for m in pts["buckling_mode"]])
        ax.set_xticks(x, names, fontsize=8)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, axis="y")
        if not table[col].notna().any():
            ax.text(0.5, 0.5, "not measured", transform=ax.transAxes, ha="center", va="center", color="0.4")
    _plot_over_time(axes[3], runset, pts, "offscreen_distance_m", list(table["compensation"]),
                    "out-of-view ballooning (m)", colors=[BUCKLING_COLORS.get(m) for m in pts["buckling_mode"]])
    axes[3].set_xlabel("simulated time (s)")
    fig.suptitle("Buckling compensation (the paper's Fig. 6): none / uniform / area-adaptive")
    fig.tight_layout()
    return save_figure(fig, out, "ablation_buckling") + write_table(
        table, out, "ablation_buckling", "Buckling compensation ablation (the paper's Fig. 6)")


def _after_cut(runset: RunSet, r, cuts, column: str = "error_px") -> float:
    """Mean of a per-frame column over the CUT_WINDOW_FRAMES frames from each cut (NaN without it)."""
    got = _per_frame(runset, r["run"], column)
    if got is None or not cuts:
        return np.nan
    fr, err = got
    t = frame_times(fr, r["frame_time_s"])
    dt = r["frame_time_s"] if np.isfinite(r["frame_time_s"]) else 1.0
    mask = np.zeros(len(t), bool)
    for c in cuts:
        mask |= (t >= c - 1e-9) & (t < c + CUT_WINDOW_FRAMES * dt - 1e-9)
    vals = err[mask]
    vals = vals[np.isfinite(vals)]
    return float(vals.mean()) if len(vals) else np.nan


def lead_label(r) -> str:
    """'off', or 'T=<frames>' for a run with anticipation; 'live T=<frames>' when its camera's
    future was not known (mode.view.lookahead=false, cloth.view.live)."""
    if not bool(r["anticipation"]):
        return "off"
    live = r.get("lookahead") is not None and r.get("lookahead") == r.get("lookahead") and not bool(r["lookahead"])
    return f"{'live ' if live else ''}T={r['T']:g}"


def live_camera(runset: RunSet, out) -> list[Path]:
    """live_camera.*: the live_camera study's runs (a camera whose future is not known, on a
    continuous move) as the anticipation table (:func:`anticipation`)."""
    runs = runset.runs
    if runs.empty or not (runs["study"] == "live_camera").any():
        raise Skip("live_camera: no runs of the live_camera study")
    return anticipation(runset, out, studies=("live_camera",), name="live_camera",
                        title="A camera whose future is not known (mode.view.lookahead=false) against its "
                              "prescribed path and against no anticipation")


def anticipation(runset: RunSet, out, studies=("ablation_anticipation", "accuracy"),
                 name: str = "ablation_anticipation",
                 title: str = "Temporal anticipation of camera cuts (the paper's Fig. 3)") -> list[Path]:
    runs = study_or_all(runset.runs, *studies)
    vd = runs[(runs["mode"] == "viewdep") & runs["anticipation"].notna()] if len(runs) else runs
    if vd.empty:
        raise Skip(f"{name}: no viewdep runs")
    vd = vd.assign(lead=[lead_label(r) for _, r in vd.iterrows()], _seed=vd["seed"].fillna(0).astype(int))
    pts = pd.concat([one_factor(g, "lead", ANTICIPATION_OTHERS) for _, g in vd.groupby(["scene", "scale", "_seed"])])
    if pts.empty:
        raise Skip("anticipation: no viewdep runs that differ only in their anticipation (mode.view.anticipation, T)")
    pts = pts.assign(_order=[-1.0 if lead == "off" else float(T) + 0.5 * lead.startswith("live")
                             for lead, T in zip(pts["lead"], pts["T"])])
    pts = pts.sort_values(["scene", "scale", "_order", "_seed"]).drop(columns="_order")
    cuts = sorted({c for cs in pts["camera_cuts_s"] for c in cs})
    col = lambda name: pts[name].to_numpy() if name in pts.columns else np.full(len(pts), np.nan)  # noqa: E731
    after = lambda name: [_after_cut(runset, r, r["camera_cuts_s"], name) for _, r in pts.iterrows()]  # noqa: E731
    per_seed = pd.DataFrame({"scene": pts["scene"].to_numpy(), "scale": pts["scale"].to_numpy(),
                             "anticipation": pts["lead"].to_numpy(), "seed": pts["_seed"].to_numpy(),
                             "run": pts["run"].to_numpy(), "faces_mean": pts["faces_mean"].to_numpy(),
                             "time_mean_s": pts["time_mean_s"].to_numpy(),
                             "faces_in_view_after_cut": after("faces_in_view"),
                             "error_px_mean": pts["error_px_mean"].to_numpy(),
                             "error_px_after_cut_mean": after("error_px"),
                             "sync_error_px_cut_mean": col("sync_error_px_cut_mean"),
                             "sync_error_px_mean": col("sync_error_px_mean"),
                             "popping_px_mean": col("popping_px_mean"),
                             "popping_px_after_cut_mean": after("popping_px")})
    table = over_seeds(per_seed)
    first = pts.groupby(["scene", "scale"])["_seed"].transform("min") == pts["_seed"]  # the plots: one seed
    shown = pts[first.to_numpy()]
    labels = [("without anticipation" if r.lead == "off" else f"anticipation {r.lead} frames")
              + (f" ({r.scene})" if shown["scene"].nunique() > 1 else "") for r in shown.itertuples()]
    fig, axes = plt.subplots(4, 1, figsize=(8, 10), sharex=True)
    _plot_over_time(axes[0], runset, shown, "faces", labels, "faces")
    _plot_over_time(axes[1], runset, shown, "faces_in_view", labels, "faces in view")
    _plot_over_time(axes[2], runset, shown, "error_px", labels, "screen-space error (px)")
    _plot_over_time(axes[3], runset, shown, "popping_px", labels, "popping (px)")
    for ax in axes:
        for c in cuts:
            ax.axvline(c, color="0.2", ls=":", lw=1.0)
    axes[3].set_xlabel(f"simulated time (s); dotted: camera cuts (seed {int(shown['_seed'].min())})")
    fig.suptitle(title)
    fig.tight_layout()
    cut_text = ", ".join(f"{c:g} s" for c in cuts) or "(no cut)"
    return save_figure(fig, out, name) + write_table(
        table, out, name,
        f"{title}, over {table['seeds'].max()} seed(s): medians over the seeds (sync_error_px_mean: every window's "
        f"re-synchronised error), "
        f"after a cut: mean over {CUT_WINDOW_FRAMES} frames from each cut at {cut_text}; sync_error_px_cut_mean: "
        f"the re-synchronised error of the windows that start before a cut and end after it, its mean over the "
        f"seeds with the 90 % BCa interval, and cut_vs_off: its paired difference from the run without "
        f"anticipation of the same seed") + write_table(
        per_seed, out, f"{name}_seeds", f"{title}, every seed")


# per-seed columns whose median over the seeds the anticipation table gives
SEED_MEDIANS = ("faces_mean", "time_mean_s", "faces_in_view_after_cut", "error_px_mean", "error_px_after_cut_mean",
                "sync_error_px_mean", "popping_px_mean", "popping_px_after_cut_mean")


def over_seeds(per_seed: pd.DataFrame) -> pd.DataFrame:
    """One row per scene, scale and anticipation of a per-seed table: seeds, the median of each of
    SEED_MEDIANS, sync_error_px_cut_mean (the mean over the seeds) with its 90 % BCa interval
    (_lo, _hi), and cut_vs_off_px with _lo, _hi: the mean of its difference from the run without
    anticipation of the same seed, with the paired interval (NaN without such runs, or an interval
    from fewer than two seeds)."""
    rows = []
    for (scene, scale), g in per_seed.groupby(["scene", "scale"], sort=False):
        off = g[g["anticipation"] == "off"].set_index("seed")["sync_error_px_cut_mean"].astype(float)
        for lead, h in g.groupby("anticipation", sort=False):
            sync = h.set_index("seed")["sync_error_px_cut_mean"].astype(float)
            ok = sync[np.isfinite(sync)]
            lo, hi = bootstrap_mean_interval(ok.to_numpy()) if len(ok) > 1 else (np.nan, np.nan)
            both = sync.index.intersection(off.index)
            diff = (sync[both] - off[both]).dropna()
            d_lo, d_hi = paired_difference_interval(sync[both], off[both]) if len(diff) > 1 else (np.nan, np.nan)
            rows.append({"scene": scene, "scale": scale, "anticipation": lead, "seeds": int(len(h)),
                         **{c: float(h[c].median()) for c in SEED_MEDIANS},
                         "sync_error_px_cut_mean": float(ok.mean()) if len(ok) else np.nan,
                         "sync_error_px_cut_lo": lo, "sync_error_px_cut_hi": hi,
                         "cut_vs_off_px": float(diff.mean()) if len(diff) and lead != "off" else np.nan,
                         "cut_vs_off_lo_px": d_lo if lead != "off" else np.nan,
                         "cut_vs_off_hi_px": d_hi if lead != "off" else np.nan})
    return pd.DataFrame(rows)


def make(runset: RunSet, out, paper_timings=None, log=print) -> list[Path]:
    """ablation_buckling.*, ablation_anticipation.* and live_camera.* (each when its runs are there)."""
    files, skipped = [], []
    for fn in (buckling, drape, standing, anticipation, live_camera):
        try:
            files += fn(runset, out)
        except Skip as exc:
            skipped.append(str(exc))
    if not files:
        raise Skip("; ".join(skipped))
    for s in skipped:
        log(f"ablations: skipped {s}")
    return files


def main(argv=None) -> int:
    return script_main(make, "ablations", argv)


if __name__ == "__main__":
    sys.exit(main())
