"""Every fault at every phase of the cycle, per configuration: the runs behind
`plchmi campaign --sweep` and the closed-loop diagnosability of `check` / `diagnose`.

:func:`sweep` explores the closed loop (hmi/engine/explore.py, on every core) and keeps the
outcome of each run (hmi/engine/closed_loop.py). Results are cached on disk, keyed by the
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

from hmi.engine.closed_loop import Outcome, explore_all, outcomes
from hmi.engine.explore import LoopConfig, faults_of

# The campaign's three columns (000 Table 1), as closed-loop configurations.
DIAG_NO_FILTER = LoopConfig("diag_no_filter", "Diag no Filter", "monitor", "observe")
FILTER_NO_DIAG = LoopConfig("filter_no_diag", "No Diag Filter", None, "off")
FTC = LoopConfig("ftc", "FTC (Diag and Filter)", None, "ftc")
CAMPAIGN_CONFIGS = (DIAG_NO_FILTER, FILTER_NO_DIAG, FTC)
# Where the diagnosers run: observing only, and driving reconstruction and masking.
DIAGNOSIS_CONFIGS = (DIAG_NO_FILTER, FTC)
CACHE_VERSION = 2


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
    exact: bool = False  # every instant (pieces), not a grid
    step_us: int | None = None  # a grid finer than the scan: every step_us of each interval
    point: str = ""  # the band point explored ("" the project's own plant)

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
        inside = [r for r in runs if r.first_us <= at <= r.last_us]
        if inside:
            return inside[0]
        return min(runs, key=lambda r: (abs(r.at_us - at), r.at_us))


def sweep(project, configs: Sequence[LoopConfig], counter: str, every_us: int | None = None,
          extras: bool = True, jobs: int | None = None,
          progress: Callable[[int, int], None] | None = None,
          cache: bool = True, compute: bool = True,
          faults: Sequence[str] | None = None, exact: bool = False,
          loaded: tuple | None = None, point: str = "") -> SweepResult | None:
    """The sweep, from the cache when it holds it; None when it does not and `compute` is
    false. `exact`: every instant of the cycle (Explorer.pieces), else a grid of `every_us`
    (a multiple of the scan period, or a divisor of it: instants inside each interval).
    `loaded` and `point`: the project is a band point's (hmi/engine/band.py), as the
    workers rebuild it and as it is named."""
    period = project.scan_period_us
    step_us = every_us if every_us is not None and every_us < period else None
    every = max(1, round((every_us or period) / period)) if step_us is None else 1
    if exact:
        extras, every, step_us = False, 1, None
    variant = project_variant(project)
    faults = tuple(faults) if faults else faults_of(project)
    # An exact sweep is kept per configuration (diagnose's two are among campaign's three);
    # a grid's instants depend on the configurations together (the extras around the
    # transitions come from one where the diagnosers run), so it is kept whole.
    groups = [(c,) for c in configs] if exact else [tuple(configs)]
    keys = [_cache_key(project, variant, group, counter, every, extras, faults,
                       f"{exact}|{step_us}|{point}") for group in groups]
    found = [_load(key) if cache else None for key in keys]
    missing = [c for group, part in zip(groups, found, strict=True) if part is None
               for c in group]
    if missing and not compute:
        return None
    if not missing:
        return _joined([p for p in found if p is not None], configs, cached=True)
    jobs = jobs or min(2, os.cpu_count() or 1)
    started = time.perf_counter()
    graphs = explore_all(project, missing, counter, faults, extras, jobs, progress, every,
                         variant or None, exact=exact, step_us=step_us, loaded=loaded)
    first = next(iter(graphs.values()))
    wall = time.perf_counter() - started
    parts = []
    for group, key, part in zip(groups, keys, found, strict=True):
        if part is None:
            part = SweepResult(project.name, variant, group, faults, period, every, extras,
                               first.cycle_start * period, first.cycle_length * period,
                               jobs=jobs, exact=exact, step_us=step_us, point=point)
            for c in group:
                g = graphs[c.key]
                part.runs[c.key] = outcomes(g)
                part.states[c.key] = len(g.obs)
            part.wall_s = wall * len(group) / len(missing)
            if cache:
                _store(key, part)
        parts.append(part)
    result = _joined(parts, configs, cached=False)
    result.wall_s = wall + sum(p.wall_s for p in parts if p.cached)
    return result


def _joined(parts: list[SweepResult], configs: Sequence[LoopConfig], cached: bool
            ) -> SweepResult:
    """One result of the parts the configurations were kept in."""
    if len(parts) == 1:
        part = parts[0]
        part.cached = cached
        return part
    first = parts[0]
    result = SweepResult(first.project, first.variant, tuple(configs), first.faults,
                         first.period_us, first.every, first.extras, first.cycle_start_us,
                         first.cycle_us, jobs=first.jobs, cached=cached, exact=first.exact,
                         step_us=first.step_us, point=first.point)
    for part in parts:
        result.runs.update(part.runs)
        result.states.update(part.states)
    result.wall_s = sum(p.wall_s for p in parts)
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


def _cache_key(project, variant, configs, counter, every, extras, faults, more="") -> str:
    h = hashlib.sha256()
    h.update(f"{CACHE_VERSION}|{variant}|{counter}|{every}|{extras}|{faults}|{more}|".encode())
    h.update(repr([(c.key, c.policy, c.diagnosis) for c in configs]).encode())
    for name in project.files:
        h.update(name.encode())
        try:
            h.update(Path(name).read_bytes())
        except OSError:
            h.update(b"?")
    h.update(_source_digest().encode())
    return h.hexdigest()[:32]


def project_digest(project, extra: str) -> str:
    """A cache key for a study of `project`: its files, the variant loaded, the source of
    plchmi, and what the study is (`extra`)."""
    h = hashlib.sha256()
    h.update(f"{project_variant(project)}|{extra}|".encode())
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
                           data["wall_s"], data["jobs"], cached=True, exact=data["exact"],
                           step_us=data["step_us"], point=data["point"])
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
        "exact": result.exact, "step_us": result.step_us, "point": result.point,
    }
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"{key}.tmp{os.getpid()}"
        tmp.write_text(json.dumps(data))
        tmp.replace(folder / f"{key}.json")
    except OSError:
        pass  # a cache that cannot be written only costs time
