"""Exhaustive exploration of the discretised closed loop, every single fault at every phase.

The closed loop — simulated plant, control law, filter, diagnosers — is deterministic and
time-invariant between injections. Its fault-free run is therefore a path that ends in a
cycle (the functional cycle: 784 scans for the valve). A single fault injected at an instant
branches off that path and is again deterministic. The exploration builds the graph of every
state these runs visit:

* a **node** is the loop's state after a scan, identified by its time-free key
  (hmi/studies/loopstate.py); each node has exactly one successor (the next scan);
* a **run** starts at a *pending* node: a fault-free state with the fault scheduled at
  instant `a` before the next scan;
* a run stops as soon as it reaches a node already in the graph — its own (it is periodic
  from there) or one another run explored (its future is known). Each distinct state is
  simulated once, so thirteen faults at every scan of a cycle cost a few tens of thousands of
  scans instead of millions, and the class of a run is *proved* settled (the loop closed),
  not guessed from a time window.

**Every instant, not a grid** (:meth:`Explorer.pieces`). A fault arriving anywhere in the
scan interval (t_{k-1}, t_k] is first seen at scan k, but the plant's physics is exact to the
microsecond: where a jam stops the valve, when a glitch ends, when a stalled motor counts as
damage depend on the instant itself. Within an interval every such quantity moves linearly
with the instant, and the run's course is decided by which side of each constant it lies on.
So two runs of the interval that see the same inputs, decisions, damage and cycles and go
through the same plant regions (hmi/studies/loopstate.py, LoopAccess.region) at every scan
until they meet vouch for every instant between them; when they differ, the interval is
halved until they do, down to a single microsecond. The result is a partition of the cycle
into *pieces* (intervals of instants with one run each): shares are measured in time,
"whatever the instant" means every piece, and nothing depends on a grid.

Edges carry what happened during the scan: damage recorded by the plant, cycles completed.
Nodes carry what was observed (inputs read, outputs written) and the diagnosers' decision.
Everything else (classes, delays, ambiguities, observational equivalence, the libFAUDES
export) is computed from this graph by :mod:`hmi.studies.closed_loop`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from hmi.engine.build import EngineOptions, build_engine
from hmi.plant.sim.device import SimDevice
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.model import Project
from hmi.studies.loopstate import LoopAccess, LoopState

HORIZON = -1  # successor of a node whose run hit the step limit without closing its loop
SETTLED = -2  # successor of a node whose future is settled (see Explorer.settled)
MAX_RUN_SCANS = 30_000  # 300 s at 10 ms: far beyond any settling seen; a guard, not a rule


@dataclass(frozen=True)
class LoopConfig:
    """How the loop is closed: the filter policy and the diagnosers' mode."""

    key: str
    title: str
    policy: str | None  # None: the project's
    diagnosis: str  # ftc, observe, off


@dataclass(frozen=True)
class Start:
    """One injection: fault `fault` at `at_us`, branching after prefix scan `k`; or, in an
    exact sweep, every instant from `lo_us` to `hi_us` (the run at `at_us` stands for them)."""

    fault: str
    at_us: int
    k: int  # index in the prefix: the state after scan k (time k * period)
    node: int  # the pending node the run starts from
    extra: str = ""  # why this instant besides the scan grid ("before N2 -> N3", ...)
    lo_us: int | None = None  # the piece of instants it stands for (None: itself alone)
    hi_us: int | None = None


@dataclass
class Graph:
    """The explored closed loop of one configuration."""

    config: LoopConfig
    period_us: int
    counter: str
    obs_names: tuple[str, ...]
    obs: list[int] = field(default_factory=list)  # packed inputs then outputs, per node
    dec: list[int] = field(default_factory=list)  # index into decisions
    nxt: list[int] = field(default_factory=list)
    dmg: list[str | None] = field(default_factory=list)  # damage during the scan leaving it
    cyc: list[int] = field(default_factory=list)  # cycles completed during that scan
    fault: list[str | None] = field(default_factory=list)  # the fault of the run (None: ok)
    state: list[str] = field(default_factory=list)  # diagnosers' states, for reports
    decisions: list[tuple[str, ...]] = field(default_factory=lambda: [()])
    prefix: list[int] = field(default_factory=list)  # the fault-free run, scan by scan
    cycle_start: int = 0  # prefix index where the fault-free cycle starts
    starts: list[Start] = field(default_factory=list)
    scans: int = 0  # scans simulated to build it
    wall_s: float = 0.0

    @property
    def cycle_length(self) -> int:
        return len(self.prefix) - self.cycle_start

    def add(self, obs: int, dec: tuple[str, ...], fault: str | None, state: str) -> int:
        self.obs.append(obs)
        try:
            index = self.decisions.index(dec)
        except ValueError:
            index = len(self.decisions)
            self.decisions.append(dec)
        self.dec.append(index)
        self.nxt.append(HORIZON)
        self.dmg.append(None)
        self.cyc.append(0)
        self.fault.append(fault)
        self.state.append(state)
        return len(self.obs) - 1

    def decision(self, node: int) -> tuple[str, ...]:
        return self.decisions[self.dec[node]]


