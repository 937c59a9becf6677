"""The palletizer of 001 under the corrector, for a long virtual time: the same figures as
the sorting section (distance histogram, solver and filter times), with pallets built.
"""

from __future__ import annotations

SECTION = "palletizer"
HELP = "the palletizer (001): max Hamming distance, solver p50/p99, pallets built"

MINUTE_US = 60_000_000


def work(counters: dict[str, int]) -> str:
    return (f"boxes arrived {counters.get('arrived', 0)}, pallets "
            f"{counters.get('pallets', 0)} ({counters.get('boxes_palletized', 0)} boxes), "
            f"layers {counters.get('layers', 0)}, lost {counters.get('lost', 0)}")


def run(args) -> None:
    from hmi.bench.cellrun import measure, report_lines, with_seed
    from hmi.paths import PROJECTS
    from hmi.project.loader import load_project

    minutes = 1 if getattr(args, "quick", False) else 10
    seed = getattr(args, "seed", 1)
    project = with_seed(load_project(PROJECTS / "palletizer"), seed)
    print(f"palletizer: {minutes} min of virtual time per row "
          f"({minutes * MINUTE_US // project.scan_period_us:,} scans of "
          f"{project.scan_period_us // 1000} ms), policy correct, box schedule seed {seed}",
          flush=True)
    for control in ("normal", "faulty"):
        result = measure(project, control, minutes * MINUTE_US)
        for line in report_lines(result, work(result.counters)):
            print(line, flush=True)
