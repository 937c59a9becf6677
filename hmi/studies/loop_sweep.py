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

An exact sweep (`exact`: every instant of the cycle, not a grid; hmi/studies/explore.py,
Explorer.pieces) is cut the same way, its units being scan intervals instead of instants
(SHARD_RUNS // EXACT_COST of them to a block). A sweep of a band point (hmi/studies/band.py)
names the point in its options: every worker applies it to the project it loaded.

Results are cached on disk, keyed by the project's files, the diagnoser variant, the grid (or
exactness), the band point and the code version, so a second `check` of an unchanged project
does not explore again; an exact sweep is kept per configuration (diagnose's two are among
campaign's three). The cache holds plain JSON (the outcomes), never code, and a damaged entry
is simply recomputed.
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
from hmi.studies.band import variant_of
from hmi.studies.closed_loop import Outcome, outcomes
from hmi.studies.explore import Explorer, LoopConfig, faults_of

# The campaign's three columns (000 Table 1), as closed-loop configurations.
DIAG_NO_FILTER = LoopConfig("diag_no_filter", "Diag no Filter", "monitor", "observe")
FILTER_NO_DIAG = LoopConfig("filter_no_diag", "No Diag Filter", None, "off")
FTC = LoopConfig("ftc", "FTC (Diag and Filter)", None, "ftc")
CAMPAIGN_CONFIGS = (DIAG_NO_FILTER, FILTER_NO_DIAG, FTC)
# Where the diagnosers run: observing only, and driving reconstruction and masking.
DIAGNOSIS_CONFIGS = (DIAG_NO_FILTER, FTC)
CACHE_VERSION = 4
# Runs per block, the unit the states are counted in (and a shard when no times are known):
# 156 blocks for the valve's full sweep, of 0.02-30 s each (docs/studies.md). An exact
# sweep's blocks hold SHARD_RUNS // EXACT_COST scan intervals.
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
    exact: bool = False  # every instant (pieces of instants), not a grid
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
          extras: bool = True, farm: Farm | None = None, cache: bool = True,
          compute: bool = True, faults: Sequence[str] | None = None, exact: bool = False,
          point: dict[str, Any] | None = None) -> SweepResult | None:
    """The sweep, from the cache when it holds it; None when it does not and `compute` is
    false. `farm` says where the shards run (default: this machine's processes). `exact`:
    every instant of the cycle, else a grid of `every_us` (a multiple of the scan period, or
    a divisor of it: instants inside each interval). `point`: a band point's plant
    ({"values", "seed", "text"}, hmi/studies/band_sweep.py); `project` is already that plant
    here, and every worker makes it from the project's files."""
    period = project.scan_period_us
    step_us = every_us if every_us is not None and every_us < period else None
    every = max(1, round((every_us or period) / period)) if step_us is None else 1
    if exact:
        extras, every, step_us = False, 1, None
    variant = variant_of(project) or ""
    faults = tuple(faults) if faults else faults_of(project)
    text = point["text"] if point else ""
    # An exact sweep is kept per configuration; a grid's instants depend on the
    # configurations together (the extras around transitions come from one where the
    # diagnosers run), so it is kept whole.
    groups = [(c,) for c in configs] if exact else [tuple(configs)]
    keys = [_cache_key(project, variant, group, counter, every, extras, faults,
                       [exact, step_us, text]) for group in groups]
    found = [_load(key) if cache else None for key in keys]
    missing = [c for group, part in zip(groups, found, strict=True) if part is None
               for c in group]
    if not missing:
        if farm is not None:
            farm.notes.append(f"the closed-loop sweep of {project.name}"
                              + (f" at {text}" if text else "") + " was read from the cache "
                              f"({cache_folder() / 'closed-loop'})")
        return _joined([p for p in found if p is not None], configs, cached=True)
    if not compute:
        return None
    study, probe = sweep_study(project, missing, counter, every, extras, faults, variant,
                               exact, step_us, point)
    parts = (farm or Farm()).run(study)
    computed = {}
    for c in missing:
        result = SweepResult(project.name, variant, (c,), faults, period, every, extras,
                             probe.graph.cycle_start * period,
                             probe.graph.cycle_length * period, exact=exact,
                             step_us=step_us, point=text)
        result.runs[c.key] = []
        result.states[c.key] = len(probe.graph.prefix)
        computed[c.key] = result
    split: dict[tuple[int, int], set[str]] = {}
    spent: list[Spent] = []
    block = block_units(exact)
    for shard, part in zip(study.shards, parts, strict=True):
        for (c, start, end), piece in zip(shard, part.pieces, strict=True):
            key_c = missing[c].key
            computed[key_c].runs[key_c] += piece.outcomes
            if piece.states is None:
                computed[key_c].states[key_c] += piece.nodes
            else:
                split.setdefault((c, start // block), set()).update(piece.states)
            spent.append((c, start, end, piece.seconds, piece.run_seconds))
    for (c, _), states in sorted(split.items()):
        computed[missing[c].key].states[missing[c].key] += len(states)
    _store_times(_times_key(project, variant, missing, counter, every, extras, faults,
                            [exact, step_us, text]), missing, spent)
    out = []
    for group, key, part in zip(groups, keys, found, strict=True):
        if part is None:
            part = _joined([computed[c.key] for c in group], group, cached=False)
            if cache:
                _store(key, part)
        out.append(part)
    return _joined(out, configs, cached=False)


def _joined(parts: list[SweepResult], configs: Sequence[LoopConfig], cached: bool
            ) -> SweepResult:
    """One result of the parts the configurations were kept in, in `configs` order."""
    first = parts[0]
    result = SweepResult(first.project, first.variant, tuple(configs), first.faults,
                         first.period_us, first.every, first.extras, first.cycle_start_us,
                         first.cycle_us, cached=cached, exact=first.exact,
                         step_us=first.step_us, point=first.point)
    for c in configs:
        part = next(p for p in parts if c.key in p.runs)
        result.runs[c.key] = part.runs[c.key]
        result.states[c.key] = part.states[c.key]
    return result


def sweep_study(project, configs: Sequence[LoopConfig], counter: str, every: int,
                extras: bool, faults: tuple[str, ...], variant: str, exact: bool = False,
                step_us: int | None = None, point: dict[str, Any] | None = None
                ) -> tuple[Study, Explorer]:
    """The sweep as shards, and the explorer whose fault-free run gave the instants (or the
    intervals, exact)."""
    # The instants come from a configuration where the diagnosers run (their transitions in
    # the fault-free cycle add instants), and are the same for every configuration.
    first = next((c for c in configs if c.diagnosis != "off"), configs[0])
    probe = Explorer(project, first, counter)
    units = ([list(i) for i in probe.intervals()] if exact
             else [list(i) for i in probe.instants(extras, every, step_us)])
    runs = len(faults) * len(units)
    per = block_units(exact)
    blocks = [(c, start, min(start + per, runs))
              for c in range(len(configs)) for start in range(0, runs, per)]
    times = _load_times(_times_key(project, variant, configs, counter, every, extras, faults,
                                   [exact, step_us, point["text"] if point else ""]),
                        configs, runs)
    costs = times.costs if times else None
    shards = cut(blocks, costs, times.pieces if times else frozenset())
    expected = None
    if costs is not None:  # cut by them: each shard's share, to send the heaviest first
        expected = tuple(sum(sum(costs[c * runs + a:c * runs + b]) for c, a, b in s)
                         for s in shards)
    options = {"configs": [[c.key, c.title, c.policy, c.diagnosis] for c in configs],
               "counter": counter, "faults": list(faults), "exact": exact, "block": per,
               "instants": units, "shape": _shape(probe), "point": point}
    job = make_job("sweep", Bundle.of(project, variant or None), _setup, _work, options,
                   shards)
    title = f"the closed-loop sweep of {project.name}" + (f" at {point['text']}" if point
                                                           else "")
    study = Study(title, job, shards, tuple(sum(end - start for _, start, end in s)
                                            for s in shards), _encode, _decode, expected)
    return study, probe


# An exact sweep's unit (a scan interval) costs about this many grid runs (two at least, the
# interval's ends; more where it splits): its blocks hold as many fewer units.
EXACT_COST = 3


def block_units(exact: bool) -> int:
    """Runs (units) per block: scan intervals for an exact sweep, else instants. Read at each
    call, not imported as a value: a report states the blocks its sweep was cut in."""
    return SHARD_RUNS // EXACT_COST if exact else SHARD_RUNS


Piece = tuple[int, int, int]  # (configuration, first run, end): runs of one block


def cut(blocks: list[Piece], costs: list[float] | None,
        measured: frozenset[tuple[int, int]] = frozenset()) -> tuple[tuple[Piece, ...], ...]:
    """The shards, each a tuple of pieces in run order, from the blocks (in run order) and
    each run's measured CPU time, in the same order (None: one shard per block).

    Shards aim at `target`, the total time over SHARDS_WANTED and SHARD_MIN_S or more: a
    block above it is split into pieces of consecutive runs of about the same time, lighter
    blocks go together until the next would pass it; a light rest goes with its neighbour.
    `measured` holds the (configuration, first run) of the pieces the times were measured
    in: a split block keeps those bounds, its pieces only split further or join a neighbour
    when light. Why: runs share states, and a piece pays for its shared states once, so a
    piece that spans two measured ones can cost much less than their runs' sum, while a
    piece within a measured one costs at least its runs' sum (it reaches none of their
    states before them); a piece joined to its neighbour costs at least the heavier of the
    two. Every piece then costs at least what the cut expected of it, or than a piece that
    was measured: the floor of target / 2 holds for what runs, not only for what was
    expected."""
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
            kept = sorted(a for cc, a in measured if cc == c and start < a < end)
            bounds = [start]
            for a, b in itertools.pairwise([start, *kept, end]):
                bounds += _shares(runs[a - start:b - start], a, target)[1:]
            _merge_light(bounds, runs, start, target / 2)
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


def _shares(runs: list[float], start: int, target: float) -> list[int]:
    """The bounds of `runs` (the first at `start`) cut into as many pieces of about the same
    time as `target` goes into their sum, each of a run at least: [start, ..., end]."""
    t = sum(runs)
    end = start + len(runs)
    n = min(len(runs), max(1, -int(-t // target)))
    bounds = [start]
    total = 0.0
    for r, x in enumerate(runs):
        total += x
        # a bound where the time so far passes the next n-th, leaving a run a piece
        if len(bounds) < n and total >= t * len(bounds) / n and \
                start + r + 1 > bounds[-1] and end - (start + r + 1) >= n - len(bounds):
            bounds.append(start + r + 1)
    return [*bounds, end]


def _merge_light(bounds: list[int], runs: list[float], start: int, floor: float) -> None:
    """Pieces of a split block expected under `floor` go with their lighter neighbour (the
    bounds changed in place): where a block's time sits in a few runs, the bounds by equal
    shares of time can leave a piece of almost nothing beside them."""
    def seconds(k: int) -> float:
        return sum(runs[bounds[k] - start:bounds[k + 1] - start])
    while len(bounds) > 2:
        times = [seconds(k) for k in range(len(bounds) - 1)]
        k = min(range(len(times)), key=times.__getitem__)
        if times[k] >= floor:
            return
        if k == 0 or (k < len(times) - 1 and times[k + 1] < times[k - 1]):
            del bounds[k + 1]  # with the next piece
        else:
            del bounds[k]  # with the one before


@dataclass(frozen=True)
class PiecePart:
    """One piece's runs: their outcomes in order, the states it explored past the fault-free
    prefix (their number; their digests too when the piece is part of a block), and the CPU
    time its thread spent on it (for the next run's cut, never for the report: unlike the
    time from start to end, it does not grow with whatever else the machine runs), and each
    run's share of it: a piece's time sits in a few of its runs, where they reach states the
    runs before them did not, and the next cut splits by it (spread evenly over the piece, a
    piece cut from a cheap stretch took a tenth of its expected time)."""

    outcomes: list[Outcome]
    nodes: int
    states: list[str] | None
    seconds: float
    run_seconds: list[float] | None = None


@dataclass(frozen=True)
class SweepPart:
    """One shard's pieces, in order."""

    pieces: list[PiecePart]


@dataclass
class _State:
    project: Any
    configs: list[LoopConfig]
    counter: str
    # (fault, k, at, why) in the order of the shards; exact: (fault, k, lo, hi)
    runs: list[tuple[Any, ...]]
    shape: str
    exact: bool
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
    point = options.get("point")
    if point:  # a band point's plant, made from the project the worker loaded
        from hmi.studies.band import plant_at
        project = plant_at(project, point)
    units = [tuple(i) for i in options["instants"]]
    return _State(project, [LoopConfig(*c) for c in options["configs"]], options["counter"],
                  [(f, *unit) for f in options["faults"] for unit in units],
                  options["shape"], bool(options.get("exact")), options["block"])


def _work(state: _State, shard: tuple[Piece, ...]) -> SweepPart:
    return SweepPart([_piece(state, *piece) for piece in shard])


def _piece(state: _State, c: int, start: int, end: int) -> PiecePart:
    ex = state.explorer(c)  # built at a worker's first piece of `c`: not the piece's cost
    started = time.thread_time()
    each = []
    before = started
    for run in state.runs[start:end]:
        if state.exact:
            ex.pieces(*run)
        else:
            ex.run(*run)
        now = time.thread_time()
        each.append(round(now - before, 6))
        before = now
    g = ex.graph
    whole = start % state.block == 0 and end == min(start + state.block, len(state.runs))
    states = None if whole else sorted(_digest(key) for key in ex.explored())
    return PiecePart(outcomes(g), len(g.obs) - len(g.prefix), states,
                     time.thread_time() - started, each)


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
             "run_seconds": p.run_seconds, "outcomes": [asdict(r) for r in p.outcomes]}
            for p in part.pieces]


def _decode(shard: Any, data: list[dict[str, Any]]) -> SweepPart:
    if len(data) != len(shard):
        raise ValueError("a result of another cut")
    return SweepPart([PiecePart([_outcome(r) for r in p["outcomes"]], int(p["nodes"]),
                                None if p["states"] is None else list(p["states"]),
                                float(p["seconds"]), p.get("run_seconds")) for p in data])


def _outcome(data: dict[str, Any]) -> Outcome:
    return Outcome(**{**data, "final": tuple(data["final"])})


# -- the cache --------------------------------------------------------------------------------


def cache_folder() -> Path:
    base = os.environ.get("PLCHMI_CACHE")
    if base:
        return Path(base)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "plchmi"


def _cache_key(project, variant, configs, counter, every, extras, faults, more=()) -> str:
    text = json.dumps([CACHE_VERSION, variant, counter, every, extras, list(faults),
                       [[c.key, c.policy, c.diagnosis] for c in configs],
                       digest_of(project, variant or None), code_version().digest, list(more)])
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _times_key(project, variant, configs, counter, every, extras, faults, more=()) -> str:
    """The sweep without the code version: the times measured before a change of the code
    still cut the next run well enough (the cut changes the time, never the result)."""
    text = json.dumps(["times", SHARD_RUNS, EXACT_COST, variant, counter, every, extras,
                       list(faults), [[c.key, c.policy, c.diagnosis] for c in configs],
                       digest_of(project, variant or None), list(more)])
    return hashlib.sha256(text.encode()).hexdigest()[:32]


@dataclass(frozen=True)
class Times:
    """What the last run of a sweep measured, for the next one's cut."""

    costs: list[float]  # each run's CPU time, in run order, configuration after configuration
    pieces: frozenset[tuple[int, int]]  # (configuration, first run) of each piece measured


def _load_times(key: str, configs, runs: int) -> Times | None:
    """Each run's CPU time, as the last run of this sweep measured it (what a piece spent
    around its runs spread evenly over them; a file of pieces' times only, all of it), and
    its pieces; None if unknown."""
    try:
        data = json.loads((cache_folder() / "closed-loop" / f"times-{key}.json").read_text())
        costs: list[float] = []
        pieces: set[tuple[int, int]] = set()
        for n, c in enumerate(configs):
            spread = [0.0] * runs
            for start, end, seconds, *each in data[c.key]:
                start, end = int(start), int(end)
                measured = [float(x) for x in each[0]] if each and each[0] else [0.0] * (
                    end - start)
                if len(measured) != end - start or not 0 <= start < end <= runs:
                    return None
                rest = (float(seconds) - sum(measured)) / (end - start)
                spread[start:end] = [x + rest for x in measured]
                if each and each[0]:  # bounds worth keeping only with the runs' own times
                    pieces.add((n, start))
            costs += spread
    except (OSError, ValueError, KeyError, TypeError, IndexError, ZeroDivisionError):
        return None
    return Times(costs, frozenset(pieces))


# A piece's CPU time as the next cut reads it: (configuration, first run, end, seconds,
# each run's seconds or None).
Spent = tuple[int, int, int, float, list[float] | None]


def _store_times(key: str, configs, spent: list[Spent]) -> None:
    """Each piece's CPU time: [first run, end, seconds, each run's] per configuration."""
    data = {c.key: [[start, end, t, each] for i, start, end, t, each in spent if i == n]
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
                           cached=True, exact=data["exact"], step_us=data["step_us"],
                           point=data["point"])
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
        "states": result.states, "exact": result.exact, "step_us": result.step_us,
        "point": result.point,
    }
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"{key}.tmp{os.getpid()}"
        tmp.write_text(json.dumps(data))
        tmp.replace(folder / f"{key}.json")
    except OSError:
        pass  # a cache that cannot be written only costs time
