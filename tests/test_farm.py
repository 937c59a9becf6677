"""The studies' shards and their executors on this machine (hmi/farm/): the same report on
one process and on a pool, a run interrupted and resumed, the fingerprint and the version
check, the explorer's reset between shards. tests/test_farm_cluster.py does the same on a
real Dask cluster."""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import random
import re
import signal
import threading
import time
from dataclasses import replace
from multiprocessing import popen_fork

import pytest

from hmi.cli import main
from hmi.errors import UsageError
from hmi.farm.bundle import Bundle, BundleError
from hmi.farm.executors import DaskCluster, InProcess, LocalPool, executor_for
from hmi.farm.run import Farm, Interrupted, makespan, run_study
from hmi.farm.worker import WrongVersion, run_shard
from hmi.project.campaign import campaign_of
from hmi.project.loader import load_project
from hmi.studies.campaign import campaign_study
from hmi.studies.closed_loop import outcomes
from hmi.studies.explore import Explorer
from hmi.studies.loop_sweep import DIAG_NO_FILTER, FTC, SweepResult, cut, sweep
from tests.conftest import PROJECTS

VALVE = PROJECTS / "cispi_valve"


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_the_campaign_report_is_the_same_on_one_process_and_two(capsys):
    reports = {}
    for jobs in ("1", "2"):
        code, out, err = _run(capsys, "campaign", str(VALVE), "--jobs", jobs)
        assert code == 0
        printed = re.search(r"report sha256 ([0-9a-f]{64})", err)
        assert printed and printed[1] == hashlib.sha256(out.encode()).hexdigest()
        assert "shard CPU times: min" in err and "64 workers" in err
        reports[jobs] = out
    assert reports["1"] == reports["2"]
    assert "s wall" not in reports["1"]  # how it ran is on stderr, not in the report


def test_a_small_sweep_is_the_same_on_one_process_and_two(capsys):
    argv = ["campaign", str(VALVE), "--sweep", "--every", "2s", "--faults", "F5,F13"]
    one = _run(capsys, *argv, "--jobs", "1")
    two = _run(capsys, *argv, "--jobs", "2", "--json")
    again = _run(capsys, *argv, "--jobs", "2")
    assert one[0] == two[0] == again[0] == 0
    assert one[1] == again[1]
    assert json.loads(two[1])["shard_runs"] == 200


