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
KeyboardInterrupt goes on to the command, which says what was kept for ``--resume``. The pool
and the cluster wait for shards with Ctrl-C deferred (:mod:`hmi.farm.interrupt`), and every
wait on the way out is bounded: the command ends within :data:`CANCEL_S` + :data:`CLOSE_S` of
Ctrl-C whatever the cluster does, and says so when the scheduler did not confirm the cancel.
"""

from __future__ import annotations

import asyncio
import atexit
import concurrent.futures
import itertools
import logging
import os
import time
import uuid
from collections.abc import Awaitable, Callable, Generator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import suppress
from typing import Any

from hmi.errors import UsageError
from hmi.farm.bundle import BundleError
from hmi.farm.interrupt import SLICE_S, CtrlC, deferred_ctrl_c
from hmi.farm.job import Job
from hmi.farm.version import code_version
from hmi.farm.worker import Done, WrongVersion, hold, install, run_installed, run_shard, who
from hmi.limits import MAX_JOBS

Note = Callable[[str], None]
Items = Sequence[tuple[int, Any]]
POOL_RESTARTS = 3  # a pool broken more often than this: the shards themselves kill it
STOP_S = 5.0  # a pool process still running this long after SIGTERM is killed
CANCEL_S = 10.0  # the longest the command waits, after Ctrl-C, for the scheduler's cancel
CLOSE_S = 10.0  # the longest it waits for the connection to the scheduler to close
ASK_S = 30.0  # the longest it waits for the scheduler's list of workers


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

    def map(self, job: Job, items: Items, note: Note) -> Generator[Done, None, None]:
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

    def map(self, job: Job, items: Items, note: Note) -> Generator[Done, None, None]:
        pending = dict(items)
        with deferred_ctrl_c() as ctrl_c:
            for attempt in itertools.count():
                if not pending:
                    return
                pool = ProcessPoolExecutor(max_workers=min(self.workers, len(pending)),
                                           initializer=install, initargs=(job,))
                try:
                    broken = yield from _pool_results(pool, pending, ctrl_c)
                except BaseException:  # Ctrl-C, an error in a shard, the caller stopped
                    _stop(pool)
                    raise
                pool.shutdown(wait=True, cancel_futures=True)
                if broken:
                    if attempt >= POOL_RESTARTS:
                        raise FarmError(f"the local worker processes died {attempt + 1} "
                                        f"times; {len(pending)} shards were never computed")
                    note(f"a worker process died: its {len(pending)} unfinished shards go to "
                         "new processes")


def _pool_results(pool: ProcessPoolExecutor, pending: dict[int, Any],
                  ctrl_c: CtrlC) -> Generator[Done, None, bool]:
    """The pending shards' results as they come, each removed from `pending`; returns True
    when a process died (the pool is broken). Waits in slices, Ctrl-C looked at between."""
    waiting = {pool.submit(run_installed, i, s) for i, s in pending.items()}
    while waiting:
        ctrl_c.check()
        finished, waiting = wait(waiting, timeout=SLICE_S, return_when=FIRST_COMPLETED)
        for future in finished:
            ctrl_c.check()
            try:
                done: Done = future.result()
            except BrokenProcessPool:
                return True
            del pending[done.index]
            yield done
    return False


def _stop(pool: ProcessPoolExecutor) -> None:
    """Stop now: queued shards cancelled, the running ones' processes ended (killed if they
    have not ended :data:`STOP_S` after SIGTERM: the interpreter's exit waits for them)."""
    processes = list(getattr(pool, "_processes", {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    deadline = time.monotonic() + STOP_S
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
    for process in processes:
        if process.is_alive():
            process.kill()
            process.join(STOP_S)
    # The pool's own thread reaps these processes too, and a join here can lose that race:
    # the process is dead, but its exit code is not yet stored, so it still counts as a
    # child. That thread ends once the processes are gone; waiting for it leaves none.
    if manager is not None:
        manager.join(STOP_S)


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
            # Not the process's default client: the interpreter's exit would close it again,
            # unbounded if the scheduler never answered (__exit__ closes it, bounded).
            self.client = distributed.Client(target, timeout=self.connect_timeout_s,
                                             set_as_default=False)
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
        """The connection closed and a LocalCluster stopped, each waited for at most
        :data:`CLOSE_S` (Ctrl-C deferred meanwhile): a scheduler that does not answer
        costs the command that, never its end."""
        with deferred_ctrl_c():
            if self.client is not None:
                client, self.client = self.client, None
                try:
                    client.close(timeout=CLOSE_S)
                except (TimeoutError, OSError, RuntimeError):
                    _abandon(client)
            if self.cluster is not None:
                cluster, self.cluster = self.cluster, None
                # its worker processes are this process's children: they end with it
                with suppress(TimeoutError, OSError, RuntimeError):
                    cluster.close(timeout=CLOSE_S)

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

    def map(self, job: Job, items: Items, note: Note) -> Generator[Done, None, None]:
        from distributed import as_completed as dask_completed

        client = self.client
        token = uuid.uuid4().hex[:8]
        with deferred_ctrl_c() as ctrl_c:
            try:
                known = self._workers(ctrl_c)
            except TimeoutError:
                raise FarmError(f"the scheduler did not answer within {ASK_S:g} s") from None
            # the job once per worker, each copy a task of its own (hmi.farm.worker.hold), and
            # the shards dealt out over the copies: a shard runs where its copy is, so the work
            # spreads from the start (idle workers steal the rest)
            holds = [client.submit(hold, job, pure=False, workers=[address],
                                   allow_other_workers=True,
                                   key=f"plchmi-{job.kind}-{token}-job{n}")
                     for n, address in enumerate(sorted(known))]
            futures = [client.submit(run_shard, holds[n % len(holds)], index, shard,
                                     pure=False, key=f"plchmi-{job.kind}-{token}-shard{index}")
                       for n, (index, shard) in enumerate(items)]
            try:
                finished = dask_completed(futures, loop=client.loop)
                while not finished.is_empty():
                    ctrl_c.check()
                    batch = finished.next_batch(block=False)
                    if not batch:
                        time.sleep(SLICE_S)
                    for future in batch:
                        ctrl_c.check()
                        known = self._watch(known, note, ctrl_c)
                        done = self._done(future, ctrl_c)
                        future.release()
                        yield done
                ctrl_c.check()  # Ctrl-C on the last shard: the command still stops
            except OSError as exc:  # distributed's CommClosedError: the scheduler is gone
                raise FarmError(f"the connection to the scheduler was lost ({exc})") from None
            except BaseException:
                self._cancel([*futures, *holds], note, ctrl_c)
                raise
            with suppress(TimeoutError):  # else released when the connection closes
                self._ask(lambda: client.cancel(holds, asynchronous=True), ctrl_c.check,
                          CANCEL_S)

    def _done(self, future: Any, ctrl_c: CtrlC) -> Done:
        """A finished shard's result, fetched from its worker; a failed one's error raised
        as the command's (another plchmi, a lost study) or as the shard's own (a bug)."""
        if future.status == "finished":
            done: Done = self._ask(lambda: self.client.gather(future, asynchronous=True),
                                   ctrl_c.check)
            return done
        error = (self._ask(lambda: future.exception(asynchronous=True), ctrl_c.check)
                 if future.status == "error" else None)
        if isinstance(error, WrongVersion | BundleError):
            raise UsageError(f"--cluster: {error}")
        if error is None or type(error).__name__ == "KilledWorker":
            raise FarmError(f"{future.key}: {error or future.status}")
        raise error  # the shard's own error: a bug, with its traceback

    def _cancel(self, futures: list[Any], note: Note, ctrl_c: CtrlC) -> None:
        """Ask the scheduler to forget the study's tasks, and wait until it has (their keys
        unknown to it), at most :data:`CANCEL_S`, or until Ctrl-C comes again: the command
        ends even when the scheduler does not answer, and then says what that means."""
        keys = [future.key for future in futures]
        first = ctrl_c.count
        deadline = time.monotonic() + CANCEL_S

        def again() -> None:
            if ctrl_c.count > first:
                raise KeyboardInterrupt

        def forgotten() -> bool:
            states = self._ask(lambda: self.client.scheduler.get_task_status(keys=keys),
                               again, deadline - time.monotonic())
            return all(state is None for state in states.values())

        try:
            self._ask(lambda: self.client.cancel(futures, asynchronous=True, force=True),
                      again, CANCEL_S)
            while not forgotten():
                again()
                if time.monotonic() >= deadline:
                    raise TimeoutError
                time.sleep(SLICE_S)
        except KeyboardInterrupt:
            note("Ctrl-C again: not waiting for the cluster to confirm the cancel; its "
                 "workers may still finish work that will be ignored")
        except Exception:  # TimeoutError, the connection lost, the client closed
            note(f"the cluster did not confirm the cancel within {CANCEL_S:g} s; its workers "
                 "may still finish work that will be ignored")

    def _ask(self, make: Callable[[], Awaitable[Any]], check: Callable[[], None],
             timeout: float | None = None) -> Any:
        """What `make()`'s coroutine returns, run on the client's event loop, waited for
        here in slices of :data:`SLICE_S`: `check` between two (it raises to stop waiting),
        and TimeoutError after `timeout` s. A wait left early cancels the coroutine."""
        answer: concurrent.futures.Future[Any] = concurrent.futures.Future()
        tasks: list[asyncio.Task[Any]] = []

        async def run() -> None:
            current = asyncio.current_task()
            if current is not None:
                tasks.append(current)
            try:
                answer.set_result(await make())
            except BaseException as exc:  # handed to the waiting thread
                answer.set_exception(exc)

        loop = self.client.loop
        loop.add_callback(run)
        deadline = None if timeout is None else time.monotonic() + timeout
        try:
            while True:
                check()
                try:
                    return answer.result(timeout=SLICE_S)
                except TimeoutError:
                    if answer.done():
                        raise
                if deadline is not None and time.monotonic() >= deadline:
                    raise TimeoutError(f"no answer from the scheduler within {timeout:g} s")
        except BaseException:
            if not answer.done():
                loop.add_callback(lambda: [task.cancel() for task in tasks])
            raise

    def _workers(self, ctrl_c: CtrlC) -> set[str]:
        identity = self._ask(lambda: self.client.scheduler.identity(n_workers=-1),
                             ctrl_c.check, ASK_S)
        return set(identity["workers"])

    def _watch(self, known: set[str], note: Note, ctrl_c: CtrlC) -> set[str]:
        try:
            now = self._workers(ctrl_c)
        except TimeoutError:
            return known  # said when it answers again
        for address in sorted(known - now):
            note(f"worker {address} left the cluster: Dask computes its unfinished shards "
                 "again on the others")
        for address in sorted(now - known):
            note(f"worker {address} joined the cluster")
        self.workers = len(now)
        return now


_ABANDONED: list[Any] = []


def _abandon(client: Any) -> None:
    """A client whose close did not end in time: its close goes on when its event loop can
    (the scheduler then forgets its tasks; the process's end closes its socket anyway).
    Kept referenced until the interpreter's exit, and marked closed then: Dask closes a
    client again when it is collected, waiting up to twice the connect timeout, on a loop
    that no longer runs at that point."""
    if not _ABANDONED:
        atexit.register(_mark_closed, _ABANDONED)
    _ABANDONED.append(client)


def _mark_closed(clients: list[Any]) -> None:
    for client in clients:
        client.status = "closed"


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
