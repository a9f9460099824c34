"""Resume a killed run from its last checkpoint: ``python -m experiments.resume RUN_DIR``.

A run saves its complete state every ``output.checkpoint_every`` frames (default 10) to
``RUN_DIR/checkpoint/state.pkl`` (cloth.io.checkpoint; only the latest is kept, and it is
removed when the run completes). Resuming reloads RUN_DIR/config.yaml and that checkpoint and
continues in the same folder to the run's ``frames``:

1. frames.parquet is first cut back to the checkpoint's frame (the records the checkpoint
   holds), so frames a killed run wrote after its last checkpoint are simulated again;
2. the simulation continues from the unpickled state; its records, frames.parquet (apart from
   the wall-time columns) and final node positions (final_state.npz) equal those of an
   uninterrupted run (tests/test_reproducibility.py kills a run with SIGKILL and checks this);
3. the Rerun recording continues in a second file, ``recording_from_NNNNN.rrd`` (NNNNN = the
   checkpoint's frame), under the recording id of the first (manifest.json ``recording_id``),
   so ``rerun RUN_DIR/recording*.rrd`` shows the whole run; recording.rrd is left as it was;
4. manifest.json gets an entry in ``resumes`` (frame, and the environment that resumed).

A crowd run (sub-folders ``dancer_NN``) resumes each character that did not complete from its
own checkpoint (a character that had not started yet runs from the beginning), on the crowd's
backend (`crowd_backend`, experiments.crowd), then recombines the crowd's records
(cloth.runner.combine_crowd).

Refused, with one message and exit code 2: a folder that is not a run folder, a run that
already completed, a run that diverged (it is deterministic: it would diverge again), a run
without a checkpoint (killed before its first one, or ``output.checkpoint_every=0``: run it
again), a checkpoint that cannot be read, or one that refers to anything but the project's
classes, numpy arrays and a few builtins (cloth.io.checkpoint.UnsafeCheckpoint: it is never
loaded, as run folders are shared and a pickle could run any code). Exit code 3: the resumed
run stopped (diverged or failed), as experiments.run.
A checkpoint written by other code (git commit, uncommitted changes, package versions) is
resumed with a warning: the result may then differ from an uninterrupted run.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig, OmegaConf

from cloth.io.checkpoint import CHECKPOINT_DIR, CHECKPOINT_INFO, CheckpointError, checkpoint_path, load_checkpoint
from cloth.io.manifest import code_version, environment_manifest, write_json_atomic, write_parquet_atomic
from cloth.runner import combine_crowd, run
from cloth.signals import Terminated, sigterm_interrupts
from cloth.simulation import SimulationDiverged
from experiments.build import ConfigError, crowd_backend, crowd_size, run_frames
from experiments.crowd import run_characters, where
from experiments.launch import checkpoint_every, make_recorder, run_character


class ResumeError(RuntimeError):
    """A folder that cannot be resumed; the message says why."""


def _load_config(run_dir: Path) -> DictConfig:
    if not run_dir.is_dir():
        raise ResumeError(f"{run_dir}: no such folder")
    path = run_dir / "config.yaml"
    if not path.is_file():
        raise ResumeError(f"{run_dir}: not a run folder (no config.yaml)")
    return OmegaConf.load(path)


def _status(run_dir: Path) -> str | None:
    """The status in a folder's summary.json (None if it has none: killed, or never started)."""
    try:
        return json.loads((run_dir / "summary.json").read_text()).get("status")
    except (OSError, ValueError):
        return None


def _refuse_finished(run_dir: Path, status: str | None) -> None:
    if status == "completed":
        raise ResumeError(f"{run_dir}: the run already completed (summary.json); nothing to resume")
    if status == "diverged":
        raise ResumeError(f"{run_dir}: the run diverged (summary.json); resuming would diverge again at the "
                          f"same frame (runs are deterministic): change the config and run it again")


