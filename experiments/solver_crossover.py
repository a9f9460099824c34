"""Benchmark: where the sparse Cholesky factorization overtakes PCG, on the systems a scene's run solves.

    python -m experiments.solver_crossover [--scene solo_dancer [karate ...]] [--scale small] [--frames 60]
                                           [--out DIR] [--report PAGE.md] [KEY=VALUE ...]

It runs each scene as a study runs it (Hydra's config; KEY=VALUE overrides such as `+point=viewdep`
or `mode=adaptive`) and, at every implicit step, solves the step's system twice, once with each
method, timing each exactly as `cloth.physics.linsolve.solve` runs it: PCG from the step's warm
start; the Cholesky factorization refactored (its analysis on the first solve after a remesh, as in
a run), its residual checked and PCG finishing from its solution when it misses the tolerance. The
run goes on with the solution of the method its own solver options pick, so its trajectory is the
run's. It prints, per band of unknowns (3 per node), the solves, the median milliseconds of each
method and their ratio, and, for thresholds from 0 up, the total solve time "auto" would take with
that threshold (`AUTO_CHOLESKY_UNKNOWNS`: Cholesky from that many unknowns up); the best of them
against the current one. It writes `<out>/<timestamp>/solves.csv` (one row per solve) and
`summary.json` (per scene); `--report` writes the tables as a Markdown page (docs/solver_crossover.md).

A benchmark, not a test: its times are this machine's, and the threshold it suggests is too.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd

from cloth.io.manifest import environment_manifest, write_json_atomic, write_text_atomic
from cloth.physics import integrator, linsolve
from experiments.benchmark import _time_mode, scene_error, scene_overrides, write_report

BANDS = (0, 150, 300, 450, 600, 900, 1200, 1500, 2000, 3000, 5000, 10000, np.inf)


class SolveTimer:
    """A stand-in for the integrator's `solve` that times both methods on every system."""

    def __init__(self, solve=linsolve.solve):
        self._solve = solve
        self.rows: list[dict] = []

    def __call__(self, pattern, data, b, options, x0=None):
        out = {}
        row = {"unknowns": int(b.size), "new_pattern": getattr(pattern, "_cholesky", None) is None}
        for method in ("pcg", "cholesky"):
            t0 = time.perf_counter()
            out[method] = self._solve(pattern, data, b, replace(options, method=method), x0=x0)
            row[f"{method}_ms"] = 1e3 * (time.perf_counter() - t0)
            row[f"{method}_iterations"] = out[method][1]
        self.rows.append(row)
        chosen = linsolve.resolve_method(options.method, b.size)
        return out[chosen if chosen in out else "pcg"]


def band_table(df: pd.DataFrame) -> pd.DataFrame:
    """Solves per band of unknowns: count and median milliseconds of each method."""
    bands = pd.cut(df["unknowns"], BANDS, right=False)
    g = df.groupby(bands, observed=True)
    table = pd.DataFrame({"solves": g.size(), "pcg_ms": g["pcg_ms"].median(), "cholesky_ms": g["cholesky_ms"].median()})
    table["pcg_over_cholesky"] = table["pcg_ms"] / table["cholesky_ms"]
    table.index = [f"{int(iv.left)}-{'' if np.isinf(iv.right) else int(iv.right)}" for iv in table.index]
    return table.rename_axis("unknowns").reset_index()


def threshold_totals(df: pd.DataFrame) -> pd.DataFrame:
    """Total solve seconds of the run with "auto" switching to Cholesky at each candidate threshold."""
    n = df["unknowns"].to_numpy()
    candidates = sorted({0, *(int(b) for b in BANDS[1:-1]), linsolve.AUTO_CHOLESKY_UNKNOWNS, int(n.max()) + 1})
    totals = [1e-3 * float(np.where(n >= t, df["cholesky_ms"], df["pcg_ms"]).sum()) for t in candidates]
    return pd.DataFrame({"threshold": candidates, "solve_s": totals})


def time_scene(scene: str, scale: str, frames: int, overrides: list[str]) -> pd.DataFrame:
    """Every solve of `frames` frames of one scene, timed with both methods (SolveTimer's rows)."""
    timer = SolveTimer()
    integrator.solve = timer
    try:
        _time_mode([*scene_overrides(scene), f"scale={scale}", "output.rerun=false", *overrides], frames, 0)
    finally:
        integrator.solve = linsolve.solve
    return pd.DataFrame(timer.rows)


