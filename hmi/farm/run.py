"""A study's run: its shards from the store or an executor, back in order, with progress.

:func:`run_study` is what every study calls. It reads the shards a previous run with the same
fingerprint kept (``--resume``), sends the others to the executor, keeps each result on disk
as it arrives, reports progress (shards, runs, runs per second, time left) and returns the
results in shard order: the study merges them the same way whatever ran them, so its report
is the same byte for byte on one process, a pool, or a cluster. How it ran — where, how long,
each shard's time — is in :class:`RunStats`, for stderr, never in the report.
"""

from __future__ import annotations

import heapq
import json
import time
from collections.abc import Callable
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hmi.farm.executors import Executor, FarmError
from hmi.farm.job import Study
from hmi.farm.store import ShardStore, default_root

SHARD_GOAL_S = 0.1  # a shard this long or more: Dask's per-task cost stays negligible


@dataclass(frozen=True)
class Tick:
    """Progress after a shard: counts, and this run's pace (shards from the store excluded)."""

    shards_done: int
    shards: int
    runs_done: int
    runs: int
    elapsed_s: float
    computed_runs: int  # runs computed by this run (not read back)
    note: str = ""  # something happened: a worker lost, shards read back

    @property
    def rate(self) -> float:
        return self.computed_runs / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def eta_s(self) -> float | None:
        left = self.runs - self.runs_done
        return left / self.rate if self.rate > 0 else None


Progress = Callable[[Tick], None]


@dataclass
class RunStats:
    executor: str
    shards: int
    from_store: int = 0
    wall_s: float = 0.0
    seconds: list[float | None] = field(default_factory=list)  # per shard, in shard order
    cpu: list[float | None] = field(default_factory=list)  # per shard: its thread's CPU time
    order: list[int] = field(default_factory=list)  # the shards in the order they are sent
    workers: set[str] = field(default_factory=set)  # where shards ran (this run)
    notes: list[str] = field(default_factory=list)
    folder: Path | None = None

    def lines(self) -> list[str]:
        """How the study ran, for stderr."""
        out = [f"{self.shards} shards: {self.shards - self.from_store} computed on "
               f"{self.executor} in {self.wall_s:.1f} s"
               + (f" ({len(self.workers)} workers took part)" if len(self.workers) > 1 else "")
               + (f", {self.from_store} read back from {self.folder}" if self.from_store
                  else "")]
        walls = [x for x in self.seconds if x is not None]
        if walls:
            out.append(f"shard times, start to end: {_spread(walls)}")
        cpus = [x for x in (self.cpu[i] for i in self.order or range(len(self.cpu)))
                if x is not None]
        if cpus:
            out.append(f"shard CPU times: {_spread(cpus)}; "
                       f"{sum(1 for x in cpus if x < SHARD_GOAL_S)} under {SHARD_GOAL_S:g} s")
            ideal = sum(cpus)
            projected = ", ".join(
                f"{n} workers {makespan(cpus, n):.1f} s"
                + (f" ({100 * ideal / n / makespan(cpus, n):.0f} % of ideal)" if n > 1 else "")
                for n in (1, 2, 16, 64))
            out.append("from these CPU times, each shard in the order sent to the first idle "
                       f"worker of a core: {projected}")
        return out


def _spread(seconds: list[float]) -> str:
    s = sorted(seconds)
    return (f"min {s[0]:.3f} s, median {s[(len(s) - 1) // 2]:.3f} s, max {s[-1]:.3f} s, "
            f"sum {sum(s):.1f} s")