def _options(cfg: DictConfig) -> dict:
    """The output options of cloth.runner.run, as experiments.run passes them."""
    return dict(obj_every=int(cfg.output.obj_every), stills_every=int(cfg.output.get("stills_every", 0)),
                states_every=int(cfg.output.get("states_every", 1)), checkpoint_every=checkpoint_every(cfg))


def _code_warning(run_dir: Path, code: dict) -> str | None:
    now = code_version()
    keys = ("git_commit", "git_dirty", "git_diff_sha1", "python", "packages")
    diff = [k for k in keys if code.get(k) != now.get(k)]
    if not diff:
        return None
    return (f"warning: {run_dir}: the checkpoint was written by other code ({', '.join(diff)} differ: "
            f"{ {k: code.get(k) for k in diff} } now { {k: now.get(k) for k in diff} }); the result may "
            f"differ from an uninterrupted run")


def _record_resume(manifest_dir: Path, frame: int, seed: int) -> str | None:
    """Append this resume to manifest.json's `resumes`; return the run's recording id."""
    path = manifest_dir / "manifest.json"
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError):
        manifest = {}
    env = environment_manifest(seed)
    manifest.setdefault("resumes", []).append({"from_frame": int(frame), **env})
    write_json_atomic(path, manifest)
    return manifest.get("recording_id")


def _continue(cfg: DictConfig, run_dir: Path, ckpt, recording_id, progress: bool, root: str = "world",
              log_camera: bool = True) -> dict:
    """Cut frames.parquet back to the checkpoint and run on to the run's frames in the same folder."""
    options = _options(cfg)
    if ckpt.rows:
        write_parquet_atomic(run_dir / "frames.parquet", pd.DataFrame(ckpt.rows))
    else:
        (run_dir / "frames.parquet").unlink(missing_ok=True)
    recorder = make_recorder(cfg, run_dir, root=root, recording_id=recording_id, log_camera=log_camera,
                         name=f"recording_from_{ckpt.frame:05d}.rrd")
    return run(ckpt.sim, run_frames(cfg), run_dir, recorder=recorder, progress=progress, rows=ckpt.rows, **options)


def resume_character(config_yaml: str, character: int, out_dir: str, recording_id: str | None) -> dict:
    """One character of a crowd, in a worker process: on from its checkpoint, or from the start."""
    out = Path(out_dir)
    status = _status(out)
    if status in ("completed", "diverged"):
        return json.loads((out / "summary.json").read_text())
    if not checkpoint_path(out).is_file():  # had not reached its first checkpoint
        return run_character(config_yaml, character, out_dir, recording_id)
    cfg = OmegaConf.create(config_yaml)
    ckpt = load_checkpoint(out)
    warning = _code_warning(out, ckpt.code)
    if warning:
        print(warning, file=sys.stderr)
    try:
        return _continue(cfg, out, ckpt, recording_id, progress=False, root=f"world/dancer_{character:02d}",
                         log_camera=character == 0)
    except SimulationDiverged:  # its summary says so; the other characters go on
        return json.loads((out / "summary.json").read_text())


def resume_crowd(cfg: DictConfig, run_dir: Path, dancers: int) -> dict:

    dirs = [run_dir / f"dancer_{i:02d}" for i in range(dancers)]
    status = [_status(d) for d in dirs]
    todo = [i for i, s in enumerate(status) if s not in ("completed", "diverged")]
    if todo and not any(checkpoint_path(dirs[i]).is_file() for i in todo):
        raise ResumeError(f"{run_dir}: no character has a checkpoint (dancer_NN/checkpoint/state.pkl): the crowd was "
                          f"killed before its first checkpoint or ran with output.checkpoint_every=0; run it again")
    config_yaml = OmegaConf.to_yaml(cfg, resolve=True)
    recording_id = None
    if todo:
        first = min(i for i in todo if checkpoint_path(dirs[i]).is_file())
        recording_id = _record_resume(run_dir, _checkpoint_frame(dirs[first]), int(cfg.seed))
    args = [(config_yaml, i, str(dirs[i]), recording_id) for i in todo]
    jobs = int(cfg.crowd_jobs)
    backend = crowd_backend(cfg)
    try:  # where the characters that completed before ran (the crowd's summary of then)
        workers = dict(enumerate(json.loads((run_dir / "summary.json").read_text()).get("workers") or []))
    except (OSError, ValueError):
        workers = {}
    resumed, errors = {}, {}
    try:
        run_characters(resume_character, args, jobs, backend, resumed, errors)
    finally:
        workers.update({todo[k]: w for k, w in resumed.items()})
        _, summary = combine_crowd(dirs, run_dir, errors={todo[k]: e for k, e in errors.items()}, extra={
            "crowd_backend": backend, "crowd_ran_in": where(backend, jobs, len(args)),
            "workers": [workers.get(i) for i in range(dancers)]})
    return summary


