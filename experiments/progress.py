"""Where a long job is: runs planned and finished per study, and an estimate of the time left.

The main job (experiments.paper) runs each study as a Hydra multirun in a child process and,
while it runs, watches the study's sweep folder (:class:`StudyWatch`): a run is finished when its
``summary.json`` exists (completed, interrupted or diverged alike). It prints a line when a run
finishes (run k of m, this study's and the whole job's estimated time left), and a line at least
every HEARTBEAT_S seconds otherwise (the run in progress and for how long, or, once every run is
done, that the study is evaluating its runs), so that the job is never silent for long.

The runs a study plans are counted from its own sweep (:func:`planned_runs`): the preset composed
with the job's overrides, its ``hydra.sweeper.params`` expanded by Hydra's override parser.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf

from experiments.checks import plain_experiment

CONF = str(Path(__file__).resolve().parents[1] / "conf")
# The longest the watch stays silent while a study runs or evaluates (the bound: a minute).
HEARTBEAT_S = 60.0
# How often the sweep folder is looked at (a glob of a few hundred folders at most).
POLL_S = 5.0


def planned_runs(study: str, overrides=()) -> int | None:
    """The number of runs of ``python -m experiments.run experiment=STUDY OVERRIDES``: the
    product of the lengths of its sweeper's parameter lists. None when the sweep cannot be
    expanded here (the watch then counts without a total)."""
    sweeps = [o for o in overrides if o.startswith("hydra.sweeper.params.")]
    plain = [o for o in overrides if not o.startswith("hydra.")]
    try:
        with initialize_config_dir(config_dir=CONF, version_base="1.3"):
            cfg = compose(config_name="config", overrides=[f"experiment={study}", *plain_experiment(plain)],
                          return_hydra_config=True)
        params = OmegaConf.to_container(cfg.hydra.sweeper.params, resolve=True) or {}
        for o in sweeps:  # the job's own choice of a swept list (table1's scenes)
            key, _, value = o[len("hydra.sweeper.params."):].partition("=")
            params[key] = value.strip("'\"")
        parsed = OverridesParser.create().parse_overrides([f"{k}={v}" for k, v in params.items()])
        return math.prod(len(list(o.sweep_string_iterator())) if o.is_sweep_override() else 1 for o in parsed)
    except Exception:  # noqa: BLE001 - a count is a convenience: never stop a job for it
        return None


def finished_runs(sweep_dir: Path) -> list[Path]:
    """Run folders of a sweep with a summary.json (the run ended, however)."""
    return sorted(p.parent for p in Path(sweep_dir).glob("*/summary.json"))


def minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min"


class JobClock:
    """The whole job's runs: planned per study and the time each finished run took, for the estimate."""

    def __init__(self, planned: dict[str, int | None]):
        self.planned = dict(planned)
        self.done: dict[str, list[float]] = {k: [] for k in planned}

    def left_s(self, current: str | None = None) -> tuple[float | None, float | None]:
        """(seconds left in study `current`, seconds left in the job): the runs not yet done times the
        mean run time of their own study where it has runs, else of every run so far; None without a
        finished run or a count."""
        every = [t for ts in self.done.values() for t in ts]
        if not every or any(v is None for v in self.planned.values()):
            return None, None
        mean_all = sum(every) / len(every)
        def study_left(name):
            ts = self.done[name]
            return max(self.planned[name] - len(ts), 0) * (sum(ts) / len(ts) if ts else mean_all)
        return (study_left(current) if current else None), sum(study_left(n) for n in self.planned)


class Heartbeat:
    """A line every HEARTBEAT_S seconds while a step without runs of its own goes on (the main
    job's kernel warm-up, its figures): ``with Heartbeat("[0] warm-up"): ...``."""

    def __init__(self, label: str, log=print, heartbeat_s: float = HEARTBEAT_S):
        self.label, self.log, self.heartbeat_s = label, log, heartbeat_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)

    def __enter__(self):
        self._t0 = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        return False

    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            self.log(f"{self.label}: still going after {minutes(time.monotonic() - self._t0)}")


class StudyWatch:
    """Watches one study's sweep folder from a thread while its multirun runs (a context manager)."""

    def __init__(self, label: str, name: str, sweep_dir: Path, clock: JobClock, log=print,
                 heartbeat_s: float = HEARTBEAT_S, poll_s: float = POLL_S):
        self.label, self.name, self.sweep_dir, self.clock, self.log = label, name, Path(sweep_dir), clock, log
        self.heartbeat_s, self.poll_s = heartbeat_s, poll_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)

    def __enter__(self):
        self._seen = set(finished_runs(self.sweep_dir)) if self.sweep_dir.exists() else set()
        self._t_last = self._t_said = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._check()  # the last runs, finished just before the multirun ended
        return False

    def _check(self) -> None:
        now = time.monotonic()
        new = [r for r in finished_runs(self.sweep_dir) if r not in self._seen] if self.sweep_dir.exists() else []
        planned = self.clock.planned.get(self.name)
        for r in new:
            self._seen.add(r)
            self.clock.done[self.name].append((now - self._t_last) / len(new))
            k = len(self.clock.done[self.name])
            study_left, job_left = self.clock.left_s(self.name)
            eta = ("" if job_left is None else
                   f"; about {minutes(study_left)} left in this study, {minutes(job_left)} in the job")
            self.log(f"{self.label} run {k}{'' if planned is None else f'/{planned}'} done ({r.name}){eta}")
            self._t_said = now
        if new:
            self._t_last = now
        if now - self._t_said >= self.heartbeat_s:
            k = len(self.clock.done[self.name])
            if planned is not None and k >= planned:
                self.log(f"{self.label} all {planned} runs done; evaluating them (accuracy, figures) for "
                         f"{minutes(now - self._t_last)}")
            else:
                self.log(f"{self.label} run {k + 1}{'' if planned is None else f'/{planned}'} running for "
                         f"{minutes(now - self._t_last)}")
            self._t_said = now

    def _watch(self) -> None:
        while not self._stop.wait(self.poll_s):
            self._check()
