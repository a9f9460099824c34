"""Hydra callbacks of the studies (conf/experiment/*): what happens when a study's multirun ends.

``StudyCallback.on_multirun_end`` reads the run folders of the sweep directory (never
re-simulating) and

1. measures accuracy: when the study has a reference run (``reference: true``, the point
   ``conf/point/reference.yaml``), every other completed run of the same scene and seed is
   measured against it (experiments.accuracy: screen-space error in pixels and the ballooning of
   out-of-view cloth), which writes accuracy.parquet and accuracy.json into each run folder; with
   the callback's ``sync`` options (conf/experiment/accuracy.yaml), also the re-synchronised
   error of each of them and of the reference itself (experiments.sync: every run restarted from
   the reference's states), which writes sync.parquet and sync.json; and where the study has
   reference checks (``reference_check: fine | half_dt``, conf/point/reference_check/), the
   reference's own error: the reference restarted from each check's states, and from its own
   states perturbed by 0.1 mm (the floor), into the reference's folder as sync_fine.*,
   sync_half_dt.* and sync_floor.*;
2. makes the study's tables and figures (paper_figures) into ``<sweep dir>/figures``.

A failure in either is reported and does not undo the runs: the folders stay as written and
``python -m experiments.accuracy`` / ``python -m paper_figures`` can be re-run on them by hand.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import traceback
from pathlib import Path

import yaml
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from experiments.analysis.accuracy import AccuracyError, evaluate_runs, write_accuracy
from experiments.analysis.sync import (
    BEFORE_CUT,
    EVERY,
    HORIZON,
    RESOLUTION_SCALE,
    RESTARTS,
    check_options,
    write_sync,
)
from experiments.analysis.sync import evaluate_run as evaluate_sync


def run_folders(sweep_dir: Path) -> list[Path]:
    """The run folders directly under a multirun's sweep directory (those with a config.yaml)."""
    return sorted(p for p in Path(sweep_dir).iterdir() if p.is_dir() and (p / "config.yaml").exists())


def _completed(run: Path) -> bool:
    try:
        return json.loads((run / "summary.json").read_text()).get("status") == "completed"
    except (OSError, ValueError):
        return False


def measure_accuracy(sweep_dir: Path, log=print, sync: dict | None = None) -> int:
    """Measure every completed run against the reference of its scene and seed in `sweep_dir`: its
    reference run, or the ensemble of its reference runs (members 0, 1, ...: conf/point/member/K)
    with their chaos floor. Returns how many runs were measured (0 when the study has no
    reference). `sync` (every, horizon, before_cut, resolution_scale: experiments.sync's options;
    reference: bool) also measures the re-synchronised error of those runs and, with `reference`,
    of the reference (member 0), which restarted from its own states measures the restart itself (~0)."""
    runs = run_folders(sweep_dir)
    cfgs = {r: yaml.safe_load((r / "config.yaml").read_text()) for r in runs}
    ensembles: dict[tuple, list[Path]] = {}
    for r in runs:
        if cfgs[r].get("reference") and not cfgs[r].get("reference_check"):  # a check is not a member
            key = (cfgs[r]["scene"]["name"], cfgs[r].get("seed"))
            ensembles.setdefault(key, []).append(r)
    measured = 0
    for (scene, seed), members in ensembles.items():
        members = sorted(members, key=lambda r: cfgs[r].get("reference_member") or 0)
        unfinished = [m for m in members if not _completed(m)]
        for m in unfinished:
            log(f"accuracy: reference {m} did not complete; left out of the reference of {scene}, seed {seed}")
        members = [m for m in members if _completed(m)]
        if not members:
            log(f"accuracy: no reference of {scene}, seed {seed} completed; its runs are not measured")
            continue
        # with repeats, each seed has its own reference: a run is measured against its seed's
        targets = [r for r in runs if cfgs[r]["scene"]["name"] == scene and cfgs[r].get("seed") == seed
                   and not cfgs[r].get("reference") and _completed(r)]
        ref = members[0]
        if targets:
            log(f"accuracy: {len(targets)} run(s) of {scene} against "
                f"{ref.name if len(members) == 1 else f'an ensemble of {len(members)} references'}")
            tables = evaluate_runs(targets, members if len(members) > 1 else ref)
            for run, table in zip(targets, tables):
                write_accuracy(run, table, members if len(members) > 1 else ref)
                measured += 1
        if sync is not None and (cfgs[ref].get("reference_member") or 0) == 0:
            opts = {k: v for k, v in sync.items() if k not in ("reference", "members")}
            n = int(sync.get("members", 1))
            if n > len(members):
                log(f"sync: {n} members asked, {len(members)} completed; the windows restart from those")
            starts = members[:n] if n > 1 else ref  # every window from each of the first n members' states
            for run in ([ref] if sync.get("reference", True) else []) + targets:
                source = f"{ref.name}'s states" if n == 1 else f"{len(starts)} members' states"
                if measured_already(run, starts, opts):
                    log(f"sync: {run.name} measured already from {source} (its sync.json is newer than the runs)")
                    continue
                log(f"sync: {run.name} restarted from {source}")
                try:
                    table = evaluate_sync(run, starts, **opts, log=log)
                except AccuracyError as exc:  # e.g. a run too short for a window: the others go on
                    log(f"sync: {run.name} not measured: {exc}")
                    continue
                write_sync(run, table, starts, **{k: v for k, v in opts.items() if k not in NOT_WRITTEN})
            checks = [r for r in runs if cfgs[r].get("reference_check") and cfgs[r]["scene"]["name"] == scene
                      and cfgs[r].get("seed") == seed and _completed(r)]
            if checks:
                reference_error(ref, {cfgs[c]["reference_check"]: c for c in checks}, opts, log)
    return measured


