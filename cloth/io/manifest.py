"""Environment manifest of a run, and atomic writers for result files.

A result file is written to a temporary file in the same folder and renamed over the target
(os.replace is atomic on POSIX), so a killed run never leaves a half-written file behind:
:func:`atomic_write` for any writer (checkpoints, states, stills, figures), and
write_json_atomic, write_parquet_atomic and write_text_atomic on top of it.

Durable by default: the file is fsynced before the rename and its folder after it, so that a
power loss or a node's crash right after a run never leaves a result (summary.json,
frames.parquet, a checkpoint, the final state) renamed into place but empty. The per-frame
outputs (states, stills, OBJ frames) pass durable=False: one fsync each per frame is not worth it.

The temporary file is ``.<name>.<8 random characters>.tmp`` (tempfile.mkstemp), unique to its
writer; it never outlives the write unless the process is killed outright (SIGKILL) during it.
:func:`remove_stale_temp_files` removes such leftovers (cloth.runner.run does at a run's start
and end, cloth.io.checkpoint.remove_checkpoint with the checkpoint).
"""

from __future__ import annotations

import contextlib
import copy
import functools
import hashlib
import json
import os
import platform
import re
import socket
import subprocess
import sys
import tempfile
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

import numpy as np

# The packages whose versions can change a result: the numerics, and the Cholesky solve's
# pypardiso and MKL (PyPI's `mkl`). Recorded with a checkpoint too (code_version), and compared on resume.
CODE_PACKAGES = ("numpy", "scipy", "numba", "llvmlite", "pypardiso", "mkl", "cloth")
# Every package a run's manifest.json names: the above, and what configures, runs and records it.
# A package that is not installed is recorded as NOT_INSTALLED (pypardiso and mkl off x86_64, ray
# without the ray extra).
PACKAGES = (*CODE_PACKAGES, "hydra-core", "omegaconf", "hydra-joblib-launcher", "pyyaml", "pandas", "pyarrow",
            "rerun-sdk", "trimesh", "tqdm", "matplotlib", "joblib", "ray")
NOT_INSTALLED = "not installed"
ENV_VARS = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "PYTHONHASHSEED",
            "CI")


def _version(pkg: str) -> str:
    try:
        return metadata.version(pkg)
    except metadata.PackageNotFoundError:
        return NOT_INSTALLED


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=Path(__file__).resolve().parent, capture_output=True,
                             text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _blas() -> str:
    """numpy's BLAS/LAPACK library and version (threaded BLAS could change summation order)."""
    try:
        b = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return f"{b.get('name')} {b.get('version')}"
    except Exception:  # older numpy without mode='dicts'
        return "unknown"


@functools.lru_cache(maxsize=1)
def _code_version() -> dict:
    """Which code produced a result: git commit, dirty flag, a hash of the uncommitted diff of
    tracked files (None when clean), python and the versions of CODE_PACKAGES."""
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no") if commit else None
    diff = _git("diff", "HEAD") if status else None
    return {"git_commit": commit, "git_dirty": (bool(status) if status is not None else None),
            "git_diff_sha1": hashlib.sha1(diff.encode()).hexdigest() if diff else None,
            "python": sys.version.split()[0],
            "packages": {p: _version(p) for p in CODE_PACKAGES}}


def code_version() -> dict:
    """Which code produced a result (see _code_version); computed once per process."""
    return copy.deepcopy(_code_version())


def environment_manifest(seed: int, extra: dict | None = None) -> dict:
    """What a reader needs to reproduce or compare a run: versions, commit, machine, seed."""
    import numba  # noqa: PLC0415 - import cost ~0.5 s (-X importtime), paid by a run, not by the table tools

    code = code_version()
    manifest = {
        "timestamp_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "seed": int(seed),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "hostname": socket.gethostname(),
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "numba_threads": numba.get_num_threads(),  # results are identical for any count (see experiments.replay)
        "blas": _blas(),
        "env": {k: os.environ.get(k) for k in ENV_VARS},
        "packages": {p: _version(p) for p in PACKAGES},
        "git_commit": code["git_commit"],
        "git_dirty": code["git_dirty"],
        "git_diff_sha1": code["git_diff_sha1"],  # which uncommitted changes (sha1 of `git diff HEAD`)
        "argv": sys.argv,
    }
    if extra:
        manifest.update(extra)
    return manifest


def _umask() -> int:
    """The process umask, read without changing it where Linux allows (no window for threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _umask()


TEMP_SUFFIX = ".tmp"
# what atomic_write's temporary files are called: "." + the target's name + "." + mkstemp's 8 characters + ".tmp"
_TEMP_NAME = re.compile(r"\..+\.[a-z0-9_]{8}\.tmp")


def fsync_dir(folder) -> None:
    """Make a folder's entries (a rename into it, a file made or removed) durable."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:  # a platform or file system without directory handles
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems refuse fsync of a directory (EINVAL): nothing more to do
        pass
    finally:
        os.close(fd)


def _fsync_file(path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_write(path, durable: bool = True):
    """Write a result file atomically: yields a temporary path beside `path` (same folder, made if
    absent, the usual permissions of a new file) for the caller to write; when the block ends
    without an exception it is renamed over `path`. The temporary file never outlives the block
    (unless the process is killed outright: see remove_stale_temp_files). `durable`: fsync the
    file before the rename and the folder after it (and a folder's parent when the folder was
    made here), so that the file is on disk, whole, once the block ends.

        with atomic_write(out_dir / "table.csv") as tmp:
            tmp.write_text(text)
    """
    path = Path(path)
    made = not path.parent.is_dir()
    path.parent.mkdir(parents=True, exist_ok=True)
    if made and durable:
        fsync_dir(path.parent.parent)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give result files the usual permissions
        yield tmp
        if durable:
            _fsync_file(tmp)
        os.replace(tmp, path)
        if durable:
            fsync_dir(path.parent)
    finally:
        tmp.unlink(missing_ok=True)


def remove_stale_temp_files(folder) -> list[Path]:
    """Remove the temporary files that writers killed outright left in `folder` (atomic_write's
    ``.<name>.<random>.tmp``; nothing else); returns the paths removed. Only for a folder that no
    other process writes into at the time (a run's own folder at its start and end)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    for p in folder.iterdir():
        if _TEMP_NAME.fullmatch(p.name) and p.is_file():
            p.unlink(missing_ok=True)
            removed.append(p)
    return removed


def write_json_atomic(path, obj, durable: bool = True) -> None:
    with atomic_write(path, durable) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, default=str))


def write_parquet_atomic(path, frame, durable: bool = True) -> None:
    with atomic_write(path, durable) as tmp:
        frame.to_parquet(tmp, index=False)


def write_text_atomic(path, text: str, durable: bool = True) -> None:
    with atomic_write(path, durable) as tmp:
        tmp.write_text(text)
