"""Launching runs from a composed config: one run (:func:`run_from_config`: build, write the
run folder's inputs, run, record), a crowd's characters on their backend (:func:`run_crowd`,
:func:`run_character`, experiments.crowd), the Rerun recorder, the checkpoint interval and the
share of the machine's cores a run gets (:func:`share_cores`). The library behind
``python -m experiments.run`` (the Hydra command line), experiments.resume and experiments.replay.
"""

from __future__ import annotations

import json
import os
import uuid
from pathlib import Path

import numba
import yaml
from omegaconf import DictConfig, OmegaConf

from cloth.io.manifest import environment_manifest, write_json_atomic, write_text_atomic
from cloth.io.recorder import Recorders, RerunRecorder
from cloth.physics.linsolve import limit_solver_threads
from cloth.simulation import SimulationDiverged
from experiments.build import ConfigError, build, crowd_backend, crowd_size, resolved_record
from experiments.crowd import SHARE_ENV, run_characters, where

# cloth.runner is imported where it is used: experiments.run, the command line, imports this
# module, and a mistyped choice (`scene=nope`, checked by experiments.run.unknown_choice before
# Hydra composes) is answered before any run. cloth.runner adds ~0.6 s (python -X importtime, on
# top of the imports above: pandas, tqdm, the writers of a run) to the ~2.5 s of that answer.


def make_recorder(cfg: DictConfig, out_dir: Path, root: str = "world", recording_id=None, log_camera=True,
                  name: str = "recording.rrd", frame_time: float | None = None, resume_from: int | None = None):
    """The run's recorders: Rerun (out_dir/name) with output.rerun, a USD stage (out_dir/cloth.usdc,
    cloth.io.usd) with output.usd_every > 0 and the scene's `frame_time`, continued after frame
    `resume_from` when resuming; None when neither."""
    recorders = []
    if cfg.output.rerun:
        recorders.append(RerunRecorder(out_dir / name, app_id=f"cloth_{cfg.scene.name}", root=root,
                                       recording_id=recording_id, log_camera=log_camera))
    usd_every = int(cfg.output.get("usd_every", 0) or 0)
    if usd_every > 0 and frame_time is not None:
        from cloth.io.usd import USD_FILE, UsdRecorder  # noqa: PLC0415 - pxr only when asked for

        recorders.append(UsdRecorder(out_dir / USD_FILE, usd_every, frame_time, resume_from=resume_from,
                                     log_camera=log_camera))
    if not recorders:
        return None
    return recorders[0] if len(recorders) == 1 else Recorders(recorders)


RESOLVED = "resolved.yaml"  # next to config.yaml: the values the run used (experiments.build.resolved_record)


def write_resolved(built, out_dir: Path) -> None:
    write_text_atomic(out_dir / RESOLVED, yaml.safe_dump(resolved_record(built), sort_keys=False))


