"""Running a hostile case in-process, bounded in time and memory.

A regression that makes plchmi hang or allocate without end must fail the test, not the
machine (it is shared): :func:`bounded` arms a timer that raises :class:`Overrun` in the main
thread after `seconds` of the process's CPU time, and lowers the process's address-space
limit to what it uses now plus `extra_mb`, so that a runaway allocation is a MemoryError
(seen by the test) instead of the kernel's out-of-memory killer. Both are restored on exit.

The bound is CPU time, not wall time: on the shared 2-core machine a load of 12 to 18 runs a
test about ten times slower on the wall clock (a 3 s wall bound on the alias bomb failed at
3.08 s), while its CPU time hardly moves. A case blocked without computing (a lock, a pipe)
is ended by a wall-clock backstop WALL_BACKSTOP times longer.

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
WALL_BACKSTOP = 30  # x the CPU bound: only for a case that waits without computing


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
    """Raise Overrun after `seconds` of CPU time (or WALL_BACKSTOP times that on the wall
    clock); MemoryError past `extra_mb` more address space."""
    def cpu_alarm(_signum, _frame):
        raise Overrun(f"the case used more than {seconds} s of CPU time")

    def wall_alarm(_signum, _frame):
        raise Overrun(f"the case ran longer than {seconds * WALL_BACKSTOP} s (wall clock)")

    previous_cpu = signal.signal(signal.SIGPROF, cpu_alarm)
    previous_wall = signal.signal(signal.SIGALRM, wall_alarm)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = _vm_bytes() + extra_mb * 1024 * 1024
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    signal.setitimer(signal.ITIMER_PROF, seconds)
    signal.setitimer(signal.ITIMER_REAL, seconds * WALL_BACKSTOP)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGPROF, previous_cpu)
        signal.signal(signal.SIGALRM, previous_wall)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def run_cli(args: Sequence[str], cwd: Path, seconds: float = 20.0, memory_mb: int = 1000,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """`plchmi ARGS` in a subprocess limited to `memory_mb` of address space and `seconds`
    of CPU time (the kernel kills it past that, SIGXCPU); a wait past WALL_BACKSTOP times
    that on the wall clock is a TimeoutExpired (the process is killed)."""
    def limit() -> None:
        size = memory_mb * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (size, size))
        cpu = max(1, round(seconds))
        resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu))

    return subprocess.run([sys.executable, "-m", "hmi.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=seconds * WALL_BACKSTOP,
                          preexec_fn=limit,
                          env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})})
