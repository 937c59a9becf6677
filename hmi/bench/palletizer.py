"""The palletizer of 001 under the corrector, for a long virtual time: the same figures as
the sorting section (distance histogram, solver and filter times), with pallets built.
"""

from __future__ import annotations

import argparse

SECTION = "palletizer"
HELP = "the palletizer (001): max Hamming distance, solver p50/p99, pallets built"


def work(counters: dict[str, int]) -> str:
    return (f"boxes arrived {counters.get('arrived', 0)}, pallets "
            f"{counters.get('pallets', 0)} ({counters.get('boxes_palletized', 0)} boxes), "
            f"layers {counters.get('layers', 0)}, lost {counters.get('lost', 0)}")


def run(args: argparse.Namespace) -> None:
    from hmi.bench.cellrun import run_cell_bench
    run_cell_bench(args, "palletizer", "palletizer", work, strategies=("exact",))
