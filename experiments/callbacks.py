"""Hydra callbacks of the studies (conf/experiment/*): what happens when a study's multirun ends.

``StudyCallback.on_multirun_end`` reads the run folders of the sweep directory (never
re-simulating) and

1. measures accuracy: when the study has a reference run (``reference: true``, the point
   ``conf/point/reference.yaml``), every other completed run of the same scene and seed is
   measured against it (experiments.accuracy: screen-space error in pixels and the ballooning of
   out-of-view cloth), which writes accuracy.parquet and accuracy.json into each run folder;
2. makes the study's tables and figures (paper_figures) into ``<sweep dir>/figures``.

A failure in either is reported and does not undo the runs: the folders stay as written and
``python -m experiments.accuracy`` / ``python -m paper_figures`` can be re-run on them by hand.
"""

from __future__ import annotations

import json
import sys
import traceback
from pathlib import Path

import yaml
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from experiments.accuracy import evaluate_runs, write_accuracy


def run_folders(sweep_dir: Path) -> list[Path]:
    """The run folders directly under a multirun's sweep directory (those with a config.yaml)."""
    return sorted(p for p in Path(sweep_dir).iterdir() if p.is_dir() and (p / "config.yaml").exists())


def _completed(run: Path) -> bool:
    try:
        return json.loads((run / "summary.json").read_text()).get("status") == "completed"
    except (OSError, ValueError):
        return False


def measure_accuracy(sweep_dir: Path, log=print) -> int:
    """Measure every completed run against the reference run of its scene and seed in `sweep_dir`; returns how
    many runs were measured (0 when the study has no reference)."""
    runs = run_folders(sweep_dir)
    cfgs = {r: yaml.safe_load((r / "config.yaml").read_text()) for r in runs}
    measured = 0
    for ref in [r for r in runs if cfgs[r].get("reference")]:
        scene, seed = cfgs[ref]["scene"]["name"], cfgs[ref].get("seed")
        if not _completed(ref):
            log(f"accuracy: reference {ref} did not complete; its scene's runs are not measured")
            continue
        # with repeats, each seed has its own reference: a run is measured against its seed's
        targets = [r for r in runs if r != ref and cfgs[r]["scene"]["name"] == scene and cfgs[r].get("seed") == seed
                   and not cfgs[r].get("reference") and _completed(r)]
        if not targets:
            continue
        log(f"accuracy: {len(targets)} run(s) of {scene} against {ref.name}")
        tables = evaluate_runs(targets, ref)
        for run, table in zip(targets, tables):
            write_accuracy(run, table, ref)
            measured += 1
    return measured


def make_figures(sweep_dir: Path, log=print) -> Path:
    """All tables and figures of the study, into <sweep_dir>/figures."""
    # paper_figures loads matplotlib.pyplot: ~1-2 s (python -X importtime), and Hydra unpickles this
    # callback in every job process of a study; only the end of the multirun needs the figures
    from paper_figures.__main__ import main as figures_main  # noqa: PLC0415 - import cost, above

    out = Path(sweep_dir) / "figures"
    figures_main([str(sweep_dir), "--out", str(out)])
    return out


class StudyCallback(Callback):
    """Registered by every conf/experiment/* preset (hydra.callbacks.study)."""

    def __init__(self, accuracy: bool = True, figures: bool = True) -> None:
        self.accuracy, self.figures = bool(accuracy), bool(figures)

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        if not sweep_dir.exists():
            return
        for step, enabled, fn in (("accuracy", self.accuracy, measure_accuracy),
                                  ("figures", self.figures, make_figures)):
            if not enabled:
                continue
            try:
                fn(sweep_dir)
            except Exception:  # noqa: BLE001 - the runs stay; say what failed and how to redo it
                print(f"study callback: {step} failed for {sweep_dir}:\n{traceback.format_exc()}"
                      f"the run folders are intact; re-run it with "
                      f"{'python -m experiments.accuracy' if step == 'accuracy' else 'python -m paper_figures'}",
                      file=sys.stderr)
