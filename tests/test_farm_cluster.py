"""The studies on a real Dask cluster: a scheduler and two workers started here on 127.0.0.1
(``python -m distributed.cli.dask_scheduler`` / ``dask_worker``, as docs/studies.md starts
them on machines), a small sweep and a small soak farm whose reports must equal the local
ones byte for byte while a worker is killed in the middle, a worker of another plchmi refused,
and Ctrl-C leaving the cluster idle. Long studies: `.ci/run` runs them (marked slow); every
process started here is ended by the fixture, and every wait is bounded."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from hmi.cli import main
from tests.conftest import PROJECTS, ROOT

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("dask-cluster")]
distributed = pytest.importorskip("distributed")  # the [cluster] extra is in [test]

VALVE = PROJECTS / "cispi_valve"
START_S = 90  # a scheduler or a worker that has not started by then: the test fails


class Cluster:
    """A scheduler and named workers, each a process of ours (no nanny: a killed worker
    stays dead, as a machine that fails; no memory limit: a worker pauses only when a test
    pauses it, never on its memory)."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.file = folder / "scheduler.json"
        self.processes: dict[str, subprocess.Popen] = {}
        log = open(folder / "scheduler.log", "wb")  # noqa: SIM115 (closed with the process)
        self.processes["scheduler"] = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
             "--port", "0", "--no-dashboard", "--scheduler-file", str(self.file)],
            stdout=log, stderr=log)
        deadline = time.monotonic() + START_S
        while not self.file.exists():
            assert time.monotonic() < deadline, "the scheduler did not start"
            assert self.processes["scheduler"].poll() is None, "the scheduler died"
            time.sleep(0.1)
        self.address = json.loads(self.file.read_text())["address"]
        self.client = distributed.Client(self.address, timeout=START_S)

    def start_worker(self, name: str, pythonpath: str | None = None) -> None:
        env = dict(os.environ)
        if pythonpath:
            env["PYTHONPATH"] = pythonpath
        log = open(self.folder / f"{name}.log", "wb")  # noqa: SIM115
        self.processes[name] = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file",
             str(self.file), "--name", name, "--nthreads", "1", "--no-nanny",
             "--no-dashboard", "--host", "127.0.0.1", "--memory-limit", "0"],
            stdout=log, stderr=log, env=env, cwd=self.folder)
        self.wait_for(lambda: name in self.names().values(), f"worker {name} to join")

    def names(self) -> dict[str, str]:
        """address -> name of the workers connected now."""
        return {address: str(info.get("name")) for address, info in
                self.client.scheduler_info()["workers"].items()}

    def address_of(self, name: str) -> str:
        names = self.names()
        found = [address for address, n in names.items() if n == name]
        assert found, f"worker {name} is not in the cluster ({names}); {self.logs()}"
        return found[0]

    def logs(self) -> str:
        """The end of each process's log, for a failure's message."""
        return "\n".join(f"-- {path.name} (last 2,000 characters):\n"
                         + path.read_text(errors="replace")[-2000:]
                         for path in sorted(self.folder.glob("*.log")))

    def ensure(self, *names: str) -> None:
        """These workers, and only these: a killed or extra one restarted or stopped."""
        for name in list(self.processes):
            if name != "scheduler" and name not in names:
                self.stop(name)
        for name in names:
            process = self.processes.get(name)
            if process is None or process.poll() is not None:
                self.start_worker(name)
        self.wait_for(lambda: sorted(self.names().values()) == sorted(names),
                      f"exactly the workers {names}")

    def stop(self, name: str) -> None:
        process = self.processes.pop(name)
        process.terminate()
        try:
            process.wait(20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(10)

    def wait_for(self, condition, what: str, timeout: float = START_S) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < deadline, f"waited {timeout} s for {what}"
            time.sleep(0.1)

    def close(self) -> None:
        self.client.close()
        for name in [n for n in self.processes if n != "scheduler"] + ["scheduler"]:
            if name in self.processes:
                self.stop(name)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    c = Cluster(tmp_path_factory.mktemp("dask"))
    try:
        c.ensure("w1", "w2")
        yield c
    finally:
        c.close()


def _hold(name: str, marker: Path):
    """A worker plugin that holds worker `name` on the first shard it starts: its event
    loop stops there, before the shard runs (as a machine that hangs), after writing the
    shard's key to `marker`. The shard can then only end by being computed again elsewhere,
    however fast or slow the machine: the study cannot finish before the worker is killed.
    Bounded (START_S), so that a failing test leaves no worker held for ever. A class made
    here, so that it travels to the workers by value (they cannot import the tests)."""

    class Hold(distributed.WorkerPlugin):
        name = "plchmi-test-hold"

        def __init__(self, target: str, marker: str):
            self.target, self.marker = target, marker

        def setup(self, worker):
            self.worker = worker

        def transition(self, key, start, finish, **kwargs):
            if finish == "executing" and "-shard" in str(key) and \
                    self.worker.name == self.target and not Path(self.marker).exists():
                Path(self.marker).write_text(str(key))
                time.sleep(START_S)

    return Hold(name, str(marker))


class Killer(threading.Thread):
    """Kills worker `name` while it holds a shard (:func:`_hold`): its shards then have to be
    computed again by the other worker. Remembers which shards it held."""

    def __init__(self, cluster: Cluster, name: str):
        super().__init__(daemon=True)
        self.cluster, self.name = cluster, name
        self.address = cluster.address_of(name)
        self.marker = cluster.folder / f"{name}-holds"
        self.marker.unlink(missing_ok=True)
        self.held: list[str] = []
        self.stop = threading.Event()

    def run(self) -> None:
        client = distributed.Client(self.cluster.address, timeout=START_S)
        try:
            while not self.stop.wait(0.05):
                if not self.marker.exists():
                    continue
                held = [str(k) for k in client.processing().get(self.address, ())]
                if self.marker.read_text() in held:
                    self.held = held
                    self.cluster.processes[self.name].send_signal(signal.SIGKILL)
                    return
        finally:
            client.close()


def _shard_workers(data: Path) -> dict[int, str]:
    """Which worker computed each shard, from the results kept in the data folder."""
    found = {}
    for path in data.glob("studies/*/shard-*.json"):
        record = json.loads(path.read_text())
        found[record["index"]] = record["worker"]
    return found


def _run_killing(cluster: Cluster, capsys, argv: list[str],
                 code: int) -> tuple[str, str, Killer]:
    """The study on the cluster, w2 killed while it holds a shard; it must end with `code`
    (the local run's), its stderr and the cluster's logs shown when it does not."""
    # Only the cluster's run in the data folder: the local run before it may have cut the
    # study otherwise (a sweep is cut by the times the previous run measured), and its files,
    # in a folder of their own, would say where they ran.
    shutil.rmtree(Path(os.environ["PLCHMI_DATA"]) / "studies", ignore_errors=True)
    killer = Killer(cluster, "w2")
    cluster.client.register_plugin(_hold("w2", killer.marker))
    killer.start()
    try:
        ended = main([*argv, "--cluster", cluster.address])
    finally:
        killer.stop.set()
        killer.join(10)
        cluster.client.unregister_worker_plugin("plchmi-test-hold")
    out, err = capsys.readouterr()
    assert ended == code, f"exit {ended}, not {code}; stderr:\n{err}\n{cluster.logs()}"
    assert killer.held, "the worker was never seen computing a shard: nothing was killed"
    return out, err, killer


def _check_rerun(killer: Killer, survivor: str) -> None:
    """The shards the killed worker held were computed again, by the other one."""
    placed = _shard_workers(Path(os.environ["PLCHMI_DATA"]))
    held = [int(key.rsplit("shard", 1)[1]) for key in killer.held]
    assert held and all(placed[i] == survivor for i in held), (held, placed)


def test_a_sweep_on_the_cluster_is_the_local_report_though_a_worker_dies(cluster, capsys,
                                                                         monkeypatch):
    cluster.ensure("w1", "w2")
    # Small shards (20 runs, ~0.2 s): more of them than the two workers hold at once.
    monkeypatch.setattr("hmi.studies.loop_sweep.SHARD_RUNS", 20)
    argv = ["campaign", str(VALVE), "--sweep", "--every", "400ms", "--faults", "F5,F8,F13"]
    assert main([*argv, "--jobs", "1"]) == 0
    local, _ = capsys.readouterr()
    survivor = cluster.address_of("w1")
    out, err, killer = _run_killing(cluster, capsys, argv, 0)
    assert out == local, err
    assert "in shards of 20 runs" in local  # the blocks it was cut in, read when it reports
    assert f"worker {killer.address} left the cluster" in err
    _check_rerun(killer, survivor)


def test_a_soak_farm_on_the_cluster_is_the_local_report_though_a_worker_dies(cluster, capsys):
    cluster.ensure("w1", "w2")
    argv = ["soak", str(VALVE), "--seeds", "1-6", "--steps", "6"]
    assert main([*argv, "--jobs", "1"]) == 0
    local, _ = capsys.readouterr()
    survivor = cluster.address_of("w1")
    out, err, killer = _run_killing(cluster, capsys, argv, 0)
    assert out == local, err
    assert f"worker {killer.address} left the cluster" in err
    assert "6 seeds (1-6)" in out and "6 kept every invariant" in out
    _check_rerun(killer, survivor)


def test_a_worker_running_another_plchmi_is_refused(cluster, capsys, tmp_path):
    cluster.ensure("w1")
    other = tmp_path / "other"
    shutil.copytree(ROOT / "hmi", other / "hmi", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "components", other / "components")
    with open(other / "hmi" / "farm" / "version.py", "a", encoding="utf-8") as f:
        f.write("\n# another build of plchmi\n")
    cluster.start_worker("odd", pythonpath=str(other))
    try:
        code = main(["campaign", str(VALVE), "--cluster", cluster.address])
        err = capsys.readouterr().err
        odd = cluster.address_of("odd")
        assert code == 2, err
        assert "workers running another plchmi than this command's" in err
        assert odd in err and "nothing was computed" in err
        assert cluster.address_of("w1") not in err
    finally:
        cluster.stop("odd")


def _gate():
    """A worker plugin that pauses its worker once it has finished a shard: a paused worker
    starts no other task (the one it may have started meanwhile ends), so a study of more
    shards than the workers can have finished or started is held unfinished, however fast or
    slow the machine, until the test opens the gate (:func:`_open`). A class made here, so
    that it travels to the workers by value (they cannot import the tests)."""

    class Gate(distributed.WorkerPlugin):
        name = "plchmi-test-gate"

        def setup(self, worker):
            self.worker = worker

        def transition(self, key, start, finish, **kwargs):
            # Called inside the worker's state machine: pause from its event loop, after.
            if finish == "memory" and "-shard" in str(key):
                self.worker.loop.add_callback(self.pause)

        def pause(self):
            from distributed.core import Status
            if self.worker.status == Status.running:
                self.worker.status = Status.paused

    return Gate()


def _statuses(cluster: Cluster) -> set[str]:
    return set(cluster.client.run(lambda dask_worker: dask_worker.status.name).values())


def _open(cluster: Cluster) -> None:
    """The gate removed and every worker running again."""
    from distributed.core import Status

    cluster.client.unregister_worker_plugin("plchmi-test-gate")

    def run(dask_worker):
        if dask_worker.status == Status.paused:
            dask_worker.status = Status.running

    cluster.client.run(run)
    cluster.wait_for(lambda: _statuses(cluster) == {"running"}, "the workers to run again")


def _terminal_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class HeldSoak:
    """`plchmi soak` of 12 seeds on the cluster, a process of its own, held by the gate
    (:func:`_gate`): each of the two workers pauses after its first shard, having finished
    two at most (the next one may start before the pause), so 8 or more are left when the
    test interrupts it."""

    def __init__(self, cluster: Cluster, data: Path):
        self.cluster, self.data = cluster, data
        self.env = {**os.environ, "PLCHMI_DATA": str(data), "PYTHONUNBUFFERED": "1"}
        self.argv = [sys.executable, "-m", "hmi.cli", "soak", str(VALVE), "--seeds", "1-12",
                     "--steps", "4", "--cluster", cluster.address]
        cluster.client.register_plugin(_gate())
        # SIGINT as a terminal leaves it, whatever this run inherited (a background job
        # ignores it, and so would the command)
        self.command = subprocess.Popen(self.argv, stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, env=self.env, cwd=ROOT,
                                        preexec_fn=_terminal_sigint)
        # Work under way and held: a shard kept by the command, every worker paused.
        cluster.wait_for(lambda: any(data.glob("studies/*/shard-*.json")) and
                         _statuses(cluster) == {"paused"},
                         "a first shard kept and the workers held")

    def interrupt(self) -> str:
        """SIGINT; the command must end (the timeout only a guard: it ends within
        CANCEL_S + CLOSE_S) with 130 and say how to go on. Its stderr."""
        self.command.send_signal(signal.SIGINT)
        _, err = self.command.communicate(timeout=120)
        text = err.decode()
        assert self.command.returncode == 130, text
        assert "interrupted:" in text and "--resume" in text and "Traceback" not in text
        return text

    def wait_idle(self) -> None:
        """The scheduler forgets the study (the workers still held): nothing left queued
        or computing on the workers."""
        client = self.cluster.client
        self.cluster.wait_for(lambda: not any(client.processing().values()) and
                              client.run_on_scheduler(lambda dask_scheduler:
                                                      len(dask_scheduler.tasks)) == 0,
                              "the cluster to be idle", timeout=START_S)

    def close(self) -> None:
        """The command ended if it still runs, the gate opened."""
        if self.command.poll() is None:
            self.command.kill()
            self.command.wait(10)
        _open(self.cluster)

    def resume(self) -> None:
        """--resume reads the kept shards back and computes the others: the study whole."""
        kept = len(list(self.data.glob("studies/*/shard-*.json")))
        assert 1 <= kept <= 4
        resumed = subprocess.run([*self.argv, "--resume"], capture_output=True, env=self.env,
                                 cwd=ROOT, timeout=300)
        assert resumed.returncode == 0, resumed.stderr.decode()
        assert f"{kept} of 12 shards read back" in resumed.stderr.decode()
        assert "12 kept every invariant" in resumed.stdout.decode()


def test_ctrl_c_cancels_the_work_on_the_cluster_and_resume_goes_on(cluster, tmp_path):
    cluster.ensure("w1", "w2")
    soak = HeldSoak(cluster, tmp_path / "data")
    try:
        err = soak.interrupt()
        assert "did not confirm the cancel" not in err
        soak.wait_idle()
    finally:
        soak.close()
    soak.resume()


def test_ctrl_c_ends_the_command_though_the_scheduler_does_not_answer(cluster, tmp_path):
    """The scheduler's process stopped (SIGSTOP: its connections open, nothing answered, as
    a machine that hangs or a link that drops every packet): Ctrl-C still ends the command,
    which says that the cancel was not confirmed. Once the scheduler runs again it forgets
    the study (the cancel was sent, or the connection closed with the command), and
    --resume goes on from the kept shards."""
    cluster.ensure("w1", "w2")
    soak = HeldSoak(cluster, tmp_path / "data")
    scheduler = cluster.processes["scheduler"]
    scheduler.send_signal(signal.SIGSTOP)
    try:
        err = soak.interrupt()
        assert "the cluster did not confirm the cancel within" in err, err
        assert "its workers may still finish work that will be ignored" in err
    finally:
        scheduler.send_signal(signal.SIGCONT)
    try:
        soak.wait_idle()
    finally:
        soak.close()
    soak.resume()


def test_ctrl_c_ends_the_command_though_its_connection_is_stuck(cluster, capsys, tmp_path):
    """The command's own connection stuck: its Dask client's event loop blocked, as a lock
    that an earlier KeyboardInterrupt left taken blocks it (hmi/farm/interrupt.py), so
    nothing more is sent to the scheduler nor read from it. Ctrl-C must still end the
    command, with 130, how to resume, and the cancel said unconfirmed, while that loop is
    still blocked: no wait of the way out is on it unbounded. The command runs in this
    process (`main`), so that the test can block its loop; the loop is released after."""
    from hmi.farm.executors import DaskCluster

    cluster.ensure("w1", "w2")
    data = tmp_path / "data"
    entered: list[DaskCluster] = []
    enter = DaskCluster.__enter__

    def spy(self: DaskCluster) -> DaskCluster:
        entered.append(self)
        return enter(self)

    release, blocked, unblocked = threading.Event(), threading.Event(), threading.Event()
    failed: list[BaseException] = []

    def block() -> None:  # on the command's event loop
        blocked.set()
        release.wait(4 * START_S)  # a guard: the loop runs again in any case
        unblocked.set()

    def interrupt() -> None:
        try:
            cluster.wait_for(lambda: entered and entered[0].client is not None and
                             any(data.glob("studies/*/shard-*.json")) and
                             _statuses(cluster) == {"paused"},
                             "a first shard kept and the workers held")
            entered[0].client.loop.add_callback(block)
            assert blocked.wait(START_S), "the command's event loop never ran the block"
        except BaseException as exc:
            failed.append(exc)
        os.kill(os.getpid(), signal.SIGINT)  # the command ends either way

    cluster.client.register_plugin(_gate())
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as a terminal's
    thread = threading.Thread(target=interrupt, daemon=True)
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(DaskCluster, "__enter__", spy)
            patch.setenv("PLCHMI_DATA", str(data))
            thread.start()
            code = main(["soak", str(VALVE), "--seeds", "1-12", "--steps", "4",
                         "--cluster", cluster.address])
            still_blocked = not unblocked.is_set()
    finally:
        release.set()
        thread.join(START_S)
        signal.signal(signal.SIGINT, previous)
    err = capsys.readouterr().err
    try:
        assert not failed, failed
        assert code == 130, err
        assert still_blocked, "the command ended only once its event loop ran again"
        assert "interrupted:" in err and "--resume" in err, err
        assert "the cluster did not confirm the cancel within" in err, err
        # The loop running again, the abandoned connection closes: the scheduler forgets.
        cluster.wait_for(lambda: cluster.client.run_on_scheduler(
            lambda dask_scheduler: len(dask_scheduler.tasks)) == 0,
            "the scheduler to forget the study", timeout=START_S)
    finally:
        _open(cluster)
