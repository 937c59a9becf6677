"""``plchmi bench engine``: scans per second of each example project, headless, no trace.

Each project runs on its simulated plant in virtual time, as ``plchmi run PROJECT --for
120s`` runs it without ``--trace``: the session's scans (engine, explanations, alarms) and the
run's summary collector reading every snapshot. A second figure is the engine alone
(``Engine.step``: the scan and its snapshot, no session), what the campaign and the studies
drive; a third the engine without snapshots (``Engine.run``: what a reader that builds them
only at scans with news pays). The run is deterministic; only the wall time varies, with the
machine's load (printed). Each figure is the median of RUNS runs after one untimed run.

The goal: cispi_valve >= 100,000 scans/s, sorting and palletizer >= 50,000.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.bench import goal_line, load_line

if TYPE_CHECKING:
    from hmi.project.model import Project

SECTION = "engine"
HELP = "scans/s of each project headless without trace (goal: valve 100k, sorting/pallet 50k)"

PROJECTS = Path(__file__).resolve().parents[2] / "projects"
# project -> goal in scans/s (the goal); None: measured, no goal set
GOALS: dict[str, int | None] = {"cispi_valve": 100_000, "conveyor_robot": None,
                                "cispi_subsystem": None, "sorting": 50_000,
                                "palletizer": 50_000}
SECONDS, QUICK_SECONDS = 120, 20
RUNS = 3
Measure = tuple[int, float, float]  # scans, wall seconds, CPU seconds


def session_rate(project: Project, duration_us: int) -> tuple[int, float, float]:
    """(scans, wall seconds, CPU seconds) of a `plchmi run` without trace: session and
    summary collector, a quiet scan only counted as that command does (Session.run_for)."""
    from hmi.engine.build import build_engine
    from hmi.session.run_report import RunCollector
    from hmi.session.session import Session

    session = Session(build_engine(project))
    collector = RunCollector()
    with _settled():
        started, cpu = time.perf_counter(), time.process_time()
        collector.finish(session.run_for(duration_us, collector.add, collector.quiet))
        return (collector.scans, time.perf_counter() - started,
                time.process_time() - cpu)


def engine_rate(project: Project, duration_us: int, snapshots: bool = True
                ) -> tuple[int, float, float]:
    """(scans, wall seconds, CPU seconds) of the engine alone stepping in virtual time;
    without `snapshots`, scans run by Engine.run (no snapshot built: what a reader that
    asks for them only at scans with news pays)."""
    from hmi.engine.build import build_engine

    engine = build_engine(project)
    period = project.scan_period_us
    with _settled():
        started, cpu = time.perf_counter(), time.process_time()
        scans = 0
        scan = engine.step if snapshots else engine.run
        for now in range(0, duration_us + 1, period):
            scan(now)
            scans += 1
        return scans, time.perf_counter() - started, time.process_time() - cpu


def median_run(measure: Callable[[], Measure]) -> Measure:
    """The median of RUNS runs of `measure` by wall time, after one untimed run. The first
    run in a process pays one-time costs (modules imported and code generated on first use):
    in a quiet run on 5b9e564 it gave the first project 50,957 scans/s against 90,179 and
    98,249 in the next two runs of the same command."""
    measure()
    runs = sorted((measure() for _ in range(RUNS)), key=lambda run: run[1])
    return runs[len(runs) // 2]


@contextmanager
def _settled() -> Iterator[None]:
    """What a headless run does before its scans (hmi.session.session.settle_memory), undone
    after, so the next project's measure starts alike."""
    import gc

    from hmi.session.session import settle_memory

    settle_memory()
    try:
        yield
    finally:
        gc.unfreeze()


def run(args: argparse.Namespace) -> None:
    from hmi.project.loader import load_project

    seconds = QUICK_SECONDS if getattr(args, "quick", False) else SECONDS
    print(f"  {seconds} s of virtual time per project on its simulated plant, median of {RUNS} "
          f"runs after an untimed one; {load_line()}",
          flush=True)
    print("  (wall: scans per second of wall time, the goal's figure; CPU: per second of this "
          "process's CPU time, what a core of its own would give: the two agree on a quiet "
          "machine)", flush=True)
    for name, goal in GOALS.items():
        project = load_project(PROJECTS / name)
        span = seconds * 1_000_000
        scans, wall, cpu = median_run(partial(session_rate, project, span))
        rate = scans / wall
        alone, alone_wall, alone_cpu = median_run(partial(engine_rate, project, span))
        bare, bare_wall, bare_cpu = median_run(partial(engine_rate, project, span, False))
        print(f"  {name:<16} {rate:>9,.0f} scans/s wall, {scans / cpu:>9,.0f} CPU "
              f"({1e6 / rate:5.1f} us/scan, {rate * project.scan_period_us / 1e6:,.0f}x real "
              "time)", flush=True)
        print(f"  {'':<16} engine alone {alone / alone_wall:,.0f} wall, "
              f"{alone / alone_cpu:,.0f} CPU; without snapshots (Engine.run) "
              f"{bare / bare_wall:,.0f} wall, {bare / bare_cpu:,.0f} CPU", flush=True)
        if goal is not None:
            print(f"  {'':<16} {goal_line(rate, goal, 'scans/s')}; per CPU-second: "
                  f"{'met' if scans / cpu >= goal else 'NOT met'} "
                  f"({scans / cpu / goal:.2f}x)", flush=True)
