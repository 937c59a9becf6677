"""The sorting cell of 004 §5.3 under the corrector, for a long virtual time.

004 reports, for its sorting system on a real PLC at a 5 ms scan: with the functional program
the corrector never needs more than Hamming distance 2 and the solver always runs in under
1 ms. This section runs projects/sorting (5 ms scan, policy correct) with its functional
program and its deliberately faulty one, with both search strategies, and prints the maximal
distance, the distance histogram, the time of the combined search (p50/p99/max, and the
vectors it tested), the whole filter stage's time per scan, the boxes sorted and the damage.
`--seed` changes the box schedule; `--quick` runs 1 virtual minute instead of 10.
"""

from __future__ import annotations

SECTION = "sorting"
HELP = "the sorting cell (004 §5.3): max Hamming distance, solver p50/p99, boxes sorted"

MINUTE_US = 60_000_000


def work(counters: dict[str, int]) -> str:
    sorted_ = counters.get("sorted_left", 0) + counters.get("sorted_right", 0)
    return (f"boxes arrived {counters.get('arrived', 0)}, sorted {sorted_} (left "
            f"{counters.get('sorted_left', 0)}, right {counters.get('sorted_right', 0)}, "
            f"missorted {counters.get('missorted', 0)}), lost {counters.get('lost', 0)}")


def run(args) -> None:
    from hmi.bench.cellrun import measure, report_lines, with_seed
    from hmi.paths import PROJECTS
    from hmi.project.loader import load_project

    minutes = 1 if getattr(args, "quick", False) else 10
    seed = getattr(args, "seed", 1)
    project = with_seed(load_project(PROJECTS / "sorting"), seed)
    print(f"sorting cell: {minutes} min of virtual time per row "
          f"({minutes * MINUTE_US // project.scan_period_us:,} scans of "
          f"{project.scan_period_us // 1000} ms), policy correct, box schedule seed {seed}",
          flush=True)
    for control in ("normal", "faulty"):
        for strategy in ("exact", "paper"):
            result = measure(project, control, minutes * MINUTE_US, strategy=strategy)
            for line in report_lines(result, work(result.counters)):
                print(line, flush=True)
    print("  (combined search: the solver proper, timed only in scans where a combined "
          "constraint had to be repaired; times measured on this machine)", flush=True)
