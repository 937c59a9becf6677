"""`plchmi bench [SECTION ...]`: measured figures, printed; never a pass/fail test.

Each module of this package that defines SECTION (its name), HELP (one line) and
`run(args) -> None` is a section; `plchmi bench` with no section runs them all.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import TypeVar

R = TypeVar("R")

# The sections' names, for `plchmi --help` and argument checks without importing every
# section (some import pymodbus or the whole engine: the HMI's start-up would pay for them;
# for the same reason this module imports what its functions need only when they run).
# tests/test_bench_sections.py checks it against sections().
NAMES = ("campaign", "corrector", "engine", "filter", "history", "live", "modbus", "opcua",
         "palletizer", "sorting", "startup", "ui")


def sections() -> dict[str, ModuleType]:
    import importlib
    import pkgutil

    found = {}
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "SECTION") and hasattr(module, "run"):
            found[module.SECTION] = module
    return dict(sorted(found.items()))


def timed(fn: Callable[..., R], *args: object) -> tuple[R, float]:
    """`fn(*args)` and how long it took, in microseconds of wall clock."""
    started = time.perf_counter()
    result = fn(*args)
    return result, (time.perf_counter() - started) * 1e6


def percentile(values: Sequence[float], p: float) -> float:
    """Nearest-rank percentile (p in 0..100) of a non-empty list."""
    ordered = sorted(values)
    rank = max(1, min(len(ordered), round(p / 100 * len(ordered) + 0.5)))
    return ordered[rank - 1]


def load_line() -> str:
    """The machine's load, to print beside timed figures: on a shared machine they vary
    with it."""
    try:
        one, five, _ = os.getloadavg()
    except OSError:
        return "load average unknown"
    return f"load average {one:.1f} (5 min {five:.1f}) on {os.cpu_count()} cores"


def goal_line(figure: float, goal: float, unit: str, higher_is_better: bool = True) -> str:
    """The figure beside its goal, and whether it is met."""
    met = figure >= goal if higher_is_better else figure < goal
    ratio = figure / goal if goal else 0.0
    sign = ">=" if higher_is_better else "<"
    return f"goal {sign} {goal:,g} {unit}: {'met' if met else 'NOT met'} ({ratio:.2f}x the goal)"


def summary(values: list[float]) -> tuple[float, float, float]:
    import statistics

    return percentile(values, 50), percentile(values, 99), statistics.fmean(values)
