"""What runs on a worker: the version check, the job's state kept between shards, a shard.

The same functions serve this process (one job), a local pool's processes (the job installed
once by the pool's initializer) and a Dask worker (the job a task of its own, :func:`hold`,
then each shard a task that depends on it). A worker whose code differs from the job's
refuses every shard with :class:`WrongVersion` before computing anything.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

from hmi.farm.job import Job
from hmi.farm.version import code_version, identity


class WrongVersion(Exception):
    """A worker runs another plchmi than the study's: its results could differ."""


@dataclass(frozen=True)
class Done:
    index: int
    result: Any
    seconds: float  # the shard's compute time on its worker, start to end (setup excluded)
    # The CPU time its thread spent on it: what a worker with a core of its own would take,
    # whatever else the machine ran meanwhile (the cut and the projections use it).
    cpu: float
    worker: str  # where it ran: a Dask worker's address, or a process id


def check_version(code: str) -> None:
    mine = code_version()
    if mine.digest != code:
        raise WrongVersion(f"worker {where()} runs {mine}, the study needs code {code[:12]}: "
                           "start every worker from the same plchmi installation as the "
                           "command (docs/studies.md)")


def where() -> str:
    """This worker's name: its Dask address inside a Dask worker, else its process id."""
    distributed = sys.modules.get("distributed")
    if distributed is not None:
        try:
            return str(distributed.get_worker().address)
        except ValueError:  # not inside a Dask worker
            pass
    return f"pid {os.getpid()}"


_STATES = threading.local()  # per thread: (fingerprint, state) of the last job


def state_of(job: Job) -> Any:
    """The job's worker state, built at this thread's first shard of the job and kept for
    the next (each Dask worker thread has its own: states are not shared between threads)."""
    kept = getattr(_STATES, "kept", None)
    if kept is not None and kept[0] == job.fingerprint:
        return kept[1]
    _STATES.kept = None  # the previous job's state goes before the new one is built
    state = job.setup(job.bundle.load(), job.options)
    _STATES.kept = (job.fingerprint, state)
    return state


def hold(job: Job) -> Job:
    """The job, as a Dask task's result that the shards depend on. Scattered data has no
    recipe: broadcast to every worker, its copies were then reduced by the scheduler's memory
    manager, and when the worker left holding the only one died, the scheduler cancelled the
    whole study ("lose scattered data"). A task's result is computed again on a surviving
    worker, from the job kept in the task."""
    return job


def run_shard(job: Job, index: int, shard: Any) -> Done:
    check_version(job.code)
    state = state_of(job)
    started, cpu = time.perf_counter(), time.thread_time()
    result = job.work(state, shard)
    return Done(index, result, time.perf_counter() - started, time.thread_time() - cpu,
                where())


# -- a local pool's processes --------------------------------------------------------------

_INSTALLED: list[Job] = []


def install(job: Job) -> None:
    """A pool process's initializer: the job, and Ctrl-C left to the command (the terminal
    sends SIGINT to the whole process group; the command stops the pool itself)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _INSTALLED[:] = [job]


def run_installed(index: int, shard: Any) -> Done:
    return run_shard(_INSTALLED[0], index, shard)


def who() -> dict[str, str]:
    """Asked of every Dask worker before the work: its version, host and process."""
    return {**identity(), "worker": where()}
