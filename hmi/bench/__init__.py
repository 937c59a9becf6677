"""`plchmi bench [SECTION ...]`: measured figures, printed; never a pass/fail test.

Each module of this package that defines SECTION (its name), HELP (one line) and
`run(args) -> None` is a section; `plchmi bench` with no section runs them all.
"""

from __future__ import annotations

import importlib
import pkgutil
import statistics
from types import ModuleType


def sections() -> dict[str, ModuleType]:
    found = {}
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "SECTION") and hasattr(module, "run"):
            found[module.SECTION] = module
    return dict(sorted(found.items()))


def percentile(values: list[float], p: float) -> float:
    """Nearest-rank percentile (p in 0..100) of a non-empty list."""
    ordered = sorted(values)
    rank = max(1, min(len(ordered), round(p / 100 * len(ordered) + 0.5)))
    return ordered[rank - 1]


def summary(values: list[float]) -> tuple[float, float, float]:
    return percentile(values, 50), percentile(values, 99), statistics.fmean(values)
