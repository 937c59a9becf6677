"""Every fault at every phase of the cycle, per configuration: the runs behind
`plchmi campaign --sweep` and the closed-loop diagnosability of `check` / `diagnose`.

:func:`sweep` explores the closed loop (hmi/studies/explore.py) and keeps the outcome of each
run (hmi/studies/closed_loop.py). The runs — per configuration, the faults one after the
other, each at every instant, taken in that order — fall in **blocks** of :data:`SHARD_RUNS`
runs: the states explored are counted per block (a state two blocks reach counts in both), so
that count is fixed by the runs alone.

The work is cut into shards that any worker computes alone from the project's files
(hmi/farm/), by their cost: the blocks' CPU times measured by the previous run of the same
sweep (kept next to the cache, :func:`cut`). Light blocks go together in one shard, a heavy
block is split into pieces of consecutive runs; with no times known, a shard is a block. A
worker explores each piece from the fault-free prefix (its explorer reset) and returns its
runs' outcomes and its states: their number for a whole block, their digests for a piece of
one (the client counts the union: the states the whole block would have explored, since a
run's path is fixed by its start). The outcomes come back in run order, so the report does
not depend on the workers nor on the cut.

Results are cached on disk, keyed by the project's files, the diagnoser variant, the grid and
the code version, so a second `check` of an unchanged project does not explore again. The
cache holds plain JSON (the outcomes), never code, and a damaged entry is simply recomputed.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import time
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
# Runs per block, the unit the states are counted in (and a shard when no times are known):
# 156 blocks for the valve's full sweep, of 0.02-30 s each (docs/studies.md).
SHARD_RUNS = 200
# The cut by cost: shards of about the total CPU time / SHARDS_WANTED (4 per worker at 64
# workers), and never aimed under SHARD_MIN_S: a piece cut finer than the one measured can take
# a tenth of its expected time (docs/studies.md), and should still pass hmi.farm.run.SHARD_GOAL_S.
SHARDS_WANTED = 256
SHARD_MIN_S = 0.4


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
    split: dict[tuple[int, int], set[str]] = {}
    spent: list[tuple[int, int, int, float]] = []
    for shard, part in zip(study.shards, parts, strict=True):
        for (c, start, end), piece in zip(shard, part.pieces, strict=True):
            block = (c, start // SHARD_RUNS)
            result.runs[configs[c].key] += piece.outcomes
            if piece.states is None:
                result.states[configs[c].key] += piece.nodes
            else:
                split.setdefault(block, set()).update(piece.states)
            spent.append((c, start, end, piece.seconds))
    for (c, _), states in sorted(split.items()):
        result.states[configs[c].key] += len(states)
    _store_times(_times_key(project, variant, configs, counter, every, extras, faults),
                 configs, spent)
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
    blocks = [(c, start, min(start + SHARD_RUNS, runs))
              for c in range(len(configs)) for start in range(0, runs, SHARD_RUNS)]
    costs = _load_times(_times_key(project, variant, configs, counter, every, extras, faults),
                        configs, runs)
    shards = cut(blocks, costs)
    expected = None
    if costs is not None:  # cut by them: each shard's share, to send the heaviest first
        expected = tuple(sum(sum(costs[c * runs + a:c * runs + b]) for c, a, b in s)
                         for s in shards)
    options = {"configs": [[c.key, c.title, c.policy, c.diagnosis] for c in configs],
               "counter": counter, "faults": list(faults), "block": SHARD_RUNS,
               "instants": [list(i) for i in instants], "shape": _shape(probe)}
    job = make_job("sweep", Bundle.of(project, variant or None), _setup, _work, options,
                   shards)
    study = Study(f"the closed-loop sweep of {project.name}", job, shards,
                  tuple(sum(end - start for _, start, end in s) for s in shards), _encode,
                  _decode, expected)
    return study, probe


Piece = tuple[int, int, int]  # (configuration, first run, end): runs of one block


def cut(blocks: list[Piece], costs: list[float] | None) -> tuple[tuple[Piece, ...], ...]:
    """The shards, each a tuple of pieces in run order, from the blocks (in run order) and
    each run's measured CPU time, in the same order (None: one shard per block).

    Shards aim at `target`, the total time over SHARDS_WANTED and SHARD_MIN_S or more: a
    block above it is split into that many pieces of consecutive runs of about the same time,
    lighter blocks go together until the next would pass it; a light rest goes with its
    neighbour."""
    if costs is None or len(costs) != sum(end - start for _, start, end in blocks):
        return tuple((b,) for b in blocks)
    target = max(SHARD_MIN_S, sum(costs) / SHARDS_WANTED)
    shards: list[list[Piece]] = []
    current: list[Piece] = []  # light blocks gathering
    spent = 0.0
    first = 0  # the block's first run in `costs`
    for c, start, end in blocks:
        runs = costs[first:first + end - start]
        first += end - start
        t = sum(runs)
        if t > target and end - start > 1:
            n = min(end - start, -int(-t // target))
            bounds = [start]
            total = 0.0
            for r, x in enumerate(runs):
                total += x
                # a bound where the time so far passes the next n-th, leaving a run a piece
                if len(bounds) < n and total >= t * len(bounds) / n and \
                        start + r + 1 > bounds[-1] and end - (start + r + 1) >= n - len(bounds):
                    bounds.append(start + r + 1)
            bounds.append(end)
            pieces = [[(c, a, b)] for a, b in itertools.pairwise(bounds)]
            if spent >= target / 2:
                shards.append(current)
            else:
                pieces[0] = current + pieces[0]
            shards += pieces
            current, spent = [], 0.0
            continue
        if current and spent + t > target and spent >= target / 2:
            shards.append(current)
            current, spent = [], 0.0
        current.append((c, start, end))
        spent += t
    if current:
        if shards and spent < target / 2:
            shards[-1] += current
        else:
            shards.append(current)
    return tuple(tuple(s) for s in shards)


@dataclass(frozen=True)
class PiecePart:
    """One piece's runs: their outcomes in order, the states it explored past the fault-free
    prefix (their number; their digests too when the piece is part of a block), and the CPU
    time its thread spent on it (for the next run's cut, never for the report: unlike the
    time from start to end, it does not grow with whatever else the machine runs)."""

    outcomes: list[Outcome]
    nodes: int
    states: list[str] | None
    seconds: float


@dataclass(frozen=True)
class SweepPart:
    """One shard's pieces, in order."""

    pieces: list[PiecePart]


