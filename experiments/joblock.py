"""One job per output folder: a lock file that a second job in the same folder meets and is refused by.

A main job (`experiments.paper`) or a stability suite continues in its `--out` folder: each run it
finds completed there is not run again. Two copies started into the same folder at once would each
skip what the other finished and time their runs against each other, so the times of both are not
timings. :class:`JobLock` makes the second one stop before any work, naming the first (its process,
host, start time and command). A lock whose process has ended (a killed job) is taken over.
"""

from __future__ import annotations

import json
import os
import socket
import sys
from datetime import datetime
from pathlib import Path

LOCK_NAME = ".job.lock"


class FolderInUse(RuntimeError):
    """The folder holds the lock of a job that is still running; the message names it."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


class JobLock:
    """`with JobLock(folder, command):` holds `folder/.job.lock` for the job's lifetime.

    Raises FolderInUse on entry when another live job on this host holds it, or a job on another
    host does (its process cannot be checked from here; the message says how to clear it)."""

    def __init__(self, folder: Path, command: str):
        self.path = Path(folder) / LOCK_NAME
        self.command = command
        self.taken_over: dict | None = None  # the stale lock replaced, if any

    def _holder(self) -> dict | None:
        try:
            return json.loads(self.path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return {}  # unreadable (a job killed while writing it): stale

    def __enter__(self) -> JobLock:
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": datetime.now().isoformat(timespec="seconds"),
              "command": self.command}
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is None:  # released in between: try again
                    continue
                if holder.get("host") not in (None, me["host"]):
                    raise FolderInUse(f"{self.path.parent} is in use by a job on host {holder['host']} (pid "
                                      f"{holder.get('pid')}, started {holder.get('started')}: "
                                      f"{holder.get('command')}); give another --out, or delete {self.path} "
                                      f"if that job has ended") from None
                pid = holder.get("pid")
                if isinstance(pid, int) and pid != me["pid"] and _alive(pid):
                    raise FolderInUse(f"{self.path.parent} is in use by another job (pid {pid}, started "
                                      f"{holder.get('started')}: {holder.get('command')}); wait for it to end or "
                                      f"give another --out") from None
                self.taken_over = holder  # its process has ended: a killed job's lock
                self.path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as fh:
                json.dump(me, fh)
            if self.taken_over:
                print(f"{self.path}: the lock of an ended job (pid {self.taken_over.get('pid')}, started "
                      f"{self.taken_over.get('started')}) taken over", file=sys.stderr)
            return self
        raise FolderInUse(f"{self.path}: could not take the lock (another job takes and releases it)")

    def __exit__(self, *exc) -> None:
        holder = self._holder()
        if holder and holder.get("pid") == os.getpid():
            self.path.unlink(missing_ok=True)
