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

import argparse

SECTION = "sorting"
HELP = "the sorting cell (004 §5.3): max Hamming distance, solver p50/p99, boxes sorted"


def work(counters: dict[str, int]) -> str:
    sorted_ = counters.get("sorted_left", 0) + counters.get("sorted_right", 0)
    return (f"boxes arrived {counters.get('arrived', 0)}, sorted {sorted_} (left "
            f"{counters.get('sorted_left', 0)}, right {counters.get('sorted_right', 0)}, "
            f"missorted {counters.get('missorted', 0)}), lost {counters.get('lost', 0)}")


FOOTNOTE = ("  (combined search: the solver proper, timed only in scans where a combined "
            "constraint had to be repaired; times measured on this machine)")


def run(args: argparse.Namespace) -> None:
    from hmi.bench.cellrun import run_cell_bench
    run_cell_bench(args, "sorting", "sorting cell", work, strategies=("exact", "paper"),
                   footnote=FOOTNOTE)
