"""`plchmi bench [SECTION ...]`: performance figures, measured and printed.

A bench prints what it measured and never fails the command: a section that cannot run says
why and the next one runs. Each section is a module here with `run(scans, out)`; other
features add theirs to SECTIONS.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence

from hmi.errors import UsageError

SECTIONS = {
    "modbus": "hmi.bench.modbus",
}


def percentiles(samples: Sequence[float]) -> tuple[float, float, float]:
    """(p50, p99, max) of samples, by rank (no interpolation)."""
    ordered = sorted(samples)
    n = len(ordered)
    return ordered[n // 2], ordered[min(n - 1, int(n * 0.99))], ordered[-1]


def run_bench(sections: Sequence[str], scans: int) -> int:
    names = list(sections) or list(SECTIONS)
    unknown = [n for n in names if n not in SECTIONS]
    if unknown:
        raise UsageError(f"unknown bench section {unknown[0]!r}; sections: "
                         + ", ".join(SECTIONS))
    if scans < 10:
        raise UsageError("--scans must be at least 10")
    for name in names:
        try:
            importlib.import_module(SECTIONS[name]).run(scans, _out)
        except Exception as exc:  # a bench reports; it does not fail
            _out(f"bench {name}: could not measure: {type(exc).__name__}: {exc}")
    return 0


def _out(line: str) -> None:
    print(line, flush=True)
