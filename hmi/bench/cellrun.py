"""Running a whole cell for a long virtual time and measuring what its filter did.

Used by the `sorting` and `palletizer` bench sections and by their tests. Everything but the
times is deterministic (the plant's box schedule is seeded); the times are measured on this
machine and vary with its load.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from hmi.bench import percentile
from hmi.project.injection import Injection
from hmi.project.model import Project


@dataclass
class CellRun:
    project: str
    control: str
    policy: str
    strategy: str
    scans: int = 0
    virtual_us: int = 0
    distances: Counter[int] = field(default_factory=Counter)  # Hamming distance -> scans
    violated_scans: int = 0
    corrected_scans: int = 0
    fallbacks: int = 0
    unsafe_written: int = 0
    solver_us: list[float] = field(default_factory=list)  # each run of the combined search
    tested: list[int] = field(default_factory=list)  # vectors tested by each of those runs
    filter_us: list[float] = field(default_factory=list)  # the whole filter stage, per scan
    counters: dict[str, int] = field(default_factory=dict)
    damage: Counter[str] = field(default_factory=Counter)  # damage event kind -> count
    wall_s: float = 0.0

    @property
    def max_distance(self) -> int:
        return max(self.distances, default=0)


def run_cell_bench(args: argparse.Namespace, folder: str, title: str,
                   work: Callable[[dict[str, int]], str],
                   strategies: Sequence[str] = ("exact",), footnote: str | None = None) -> None:
    """The body of a cell's bench section: each program (and strategy) for 10 virtual
    minutes (1 with --quick), one block of figures per row."""
    from hmi.paths import PROJECTS
    from hmi.project.loader import load_project

    minute = 60_000_000
    minutes = 1 if getattr(args, "quick", False) else 10
    seed = getattr(args, "seed", 1)
    project = with_seed(load_project(PROJECTS / folder), seed)
    print(f"{title}: {minutes} min of virtual time per row "
          f"({minutes * minute // project.scan_period_us:,} scans of "
          f"{project.scan_period_us // 1000} ms), policy correct, box schedule seed {seed}",
          flush=True)
    for control in ("normal", "faulty"):
        for strategy in strategies:
            result = measure(project, control, minutes * minute, strategy=strategy)
            for line in report_lines(result, work(result.counters)):
                print(line, flush=True)
    if footnote:
        print(footnote, flush=True)


def with_seed(project: Project, seed: int) -> Project:
    """The project with every simulated device's `seed` parameter (if it has one) replaced."""
    devices = tuple(dataclasses.replace(d, params={**d.params, "seed": seed})
                    for d in project.plant.devices)
    return dataclasses.replace(project, plant=dataclasses.replace(project.plant,
                                                                  devices=devices))


def measure(project: Project, control: str, duration_us: int, policy: str = "correct",
            strategy: str = "exact", timed: bool = True,
            inject: Sequence[Injection | str] = ()) -> CellRun:
    """Run the cell headless on its simulated plant, scan by scan, and collect the figures.

    `inject` holds fault injections: Injection objects (a scenario's), or text as written on
    the command line (`table_jam@30s`).
    """
    from hmi.engine.build import EngineOptions, build_engine
    from hmi.plant.sim.plant import SimPlant
    from hmi.project.injection import Injection, parse_injection
    from hmi.session.session import settle_memory

    plant = SimPlant(project)
    for item in inject:
        plant.inject(item if isinstance(item, Injection) else parse_injection(item))
    engine = build_engine(project, plant, EngineOptions(control=control, policy=policy,
                                                        solver=strategy))
    # This bench measures the corrector: every correction is searched, none given again
    # from the filter's memory (SafetyFilter.remember).
    engine.safety_filter.remember = False
    run = CellRun(project.name, control, policy, strategy)
    filter_us = run.filter_us
    period = project.scan_period_us
    settle_memory()
    started = time.perf_counter()
    try:
        k = 0
        while k * period <= duration_us:
            snap = engine.step(k * period)
            k += 1
            report = snap.filter_report
            if timed:
                filter_us.append(snap.filter_wall_us)
            for event in snap.plant_events:
                if event.damage:
                    run.damage[event.kind] += 1
            if report is None:
                continue
            run.distances[report.distance] += 1
            if report.violations:
                run.violated_scans += 1
                if report.changes and not report.safe_state:
                    run.corrected_scans += 1
            if report.solver_us:
                run.solver_us.append(report.solver_us)
                run.tested.append(report.tested)
            run.fallbacks += bool(report.fallback)
            run.unsafe_written += report.unsafe_written
    finally:
        gc.unfreeze()
    run.wall_s = time.perf_counter() - started
    run.scans = k
    run.virtual_us = (k - 1) * period
    run.counters = dict(plant.counters())
    return run


def _us(value: float) -> str:
    return f"{value:.0f} us" if value < 1000 else f"{value / 1000:.2f} ms"


def report_lines(run: CellRun, work: str) -> list[str]:
    """A few lines for one run; `work` summarises the plant's counters."""
    damage = sum(run.damage.values())
    lines = [f"  control {run.control}, solver {run.strategy}: {work}; damage events "
             f"{damage}" + (f" ({', '.join(f'{k} x{v}' for k, v in sorted(run.damage.items()))})"
                            if damage else ""),
             f"    scans {run.scans:,} ({run.wall_s:.1f} s wall); with a violation "
             f"{run.violated_scans:,} ({100 * run.violated_scans / max(run.scans, 1):.1f} %), "
             f"corrected {run.corrected_scans:,}, fallbacks {run.fallbacks}, unsafe vectors "
             f"written {run.unsafe_written}",
             f"    Hamming distance: max {run.max_distance}; histogram "
             + "  ".join(f"{d}: {n:,}" for d, n in sorted(run.distances.items()))]
    if run.solver_us:
        tested = sorted(run.tested)
        lines.append(f"    combined search ({len(run.solver_us):,} runs): p50 "
                     f"{_us(percentile(run.solver_us, 50))}, p99 "
                     f"{_us(percentile(run.solver_us, 99))}, max {_us(max(run.solver_us))}; "
                     f"{'vectors tested' if run.strategy == 'paper' else 'search nodes'} "
                     f"median {tested[len(tested) // 2]}, max {tested[-1]}")
    else:
        lines.append("    combined search: never needed (only simple constraints corrected)")
    if run.filter_us:
        lines.append(f"    whole filter stage per scan: p50 {_us(percentile(run.filter_us, 50))}"
                     f", p99 {_us(percentile(run.filter_us, 99))}, max "
                     f"{_us(max(run.filter_us))}")
    return lines
