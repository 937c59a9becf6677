"""Every fault at every phase of the cycle, per configuration: the runs behind
`plchmi campaign --sweep` and the closed-loop diagnosability of `check` / `diagnose`.

:func:`sweep` explores the closed loop (hmi/studies/explore.py) and keeps the outcome of each
run (hmi/studies/closed_loop.py). The work is cut into shards of :data:`SHARD_RUNS` runs —
per configuration, the faults one after the other, each at every instant, taken in that order
and cut every SHARD_RUNS runs — that any worker computes alone from the project's files
(hmi/farm/): its explorer back at the fault-free prefix before each shard, the runs of the
shard explored, their outcomes computed there. The outcomes come back in shard order, so the
result does not depend on the workers; the states explored are counted per shard (a state two
shards reach counts in both), so their number depends on the cut, which is fixed here.

Results are cached on disk, keyed by the project's files, the diagnoser variant, the grid and
the code version, so a second `check` of an unchanged project does not explore again. The
cache holds plain JSON (the outcomes), never code, and a damaged entry is simply recomputed.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from hmi.farm.bundle import Bundle, digest_of
from hmi.farm.job import Study, make_job
from hmi.farm.run import Farm
from hmi.farm.version import code_version
from hmi.studies.closed_loop import Outcome, outcomes
from hmi.studies.explore import Explorer, LoopConfig, faults_of

# The campaign's three columns (000 Table 1), as closed-loop configurations.
DIAG_NO_FILTER = LoopConfig("diag_no_filter", "Diag no Filter", "monitor", "observe")
FILTER_NO_DIAG = LoopConfig("filter_no_diag", "No Diag Filter", None, "off")
FTC = LoopConfig("ftc", "FTC (Diag and Filter)", None, "ftc")
CAMPAIGN_CONFIGS = (DIAG_NO_FILTER, FILTER_NO_DIAG, FTC)
# Where the diagnosers run: observing only, and driving reconstruction and masking.
DIAGNOSIS_CONFIGS = (DIAG_NO_FILTER, FTC)
CACHE_VERSION = 2
# Runs per shard: 0.3-3 s of work each on the valve (docs/studies.md), far above Dask's
# per-task cost, and 156 shards for the valve's full sweep: enough to keep 64 workers busy.
SHARD_RUNS = 200


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
    cached: bool = False  # read whole from the cache (how it ran is not part of the result)

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
          extras: bool = True, farm: Farm | None = None, cache: bool = True,
          compute: bool = True, faults: Sequence[str] | None = None) -> SweepResult | None:
    """The sweep, from the cache when it holds it; None when it does not and `compute` is
    false. `farm` says where the shards run (default: this machine's processes)."""
    period = project.scan_period_us
    every = max(1, round((every_us or period) / period))
    variant = project_variant(project)
    faults = tuple(faults) if faults else faults_of(project)
    key = _cache_key(project, variant, configs, counter, every, extras, faults)
    if cache:
        found = _load(key)
        if found is not None:
            if farm is not None:
                farm.notes.append(f"the closed-loop sweep of {project.name} was read from the "
                                  f"cache ({cache_folder() / 'closed-loop'})")
            return found
    if not compute:
        return None
    study, probe = sweep_study(project, configs, counter, every, extras, faults, variant)
    parts = (farm or Farm()).run(study)
    result = SweepResult(project.name, variant, tuple(configs), faults, period, every, extras,
                         probe.graph.cycle_start * period, probe.graph.cycle_length * period)
    prefix = len(probe.graph.prefix)
    for c in configs:
        result.runs[c.key] = []
        result.states[c.key] = prefix
    for (c, _, _), part in zip(study.shards, parts, strict=True):
        key_c = configs[c].key
        result.runs[key_c] += part.outcomes
        result.states[key_c] += part.nodes
    if cache:
        _store(key, result)
    return result


def sweep_study(project, configs: Sequence[LoopConfig], counter: str, every: int,
                extras: bool, faults: tuple[str, ...], variant: str
                ) -> tuple[Study, Explorer]:
    """The sweep as shards, and the explorer whose fault-free run gave the instants."""
    # The instants come from a configuration where the diagnosers run (their transitions in
    # the fault-free cycle add instants), and are the same for every configuration.
    first = next((c for c in configs if c.diagnosis != "off"), configs[0])
    probe = Explorer(project, first, counter)
    instants = probe.instants(extras, every)
    runs = len(faults) * len(instants)
    shards = tuple((c, start, min(start + SHARD_RUNS, runs))
                   for c in range(len(configs)) for start in range(0, runs, SHARD_RUNS))
    options = {"configs": [[c.key, c.title, c.policy, c.diagnosis] for c in configs],
               "counter": counter, "faults": list(faults),
               "instants": [list(i) for i in instants], "shape": _shape(probe)}
    job = make_job("sweep", Bundle.of(project, variant or None), _setup, _work, options,
                   shards)
    study = Study(f"the closed-loop sweep of {project.name}", job, shards,
                  tuple(end - start for _, start, end in shards), _encode, _decode)
    return study, probe


@dataclass(frozen=True)
class SweepPart:
    """One shard's runs: their outcomes in order, and the states it explored past the
    fault-free prefix."""

    outcomes: list[Outcome]
    nodes: int


@dataclass
class _State:
    project: Any
    configs: list[LoopConfig]
    counter: str
    runs: list[tuple[str, int, int, str]]  # (fault, k, at, why) in the order of the shards
    shape: str
    explorers: dict[int, Explorer] = field(default_factory=dict)

    def explorer(self, c: int) -> Explorer:
        ex = self.explorers.get(c)
        if ex is None:
            ex = Explorer(self.project, self.configs[c], self.counter)
            if _shape(ex) != self.shape:
                raise RuntimeError(f"the fault-free run under {ex.config.title} differs from "
                                   "the others': the sweep's instants would not be the same "
                                   "phases")
            self.explorers[c] = ex
        else:
            ex.reset()
        return ex


def _setup(project, options: dict[str, Any]) -> _State:
    instants = [tuple(i) for i in options["instants"]]
    return _State(project, [LoopConfig(*c) for c in options["configs"]], options["counter"],
                  [(f, k, at, why) for f in options["faults"] for k, at, why in instants],
                  options["shape"])


def _work(state: _State, shard: tuple[int, int, int]) -> SweepPart:
    c, start, end = shard
    ex = state.explorer(c)
    for fault, k, at, why in state.runs[start:end]:
        ex.run(fault, k, at, why)
    g = ex.graph
    return SweepPart(outcomes(g), len(g.obs) - len(g.prefix))


def _shape(ex: Explorer) -> str:
    """The fault-free run's digest: no configuration acts on a fault-free cell, so it must
    be the same run under each (its instants are the same phases)."""
    g = ex.graph
    text = repr((g.cycle_start, [g.obs[n] for n in g.prefix]))
    return hashlib.sha256(text.encode()).hexdigest()


def _encode(part: SweepPart) -> dict[str, Any]:
    return {"nodes": part.nodes, "outcomes": [asdict(r) for r in part.outcomes]}


def _decode(shard: Any, data: dict[str, Any]) -> SweepPart:
    return SweepPart([_outcome(r) for r in data["outcomes"]], int(data["nodes"]))


def _outcome(data: dict[str, Any]) -> Outcome:
    return Outcome(**{**data, "final": tuple(data["final"])})


def project_variant(project) -> str:
    """The diagnoser variant the project was loaded with, or the diagnosers file."""
    from hmi.project.diagnosers import diagnosers_of
    if project.diagnosers_file:
        return project.diagnosers_file
    return next((s.variant for s in diagnosers_of(project) if s.variant), "")


# -- the cache --------------------------------------------------------------------------------


def cache_folder() -> Path:
    base = os.environ.get("PLCHMI_CACHE")
    if base:
        return Path(base)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "plchmi"


def _cache_key(project, variant, configs, counter, every, extras, faults) -> str:
    text = json.dumps([CACHE_VERSION, variant, counter, every, extras, list(faults),
                       [[c.key, c.policy, c.diagnosis] for c in configs],
                       digest_of(project, variant or None), code_version().digest])
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _load(key: str) -> SweepResult | None:
    path = cache_folder() / "closed-loop" / f"{key}.json"
    try:
        data = json.loads(path.read_text())
        configs = tuple(LoopConfig(**c) for c in data["configs"])
        runs = {k: [_outcome(r) for r in v] for k, v in data["runs"].items()}
        return SweepResult(data["project"], data["variant"], configs, tuple(data["faults"]),
                           data["period_us"], data["every"], data["extras"],
                           data["cycle_start_us"], data["cycle_us"], runs, data["states"],
                           cached=True)
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
        "states": result.states,
    }
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"{key}.tmp{os.getpid()}"
        tmp.write_text(json.dumps(data))
        tmp.replace(folder / f"{key}.json")
    except OSError:
        pass  # a cache that cannot be written only costs time