class Explorer:
    """Builds the graph of one configuration: the prefix, then the runs of given faults."""

    def __init__(self, project: Project, config: LoopConfig, counter: str,
                 settle: bool = True):
        self.project = project
        self.config = config
        self.settle = settle
        self.period = project.scan_period_us
        plant = SimPlant(project)
        engine = build_engine(project, plant, EngineOptions(policy=config.policy,
                                                            diagnosis=config.diagnosis))
        # The exploration advances the engine without snapshots (Engine.advance): what is
        # shown to people never feeds back into the scan (the state key leaves it out too).
        self.engine, self.plant = engine, plant
        self.access = LoopAccess(engine, plant)
        lay = engine.layout
        self.obs_slots = lay.indices(lay.inputs) + lay.indices(lay.outputs)
        names = tuple(lay.inputs) + tuple(lay.outputs)
        self.graph = Graph(config, self.period, counter, names)
        self.memo: dict[tuple[object, ...], int] = {}
        # Per node, its plant region (interned): what the exact sweep compares runs by.
        self.sig: list[int] = []
        self.sigs: dict[tuple[object, ...], int] = {}
        self.captures: list[LoopState] = []
        counters = [name for name, _ in plant.counters()]
        if counter not in counters:
            raise ValueError(f"the plant has no counter {counter!r}")
        self.counter_index = counters.index(counter)
        self._build_prefix()

    # -- observation of the current state ----------------------------------------------------
    def _observe(self) -> tuple[int, tuple[str, ...], str]:
        image = self.engine.image
        packed = 0
        for bit, slot in enumerate(self.obs_slots):
            if image[slot]:
                packed |= 1 << bit
        runtimes = self.access.runtimes
        labels = tuple(lab for rt in runtimes for lab in rt.state.labels)
        state = "/".join(rt.names[rt.current] for rt in runtimes)
        return packed, labels, state

    def _count(self) -> int:
        return self.plant.counters()[self.counter_index][1]

    def _step(self, now: int) -> tuple[str | None, int]:
        """One scan; the damage it recorded (first kind) and the cycles it completed."""
        before = self._count()
        self.engine.advance(now)
        damage = next((e.kind for e in self.plant.take_events() if e.damage), None)
        self.graph.scans += 1
        return damage, self._count() - before

    def _build_prefix(self) -> None:
        g = self.graph
        now = 0
        previous: int | None = None
        while True:
            damage, done = self._step(now)
            key = self.access.key()
            if previous is not None:
                g.dmg[previous], g.cyc[previous] = damage, done
            if key in self.memo:
                assert previous is not None  # the memo holds the nodes before this one
                g.nxt[previous] = self.memo[key]
                g.cycle_start = g.prefix.index(self.memo[key])
                self._prefix = (len(g.obs), len(g.decisions), g.scans, dict(self.memo))
                return
            obs, dec, state = self._observe()
            node = g.add(obs, dec, None, state)
            self._sign()
            self.memo[key] = node
            if previous is not None:
                g.nxt[previous] = node
            g.prefix.append(node)
            self.captures.append(self.access.capture())
            previous = node
            now += self.period
            if len(g.prefix) > MAX_RUN_SCANS:
                raise RuntimeError("the fault-free run never became periodic")

    def reset(self) -> None:
        """Forget every run explored: back to the fault-free prefix, as just built. A worker
        explores shard after shard with one explorer per configuration; each shard's graph,
        and so what it reports, must not depend on the shards the worker ran before."""
        nodes, decisions, scans, memo = self._prefix
        g = self.graph
        for column in (g.obs, g.dec, g.nxt, g.dmg, g.cyc, g.fault, g.state, self.sig):
            del column[nodes:]
        del g.decisions[decisions:]
        g.starts.clear()
        g.scans = scans
        g.wall_s = 0.0
        self.memo = dict(memo)

    def explored(self) -> list[tuple[object, ...]]:
        """The states reached since the prefix (the keys of the nodes the runs added)."""
        nodes = self._prefix[0]
        return [key for key, node in self.memo.items() if node >= nodes]

    # -- injections ---------------------------------------------------------------------------
    def instants(self, extras: bool = True, every: int = 1, step_us: int | None = None
                 ) -> list[tuple[int, int, str]]:
        """(prefix index k, instant a, why) over one fault-free cycle.

        Every `every`-th scan instant of the cycle (the fault is there at that scan's input
        read: `every` 1 is every scan period), or with `step_us` (a divisor of the period)
        every `step_us` inside every scan interval; and
        when `extras`, 1 us before and 1 us after each scan where a diagnoser changes state
        in the fault-free cycle (the fault arriving just before / just after the transition,
        with the plant's physics at microsecond resolution).
        """
        g = self.graph
        out: list[tuple[int, int, str]] = []
        first = g.cycle_start
        last = len(g.prefix)
        if step_us is not None:
            for j in range(first, last):
                out += [(j - 1, (j - 1) * self.period + m * step_us, "")
                        for m in range(1, self.period // step_us + 1)]
        else:
            for j in range(first, last, every):
                out.append((j - 1, j * self.period, ""))
        if extras:
            for j in range(first, last):
                before, now = g.state[g.prefix[j - 1]], g.state[g.prefix[j]]
                if before != now:
                    what = f"{before} -> {now}"
                    out.append((j - 1, j * self.period - 1, f"1 us before {what}"))
                    out.append((j, j * self.period + 1, f"1 us after {what}"))
        return out

    def _sign(self) -> None:
        """The region of the node just added (Explorer.sig)."""
        region = self.access.region()
        self.sig.append(self.sigs.setdefault(region, len(self.sigs)))

    def intervals(self) -> list[tuple[int, int, int]]:
        """(prefix index k, first instant, last instant) of every scan interval of the
        fault-free cycle: a fault arriving in (t_k, t_{k+1}] is first seen at scan k + 1."""
        g = self.graph
        return [(j - 1, (j - 1) * self.period + 1, j * self.period)
                for j in range(g.cycle_start, len(g.prefix))]

    def pieces(self, fault: str, k: int, lo: int, hi: int) -> list[Start]:
        """Every instant from `lo` to `hi` (one scan interval, after prefix scan k), as the
        pieces of instants that share a run (module docstring); recorded in the graph."""
        runs: dict[int, Start] = {}

        def at(instant: int) -> Start:
            found = runs.get(instant)
            if found is None:
                found = runs[instant] = self.run(fault, k, instant, record=False)
            return found

        found = self._refine(at, lo, hi)
        out = [Start(fault, run.at_us, k, run.node, "", a, b) for a, b, run in found]
        self.graph.starts += out
        return out

    def _refine(self, at: Callable[[int], Start], lo: int, hi: int
                ) -> list[tuple[int, int, Start]]:
        if lo == hi:
            return [(lo, hi, at(lo))]
        if self.same(at(lo).node, at(hi).node):
            return [(lo, hi, at(hi))]
        if hi - lo <= 5:
            return self._join([(t, t, at(t)) for t in range(lo, hi + 1)])
        # Most intervals split near an end (the fault exactly at a scan instant, or a
        # microsecond or two from it: strict comparisons with durations): a piece inside,
        # and single instants at its ends, before halving.
        for inner in range(1, 5):
            for left in range(inner + 1):
                a, b = lo + left, hi - (inner - left)
                if self.same(at(a).node, at(b).node):
                    ends = [(t, t, at(t)) for t in range(lo, a)]
                    ends_hi = [(t, t, at(t)) for t in range(b + 1, hi + 1)]
                    return self._join([*ends, (a, b, at(b)), *ends_hi])
        mid = (lo + hi) // 2
        return self._join([*self._refine(at, lo, mid), *self._refine(at, mid + 1, hi)])

    def _join(self, pieces: list[tuple[int, int, Start]]) -> list[tuple[int, int, Start]]:
        """Adjacent pieces whose runs go the same way, as one."""
        out: list[tuple[int, int, Start]] = []
        for piece in pieces:
            if out and self.same(out[-1][2].node, piece[2].node):
                out[-1] = (out[-1][0], piece[1], piece[2])
            else:
                out.append(piece)
        return out

    def same(self, n: int, m: int) -> bool:
        """Whether two runs (from their first nodes) go the same way scan for scan — same
        inputs, outputs, decisions, damage, cycles and plant regions — until they meet or
        repeat together (module docstring)."""
        g, sig = self.graph, self.sig
        seen = set()
        while n != m:
            if n < 0 or m < 0 or (n, m) in seen:
                return n >= 0 and m >= 0
            seen.add((n, m))
            if (g.obs[n] != g.obs[m] or g.dec[n] != g.dec[m] or g.dmg[n] != g.dmg[m]
                    or g.cyc[n] != g.cyc[m] or sig[n] != sig[m]):
                return False
            n, m = g.nxt[n], g.nxt[m]
        return True

    def run(self, fault: str, k: int, at_us: int, extra: str = "",
            record: bool = True) -> Start:
        """Explore the run of `fault` injected at `at_us`, after prefix scan k (`record`:
        list it among the graph's runs)."""
        g = self.graph
        self.access.restore(self.captures[k])
        self.plant.inject(Injection(fault, at_us))
        key = self.access.key()
        node = self.memo.get(key)
        if node is not None:
            start = Start(fault, at_us, k, node, extra)
            if record:
                g.starts.append(start)
            return start
        base = g.prefix[k]
        node = g.add(g.obs[base], g.decision(base), fault, g.state[base])
        self._sign()
        self.memo[key] = node
        start = Start(fault, at_us, k, node, extra)
        if record:
            g.starts.append(start)
        now = k * self.period
        for _ in range(MAX_RUN_SCANS):
            now += self.period
            damage, done = self._step(now)
            g.dmg[node], g.cyc[node] = damage, done
            key = self.access.key()
            found = self.memo.get(key)
            if found is not None:
                g.nxt[node] = found
                return start
            obs, dec, state = self._observe()
            new = g.add(obs, dec, fault, state)
            self._sign()
            self.memo[key] = new
            g.nxt[node] = new
            node = new
            if self.settle and self.settled():
                g.nxt[node] = SETTLED
                return start
        return start  # the last node keeps HORIZON as its successor

    # -- settled states -----------------------------------------------------------------------
    def settled(self) -> bool:
        """Whether nothing the sweep reports can change any more from this state.

        Requires the diagnosers to be off or in final states (their decision is fixed: no
        transition leaves, and the sweep never resets), and then either
        * damage already happened (a device's state says so: every path here went through
          a damaging scan, so the run is a Defect whatever follows), or
        * every output is masked for good (FTC, a final decision masking them all) and the
          plant cannot move on its own: it stays as it is, no cycle, no damage: Blocked.
        """
        stage = self.access.stage
        if stage is not None and stage.mode != "off" and \
                not all(rt.final[rt.current] for rt in stage.runtimes):
            return False
        devices = self.plant.devices
        if any(_damaged(d) for d in devices):
            return True
        if stage is None or stage.mode != "ftc" or self.engine.policy == "monitor":
            return False
        if stage.current.mask is None or not all(stage.current.mask):
            return False
        return all(_static(d, self.engine.now) for d in devices)

    def explore(self, faults: Iterable[str], instants: list[tuple[int, int, str]] | None,
                progress: Callable[[int], None] | None = None) -> Graph:
        """Every fault at every instant (from :meth:`instants`, possibly another config's:
        the fault-free run is the same in every configuration); None: at every instant of
        the cycle, exactly (:meth:`intervals`, :meth:`pieces`)."""
        started = time.perf_counter()
        for fault in faults:
            if instants is None:
                for k, lo, hi in self.intervals():
                    self.pieces(fault, k, lo, hi)
                    if progress is not None:
                        progress(1)
                continue
            for k, at, why in instants:
                self.run(fault, k, at, why)
                if progress is not None:
                    progress(1)
        self.graph.wall_s += time.perf_counter() - started
        return self.graph


def _damaged(device: SimDevice) -> bool:
    """The device's own state records damage (set only by a damaging event, see valve.py)."""
    return bool(getattr(device, "stall_reported", False) or getattr(device, "both_on", False))


def _static(device: SimDevice, now: int) -> bool:
    """With every order off, the valve never moves or changes a switch again."""
    self_drive: object = getattr(device, "self_drive", 0)
    if device.pending or self_drive:
        return False
    if getattr(device, "armed", set()) & {"F11", "F12"}:  # they start moving at rest
        return False
    return all(end <= now for _, _, end in getattr(device, "glitches", {}).values())


def faults_of(project: Project) -> tuple[str, ...]:
    """The fault codes of the plant, in the model's order (F1..F13 for the valve)."""
    plant = SimPlant(project)
    return tuple(code for device in plant.devices for code in device.FAULTS)