def test_the_cut_by_cost_splits_heavy_blocks_and_gathers_light_ones(monkeypatch):
    monkeypatch.setattr("hmi.studies.loop_sweep.SHARD_MIN_S", 0.4)
    blocks = [(c, start, start + 200) for c in range(2) for start in range(0, 1000, 200)]
    assert cut(blocks, None) == tuple((b,) for b in blocks)
    times = [0.01, 0.02, 30.0, 0.05, 0.01, 2.0, 0.01, 0.01, 0.01, 0.3]
    shards = cut(blocks, [t / 200 for t in times for _ in range(200)])
    pieces = [p for s in shards for p in s]
    # Every run once, in order; a piece never leaves its block.
    assert [(c, r) for c, a, b in pieces for r in range(a, b)] == \
        [(c, r) for c, a, b in blocks for r in range(a, b)]
    assert all(a // 200 == (b - 1) // 200 for _, a, b in pieces)
    cost = {b: t for b, t in zip(blocks, times, strict=True)}

    def seconds(shard):  # a piece costs its share of its block's time
        return sum(cost[(c, a - a % 200, a - a % 200 + 200)] * (b - a) / 200
                   for c, a, b in shard)

    target = max(0.4, sum(times) / 256)
    assert max(seconds(s) for s in shards) <= target * 1.5
    assert min(seconds(s) for s in shards) >= target / 2
    heavy = [p for p in pieces if p[0] == 0 and 400 <= p[1] < 600]
    assert len(heavy) == 75  # 30 s in pieces of 0.4 s
    # Pieces of about the same time where the time is not spread evenly over the runs.
    costs = [0.001] * 150 + [0.1] * 50  # 5.15 s, most in the last 50 runs
    split = [p for s in cut([(0, 0, 200)], costs) for p in s]
    assert len(split) == 13 and split[0] == (0, 0, 153)
    assert all(sum(costs[a:b]) <= 0.55 for _, a, b in split)


def test_a_sweep_cut_by_its_measured_times_finds_the_same(monkeypatch):
    project = load_project(VALVE)
    counter = campaign_of(project).counter
    monkeypatch.setattr("hmi.studies.loop_sweep.SHARD_RUNS", 10)

    def run() -> tuple[SweepResult, int]:
        farm = Farm(InProcess(), keep=False)
        result = sweep(project, [DIAG_NO_FILTER, FTC], counter, 1_000_000, farm=farm,
                       cache=False, faults=("F5", "F13"))
        assert result is not None
        return result, farm.stats[0].shards

    first, blocks = run()  # one shard per block; measures the blocks
    monkeypatch.setattr("hmi.studies.loop_sweep.SHARD_MIN_S", 0.0)
    monkeypatch.setattr("hmi.studies.loop_sweep.SHARDS_WANTED", 4 * blocks)
    second, shards = run()  # blocks split and gathered by their time
    assert shards != blocks
    assert first.runs == second.runs and first.states == second.states


def _lumpy_sweep(seed: int, runs: int):
    """A cost model of a sweep's configuration: most runs cost a millisecond or two, but in
    every third block a fifth of the runs cost 0.05-0.4 s, and runs share states in groups
    of 5-40 consecutive runs that only the group's first run in a piece pays for (up to
    0.3 s). A piece's CPU time is its runs' plus 4 ms, and each run's is known, as a worker
    measures them."""
    rnd = random.Random(seed)
    private, group, shared = [], [], {}
    for r in range(runs):
        heavy = (r // 200) % 3 == 1
        private.append(rnd.choice([0.0005, 0.001, 0.002]) if not heavy or rnd.random() < 0.8
                       else rnd.uniform(0.05, 0.4))
        group.append(r // rnd.choice([5, 10, 40]) if heavy else r // 50)
        shared.setdefault(group[-1], rnd.uniform(0.01, 0.3) if heavy else 0.003)

    def piece(a: int, b: int) -> tuple[float, list[float]]:
        seen: set[int] = set()
        each = []
        for r in range(a, b):
            each.append(private[r] + (shared[group[r]] if group[r] not in seen else 0.0))
            seen.add(group[r])
        return 0.004 + sum(each), each
    return piece


def test_shards_cut_by_each_runs_time_stay_over_the_goal(tmp_path, monkeypatch):
    """Cut, measured, cut again by what was measured, five times over, on 8 lumpy sweeps of
    about 100 s of CPU: not one shard under 0.2 s (the 0.1 s goal twice over) once the cut
    has times to go by. With a piece's time spread evenly over its runs (what a times file
    of pieces only says), the same sweeps give shards of 0.015-0.13 s."""
    from hmi.farm.run import SHARD_GOAL_S
    from hmi.studies import loop_sweep

    monkeypatch.setenv("PLCHMI_CACHE", str(tmp_path))
    runs = 2000
    blocks = [(0, start, start + 200) for start in range(0, runs, 200)]

    def shortest(seed: int, each_run: bool) -> float:
        piece = _lumpy_sweep(seed, runs)
        times, least = None, float("inf")
        for attempt in range(5):
            shards = cut(blocks, times.costs if times else None,
                         times.pieces if times else frozenset())
            spent, times = [], []
            for shard in shards:
                measured = [(c, a, b, *piece(a, b)) for c, a, b in shard]
                times.append(sum(m[3] for m in measured))
                spent += [(c, a, b, t, each if each_run else None)
                          for c, a, b, t, each in measured]
            if attempt:  # the first cut has no times: one shard per block
                least = min(least, *times)
            loop_sweep._store_times("model", [DIAG_NO_FILTER], spent)
            times = loop_sweep._load_times("model", [DIAG_NO_FILTER], runs)
            assert times is not None and len(times.costs) == runs
        return least

    # The floor the cut aims at (target / 2) holds for what ran, not only for what it
    # expected: a piece within a measured one costs at least its runs' measured sum.
    monkeypatch.setattr(loop_sweep, "SHARD_MIN_S", 0.4)
    assert min(shortest(seed, True) for seed in range(8)) >= 0.2 > SHARD_GOAL_S
    assert min(shortest(seed, False) for seed in range(8)) < SHARD_GOAL_S


class Counting(InProcess):
    """This process, counting the shards it computes."""

    def __init__(self) -> None:
        super().__init__()
        self.computed: list[int] = []

    def map(self, job, items, note):
        for done in super().map(job, items, note):
            self.computed.append(done.index)
            yield done


def test_an_interrupted_campaign_resumes_where_it_stopped(tmp_path):
    project = load_project(VALVE)
    spec = campaign_of(project)
    study = campaign_study(project, spec)
    fresh = run_study(study, InProcess(), root=tmp_path / "fresh").results

    def stop_after_two(tick):
        if tick.shards_done == 2:
            raise KeyboardInterrupt

    with pytest.raises(Interrupted) as stopped:
        run_study(study, InProcess(), stop_after_two, root=tmp_path / "kept")
    assert (stopped.value.done, stopped.value.shards) == (2, len(study.shards))
    folder = stopped.value.folder
    assert len(list(folder.glob("shard-*.json"))) == 2
    # A damaged shard file is computed again, never trusted.
    damaged = sorted(folder.glob("shard-*.json"))[0]
    data = json.loads(damaged.read_text())
    damaged.write_text(json.dumps({**data, "fingerprint": "0" * 64}))
    counting = Counting()
    resumed = run_study(study, counting, resume=True, root=tmp_path / "kept")
    assert resumed.stats.from_store == 1
    assert sorted(counting.computed) == [i for i in range(len(study.shards)) if i != 1]
    assert resumed.results == fresh
    # Without --resume a run starts afresh, whatever the folder holds.
    again = Counting()
    run_study(study, again, root=tmp_path / "kept")
    assert len(again.computed) == len(study.shards)


def _reaped_slowly_by_other_threads(monkeypatch):
    """The pool's own thread reaps its processes too; here it comes first and stores what it
    reaped 1 s late, which makes the race with the stopping thread's joins happen."""

    def poll(self, flag=os.WNOHANG):
        if self.returncode is None:
            if threading.current_thread() is threading.main_thread():
                time.sleep(0.05)
            try:
                pid, status = os.waitpid(self.pid, flag)
            except OSError:
                return None
            if pid == self.pid:
                if threading.current_thread() is not threading.main_thread():
                    time.sleep(1.0)
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode
    monkeypatch.setattr(popen_fork.Popen, "poll", poll)


@pytest.mark.parametrize("reaping", ["as it comes", "slow in the pool's thread"])
def test_ctrl_c_on_a_pool_stops_its_processes_before_the_run_gives_up(tmp_path, monkeypatch,
                                                                     reaping):
    """SIGINT to this process (as a terminal's Ctrl-C) while a pool of 2 processes computes
    the campaign's 3 shards, sent as the first shard is kept: the pool, which defers Ctrl-C
    while it waits (hmi/farm/interrupt.py), takes it at its next look, so the run stops
    with 1 shard done; its processes are gone when run_study gives up, and Python's own
    SIGINT handler is back."""
    if reaping != "as it comes":
        _reaped_slowly_by_other_threads(monkeypatch)
    project = load_project(VALVE)
    study = campaign_study(project, campaign_of(project))
    before = set(multiprocessing.active_children())

    def ctrl_c(tick):
        if tick.shards_done == 1:
            os.kill(os.getpid(), signal.SIGINT)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(Interrupted) as stopped:
            run_study(study, LocalPool(2), ctrl_c, root=tmp_path)
        left = [p for p in multiprocessing.active_children() if p not in before]
    finally:
        signal.signal(signal.SIGINT, previous)
    assert (stopped.value.done, stopped.value.shards) == (1, 3)
    assert left == []
    assert signal.getsignal(signal.SIGINT) is previous


def test_the_command_says_how_to_resume_and_does(tmp_path, capsys, monkeypatch):
    import hmi.farm.run as farm_run
    real = farm_run.run_study
    calls = []

    def interrupted_once(study, executor, progress=None, *args, **kwargs):
        calls.append(1)
        if len(calls) > 1:
            return real(study, executor, progress, *args, **kwargs)

        def stop(tick):
            if tick.shards_done == 2:
                raise KeyboardInterrupt
        return real(study, executor, stop, *args, **kwargs)
    monkeypatch.setattr(farm_run, "run_study", interrupted_once)
    kept = tmp_path / "kept"
    code, out, err = _run(capsys, "campaign", str(VALVE), "--jobs", "1", "--resume", str(kept))
    assert code == 130 and out == ""
    assert "interrupted: 2 of 3 shards done" in err and f"--resume {kept}" in err
    code, out, err = _run(capsys, "campaign", str(VALVE), "--jobs", "1", "--resume", str(kept))
    assert code == 0 and "2 read back from" in err
    monkeypatch.setattr(farm_run, "run_study", real)
    assert _run(capsys, "campaign", str(VALVE), "--jobs", "2")[1] == out


def test_the_fingerprint_names_project_code_options_and_cut(tmp_path):
    project = load_project(VALVE)
    spec = campaign_of(project)
    base = campaign_study(project, spec).job.fingerprint
    assert campaign_study(project, spec).job.fingerprint == base
    assert campaign_study(project, spec, period_us=20_000).job.fingerprint != base
    paper = load_project(VALVE, "paper")
    assert campaign_study(paper, spec, variant="paper").job.fingerprint != base
    copy = tmp_path / "cispi_valve"
    import shutil
    shutil.copytree(VALVE, copy)
    moved = load_project(copy)
    assert campaign_study(moved, campaign_of(moved)).job.fingerprint == base  # same files
    (copy / "campaign.yaml").write_text((copy / "campaign.yaml").read_text() + "\n# note\n")
    edited = load_project(copy)
    assert campaign_study(edited, campaign_of(edited)).job.fingerprint != base


def test_a_worker_running_other_code_refuses_the_shard():
    project = load_project(VALVE)
    study = campaign_study(project, campaign_of(project))
    other = replace(study.job, code="0" * 64)
    with pytest.raises(WrongVersion, match=r"runs plchmi .* the study needs code 000000000000"):
        run_shard(other, 0, study.shards[0])


def test_a_project_travels_as_its_files_and_is_checked_where_it_lands():
    project = load_project(PROJECTS / "cispi_subsystem")  # it instantiates the library's valve
    bundle = Bundle.of(project)
    assert "components/valve.yaml" not in {name for name, _ in bundle.files}
    loaded = bundle.load()
    assert loaded.path != project.path and loaded.name == project.name
    assert Bundle.of(loaded).digest == bundle.digest
    with pytest.raises(BundleError, match="loads differently on this worker"):
        replace(bundle, digest="f" * 64).load()


def test_the_explorer_back_at_its_prefix_explores_a_shard_as_a_fresh_one():
    project = load_project(VALVE)
    used = Explorer(project, FTC, "cycles")
    instants = used.instants(extras=False, every=100)
    used.explore(["F4"], instants)
    used.reset()
    used.explore(["F9"], instants)
    fresh = Explorer(project, FTC, "cycles")
    fresh.explore(["F9"], instants)
    assert outcomes(used.graph) == outcomes(fresh.graph)
    assert len(used.graph.obs) == len(fresh.graph.obs)
    assert used.graph.scans == fresh.graph.scans


def test_executors_are_named_by_the_options():
    assert isinstance(executor_for(None, 1), InProcess)
    assert isinstance(executor_for(None, 2), LocalPool)
    assert executor_for("local:3", None).local_workers == 3
    cluster = executor_for("10.0.0.5:8786", None)
    assert isinstance(cluster, DaskCluster) and cluster.address == "tcp://10.0.0.5:8786"
    for bad in ("local:0", "local:x", "tcp://host", "udp://h:1", "h:99999"):
        with pytest.raises(UsageError, match="--cluster"):
            executor_for(bad, None)
    with pytest.raises(UsageError, match="--jobs and --cluster"):
        executor_for("local:2", 2)
    with pytest.raises(UsageError, match="--jobs 0"):
        executor_for(None, 0)


def test_farm_options_are_checked(capsys):
    with pytest.raises(SystemExit) as stopped:  # argparse's own exit, status 2
        main(["soak", str(VALVE), "--seeds", "5-1"])
    assert stopped.value.code == 2 and "the range goes down" in capsys.readouterr().err
    assert main(["soak", str(VALVE), "--cluster", "local:2"]) == 2
    assert "with --seeds only" in capsys.readouterr().err
    assert main(["soak", str(VALVE), "--seeds", "1-3", "--shrink", "10s"]) == 2
    assert "not by time" in capsys.readouterr().err
    assert main(["campaign", str(VALVE), "--cluster", "nowhere"]) == 2
    assert "expected tcp://HOST:PORT" in capsys.readouterr().err


def test_a_shards_cpu_time_is_measured_kept_and_read_back(tmp_path):
    project = load_project(VALVE)
    study = campaign_study(project, campaign_of(project))
    run = run_study(study, InProcess(), root=tmp_path)
    # A shard is one thread's work: its CPU time is positive, and within its wall time.
    pairs = list(zip(run.stats.cpu, run.stats.seconds, strict=True))
    assert all(cpu is not None and wall is not None and 0 < cpu <= wall + 1e-3
               for cpu, wall in pairs), pairs
    # A file of an older plchmi has no CPU time: read back without one, the others with theirs.
    old = run.stats.folder / "shard-000001.json"
    data = json.loads(old.read_text())
    del data["cpu"]
    old.write_text(json.dumps(data))
    again = run_study(study, Counting(), resume=True, root=tmp_path).stats
    assert again.from_store == len(study.shards)
    assert again.cpu[1] is None
    assert [c for i, c in enumerate(again.cpu) if i != 1] == \
        [round(c, 6) for i, (c, _) in enumerate(pairs) if i != 1]
    lines = again.lines()
    assert lines[1].startswith("shard times, start to end: min")
    assert lines[2].startswith("shard CPU times: min") and "under 0.1 s" in lines[2]
    assert "64 workers" in lines[3] and "% of ideal" in lines[3]


def test_the_heaviest_shards_are_sent_first_and_the_projection_follows(tmp_path):
    project = load_project(VALVE)
    study = campaign_study(project, campaign_of(project))
    assert study.costs is None  # no costs known: sent in shard order
    counting = Counting()
    stats = run_study(replace(study, costs=(0.1, 0.05, 0.3)), counting, root=tmp_path).stats
    assert counting.computed == stats.order == [2, 0, 1]
    # The projection gives the shards out in that order: with CPU times 1, 1 and 2 s on two
    # workers, 2 s (2 | 1 + 1), where shard order would take 3 s (1 + 2 | 1).
    stats.cpu = [1.0, 1.0, 2.0]
    assert "2 workers 2.0 s (100 % of ideal)" in stats.lines()[3]
    stats.order = []
    assert "2 workers 3.0 s (67 % of ideal)" in stats.lines()[3]


def test_the_time_on_n_workers_is_projected_from_the_shard_times():
    assert makespan([1.0, 1.0, 1.0, 1.0], 2) == 2.0
    assert makespan([3.0, 1.0, 1.0, 1.0], 2) == 3.0
    assert makespan([1.0] * 10, 64) == 1.0


def test_the_default_farm_runs_on_local_processes():
    farm = Farm(keep=False)
    project = load_project(VALVE)
    results = farm.run(campaign_study(project, campaign_of(project)))
    assert len(results) == 3 and farm.stats[0].executor.endswith("local processes")


def test_the_data_folder_keeps_the_latest_studies_of_a_project(tmp_path, monkeypatch):
    from hmi.farm import store
    monkeypatch.setenv("PLCHMI_DATA", str(tmp_path / "data"))
    project = load_project(VALVE)
    spec = campaign_of(project)
    folders = []
    for period in range(10_000, 10_000 + 7 * 10_000, 10_000):  # seven studies, seven prints
        study = campaign_study(project, spec, period_us=period)
        kept = store.ShardStore(store.default_root(), study.job, study.title, 1, prune=True)
        kept.start(resume=False)
        folders.append(kept.folder)
    left = sorted((tmp_path / "data" / "studies").iterdir())
    assert len(left) == store.KEPT_STUDIES and folders[-1] in left and folders[0] not in left


def test_a_seed_that_raises_is_reported_failing_and_the_farm_goes_on(tmp_path, capsys,
                                                                     monkeypatch):
    """Seed 2's session raises; seed 3 breaks an invariant and a replay of its shrink raises
    (as a headless drain's WaitTimeout once did): both are failing seeds, with what raised,
    seed 3 with the shortest list found before; seeds 1 and 4 are reported as usual."""
    from hmi.soak import farm as soak_farm
    from hmi.soak import runner
    from hmi.soak.invariants import Broken

    real = runner.session
    replays = []

    async def flaky(config, replay=None, journal_dir=None, progress=None):
        if config.seed == 2:
            raise RuntimeError("deliberate: the session")
        if replay is not None:
            replays.append(len(replay))
            if len(replays) == 2:
                raise TimeoutError("deliberate: a replay")
        result = await real(config, replay, journal_dir, progress)
        if config.seed == 3 and replay is None:
            result.broken.append(Broken("exception", "deliberate", 1, 0))
        return result
    monkeypatch.setattr(runner, "session", flaky)
    monkeypatch.setattr(soak_farm, "session", flaky)
    monkeypatch.setenv("PLCHMI_DATA", str(tmp_path))
    code, out, err = _run(capsys, "soak", str(VALVE), "--seeds", "1-4", "--steps", "4",
                          "--jobs", "1")
    assert code == 1, err
    assert "4 seeds (1-4)" in out and "2 kept every invariant, 1 broke one, 1 raised" in out
    assert "Seed 2: RAISED the session raised RuntimeError: deliberate: the session" in out
    assert f"run again: plchmi soak {VALVE} --size 80x24 --seed 2 --minutes 30 --steps 4" in out
    assert "Seed 3: BROKEN exception at scan 1" in out
    assert "the shrink stopped: replay 2 raised TimeoutError: deliberate: a replay" in out
    assert "after 4 steps; shrunk to 4 in 2 replays" in out  # nothing dropped before
    assert "Seed 1" not in out and "Seed 4" not in out
    saved = list(tmp_path.rglob("seed3.steps"))
    assert len(saved) == 1 and len(saved[0].read_text().splitlines()) == 2 + 4
    # its first line is a command to copy: no --control the project does not have
    assert saved[0].read_text().splitlines()[0] == f"# plchmi soak {VALVE} --size 80x24 --seed 3"


def test_a_soak_farm_over_the_socket_says_so_and_its_replays_do_too(tmp_path, capsys,
                                                                    monkeypatch):
    """--split reaches every seed's session (the HMI attached over the runtime's socket), the
    report says so, and a failing seed's saved list and replay line carry --split: a replay
    without it would run another protocol than the one that failed."""
    from hmi.soak import farm as soak_farm
    from hmi.soak import runner
    from hmi.soak.invariants import Broken

    real = runner.session
    seen = []

    async def marked(config, replay=None, journal_dir=None, progress=None):
        seen.append(config.split)
        result = await real(config, replay, journal_dir, progress)
        if config.seed == 2 and replay is None:
            result.broken.append(Broken("exception", "deliberate", 1, 0))
        return result
    monkeypatch.setattr(soak_farm, "session", marked)
    monkeypatch.setenv("PLCHMI_DATA", str(tmp_path))
    code, out, err = _run(capsys, "soak", str(VALVE), "--seeds", "1-2", "--steps", "3",
                          "--jobs", "1", "--split", "--shrink-replays", "0")
    assert code == 1, err
    assert seen and all(seen), seen
    assert "(control default, 80x24, over the socket): 2 seeds (1-2)" in out
    assert f"replay: plchmi soak {VALVE} --split --size 80x24 --replay seed2.steps" in out
    saved = list(tmp_path.rglob("seed2.steps"))
    assert len(saved) == 1
    assert saved[0].read_text().splitlines()[0] == (
        f"# plchmi soak {VALVE} --split --size 80x24 --seed 2")
