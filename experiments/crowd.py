"""Where a crowd's characters run: each is an independent simulation, a task `task(*args)` that
writes its own run folder (experiments.launch.run_character, experiments.resuming.resume_character).

`crowd_backend` (experiments.build.CROWD_BACKENDS) picks how they run, `crowd_jobs` how many at once.
The default, ``auto``, is ``ray`` when Ray is installed (the ``ray`` extra) and there is a Ray to
use (RAY_ADDRESS set, or this process is itself a Ray task), else ``processes``
(experiments.build.crowd_backend resolves it; this module sees only the two):

* ``ray``: one Ray task per character, each with one CPU and one thread
  (MKL_NUM_THREADS, OMP_NUM_THREADS and NUMBA_NUM_THREADS set to 1 in the worker before anything
  loads, and numba's thread count set to 1 in the task), so that the characters never
  oversubscribe the cores. With RAY_ADDRESS set the tasks go to that cluster (``ray.init(address=
  RAY_ADDRESS)``: its nodes need this code and the run folder on a shared file system) and the
  cluster decides how many run at once; without it a local Ray instance of `crowd_jobs` CPUs is
  started for the crowd and shut down after it. In a process that is already connected to Ray (a
  run that is itself a Ray task: cluster=ray), the characters go to that Ray.
* ``processes``: `crowd_jobs` local processes (joblib's loky), each with the thread count that
  experiments.launch.share_cores gave this process (SHARE_ENV, inherited; the user's
  NUMBA_NUM_THREADS is the ceiling).

With `crowd_jobs` 1 (and no RAY_ADDRESS for ray) the characters run one after the other in this
process, as the only run on the machine (with its threads: experiments.launch.share_cores); so does
a crowd of one character in processes (joblib runs a single job in this process), while on Ray
it is a Ray task like any other, on one thread. Either way a character that fails keeps what it wrote
(cloth.runner.run writes its summary on the way out); on Ray every other character still runs to
its end, and then the first failure (by character) is raised; in processes joblib stops the
characters not yet started and raises it at once.
"""

from __future__ import annotations

import os
import socket

import numba
from joblib import Parallel, delayed

from cloth.physics.linsolve import limit_solver_threads

# The thread environment of a character on Ray: one thread each (every library that reads one).
THREAD_ENV = {"MKL_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
# A local worker process's numba thread count (experiments.launch.share_cores sets it, `here` reads
# it). Not NUMBA_NUM_THREADS: numba re-reads that at every compilation and refuses a change once
# its threads run, and the user's own value is a ceiling, not ours to rewrite.
SHARE_ENV = "CLOTH_NUMBA_THREADS"


def worker_info() -> dict:
    """Where a character ran: host, process id, numba's thread count and the thread variables."""
    return {"host": socket.gethostname(), "pid": os.getpid(), "numba_threads": numba.get_num_threads(),
            **{k: os.environ.get(k) for k in THREAD_ENV}}


def here(task, *args) -> dict:
    """A character in this process or a local worker process, with its share of the cores
    (SHARE_ENV, set by experiments.launch.share_cores; at most numba's NUMBA_NUM_THREADS)."""
    share = os.environ.get(SHARE_ENV, "")
    if share.isdigit() and int(share) >= 1:
        numba.set_num_threads(min(int(share), numba.config.NUMBA_NUM_THREADS))
        limit_solver_threads(int(share))
    task(*args)
    return worker_info()


def one_thread(task, *args) -> dict:
    """A character in a Ray worker, on one thread (THREAD_ENV; the runtime environment of the
    task sets the variables before the worker loads anything, this makes sure of them)."""
    os.environ.update(THREAD_ENV)
    numba.set_num_threads(1)
    limit_solver_threads(1)
    task(*args)
    return worker_info()


def where(backend: str, jobs: int, characters: int) -> str:
    """How `characters` characters of a crowd with `jobs` (crowd_jobs) run, in words (recorded in
    the crowd's summary as crowd_ran_in)."""
    at_once = min(jobs, characters)
    if characters == 0:
        return "nowhere (no character to run)"
    if backend == "ray" and os.environ.get("RAY_ADDRESS"):
        return f"ray (cluster at {os.environ['RAY_ADDRESS']})"
    if jobs == 1 or (backend == "processes" and at_once == 1):
        return "this process (one after the other)"
    if backend == "ray":
        return f"ray (local instance, {at_once} CPUs)"
    return f"processes (joblib loky, {at_once} at once)"


def run_characters(task, args: list, jobs: int, backend: str, workers: dict, errors: dict) -> None:
    """Run task(*a) for every a in `args` (character i: args[i]) on `backend` with `jobs`
    (crowd_jobs; see the module docstring); fills `workers` (character -> worker_info) and, on
    Ray, `errors` (character -> what went wrong) as they finish, then raises the first failure."""
    # accumulates into `workers` and `errors`: the caller combines the crowd's records whatever happens
    if not args:
        return
    at_once = min(jobs, len(args))
    if where(backend, jobs, len(args)).startswith("this process"):
        for i, a in enumerate(args):
            workers[i] = here(task, *a)
    elif backend == "ray":
        _on_ray(task, args, at_once, workers, errors)
    else:
        done = Parallel(n_jobs=at_once, backend="loky")(delayed(here)(task, *a) for a in args)
        workers.update(enumerate(done))


def _on_ray(task, args: list, jobs: int, workers: dict, errors: dict) -> None:
    import ray  # noqa: PLC0415 - import cost (~1 s): only the ray backend needs it

    started = not ray.is_initialized()
    if started:
        address = os.environ.get("RAY_ADDRESS")
        if address:
            ray.init(address=address, logging_level="WARNING")
        else:
            # a new instance of its own ("local"), never a cluster that `ray start` left running here
            ray.init(address="local", num_cpus=jobs, include_dashboard=False, logging_level="WARNING")
    remote = ray.remote(num_cpus=1, max_retries=0, runtime_env={"env_vars": dict(THREAD_ENV)})(one_thread)
    pending = {}
    try:
        pending = {remote.remote(task, *a): i for i, a in enumerate(args)}
        failures = {}
        while pending:
            finished, _ = ray.wait(list(pending), num_returns=1)
            for ref in finished:
                i = pending.pop(ref)
                try:
                    workers[i] = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - the others go on; raised below, after all finished
                    failures[i] = exc
                    cause = getattr(exc, "cause", None) or exc  # a task's own exception, inside Ray's
                    errors[i] = f"{type(cause).__name__}: {cause}"
        if failures:
            raise failures[min(failures)]
    finally:
        for ref in pending:  # interrupted (Ctrl-C): the characters still running stop too
            ray.cancel(ref, force=True)
        if started:
            ray.shutdown()
