"""The resumption of run folders (the library under ``python -m experiments.resume``, whose
docstring says what resuming does and refuses): :func:`resume` continues a killed run from its
checkpoint, :func:`continue_in_place` is what ``output.resume=true`` does with a folder that
already holds the run asked for (experiments.run; the main job sets it, so that a killed
experiments.paper continues with the same ``--out``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig, OmegaConf

from cloth.io.checkpoint import CHECKPOINT_DIR, CHECKPOINT_INFO, CheckpointError, checkpoint_path, load_checkpoint
from cloth.io.manifest import code_version, environment_manifest, write_json_atomic, write_parquet_atomic
from cloth.runner import combine_crowd, run
from cloth.simulation import SimulationDiverged
from experiments.build import ConfigError, build, crowd_backend, crowd_size, run_frames
from experiments.crowd import run_characters, where
from experiments.launch import checkpoint_every, crowd_stage, make_recorder, run_character


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
                             name=f"recording_from_{ckpt.frame:05d}.rrd", frame_time=ckpt.sim.scene.frame_time,
                             resume_from=ckpt.frame)
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
        crowd_stage(cfg, run_dir, dirs, float(cfg.scene.params.frame_time))
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


# keys that may differ between a folder's run and the same run asked again with output.resume=true
RESUME_FREE_KEYS = ("output.resume", "output.progress")


def _first_difference(old, new, path: str = "") -> tuple[str, object, object] | None:
    """(dotted key, old value, new value) of the first difference of two plain configs, or None."""
    if isinstance(old, dict) and isinstance(new, dict):
        for key in sorted(set(old) | set(new), key=str):
            sub = f"{path}.{key}" if path else str(key)
            if sub in RESUME_FREE_KEYS:
                continue
            diff = _first_difference(old.get(key, "<absent>"), new.get(key, "<absent>"), sub)
            if diff:
                return diff
        return None
    return None if old == new else (path, old, new)


def continue_in_place(cfg: DictConfig, run_dir: Path) -> dict | None:
    """With output.resume=true, what `run_dir` already holds of the run `cfg` asks for: its summary
    when it completed or diverged (skipped: runs are deterministic), the resumed run's summary when
    it has a checkpoint, None when it holds nothing to continue (the run then starts afresh).
    ConfigError (key `output.resume`) when the folder holds a run of another config."""
    run_dir = Path(run_dir)
    if not (run_dir / "config.yaml").is_file():
        return None
    old = OmegaConf.to_container(OmegaConf.load(run_dir / "config.yaml"), resolve=False)
    diff = _first_difference(old, OmegaConf.to_container(cfg, resolve=True))
    if diff:
        build(cfg)  # a bad value is named as without output.resume (ConfigError), before the mismatch
        key, was, now = diff
        raise ConfigError(f"output.resume: {run_dir} holds a run of another config ({key}: {was!r} there, "
                          f"{now!r} now); give another folder, or output.resume=false to run it afresh")
    status = _status(run_dir)
    if status in ("completed", "diverged"):
        print(f"{run_dir}: {status} already (output.resume=true): not run again")
        return json.loads((run_dir / "summary.json").read_text())
    started = checkpoint_path(run_dir).is_file() or any(  # a crowd: a character's checkpoint or end
        checkpoint_path(d).is_file() or _status(d) in ("completed", "diverged") for d in run_dir.glob("dancer_*"))
    if not started:
        return None
    try:
        return resume(run_dir, progress=bool(cfg.output.get("progress", False)))
    except ResumeError as exc:  # e.g. a crowd whose unfinished characters have no checkpoint
        print(f"{exc}; running it from the start (output.resume=true)")
        return None