def verdict(df: pd.DataFrame, totals: pd.DataFrame) -> tuple[int, str]:
    """The fastest threshold of one scene's solves, and a sentence comparing it with the current one."""
    best = totals.loc[totals["solve_s"].idxmin()]
    current = totals.loc[totals["threshold"] == linsolve.AUTO_CHOLESKY_UNKNOWNS].iloc[0]
    return int(best["threshold"]), (
        f"{len(df)} solves: the fastest threshold {int(best['threshold'])} unknowns, {best['solve_s']:.3f} s of "
        f"solves; the current AUTO_CHOLESKY_UNKNOWNS={linsolve.AUTO_CHOLESKY_UNKNOWNS}, {current['solve_s']:.3f} s "
        f"({current['solve_s'] / best['solve_s']:.3f}x)")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", nargs="+", default=["solo_dancer"],
                        help="conf/scene/ names or ARCSim .json paths, run one after the other")
    parser.add_argument("--scale", default="small", choices=("small", "paper"))
    parser.add_argument("--frames", type=int, default=60, help="frames to run (every solve of each is timed)")
    parser.add_argument("--out", type=Path, default=Path("results/solver_crossover"))
    parser.add_argument("--report", type=Path, default=None, metavar="PAGE.md")
    parser.add_argument("overrides", nargs="*",
                        help="config overrides (key=value) for every scene, e.g. +point=viewdep")
    args = parser.parse_args(argv)
    # `--scene a b key=value` : argparse gives the overrides to --scene; a scene has no '='
    args.overrides = [v for v in args.scene if "=" in v] + args.overrides
    args.scene = [v for v in args.scene if "=" not in v]
    if not args.scene:
        parser.error("--scene: at least one scene")
    command = "python -m experiments.solver_crossover " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.frames < 1:
        parser.error(f"--frames {args.frames}: at least 1")
    for scene in args.scene:
        if (why := scene_error(scene)) is not None:
            parser.error(why)
    if (why := linsolve.cholesky_available()) is not None:
        parser.error(f"nothing to compare: {why}")
    out_dir = args.out / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out_dir.mkdir(parents=True, exist_ok=True)
    fmt = {"float_format": lambda v: f"{v:.3f}", "index": False}
    scenes, tables, sentences, frames = [], [], [], []
    for scene in args.scene:
        df = time_scene(scene, args.scale, args.frames, args.overrides)
        if df.empty:
            raise SystemExit(f"{scene}: the run solved no system: nothing to compare")
        frames.append(df.assign(scene=scene))
        write_text_atomic(out_dir / "solves.csv", pd.concat(frames).to_csv(index=False))  # kept if a later scene fails
        bands, totals = band_table(df), threshold_totals(df)
        best, sentence = verdict(df, totals)
        print(f"{scene}:")
        print(bands.to_string(**fmt))
        print(totals.to_string(**fmt))
        print(f"{scene}: {sentence}", flush=True)
        scenes.append({"scene": scene, "solves": len(df), "best_threshold": best,
                       "bands": bands.to_dict("records"), "totals": totals.to_dict("records")})
        sentences.append(f"`{scene}`: {sentence}.")
        tables += [(f"{scene}: median milliseconds per solve", bands),
                   (f"{scene}: total solve time by threshold", totals)]
    manifest = environment_manifest(0)
    write_json_atomic(out_dir / "summary.json", {"scale": args.scale, "frames": args.frames,
                                                 "overrides": args.overrides,
                                                 "current_threshold": linsolve.AUTO_CHOLESKY_UNKNOWNS,
                                                 "scenes": scenes, "manifest": manifest})
    print(f"results in {out_dir}")
    if args.report is not None:
        write_report(args.report, "Cholesky against PCG by system size",
                     f"Scale={args.scale}, {' '.join(args.overrides) or 'no overrides'}: every implicit step of "
                     f"{args.frames} frames of each scene solved with both methods (each as `linsolve.solve` runs "
                     "it: PCG from the step's warm start; the factorization refactored, analysed on the first solve "
                     "after a remesh, PCG finishing when it misses the tolerance). " + " ".join(sentences),
                     tables, manifest, command)


if __name__ == "__main__":
    main()