def write_inputs(cfg: DictConfig, out_dir: Path, recording_id: str | None = None, built=None) -> None:
    """config.yaml, resolved.yaml (of `built`) and manifest.json; an output folder that cannot be
    written is a ConfigError naming hydra.run.dir."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out_dir / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))
        if built is not None:
            write_resolved(built, out_dir)
        # the Rerun recording id: a resumed run continues the recording under the same id
        write_json_atomic(out_dir / "manifest.json",
                          environment_manifest(int(cfg.seed), {"recording_id": recording_id}))
    except OSError as exc:
        raise ConfigError(f"hydra.run.dir: cannot write the run folder {out_dir}: {exc.strerror or exc}") from None


def checkpoint_every(cfg: DictConfig) -> int:
    """output.checkpoint_every (0 when absent: configs of older runs); ConfigError if bad."""
    every = cfg.output.get("checkpoint_every", 0)
    if not (isinstance(every, int) and not isinstance(every, bool) and every >= 0):
        raise ConfigError(f"output.checkpoint_every: must be an integer >= 0 (frames; 0: never), got {every!r}")
    return every


def run_character(config_yaml: str, character: int, out_dir: str, recording_id: str) -> dict:
    """One character of a crowd, in a worker process: rebuild it from the resolved config and run."""
    from cloth.runner import run  # noqa: PLC0415 - import cost (module note)

    cfg = OmegaConf.create(config_yaml)
    built = build(cfg, character=character)
    sim, n_frames = built.sim, built.frames
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_resolved(built, out)
    recorder = make_recorder(cfg, out, root=f"world/dancer_{character:02d}", recording_id=recording_id,
                             log_camera=character == 0, frame_time=sim.scene.frame_time)
    try:
        return run(sim, n_frames, out, recorder=recorder, obj_every=int(cfg.output.obj_every), progress=False,
                   stills_every=int(cfg.output.get("stills_every", 0)),
                   states_every=int(cfg.output.get("states_every", 1)), checkpoint_every=checkpoint_every(cfg))
    except SimulationDiverged:  # its summary says so; the other characters go on
        return json.loads((out / "summary.json").read_text())


def run_crowd(cfg: DictConfig, out_dir: Path, dancers: int) -> dict:
    """Every character of a crowd on its backend (experiments.crowd), then the combined records."""
    from cloth.runner import combine_crowd  # noqa: PLC0415 - import cost (module note)

    first = build(cfg, character=0)  # every config check, before any output
    checkpoint_every(cfg)
    backend = crowd_backend(cfg)
    recording_id = str(uuid.uuid4())
    write_inputs(cfg, out_dir, recording_id, first)  # character 0's values (each folder has its own)
    config_yaml = OmegaConf.to_yaml(cfg, resolve=True)
    dirs = [out_dir / f"dancer_{i:02d}" for i in range(dancers)]
    jobs = int(cfg.crowd_jobs)
    args = [(config_yaml, i, str(d), recording_id) for i, d in enumerate(dirs)]
    workers, errors = {}, {}
    try:
        run_characters(run_character, args, jobs, backend, workers, errors)
    finally:  # a failed character keeps what it wrote; the crowd's records say which one
        _, summary = combine_crowd(dirs, out_dir, errors=errors, extra={
            "crowd_backend": backend, "crowd_ran_in": where(backend, jobs, len(args)),
            "workers": [workers.get(i) for i in range(dancers)]})
        crowd_stage(cfg, out_dir, dirs, first.sim.scene.frame_time)
    return summary


def crowd_stage(cfg: DictConfig, out_dir: Path, dirs, frame_time: float) -> None:
    """With output.usd_every, the crowd's stage (crowd.usda) over its characters' (cloth.io.usd)."""
    if int(cfg.output.get("usd_every", 0) or 0) > 0:
        from cloth.io.usd import CROWD_USD_FILE, write_crowd_stage  # noqa: PLC0415 - pxr only when asked for

        write_crowd_stage(out_dir / CROWD_USD_FILE, dirs, frame_time)


def threads_per_run(cores: int, runs_at_once: int) -> int:
    """Numba threads for each of `runs_at_once` runs on `cores` cores, so that runs x threads <=
    cores (at least one thread each): runs that are timed must not compete for cores."""
    return max(1, int(cores) // max(1, int(runs_at_once)))


def share_cores(runs_at_once: int) -> int:
    """Give this process, and the processes it starts (a crowd's characters), their share of the
    machine's cores, numba's threads and the factorization's (cloth.physics.linsolve.limit_solver_threads);
    returns the thread count (recorded as numba_threads in manifest.json).

    The user's NUMBA_NUM_THREADS (what numba read at import: numba.config.NUMBA_NUM_THREADS) is a
    ceiling, never rewritten: numba re-reads the environment at every compilation and refuses a
    value other than the one its thread pool started with (a cold cache with NUMBA_NUM_THREADS=1
    stopped a run). Worker processes read their share from SHARE_ENV (experiments.crowd.here)."""
    threads = min(threads_per_run(os.cpu_count() or 1, runs_at_once), numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(threads)
    limit_solver_threads(threads)  # the factorization's MKL threads too: they waited on each other's cores
    os.environ[SHARE_ENV] = str(threads)  # inherited by worker processes started from here
    return numba.get_num_threads()


def run_from_config(cfg: DictConfig, out_dir: Path) -> dict:
    """Validate, build, run and record; returns the summary (raises ConfigError first if bad)."""
    from cloth.runner import run  # noqa: PLC0415 - import cost (module note)

    dancers = crowd_size(cfg)
    if dancers is not None:
        return run_crowd(cfg, out_dir, dancers)
    built = build(cfg)  # every config check happens here, before any output
    sim, n_frames = built.sim, built.frames
    every = checkpoint_every(cfg)
    recording_id = str(uuid.uuid4())
    write_inputs(cfg, out_dir, recording_id, built)
    recorder = make_recorder(cfg, out_dir, recording_id=recording_id, frame_time=sim.scene.frame_time)
    return run(sim, n_frames, out_dir, recorder=recorder,
               obj_every=int(cfg.output.obj_every),
               progress=bool(cfg.output.progress), stills_every=int(cfg.output.get("stills_every", 0)),
               states_every=int(cfg.output.get("states_every", 1)), checkpoint_every=every)