def measured_already(run: Path, starts, opts: dict) -> bool:
    """Whether `run`'s sync.json holds the re-synchronised error with these options from these
    reference runs and was written after all of them finished (a main job run again in its folder,
    experiments.paper: the windows are not simulated again)."""
    starts = [starts] if isinstance(starts, Path) else list(starts)
    path = run / "sync.json"
    try:
        done = json.loads(path.read_text())
        written = path.stat().st_mtime_ns
        finished = max((r / "summary.json").stat().st_mtime_ns for r in [run, *starts])
    except (OSError, ValueError):
        return False
    same = all(done.get(k) == opts[k] for k in ("every", "horizon", "before_cut", "resolution_scale", "restart")
               if k in opts)
    views = all(f"sync_error_px_view_{v}_mean" in done for v in opts.get("views") or [])
    views = views and (not opts.get("perceptual") or "flip_mean" in done)
    return (same and views and done.get("reference") == str(starts[0].resolve())
            and done.get("members") == len(starts) and written > finished)


# the sync options that write_sync does not take (what was measured is in the table's columns)
NOT_WRITTEN = ("per_frame", "views", "perceptual")


# The perturbed restart's displacement: 0.1 mm, a thousandth of the study's edges (centimetres) and far
# below a pixel of any shot, so what the reference restarted so against itself shows is chaos, not
# the perturbation.
FLOOR_PERTURBATION_M = 1e-4


def reference_error(ref: Path, checks: dict, opts: dict, log=print) -> None:
    """The reference's own error, by the re-synchronised error on the study's windows: the reference
    restarted from each check's states (`checks`: reference_check -> run folder; fine: twice its
    segments, half_dt: half its time step) against the check's continuation, into the reference's
    folder as sync_<check>.parquet/.json; and the reference restarted from its own states moved by
    FLOOR_PERTURBATION_M against itself (sync_floor.*: the floor chaos sets within a window)."""
    write_opts = {k: v for k, v in opts.items() if k not in NOT_WRITTEN}
    for check, run in sorted(checks.items()):
        log(f"sync: the reference {ref.name} restarted from {run.name}'s states (its own error: {check})")
        try:
            table = evaluate_sync(ref, run, **opts, log=log)
        except AccuracyError as exc:
            log(f"sync: the reference's own error ({check}) not measured: {exc}")
            continue
        write_sync(ref, table, run, **write_opts, stem=f"sync_{check}")
    log(f"sync: the reference {ref.name} restarted {FLOOR_PERTURBATION_M * 1e3:g} mm off its own states (the floor)")
    try:
        table = evaluate_sync(ref, ref, **opts, log=log, perturb_m=FLOOR_PERTURBATION_M)
    except AccuracyError as exc:
        log(f"sync: the reference's floor not measured: {exc}")
        return
    write_sync(ref, table, ref, **write_opts, stem="sync_floor")


