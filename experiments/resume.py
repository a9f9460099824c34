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
import signal
import sys
from pathlib import Path

from cloth.io.checkpoint import CheckpointError
from cloth.signals import Terminated, sigterm_interrupts
from cloth.simulation import SimulationDiverged
from experiments.resuming import ResumeError, resume


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