@dataclass
class _State:
    project: Any
    configs: list[LoopConfig]
    counter: str
    runs: list[tuple[str, int, int, str]]  # (fault, k, at, why) in the order of the shards
    shape: str
    block: int
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
                  options["shape"], options["block"])


def _work(state: _State, shard: tuple[Piece, ...]) -> SweepPart:
    return SweepPart([_piece(state, *piece) for piece in shard])


def _piece(state: _State, c: int, start: int, end: int) -> PiecePart:
    ex = state.explorer(c)  # built at a worker's first piece of `c`: not the piece's cost
    started = time.thread_time()
    for fault, k, at, why in state.runs[start:end]:
        ex.run(fault, k, at, why)
    g = ex.graph
    whole = start % state.block == 0 and end == min(start + state.block, len(state.runs))
    states = None if whole else sorted(_digest(key) for key in ex.explored())
    return PiecePart(outcomes(g), len(g.obs) - len(g.prefix), states,
                     time.thread_time() - started)


def _digest(key: tuple) -> str:
    """A state's name that is the same in every process (its key holds numbers, strings and
    tuples only, whose repr is fixed): 64 bits, so that 10^5 states of a block collide with
    odds of about 10^-10."""
    return hashlib.blake2b(repr(key).encode(), digest_size=8).hexdigest()


def _shape(ex: Explorer) -> str:
    """The fault-free run's digest: no configuration acts on a fault-free cell, so it must
    be the same run under each (its instants are the same phases)."""
    g = ex.graph
    text = repr((g.cycle_start, [g.obs[n] for n in g.prefix]))
    return hashlib.sha256(text.encode()).hexdigest()


def _encode(part: SweepPart) -> list[dict[str, Any]]:
    return [{"nodes": p.nodes, "states": p.states, "seconds": p.seconds,
             "outcomes": [asdict(r) for r in p.outcomes]} for p in part.pieces]


def _decode(shard: Any, data: list[dict[str, Any]]) -> SweepPart:
    if len(data) != len(shard):
        raise ValueError("a result of another cut")
    return SweepPart([PiecePart([_outcome(r) for r in p["outcomes"]], int(p["nodes"]),
                                None if p["states"] is None else list(p["states"]),
                                float(p["seconds"])) for p in data])


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


def _times_key(project, variant, configs, counter, every, extras, faults) -> str:
    """The sweep without the code version: the times measured before a change of the code
    still cut the next run well enough (the cut changes the time, never the result)."""
    text = json.dumps(["times", SHARD_RUNS, variant, counter, every, extras, list(faults),
                       [[c.key, c.policy, c.diagnosis] for c in configs],
                       digest_of(project, variant or None)])
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _load_times(key: str, configs, runs: int) -> list[float] | None:
    """Each run's CPU time, as the last run of this sweep measured it (a piece's time
    spread evenly over its runs), in run order; None if unknown."""
    try:
        data = json.loads((cache_folder() / "closed-loop" / f"times-{key}.json").read_text())
        costs: list[float] = []
        for c in configs:
            spread = [0.0] * runs
            for start, end, seconds in data[c.key]:
                for r in range(int(start), int(end)):
                    spread[r] = float(seconds) / (int(end) - int(start))
            costs += spread
    except (OSError, ValueError, KeyError, TypeError, IndexError, ZeroDivisionError):
        return None
    return costs


def _store_times(key: str, configs, spent: list[tuple[int, int, int, float]]) -> None:
    """Each piece's CPU time: [first run, end, seconds] per configuration."""
    data = {c.key: [[start, end, t] for i, start, end, t in spent if i == n]
            for n, c in enumerate(configs)}
    folder = cache_folder() / "closed-loop"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"times-{key}.tmp{os.getpid()}"
        tmp.write_text(json.dumps(data))
        tmp.replace(folder / f"times-{key}.json")
    except OSError:
        pass  # times not kept only cost the next run its cut by cost


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