def _checkpoint_frame(run_dir: Path) -> int:
    try:
        return int(json.loads((run_dir / CHECKPOINT_DIR / CHECKPOINT_INFO).read_text())["frame"])
    except (OSError, ValueError, KeyError):
        return -1


def resume(run_dir, progress: bool | None = None) -> dict:
    """Resume the run in `run_dir` to its configured frames; returns its summary.

    Raises ResumeError (before any work) when the folder cannot be resumed; re-raises
    SimulationDiverged as cloth.runner.run does.
    """
    run_dir = Path(run_dir)
    cfg = _load_config(run_dir)
    _refuse_finished(run_dir, _status(run_dir))
    try:
        _options(cfg)
        run_frames(cfg)
        dancers = crowd_size(cfg)
    except ConfigError as exc:
        raise ResumeError(f"{run_dir}/config.yaml: {exc}") from None
    if dancers is not None:
        return resume_crowd(cfg, run_dir, dancers)
    try:
        ckpt = load_checkpoint(run_dir)
    except CheckpointError as exc:
        if checkpoint_path(run_dir).is_file():  # there is one, but it is bad: the message says how
            raise ResumeError(str(exc)) from None
        raise ResumeError(f"{exc}: the run was killed before its first checkpoint or ran with "
                          f"output.checkpoint_every=0; run it again") from None
    except KeyError as exc:  # a checkpoint of this format without one of its parts
        raise ResumeError(f"{checkpoint_path(run_dir)}: the checkpoint has no {exc.args[0]!r} (damaged, or "
                          f"written by other code); it cannot be resumed: run it again") from None
    warning = _code_warning(run_dir, ckpt.code)
    if warning:
        print(warning, file=sys.stderr)
    recording_id = _record_resume(run_dir, ckpt.frame, int(cfg.seed))
    print(f"resuming {run_dir} from frame {ckpt.frame} (t = {ckpt.time:.4f} s) to frame {run_frames(cfg)}")
    return _continue(cfg, run_dir, ckpt, recording_id,
                     progress=bool(cfg.output.get("progress", False)) if progress is None else progress)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.resume", description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path, help="the run folder of a killed run (has checkpoint/state.pkl)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        with sigterm_interrupts():  # a scheduler's SIGTERM stops the run as Ctrl-C does, its records written
            summary = resume(args.run_dir, progress=False if args.no_progress else None)
    except (ResumeError, CheckpointError) as exc:  # CheckpointError: a crowd character's (resume_character)
        print(f"cannot resume: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        signum = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
        print(f"interrupted ({signal.Signals(signum).name}): the frames so far are in {args.run_dir}; "
              f"continue with: python -m experiments.resume {args.run_dir}", file=sys.stderr)
        return 128 + signum
    except SimulationDiverged as exc:
        print(f"run stopped: {exc}\nframes written so far are in {args.run_dir}", file=sys.stderr)
        return 3
    print(f"run folder: {args.run_dir}\n  status: {summary.get('status')}  frames: {summary.get('frames_completed')}")
    if summary.get("status") != "completed":
        print(f"  {summary.get('message', '')}", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
