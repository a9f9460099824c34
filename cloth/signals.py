"""SIGTERM stops a run as Ctrl-C does: what SLURM and most schedulers send at a time limit.

Ctrl-C raises KeyboardInterrupt in the main thread, and cloth.runner.run writes frames.parquet
and summary.json (status ``interrupted``) on the way out, so that experiments.resume can continue
the run from its checkpoint. The default action of SIGTERM is to end the process at once, with
nothing written. :func:`sigterm_interrupts` makes SIGTERM raise :class:`Terminated` (a
KeyboardInterrupt) instead, for the duration of a ``with`` block, and then puts back the handler
that was there before. Only the main thread can receive signals in Python: elsewhere (a worker
thread) the block changes nothing.

A second SIGTERM while the first one's records are being written is ignored, in this block and
any block around it: the run is already stopping, and a scheduler's SIGKILL follows anyway.
"""

from __future__ import annotations

import contextlib
import signal
import threading


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM (`signum`): raised where the main thread was, as Ctrl-C is."""

    def __init__(self, signum: int = signal.SIGTERM):
        self.signum = int(signum)
        super().__init__(signal.Signals(self.signum).name)


_state = {"depth": 0, "raised": False}  # nested blocks in this process, and whether one has raised


def _handler(signum, frame):
    if _state["raised"]:  # stopping already: let it write its records
        return
    _state["raised"] = True
    raise Terminated(signum)


@contextlib.contextmanager
def sigterm_interrupts():
    """SIGTERM raises Terminated in the main thread inside the block; the previous handler after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _handler)
    _state["depth"] += 1
    try:
        yield
    finally:
        _state["depth"] -= 1
        if _state["depth"] == 0:
            _state["raised"] = False
        # None: a handler that was not installed from Python; the default is what it did
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