def makespan(seconds: list[float], workers: int) -> float:
    """The time `workers` idle workers take over shards of these compute times, each shard
    given in order to the first worker free (as a scheduler fed in that order does; the
    per-task overhead and the workers' start left out)."""
    free = [0.0] * workers
    for s in seconds:
        heapq.heapreplace(free, free[0] + s)
    return max(free)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a study: how far it got, and where the finished shards are kept."""

    def __init__(self, done: int, shards: int, folder: Path | None):
        super().__init__(f"{done} of {shards} shards done")
        self.done, self.shards, self.folder = done, shards, folder


@dataclass
class StudyRun:
    results: list[Any]
    stats: RunStats


def run_study(study: Study, executor: Executor, progress: Progress | None = None,
              resume: bool = False, root: Path | None = None, keep: bool = True,
              each: Callable[[int, Any], None] | None = None) -> StudyRun:
    """Every shard's result, in shard order. `keep` writes each to the store as it
    arrives (under `root`, default the data folder's studies/); `resume` first reads back
    those of an earlier run with the same fingerprint. `each` is told of every shard's
    result as it comes.

    A computed result goes through its JSON form too (``decode(encode(result))``), as one
    read back does: a resumed run and a fresh one build their report from the same data."""
    started = time.perf_counter()
    n = len(study.shards)
    # The heaviest first when the study knows the costs (sorted is stable: ties in order).
    costs = study.costs
    order = sorted(range(n), key=lambda i: -costs[i]) if costs else list(range(n))
    stats = RunStats(executor.description, n, seconds=[None] * n, cpu=[None] * n, order=order)
    store = ShardStore(root or default_root(), study.job, study.title, n,
                       prune=root is None) if keep else None
    results: list[Any] = [None] * n
    found = [False] * n
    runs_done = computed = 0
    if store is not None:
        stats.folder = store.folder
        try:
            store.start(resume)
        except OSError as exc:
            raise FarmError(f"cannot keep the results in {store.folder}: {exc.strerror}; "
                            "another folder: --resume DIR") from None
        if resume:
            for i, shard in enumerate(study.shards):
                kept = store.load(i)
                if kept is None:
                    continue
                try:
                    results[i] = study.decode(shard, kept.data)
                except (KeyError, TypeError, ValueError, IndexError):
                    continue  # a damaged or foreign file: computed again
                found[i] = True
                if each is not None:
                    each(i, results[i])
                stats.from_store += 1
                stats.seconds[i] = kept.seconds
                stats.cpu[i] = kept.cpu
                runs_done += study.runs[i]
    done_shards = stats.from_store

    def tick(note: str = "") -> None:
        if note:
            stats.notes.append(note)
        if progress is not None:
            progress(Tick(done_shards, n, runs_done, study.total_runs,
                          time.perf_counter() - started, computed, note))

    if stats.from_store:
        tick(f"{stats.from_store} of {n} shards read back from {store and store.folder}")
    pending = [(i, study.shards[i]) for i in order if not found[i]]
    try:
        # closed here whatever stops the loop: the executor's work is cancelled before the
        # command goes on, whoever else holds the generator
        with closing(executor.map(study.job, pending, tick)) as finished:
            for done in finished:
                data = json.loads(json.dumps(study.encode(done.result)))  # as the store reads it
                results[done.index] = study.decode(study.shards[done.index], data)
                stats.seconds[done.index] = done.seconds
                stats.cpu[done.index] = done.cpu
                stats.workers.add(done.worker)
                if store is not None:
                    try:
                        store.save(done.index, data, done.seconds, done.cpu, done.worker)
                    except OSError as exc:  # results not kept only cost a resume
                        tick(f"the results cannot be kept in {store.folder} ({exc.strerror}): "
                             "the study goes on, but --resume will find nothing")
                        store = None
                if each is not None:
                    each(done.index, results[done.index])
                done_shards += 1
                runs_done += study.runs[done.index]
                computed += study.runs[done.index]
                tick()
    except KeyboardInterrupt:
        raise Interrupted(done_shards, n, stats.folder) from None
    stats.wall_s = time.perf_counter() - started
    return StudyRun(results, stats)


@dataclass
class Farm:
    """How a command runs its studies: the executor (entered by the caller: a cluster is
    connected and its workers checked before anything is computed), the progress, and the
    store. Each study run through it adds its :class:`RunStats`."""

    executor: Executor | None = None  # None: this machine's default (hmi.farm.executors)
    progress: Progress | None = None
    resume: bool = False
    root: Path | None = None
    keep: bool = True
    stats: list[RunStats] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what a study found without running

    def run(self, study: Study, each: Callable[[int, Any], None] | None = None) -> list[Any]:
        from hmi.farm.executors import executor_for
        executor = self.executor if self.executor is not None else executor_for(None, None)
        run = run_study(study, executor, self.progress, self.resume, self.root, self.keep,
                        each)
        self.stats.append(run.stats)
        return run.results