def make_figures(sweep_dir: Path, log=print) -> Path:
    """All tables and figures of the study, into <sweep_dir>/figures."""
    # paper_figures loads matplotlib.pyplot: ~1-2 s (python -X importtime), and Hydra unpickles this
    # callback in every job process of a study; only the end of the multirun needs the figures
    from paper_figures.__main__ import main as figures_main  # noqa: PLC0415 - import cost, above

    out = Path(sweep_dir) / "figures"
    figures_main([str(sweep_dir), "--out", str(out)])
    return out


REDO = {"accuracy": "python -m experiments.accuracy (and python -m experiments.sync)",
        "figures": "python -m paper_figures"}


class StudyCallback(Callback):
    """Registered by every conf/experiment/* preset (hydra.callbacks.study)."""

    def __init__(self, accuracy: bool = True, figures: bool = True, sync=None) -> None:
        """`sync`: None, or the options of the re-synchronised error (every, horizon, before_cut,
        resolution_scale, restart, per_frame; experiments.sync defaults for those not given),
        `members` (default 1: every window restarted from member 0's states only; N: from each of
        the first N members') and `reference` (default true: also the reference restarted from its
        own states, which measures the restart at the cost of the reference's frames again)."""
        self.accuracy, self.figures = bool(accuracy), bool(figures)
        self.sync = None
        if sync is not None:
            opts = {"every": EVERY, "horizon": HORIZON, "before_cut": BEFORE_CUT, "resolution_scale": RESOLUTION_SCALE,
                    "reference": True, "restart": "reference_mesh", "per_frame": False, "members": 1, "views": [],
                    "perceptual": False}
            unknown = set(sync) - set(opts)
            if unknown:
                raise ValueError(f"hydra.callbacks.study.sync: unknown option(s) {sorted(unknown)}; "
                                 f"known: {sorted(opts)}")
            opts.update({k: sync[k] for k in sync})
            views = opts["views"]
            views = list(views) if isinstance(views, (list, tuple)) or OmegaConf.is_list(views) else views
            if not (isinstance(views, list) and all(isinstance(v, str) for v in views)):
                raise ValueError(f"hydra.callbacks.study.sync.views: a list of camera names (conf/camera/), "
                                 f"got {opts['views']!r}")
            opts["views"] = views
            check_options(opts["every"], opts["horizon"], opts["before_cut"], opts["resolution_scale"])
            for flag in ("reference", "per_frame", "perceptual"):
                if not isinstance(opts[flag], bool):
                    raise ValueError(f"hydra.callbacks.study.sync.{flag}: true or false, got {opts[flag]!r}")
            if opts["perceptual"] and importlib.util.find_spec("flip_evaluator") is None:
                raise ValueError("hydra.callbacks.study.sync.perceptual: FLIP needs the flip-evaluator package "
                                 "(pip install -e '.[perceptual]'), which is not installed")
            m = opts["members"]
            if not (isinstance(m, int) and not isinstance(m, bool) and m >= 1):
                raise ValueError(f"hydra.callbacks.study.sync.members: an integer >= 1, got {opts['members']!r}")
            if opts["restart"] not in RESTARTS:
                raise ValueError(f"hydra.callbacks.study.sync.restart: one of {', '.join(RESTARTS)}, "
                                 f"got {opts['restart']!r}")
            self.sync = opts

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        if not sweep_dir.exists():
            return
        steps = (("accuracy", self.accuracy, lambda d: measure_accuracy(d, sync=self.sync)),
                 ("figures", self.figures, make_figures))
        for step, enabled, fn in steps:
            if not enabled:
                continue
            try:
                fn(sweep_dir)
            except Exception:  # noqa: BLE001 - the runs stay; say what failed and how to redo it
                print(f"study callback: {step} failed for {sweep_dir}:\n{traceback.format_exc()}"
                      f"the run folders are intact; re-run it with "
                      f"{REDO[step]}",
                      file=sys.stderr)
