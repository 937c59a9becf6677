"""Where shards run: this process, a pool of local processes, or a Dask cluster.

Each executor takes a job and the shards still to compute, and yields each shard's
:class:`~hmi.farm.worker.Done` as it finishes, in any order (the farm puts them back in
order). What they share and what differs:

* :class:`InProcess` — one shard after the other, here (``--jobs 1``);
* :class:`LocalPool` — ``--jobs N`` processes of this machine (the default: 2); a process
  that dies (killed, out of memory) breaks the pool: its unfinished shards go to a new one;
* :class:`DaskCluster` — ``--cluster tcp://HOST:PORT`` (a running scheduler) or
  ``--cluster local:N`` (a LocalCluster of N worker processes started here). Every worker is
  asked its version before the work, and a worker running another plchmi refuses its
  shards anyway; the job goes to each worker once; a lost worker's shards are computed again
  by the others (the scheduler does it), and the command says so.

Ctrl-C in the middle: the pool's processes are stopped, the cluster's futures cancelled (the
scheduler forgets them and the workers drop what they were computing), and the
KeyboardInterrupt goes on to the command, which says what was kept for ``--resume``.
"""

from __future__ import annotations

import itertools
import logging
import os
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from hmi.errors import UsageError
from hmi.farm.bundle import BundleError
from hmi.farm.job import Job
from hmi.farm.version import code_version
from hmi.farm.worker import Done, WrongVersion, hold, install, run_installed, run_shard, who
from hmi.limits import MAX_JOBS

Note = Callable[[str], None]
Items = Sequence[tuple[int, Any]]
POOL_RESTARTS = 3  # a pool broken more often than this: the shards themselves kill it


class FarmError(RuntimeError):
    """The study cannot go on where it runs: workers keep dying, the scheduler is gone."""


class InProcess:
    workers = 1

    def __init__(self) -> None:
        self.description = "1 process (this one)"

    def __enter__(self) -> InProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def map(self, job: Job, items: Items, note: Note) -> Iterator[Done]:
        for index, shard in items:
            yield run_shard(job, index, shard)


class LocalPool:
    def __init__(self, jobs: int) -> None:
        self.workers = jobs
        self.description = f"{jobs} local processes"

    def __enter__(self) -> LocalPool:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def map(self, job: Job, items: Items, note: Note) -> Iterator[Done]:
        pending = dict(items)
        for attempt in itertools.count():
            if not pending:
                return
            pool = ProcessPoolExecutor(max_workers=min(self.workers, len(pending)),
                                       initializer=install, initargs=(job,))
            broken = False
            try:
                futures = {pool.submit(run_installed, i, s): i for i, s in pending.items()}
                for future in as_completed(futures):
                    try:
                        done = future.result()
                    except BrokenProcessPool:
                        broken = True
                        break
                    del pending[done.index]
                    yield done
            except BaseException:  # Ctrl-C, an error in a shard, the caller stopped
                _stop(pool)
                raise
            pool.shutdown(wait=True, cancel_futures=True)
            if broken:
                if attempt >= POOL_RESTARTS:
                    raise FarmError(f"the local worker processes died {attempt + 1} times; "
                                       f"{len(pending)} shards were never computed")
                note(f"a worker process died: its {len(pending)} unfinished shards go to "
                     "new processes")


