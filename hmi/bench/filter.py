"""Filter benchmark: the corrector's two strategies on random constraint sets, and the
per-scan cost of the filter (and of the whole scan) on the CISPI valve.

Random sets: No outputs, each output in 2 to 5 constraints (combined ones of 2-3 outputs,
plus a few simple ones), each constraint's context holding with probability ACTIVE in a
given situation, and a random functional vector. The minimal distance of an instance is
measured (exact search; it is checked against the paper's on the same instance) and
instances are kept by distance 1..4, so each row has a controlled distance.
"""

from __future__ import annotations

import argparse
import gc
import random
import time
from collections.abc import Iterator
from dataclasses import dataclass

from hmi.bench import percentile, summary, timed
from hmi.engine.solver import exact_solve, paper_solve
from hmi.session.session import settle_memory

SECTION = "filter"
HELP = "corrector strategies on random constraint sets; per-scan filter time of cispi_valve"

SIZES = (8, 16, 32, 64)
DISTANCES = (1, 2, 3, 4)
ACTIVE = 0.3


@dataclass
class Instance:
    start: int
    combined: list[tuple[int, int]]
    unforced: int
    f0: int
    f1: int


def random_instance(rng: random.Random, n: int) -> Instance:
    membership = {k: rng.randint(2, 5) for k in range(n)}
    slots = [k for k, m in membership.items() for _ in range(m)]
    rng.shuffle(slots)
    constraints: list[tuple[int, int, bool]] = []  # pos, neg, simple
    while slots:
        size = 1 if rng.random() < 0.15 else rng.choice((2, 2, 3))
        group: list[int] = []
        while slots and len(group) < size:
            k = slots.pop()
            if k not in group:
                group.append(k)
        pos = neg = 0
        for k in group:
            if rng.random() < 0.7:
                pos |= 1 << k
            else:
                neg |= 1 << k
        constraints.append((pos, neg, len(group) == 1))
    f0 = f1 = 0
    combined = []
    for pos, neg, simple in constraints:
        if rng.random() >= ACTIVE:
            continue
        if simple:
            f0 |= pos
            f1 |= neg
        else:
            combined.append((pos, neg))
    f1 &= ~f0  # keep the simple constraints consistent (004 eq. 4)
    fov = rng.getrandbits(n)
    mem = (fov & ~f0) | f1
    return Instance(mem, combined, ((1 << n) - 1) & ~(f0 | f1), f0, f1)


def collect(n: int, per_distance: int, seed: int, max_tries: int = 200_000
            ) -> dict[int, list[Instance]]:
    rng = random.Random(seed * 1000 + n)
    buckets: dict[int, list[Instance]] = {d: [] for d in DISTANCES}
    for _ in range(max_tries):
        if all(len(b) >= per_distance for b in buckets.values()):
            break
        inst = random_instance(rng, n)
        sol = exact_solve(inst.start, inst.combined, inst.unforced)
        d = sol.distance if sol.vector is not None else 0
        if d in buckets and len(buckets[d]) < per_distance:
            buckets[d].append(inst)
    return buckets


def run_strategies(samples: int, seed: int) -> Iterator[str]:
    lines = [f"Corrector on random constraint sets ({samples} instances per row, context "
             f"active with p={ACTIVE}, seed {seed})",
             f"  {'No':>3} {'d':>2} {'n':>3} | {'exact p50':>10} {'p99':>9} {'tested':>11} |"
             f" {'paper p50':>10} {'p99':>10} {'tested':>13} | {'time ratio':>10}"
             f" {'tested ratio':>12} | agree"]
    yield from lines
    lines = []
    for n in SIZES:
        buckets = collect(n, samples, seed)
        for d in DISTANCES:
            instances = buckets[d]
            if not instances:
                yield f"  {n:>3} {d:>2}   0 | (no instance of this distance found)"
                continue
            ex_t, ex_n, pa_t, pa_n = [], [], [], []
            agree = 0
            gc.disable()
            try:
                for inst in instances:
                    ex, t1 = timed(exact_solve, inst.start, inst.combined, inst.unforced)
                    pa, t2 = timed(paper_solve, inst.start, inst.combined, inst.unforced,
                                   inst.f0, inst.f1)
                    ex_t.append(t1)
                    pa_t.append(t2)
                    ex_n.append(ex.tested)
                    pa_n.append(pa.tested)
                    agree += ex.distance == pa.distance == d
            finally:
                gc.enable()
            e50, e99, _ = summary(ex_t)
            p50, p99, _ = summary(pa_t)
            en, en99 = percentile(ex_n, 50), percentile(ex_n, 99)
            pn, pn99 = percentile(pa_n, 50), percentile(pa_n, 99)
            yield (f"  {n:>3} {d:>2} {len(instances):>3} | {_us(e50):>10} {_us(e99):>9}"
                   f" {f'{en:.0f}/{en99:.0f}':>11} | {_us(p50):>10} {_us(p99):>10}"
                   f" {f'{pn:.0f}/{pn99:.0f}':>13} | {p50 / e50:>9.1f}x"
                   f" {pn / max(en, 1):>11.1f}x | {agree}/{len(instances)}")
    yield ("  (times: solver only, cold; tested p50/p99: search nodes (exact), vectors evaluated "
           "(paper); ratios paper/exact at the median; agree: both found the same minimal "
           "distance; 64 outputs with 200 active constraints: plchmi bench corrector)")


def _us(value: float) -> str:
    return f"{value:.0f} us" if value < 1000 else f"{value / 1000:.2f} ms"


def run_valve(scans: int) -> Iterator[str]:
    from hmi.engine.build import EngineOptions, build_engine
    from hmi.paths import PROJECTS
    from hmi.project.loader import load_project

    project = load_project(PROJECTS / "cispi_valve")
    yield f"cispi_valve, {scans} scans per row (10 ms virtual period, policy correct)"
    for control, frozen in (("normal", False), ("faulty", False), ("normal", True),
                            ("faulty", True)):
        engine = build_engine(project, options=EngineOptions(control=control, policy="correct"))
        if frozen:
            settle_memory()
        filter_us: list[float] = []
        scan_us: list[float] = []
        for k in range(scans):
            started = time.perf_counter()
            snap = engine.step(k * 10_000)
            scan_us.append((time.perf_counter() - started) * 1e6)
            filter_us.append(snap.filter_wall_us)
        if frozen:
            gc.unfreeze()
        s50, s99, _ = summary(scan_us)
        f50, f99, _ = summary(filter_us)
        how = "gc frozen (runners)" if frozen else "default gc        "
        yield (f"  {how}  control {control:<7} full scan p50 {s50:6.1f} us  p99 "
               f"{s99:6.1f} us  | filter p50 {f50:5.1f} us  p99 {f99:5.1f} us")


def run(args: argparse.Namespace) -> None:
    quick = getattr(args, "quick", False)
    samples = 5 if quick else 20
    for line in run_valve(2_000 if quick else 20_000):
        print(line, flush=True)
    print(flush=True)
    for line in run_strategies(samples, seed=getattr(args, "seed", 1)):
        print(line, flush=True)
