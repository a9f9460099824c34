"""The main job: the accuracy/time Pareto figure, the paper's Table 1 and Fig. 8, and both ablations.

    python -m experiments.paper [--scale small|paper] [--jobs N] [--out results/paper/<timestamp>]
                                [--studies accuracy table1 ... | --full] [--frames N] [--repeats 3]
                                [--crowd-repeats 1]

The default studies, in this order: ``accuracy`` (the Pareto study: the fixed mesh at four
resolutions, adaptive, view-dependent settings, against a reference ensemble of five seeds with
the reference's own error), ``table1`` (its non-adaptive row is the fixed mesh the accuracy study
found of adaptive's quality: by the millimetre windows, the coarsest not worse than adaptive by
more than the equivalence margin, at its factor interpolated between the study's resolutions
(conf/point/fixed_factor); else the coarsest whose error is not told apart as worse than
adaptive's; the preset's own fixed mesh when the accuracy study is not run or finds none; karate
takes its own when ``accuracy_karate`` ran, else it inherits the dancer's factor, as the crowd
does, and the log says so), ``ablation_buckling`` (the drape test) and ``ablation_buckling_dancer``
(the standing dancer).
``--full`` adds what the default job leaves out to fit in about 90 minutes on 2 cores: the
accuracy study's integration points (ACCURACY_FULL_ONLY), karate's own accuracy study
(``accuracy_karate``), the anticipation ablation (five seeds) and the sweeps of nu_out, k, T and
the margin. Others on
request (``--studies``), among them ``crowd_scaling`` (beyond the paper: adaptive and
view-dependent crowds of 1, 10 and 100 dancers; hours at scale=small, see docs/studies.md),
``cameras`` and ``cameras_crowd`` (beyond the paper: a second camera) and ``live_camera`` (beyond the
paper: a camera whose future is not known, on a continuous move).

Runs each study as a Hydra multirun (``python -m experiments.run experiment=<study>``, joblib
launcher, ``--jobs`` runs at a time: one by default, so that timed runs never compete) into
``<out>/<study>/``; every study's multirun ends with the study callback (experiments.callbacks),
which measures each run's screen-space error against the study's fine nonadaptive reference run
when it has one. Then ``python -m paper_figures`` makes every table and figure from the run folders
into ``<out>/figures/``, and the paths are printed. Before the studies, a two-frame run into
``<out>/warmup/`` fills numba's kernel cache, so that no timed frame includes compilation.

A study that fails (a run that diverges, a killed process) does not stop the others: its run
folders stay as written, the aggregation reports the broken ones by name and skips them, and the
job exits non-zero at the end. A killed job continues where it stopped when run again with the
same arguments and ``--out``: every run is made with ``output.resume=true`` (a run that completed
or diverged is not run again, one with a checkpoint resumes from it, every ``output.checkpoint_every``
frames; experiments.resuming.continue_in_place), and each study's measurements and the figures
are made again from the run folders. At scale=small on 2 cores the whole job took 49-51 minutes from
a clean clone (at de619a4 and 9855c73; README: Quick start); at scale=paper expect a day or a cluster
(docs/studies.md: Scale).
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import pandas as pd
import yaml

from cloth.io.manifest import write_text_atomic
from experiments.joblock import FolderInUse, JobLock
from experiments.progress import Heartbeat, JobClock, StudyWatch, planned_runs

ROOT = Path(__file__).resolve().parents[1]
# in the order they run (the accuracy study first: Table 1's non-adaptive row depends on it)
STUDIES = ("accuracy", "accuracy_karate", "table1", "ablation_buckling", "ablation_buckling_dancer",
           "ablation_anticipation", "sweep_nu_out", "sweep_k", "sweep_T", "sweep_margin", "sweep_resolution",
           "crowd_scaling", "cameras", "cameras_crowd", "live_camera")
DEFAULT_STUDIES = ("accuracy", "table1", "ablation_buckling", "ablation_buckling_dancer")
# --full: the default studies and what the 90-minute job leaves out to fit, karate's own accuracy
# study (its Table 1 row then at karate's own fixed mesh of adaptive's quality), the anticipation ablation
# and the four sweeps of the view-dependent method's parameters (crowd_scaling and the resolution
# sweep stay on request: hours, and the accuracy study already sweeps the fixed mesh)
FULL_STUDIES = (*DEFAULT_STUDIES, "accuracy_karate", "ablation_anticipation", "sweep_nu_out", "sweep_k", "sweep_T",
                "sweep_margin")
WARMUP = [sys.executable, "-m", "experiments.run", "scene=karate", "+point=viewdep", "scale=small", "frames=2",
          "output.rerun=false", "output.progress=false"]


# Table 1's crowd (ten characters) costs ten times a character per run: the main job runs the
# single-character scenes with table1's repeats and the crowd `--crowd-repeats` times (default 1),
# its characters two at a time with one numba thread each (experiments.launch.share_cores), so that
# the job stays within about 90 minutes on 2 cores at scale=small.
SINGLE_SCENES = ("karate", "solo_dancer")
# The accuracy study that finds each single scene's fixed mesh of adaptive's quality (its folder in
# the job); a scene whose study did not run inherits the solo dancer's, and the log says so.
ACCURACY_STUDY_OF = {"solo_dancer": "accuracy", "karate": "accuracy_karate"}
CROWD_SCENE = "multiple_dancers"
# Table 1's points in the main job: its fixed mesh (the baseline), then these (the preset's own).
TABLE1_POINTS = ("adaptive", "viewdep", "viewdep_nofloor")
# The accuracy study's points that only --full runs: the integration points (the Hessian choices
# and the steps per frame, compared window by window with the points they vary), twelve runs that
# would take the default job past 90 minutes on 2 cores.
ACCURACY_FULL_ONLY = ("bending/", "membrane/", "steps/")
# A still (camera view by view factor beside an outside view) of every single-character run every
# this many frames, for the report's stills of each mode; I/O, so outside the timed sim_s.
TABLE1_STILLS_EVERY = 50


def study_command(study: str, out: Path, scale: str, jobs: int, frames: int | None, extra=(),
                  folder: str | None = None) -> list[str]:
    """The Hydra multirun command of one study (into out/<folder or study>)."""
    cmd = [sys.executable, "-m", "experiments.run", f"experiment={study}", f"scale={scale}",
           f"hydra.sweep.dir={out / (folder or study)}", f"hydra.launcher.n_jobs={jobs}", "output.resume=true"]
    if frames is not None:
        cmd.append(f"frames={frames}")
    return cmd + list(extra)


def equal_quality_point(out: Path, log=print) -> str:
    """The point (conf/point) of the fixed mesh of adaptive's quality that the accuracy study in
    out/accuracy found (paper_figures.pareto: equal_quality), for Table 1's non-adaptive row;
    "nonadaptive" (the preset's fixed mesh), with the reason logged, when there is none."""
    table = out / "accuracy" / "figures" / "pareto.csv"
    if not table.is_file():
        log(f"table1: no accuracy study in {out} ({table.name} missing): the non-adaptive row is the preset's "
            "fixed mesh")
        return "nonadaptive"
    rows = pd.read_csv(table)
    rows = rows[rows["equal_quality"].astype(bool)] if "equal_quality" in rows.columns else rows.iloc[:0]
    if rows.empty:
        log("table1: no fixed mesh of the accuracy study reaches adaptive's error: the non-adaptive row is the "
            "preset's fixed mesh")
        return "nonadaptive"
    r = rows.iloc[0]
    cfg = yaml.safe_load((out / "accuracy" / r["run"] / "config.yaml").read_text())
    factor = float(cfg.get("resolution_factor") or 1.0)
    point = "nonadaptive" if factor == 1.0 else f"resolution/{factor:g}"
    if not (ROOT / "conf" / "point" / f"{point}.yaml").is_file():
        log(f"table1: the fixed mesh of adaptive's quality (x{factor:g}) has no conf/point/{point}.yaml: the "
            "non-adaptive row is the preset's fixed mesh")
        return "nonadaptive"
    log(f"table1: the non-adaptive row is the fixed mesh of adaptive's quality on {r['scene']}: {r['variant']} "
        f"({r['error_px']:.3g} px; conf/point/{point})")
    return point


def equal_quality_baseline(out: Path, log=print, scene: str = "solo_dancer") -> list[str]:
    """Table 1's non-adaptive row of `scene` as overrides: the fixed mesh of adaptive's quality
    that the scene's accuracy study (ACCURACY_STUDY_OF; the solo dancer's for a scene without one,
    the crowd's) found by its millimetre windows (figures/equal_quality.csv: the coarsest not worse
    than adaptive by more than the margin, its factor interpolated where the sweep brackets it;
    conf/point/fixed_factor at that factor), else :func:`equal_quality_point`."""
    own = ACCURACY_STUDY_OF.get(scene)
    for study, of in ((own, scene), ("accuracy", "solo_dancer")) if own else (("accuracy", "solo_dancer"),):
        table = out / study / "figures" / "equal_quality.csv"
        rows = pd.read_csv(table) if table.is_file() else pd.DataFrame()
        rows = rows[rows["scene"] == of] if "scene" in rows.columns else rows.iloc[:0]
        if len(rows):
            r = rows.iloc[0]
            factor = float(r["interpolated_factor"])
            if math.isfinite(factor) and factor > 0:
                whose = "its own" if of == scene else f"{of}'s (inherited: {scene} has no accuracy study here)"
                log(f"table1: {scene}'s non-adaptive row is the fixed mesh of adaptive's quality by {whose} "
                    f"millimetre windows: x{factor:.3g} ({'interpolated beside' if r['bracketed'] else 'as'} "
                    f"{r['variant']})")
                return ["baseline=fixed_factor", f"baseline_factor={factor:.3g}"]
    return [f"baseline={equal_quality_point(out, log)}"]


def study_parts(study: str, args, out: Path | None = None) -> list[tuple[str, list[str]]]:
    """(folder, extra overrides) of each multirun a study of the main job is made of: table1 is
    split into its single characters (``--repeats``) and its crowd (``--crowd-repeats``), its
    non-adaptive row the fixed mesh of adaptive's quality when the accuracy study ran first."""
    if study == "accuracy" and not getattr(args, "full", False):
        return [(study, [f"points='{','.join(accuracy_points(full=False))}'"])]
    if study != "table1":
        return [(study, [])]
    crowd_jobs = min(2, args.jobs_cores)
    measured = out is not None and any(ACCURACY_STUDY_OF[s] in args.studies for s in SINGLE_SCENES)

    def chosen(scene):
        return equal_quality_baseline(out, scene=scene) if measured else ["baseline=nonadaptive"]

    def points(choice):  # quoted: the sweeper's own list (a bare comma would make the override itself a sweep)
        return f"points='{','.join((choice[0].split('=', 1)[1], *TABLE1_POINTS))}'"

    parts = []
    for scene in SINGLE_SCENES:  # each scene with its own fixed mesh of adaptive's quality
        choice = chosen(scene)
        parts.append(("table1" if scene == "solo_dancer" else f"table1_{scene}",
                      [f"hydra.sweeper.params.scene={scene}", f"repeats={args.repeats}", *choice, points(choice),
                       f"output.stills_every={TABLE1_STILLS_EVERY}"]))
    choice = chosen(CROWD_SCENE)  # the dancer's: the crowd wears the same skirt
    parts.append(("table1_crowd", [f"hydra.sweeper.params.scene='{CROWD_SCENE}'", f"repeats={args.crowd_repeats}",
                                   f"crowd_jobs={crowd_jobs}", *choice, points(choice)]))
    return parts


def accuracy_points(full: bool) -> list[str]:
    """The accuracy study's points (conf/experiment/accuracy.yaml), without ACCURACY_FULL_ONLY's
    unless `full`."""
    points = yaml.safe_load((ROOT / "conf" / "experiment" / "accuracy.yaml").read_text())["points"].split(",")
    return [p for p in points if full or not p.startswith(ACCURACY_FULL_ONLY)]


def plan(args) -> dict[str, int | None]:
    """{folder: runs} of every multirun of the job, counted from the presets' sweeps with the job's
    overrides (table1's fixed-mesh point is chosen later, after the accuracy study: it does not
    change the count)."""
    runs = {}
    for study in args.studies:
        for folder, extra in study_parts(study, args, None):
            frames = [] if args.frames is None else [f"frames={args.frames}"]
            runs[folder] = planned_runs(study, [f"scale={args.scale}", *frames, *extra, *args.overrides])
    return runs


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m experiments.paper", description=__doc__.split("\n")[0])
    ap.add_argument("--scale", default="small", choices=("small", "paper"))
    ap.add_argument("--jobs", type=int, default=1,
                    help="runs at once (local processes; default 1: timed runs do not compete; with N, each run "
                         "gets cores // N numba threads)")
    ap.add_argument("--out", type=Path, default=None,
                    help="default results/paper/<timestamp>; the folder of a killed job: it continues there")
    ap.add_argument("--studies", nargs="+", default=None, metavar="STUDY",
                    help=f"any of {', '.join(STUDIES)} (default: {' '.join(DEFAULT_STUDIES)})")
    ap.add_argument("--full", action="store_true",
                    help=f"the default studies and what the default job leaves out to fit in about 90 minutes: "
                         f"{' '.join(s for s in FULL_STUDIES if s not in DEFAULT_STUDIES)}")
    ap.add_argument("--frames", type=int, default=None, help="frames per run (default: each scene's own)")
    ap.add_argument("--repeats", type=int, default=3, help="table1: runs per cell of karate and solo_dancer (seeds)")
    ap.add_argument("--crowd-repeats", type=int, default=1,
                    help="table1: runs per cell of the crowd (ten characters: ten times the cost)")
    ap.add_argument("--docs", type=Path, default=None, metavar="DIR",
                    help="also write the measurement pages into DIR (docs/results: the repository's) and the "
                         "README's headline table (python -m paper_figures --docs)")
    ap.add_argument("overrides", nargs="*", help="extra Hydra overrides for every run (e.g. crowd_jobs=1)")
    args = ap.parse_args(argv)
    if args.full and args.studies is not None:
        ap.error("--full and --studies: give one (--full is the studies "
                 f"{' '.join(FULL_STUDIES)})")
    args.studies = list(FULL_STUDIES if args.full else args.studies or DEFAULT_STUDIES)
    bad = [s for s in args.studies if s not in STUDIES]
    if bad:
        ap.error(f"unknown study {bad[0]!r}; known: {', '.join(STUDIES)}")
    args.studies = sorted(dict.fromkeys(args.studies), key=STUDIES.index)  # each once, in STUDIES' order
    if args.jobs < 1:
        ap.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.frames is not None and args.frames < 1:
        ap.error(f"--frames must be >= 1, got {args.frames}")
    for name in ("repeats", "crowd_repeats"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    args.jobs_cores = max(1, (os.cpu_count() or 1) // args.jobs)  # cores per run at once
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    out = (args.out or ROOT / "results" / "paper" / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")).resolve()
    out.mkdir(parents=True, exist_ok=True)
    command = shlex.join(["python", "-m", "experiments.paper", *(sys.argv[1:] if argv is None else argv)])
    try:  # a second job in this folder would skip what the first finished and share its cores
        with JobLock(out, command):
            return run_job(args, out, argv)
    except FolderInUse as exc:
        print(f"experiments.paper: {exc}", file=sys.stderr)
        return 2


def run_job(args, out: Path, argv=None) -> int:
    """The main job into `out` (main holds its lock)."""
    failed = []
    t_start = time.perf_counter()
    # Numba compiles a kernel the first time any process calls it and caches it on disk; on a
    # fresh machine the first runs' first frames would carry tens of seconds of compilation
    # (seen: 38 s in a 150-frame run, 40% of its mean time per frame). One short run of the
    # view-dependent karate (remesh, viewdep sizing, body contact, self-collision) fills the
    # cache first, so the studies time simulation only.
    write_text_atomic(out / "command.txt", shlex.join(["python", "-m", "experiments.paper",
                                                       *(sys.argv[1:] if argv is None else argv)]) + "\n")
    print("[0] compiling the solver's kernels once (numba cache), so that no timed frame pays for it", flush=True)
    with Heartbeat("[0] compiling"):
        subprocess.call(WARMUP + [f"hydra.run.dir={out / 'warmup'}"], cwd=ROOT, stdout=subprocess.DEVNULL)
    clock = JobClock(plan(args))
    print("[plan] " + ", ".join(f"{k} {'?' if n is None else n}" for k, n in clock.planned.items())
          + " runs; a line when a run ends, with the time left estimated from the runs so far", flush=True)
    for i, study in enumerate(args.studies, 1):
        for folder, extra in study_parts(study, args, out):
            print(f"[{i}/{len(args.studies)}] study {study} at scale={args.scale} -> {out / folder}", flush=True)
            t0 = time.perf_counter()
            cmd = study_command(study, out, args.scale, args.jobs, args.frames, [*extra, *args.overrides], folder)
            with StudyWatch(f"[{i}/{len(args.studies)}] {folder}:", folder, out / folder, clock):
                rc = subprocess.call(cmd, cwd=ROOT)
            print(f"[{i}/{len(args.studies)}] study {study} ({folder}): {'done' if rc == 0 else f'FAILED (exit {rc})'} "
                  f"in {(time.perf_counter() - t0) / 60:.1f} min", flush=True)
            if rc != 0:
                failed.append(folder)
    figures = out / "figures"
    print(f"figures and tables from {out} -> {figures}", flush=True)
    docs = [] if args.docs is None else ["--docs", str(args.docs.resolve())]
    with Heartbeat("figures"):
        rc = subprocess.call([sys.executable, "-m", "paper_figures", str(out), "--out", str(figures), *docs], cwd=ROOT)
    if rc != 0:
        failed.append("paper_figures")
    print(f"\nall done in {(time.perf_counter() - t_start) / 60:.1f} min")
    print(f"  run folders: {out}")
    print(f"  Table 1:     {figures / 'table1.md'} (.csv, .tex)")
    print(f"  Fig. 8:      {figures}/fig8_*.png")
    print(f"  Pareto:      {figures / 'pareto.png'} ({figures / 'pareto.md'})")
    print(f"  Report:      {out / 'report' / 'index.html'} (every table and figure on one page)")
    if "crowd_scaling" in args.studies:
        print(f"  Crowds:      {figures / 'crowd_scaling.md'} (.csv)")
    if failed:
        print(f"  FAILED: {', '.join(failed)} (the records above say which runs)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
