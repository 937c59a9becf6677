"""Every fault at every phase of the cycle, per configuration: the runs behind
`plchmi campaign --sweep` and the closed-loop diagnosability of `check` / `diagnose`.

:func:`sweep` explores the closed loop (hmi/studies/explore.py, on every core) and keeps the
outcome of each run (hmi/studies/closed_loop.py). Results are cached on disk, keyed by the
project's files, the diagnoser variant, the grid and the source of the `hmi` package, so a
second `check` of an unchanged project does not explore again. The cache holds plain JSON
(the outcomes), never code, and a damaged entry is simply recomputed.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from hmi.studies.closed_loop import Outcome, explore_all, outcomes
from hmi.studies.explore import LoopConfig, faults_of

# The campaign's three columns (000 Table 1), as closed-loop configurations.
DIAG_NO_FILTER = LoopConfig("diag_no_filter", "Diag no Filter", "monitor", "observe")
FILTER_NO_DIAG = LoopConfig("filter_no_diag", "No Diag Filter", None, "off")
FTC = LoopConfig("ftc", "FTC (Diag and Filter)", None, "ftc")
CAMPAIGN_CONFIGS = (DIAG_NO_FILTER, FILTER_NO_DIAG, FTC)
# Where the diagnosers run: observing only, and driving reconstruction and masking.
DIAGNOSIS_CONFIGS = (DIAG_NO_FILTER, FTC)
CACHE_VERSION = 1


@dataclass
class SweepResult:
    project: str
    variant: str
    configs: tuple[LoopConfig, ...]
    faults: tuple[str, ...]
    period_us: int
    every: int  # scans between two grid instants
    extras: bool
    cycle_start_us: int
    cycle_us: int
    runs: dict[str, list[Outcome]] = field(default_factory=dict)
    states: dict[str, int] = field(default_factory=dict)  # nodes explored per config
    wall_s: float = 0.0
    jobs: int = 1
    cached: bool = False

    def of(self, config: str) -> list[Outcome]:
        return self.runs[config]

    def at_phase(self, config: str, fault: str, at_us: int) -> Outcome:
        """The run of `fault` at the grid instant with the same phase as `at_us` (the
        fault-free loop repeats every cycle, so an instant of a later cycle is the same
        state as its phase in the swept one)."""
        at = at_us
        if at >= self.cycle_start_us:
            at = self.cycle_start_us + (at - self.cycle_start_us) % self.cycle_us
        runs = [r for r in self.runs[config] if r.fault == fault and not r.extra]
        return min(runs, key=lambda r: (abs(r.at_us - at), r.at_us))


def sweep(project, configs: Sequence[LoopConfig], counter: str, every_us: int | None = None,
          extras: bool = True, jobs: int | None = None,
          progress: Callable[[int, int], None] | None = None,
          cache: bool = True, compute: bool = True,
          faults: Sequence[str] | None = None) -> SweepResult | None:
    """The sweep, from the cache when it holds it; None when it does not and `compute` is
    false."""
    period = project.scan_period_us
    every = max(1, round((every_us or period) / period))
    variant = project_variant(project)
    faults = tuple(faults) if faults else faults_of(project)
    key = _cache_key(project, variant, configs, counter, every, extras, faults)
    if cache:
        found = _load(key)
        if found is not None:
            return found
    if not compute:
        return None
    jobs = jobs or min(2, os.cpu_count() or 1)
    started = time.perf_counter()
    graphs = explore_all(project, configs, counter, faults, extras, jobs, progress, every,
                         variant or None)
    first = next(iter(graphs.values()))
    result = SweepResult(project.name, variant, tuple(configs), faults, period, every, extras,
                         first.cycle_start * period, first.cycle_length * period, jobs=jobs)
    for c in configs:
        g = graphs[c.key]
        result.runs[c.key] = outcomes(g)
        result.states[c.key] = len(g.obs)
    result.wall_s = time.perf_counter() - started
    if cache:
        _store(key, result)
    return result


def project_variant(project) -> str:
    from hmi.project.diagnosers import diagnosers_of
    return next((s.variant for s in diagnosers_of(project) if s.variant), "")


# -- the cache --------------------------------------------------------------------------------


def cache_folder() -> Path:
    base = os.environ.get("PLCHMI_CACHE")
    if base:
        return Path(base)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "plchmi"


def _source_digest() -> str:
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _cache_key(project, variant, configs, counter, every, extras, faults) -> str:
    h = hashlib.sha256()
    h.update(f"{CACHE_VERSION}|{variant}|{counter}|{every}|{extras}|{faults}|".encode())
    h.update(repr([(c.key, c.policy, c.diagnosis) for c in configs]).encode())
    for name in project.files:
        h.update(name.encode())
        try:
            h.update(Path(name).read_bytes())
        except OSError:
            h.update(b"?")
    h.update(_source_digest().encode())
    return h.hexdigest()[:32]


def _load(key: str) -> SweepResult | None:
    path = cache_folder() / "closed-loop" / f"{key}.json"
    try:
        data = json.loads(path.read_text())
        configs = tuple(LoopConfig(**c) for c in data["configs"])
        runs = {k: [Outcome(**{**r, "final": tuple(r["final"])}) for r in v]
                for k, v in data["runs"].items()}
        return SweepResult(data["project"], data["variant"], configs, tuple(data["faults"]),
                           data["period_us"], data["every"], data["extras"],
                           data["cycle_start_us"], data["cycle_us"], runs, data["states"],
                           data["wall_s"], data["jobs"], cached=True)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _store(key: str, result: SweepResult) -> None:
    folder = cache_folder() / "closed-loop"
    data = {
        "project": result.project, "variant": result.variant,
        "configs": [asdict(c) for c in result.configs], "faults": list(result.faults),
        "period_us": result.period_us, "every": result.every, "extras": result.extras,
        "cycle_start_us": result.cycle_start_us, "cycle_us": result.cycle_us,
        "runs": {k: [asdict(r) for r in v] for k, v in result.runs.items()},
        "states": result.states, "wall_s": result.wall_s, "jobs": result.jobs,
    }
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"{key}.tmp{os.getpid()}"
        tmp.write_text(json.dumps(data))
        tmp.replace(folder / f"{key}.json")
    except OSError:
        pass  # a cache that cannot be written only costs time
