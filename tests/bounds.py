"""Running a hostile case in-process, bounded in time and memory.

A regression that makes plchmi hang or allocate without end must fail the test, not the
machine (it is shared): :func:`bounded` arms a SIGALRM timer that raises :class:`Overrun`
in the main thread after `seconds`, and lowers the process's address-space limit to what it
uses now plus `extra_mb`, so that a runaway allocation is a MemoryError (seen by the test)
instead of the kernel's out-of-memory killer. Both are restored on exit.

Cases that must run in another process (a real hang in C code, a FIFO) use :func:`run_cli`,
a subprocess with the same limits.
"""

from __future__ import annotations

import contextlib
import os
import resource
import signal
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


class Overrun(Exception):
    """A case ran longer than its bound."""


def _vm_bytes() -> int:
    with open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


@contextlib.contextmanager
def bounded(seconds: float = 5.0, extra_mb: int = 600) -> Iterator[None]:
    """Raise Overrun after `seconds`; MemoryError past `extra_mb` more address space."""
    def alarm(_signum, _frame):
        raise Overrun(f"the case ran longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, alarm)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = _vm_bytes() + extra_mb * 1024 * 1024
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def run_cli(args: Sequence[str], cwd: Path, seconds: float = 20.0, memory_mb: int = 1000,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """`plchmi ARGS` in a subprocess limited to `memory_mb` of address space; a hang past
    `seconds` is a TimeoutExpired (the process is killed)."""
    def limit() -> None:
        size = memory_mb * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (size, size))

    return subprocess.run([sys.executable, "-m", "hmi.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=seconds, preexec_fn=limit,
                          env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})})
