"""Ctrl-C while an executor waits for shards: taken where the wait can stop cleanly.

Python raises KeyboardInterrupt in the main thread at whatever bytecode it runs when SIGINT
comes. Inside Dask's client or ``concurrent.futures`` that can be just after a lock shared
with their own thread was taken (``threading.Condition.__enter__`` takes it, and the pending
signal is raised on the way out, before the ``with`` that would release it is set up): the
lock stays taken, and their thread — the one that sends the cancel, closes the connection,
hands the results over, lets the interpreter exit — blocks on it for ever. On a loaded
machine a thread is often preempted in that window, so the command hung after Ctrl-C there.

So while an executor waits, SIGINT only counts (:func:`deferred_ctrl_c`); the executor waits
in short slices, looks at the count between two, and raises KeyboardInterrupt itself, from
its own code, with every lock released. Every wait it makes meanwhile is bounded or sliced,
so the count is looked at within a slice (:data:`SLICE_S`).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from types import FrameType

SLICE_S = 0.1  # the longest an executor waits before it looks at the Ctrl-C count again


@dataclass
class CtrlC:
    """How many times SIGINT came since the executor began to wait."""

    count: int = 0

    def handle(self, signum: int, frame: FrameType | None) -> None:
        self.count += 1  # nothing else: a handler may run between any two bytecodes

    def check(self) -> None:
        """KeyboardInterrupt if Ctrl-C came: called where nothing is half done."""
        if self.count:
            raise KeyboardInterrupt


@contextmanager
def deferred_ctrl_c() -> Iterator[CtrlC]:
    """SIGINT counted, not raised, for the block's length; the previous handler back after.
    Only where Python's own handler is in place, in the main thread (where signals go): an
    ignored SIGINT (a background job) stays ignored, and another thread's wait is left as
    it is (Ctrl-C never raises there)."""
    ctrl_c = CtrlC()
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield ctrl_c
        return
    signal.signal(signal.SIGINT, ctrl_c.handle)
    try:
        yield ctrl_c
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


__all__ = ["SLICE_S", "CtrlC", "deferred_ctrl_c"]
