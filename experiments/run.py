"""Run one simulation from the Hydra config: ``python -m experiments.run scene=flag frames=30``.

Everything is built and checked from the config before any work starts; a config error stops
with one line ``config error: KEY: message`` and exit code 2, nothing written but Hydra's
.hydra/. What the command line sets wins over the scene's scale preset
(experiments.build.command_line_wins). The run folder (Hydra's output dir) receives the resolved
config (config.yaml: what was asked), resolved.yaml (the values the run used, read from the built
objects: experiments.build.resolved_record), manifest.json, frames.parquet, summary.json,
recording.rrd and optional OBJ frames; every ``output.checkpoint_every`` frames the whole state
goes to checkpoint/state.pkl, from which ``python -m experiments.resume RUN_DIR`` continues a
killed run (``python -m experiments.replay RUN_DIR`` re-runs a folder and checks that it
reproduces).

A crowd scene (``scene=multiple_dancers``) runs each character as its own simulation in its own
sub-folder (``dancer_00`` ...), `crowd_jobs` at a time on Ray or in local processes
(`crowd_backend`, experiments.crowd), all under the one camera; the run folder then holds the
combined records (sums over the characters) and characters.csv, one row per character (see
cloth.runner.combine_crowd). Each character's results are those of running it alone.
"""

from __future__ import annotations

import os
import re
import signal
import sys
from pathlib import Path

import hydra
import yaml
from hydra.types import RunMode
from omegaconf import DictConfig

from cloth.scenes.registry import CROWDS
from cloth.signals import Terminated, sigterm_interrupts
from cloth.simulation import SimulationDiverged
from experiments.build import ConfigError, command_line_wins, plain_experiment
from experiments.launch import run_from_config, share_cores
from experiments.resuming import continue_in_place

# The config tree, as an absolute path: `cloth-run` (a console script) imports this module as
# experiments.run, and Hydra would then look for a relative config_path as a Python package.
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def config_error(exc) -> None:
    """Stop with exit code 2 and one line on stderr: `config error: KEY: message`."""
    print("config error: " + " ".join(str(exc).split()), file=sys.stderr)
    sys.exit(2)


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    hydra_cfg = hydra.core.hydra_config.HydraConfig.get()
    out_dir = Path(hydra_cfg.runtime.output_dir)
    # In a multirun a run that goes bad must not stop the others: its summary.json says
    # 'diverged' and the aggregation reports it; a single run exits non-zero.
    multirun = hydra_cfg.mode == RunMode.MULTIRUN
    # runs at once on this machine: the launcher's parallel runs (joblib's n_jobs; a cluster
    # launcher's runs each get a machine of their own), times a crowd's parallel characters
    launcher_jobs = int(hydra_cfg.launcher.get("n_jobs", 1) or 1) if multirun else 1
    jobs = cfg.get("crowd_jobs", 1)  # checked by the build (crowd_size); a bad one counts as 1 here
    crowd = jobs if cfg.scene.name in CROWDS and type(jobs) is int and jobs > 1 else 1
    share_cores(launcher_jobs * crowd)
    try:
        # what the command line says wins over the scene's scale preset (recorded so in config.yaml)
        cfg = command_line_wins(cfg, hydra_cfg.overrides.task)
        with sigterm_interrupts():  # a scheduler's SIGTERM stops the run as Ctrl-C does, its records written
            summary = continue_in_place(cfg, out_dir) if cfg.output.get("resume") is True else None
            if summary is None:
                summary = run_from_config(cfg, out_dir)
    except ConfigError as exc:
        config_error(exc)
    except KeyboardInterrupt as exc:  # Ctrl-C or a scheduler's SIGTERM: the records are written
        if multirun:  # the whole sweep stops
            raise
        signum = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
        print(f"interrupted ({signal.Signals(signum).name}): the frames so far are in {out_dir}; "
              f"continue with: python -m experiments.resume {out_dir}", file=sys.stderr)
        sys.exit(128 + signum)
    except SimulationDiverged as exc:
        print(f"run stopped: {exc}\nframes written so far are in {out_dir}", file=sys.stderr)
        if multirun:
            return
        sys.exit(3)
    print(f"run folder: {out_dir}")
    if "characters" in summary:
        print(f"  crowd of {summary['characters']} characters (one sub-folder each, per character in "
              f"characters.csv), run in {summary.get('crowd_ran_in', '?')}; status: {summary['status']}")
    print(f"  frames: {summary['frames_completed']}  faces: {summary.get('faces_mean', 0):.0f}  "
          f"mean time per frame: {summary.get('sim_s_mean', 0):.3f} s simulation, "
          f"{summary.get('wall_s_mean', 0):.3f} s with I/O")
    for note in summary.get("notes", []):
        print(f"  note: {note}")
    if cfg.output.rerun:
        rrd = "dancer_*/recording.rrd" if "characters" in summary else "recording.rrd"
        print(f"  recording: {out_dir / rrd}  (view with: rerun {out_dir / rrd})")
    if summary.get("status") not in (None, "completed"):
        print(f"  status: {summary['status']}: {summary.get('message', '')}", file=sys.stderr)
        if not multirun:
            sys.exit(3)