def _stop(pool: ProcessPoolExecutor) -> None:
    """Stop now: queued shards cancelled, the running ones' processes ended."""
    processes = list(getattr(pool, "_processes", {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(5)


class DaskCluster:
    """A Dask cluster: a scheduler's address, or ``local:N`` worker processes started here."""

    def __init__(self, address: str | None = None, local_workers: int | None = None,
                 connect_timeout_s: float = 20.0, workers_timeout_s: float = 60.0) -> None:
        self.address = address
        self.local_workers = local_workers
        self.connect_timeout_s = connect_timeout_s
        self.workers_timeout_s = workers_timeout_s
        self.cluster: Any = None
        self.client: Any = None
        self.workers = local_workers or 0
        self.description = (f"a Dask LocalCluster of {local_workers} workers"
                            if local_workers else f"the Dask cluster at {address}")

    def __enter__(self) -> DaskCluster:
        try:
            import distributed
        except ImportError:
            raise UsageError("--cluster needs Dask: pip install 'plchmi[cluster]'") from None
        # The command says what happens (a lost worker, a cancelled run); Dask's own log
        # lines on stderr would say it again, in its words, between the progress lines.
        logging.getLogger("distributed").setLevel(logging.ERROR)
        try:
            if self.local_workers:
                self.cluster = distributed.LocalCluster(
                    n_workers=self.local_workers, threads_per_worker=1, processes=True,
                    host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR,
                    # No dashboard; the scheduler's own HTTP routes (health, metrics) on a
                    # free port of the loopback, not 8787 (another cluster may have it).
                    scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
            target = self.cluster if self.cluster is not None else self.address
            self.client = distributed.Client(target, timeout=self.connect_timeout_s)
        except (OSError, TimeoutError) as exc:
            self.__exit__()
            raise UsageError(f"--cluster {self.address}: no Dask scheduler answered "
                             f"({exc})") from None
        try:
            self.client.wait_for_workers(1, timeout=self.workers_timeout_s)
        except TimeoutError:
            self.__exit__()
            raise UsageError(f"--cluster {self.address}: the scheduler has no worker after "
                             f"{self.workers_timeout_s:g} s") from None
        try:
            self.check_workers()
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None

    def check_workers(self) -> None:
        """Ask every worker its version before any work; refuse the cluster if one differs
        (a worker joining later refuses its shards itself: hmi.farm.worker.check_version)."""
        answers = self.client.run(who, on_error="return")
        mine = code_version()
        wrong = []
        for address, answer in sorted(answers.items()):
            if isinstance(answer, BaseException):
                wrong.append(f"  {address}: cannot run plchmi ({type(answer).__name__}: "
                             f"{answer})")
            elif answer["digest"] != mine.digest or answer["release"] != mine.release:
                wrong.append(f"  {address} (host {answer['host']}, pid {answer['pid']}): "
                             f"plchmi {answer['release']} (code {answer['digest'][:12]})")
        self.workers = len(answers)
        self.description += f" ({len(answers)} workers)" if not self.local_workers else ""
        if wrong:
            raise UsageError("--cluster: workers running another plchmi than this command's "
                             f"{mine}:\n" + "\n".join(wrong) + "\nstart every worker from "
                             "the same plchmi installation (docs/studies.md); nothing was "
                             "computed")

    def map(self, job: Job, items: Items, note: Note) -> Iterator[Done]:
        from distributed import as_completed as dask_completed

        client = self.client
        token = uuid.uuid4().hex[:8]
        # the job once per worker, each copy a task of its own (hmi.farm.worker.hold), and the
        # shards dealt out over the copies: a shard runs where its copy is, so the work
        # spreads from the start (idle workers steal the rest)
        holds = [client.submit(hold, job, pure=False, workers=[address],
                               allow_other_workers=True,
                               key=f"plchmi-{job.kind}-{token}-job{n}")
                 for n, address in enumerate(sorted(self._workers()))]
        futures = [client.submit(run_shard, holds[n % len(holds)], index, shard, pure=False,
                                 key=f"plchmi-{job.kind}-{token}-shard{index}")
                   for n, (index, shard) in enumerate(items)]
        known = self._workers()
        try:
            for future in dask_completed(futures):
                known = self._watch(known, note)
                if future.status != "finished":
                    error = future.exception() if future.status == "error" else None
                    if isinstance(error, WrongVersion | BundleError):
                        raise UsageError(f"--cluster: {error}")
                    if error is None or type(error).__name__ == "KilledWorker":
                        raise FarmError(f"{future.key}: {error or future.status}")
                    raise error  # the shard's own error: a bug, with its traceback
                done: Done = future.result()
                future.release()
                yield done
        except OSError as exc:  # distributed's CommClosedError: the scheduler is gone
            raise FarmError(f"the connection to the scheduler was lost ({exc})") from None
        except BaseException:
            client.cancel([*futures, *holds], force=True)
            raise
        client.cancel(holds)

    def _workers(self) -> set[str]:
        return set(self.client.scheduler_info()["workers"])

    def _watch(self, known: set[str], note: Note) -> set[str]:
        now = self._workers()
        for address in sorted(known - now):
            note(f"worker {address} left the cluster: Dask computes its unfinished shards "
                 "again on the others")
        for address in sorted(now - known):
            note(f"worker {address} joined the cluster")
        self.workers = len(now)
        return now


Executor = InProcess | LocalPool | DaskCluster


def executor_for(cluster: str | None, jobs: int | None) -> Executor:
    """The executor the options name: ``--cluster`` (a Dask scheduler's address or
    ``local:N``), else ``--jobs`` local processes (default: 2, or 1 on one core)."""
    if cluster is not None:
        if jobs is not None:
            raise UsageError("--jobs and --cluster: the cluster's workers are the processes "
                             "(--cluster local:N for N of them on this machine)")
        if cluster.startswith("local:"):
            text = cluster.removeprefix("local:")
            if not text.isdigit() or not 1 <= int(text) <= MAX_JOBS:
                raise UsageError(f"--cluster {cluster}: expected local:N with N from 1 to "
                                 f"{MAX_JOBS}")
            return DaskCluster(local_workers=int(text))
        address = cluster if "://" in cluster else f"tcp://{cluster}"
        scheme, _, rest = address.partition("://")
        host, _, port = rest.rpartition(":")
        if scheme not in ("tcp", "tls") or not host or not port.isdigit() or \
                not 0 < int(port) < 65536:
            raise UsageError(f"--cluster {cluster}: expected tcp://HOST:PORT (a Dask "
                             "scheduler, e.g. tcp://10.0.0.5:8786) or local:N")
        return DaskCluster(address)
    count = jobs if jobs is not None else min(2, os.cpu_count() or 1)
    if not 1 <= count <= MAX_JOBS:
        raise UsageError(f"--jobs {count}: expected 1 to {MAX_JOBS} worker processes")
    return InProcess() if count == 1 else LocalPool(count)


__all__ = ["DaskCluster", "Executor", "FarmError", "InProcess", "LocalPool", "executor_for"]