def unknown_choice(overrides: list[str], conf_dir: Path = CONF_DIR) -> str | None:
    """The message for the first command-line choice of a config group that has no such config
    (``scene=nope``, ``material=silk``), or None. Checked before Hydra composes, so that the
    error is one line naming the key, not Hydra's report with its search path. Sweep values
    (``material=cotton,denim``) are checked one by one; Hydra's sweep functions are left to it."""
    for arg in overrides:
        m = re.fullmatch(r"[+~]{0,2}([A-Za-z_]\w*)=(.*)", arg)
        if not m or not (conf_dir / m.group(1)).is_dir():
            continue
        group, value = m.groups()
        for choice in value.split(","):
            if not re.fullmatch(r"[\w.\-/]+", choice) or choice == "null":
                continue
            if not (conf_dir / group / f"{choice}.yaml").is_file():
                known = sorted(str(p.relative_to(conf_dir / group).with_suffix(""))
                               for p in (conf_dir / group).rglob("*.yaml") if not p.name.startswith("_"))
                return f"{group}: unknown {group} {choice!r}; known: {', '.join(known)}"
    return None


def unwritable_run_dir(argv: list[str], conf_dir: Path = CONF_DIR) -> str | None:
    """The message for a run folder (hydra.run.dir; hydra.sweep.dir with --multirun) that cannot
    be created or written, or None. Checked before Hydra composes: Hydra makes the folder before
    the run starts and would stop with a traceback. The folder's fixed part (up to its first
    ${...}) is checked: its nearest existing ancestor must be a writable folder."""
    # a study preset (experiment=NAME) is a multirun of its own (conf/experiment/_base.yaml)
    multirun = any(a in ("-m", "--multirun") or a.startswith("experiment=") for a in plain_experiment(argv))
    key = "hydra.sweep.dir" if multirun else "hydra.run.dir"
    given = [a.split("=", 1)[1] for a in argv if re.fullmatch(rf"\+{{0,2}}{re.escape(key)}=.*", a)]
    if given:
        where = given[-1]
    else:
        conf = yaml.safe_load((conf_dir / "config.yaml").read_text()) or {}
        where = ((conf.get("hydra") or {}).get("sweep" if multirun else "run") or {}).get("dir") or ""
    fixed = Path(where.split("${", 1)[0] or ".").expanduser()
    path = fixed if fixed.is_absolute() else Path.cwd() / fixed
    while not path.exists() and path != path.parent:
        path = path.parent
    if not path.is_dir():
        return f"{key}: cannot make the run folder {where}: {path} is not a folder"
    if not os.access(path, os.W_OK | os.X_OK):
        return f"{key}: cannot make the run folder {where}: {path} is not writable"
    return None


def cli() -> None:
    """The command line (`python -m experiments.run`, `cloth-run`): a mistyped choice or a run
    folder that cannot be made stops with one config error line, before Hydra composes."""
    sys.argv[1:] = plain_experiment(sys.argv[1:])  # +experiment=NAME, the form before, still works
    problem = unknown_choice(sys.argv[1:]) or unwritable_run_dir(sys.argv[1:])
    if problem:
        print(f"config error: {problem}", file=sys.stderr)
        sys.exit(2)
    main()


if __name__ == "__main__":
    cli()
