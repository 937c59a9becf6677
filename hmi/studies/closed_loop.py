"""What the explored closed loop says: each run's class, detection, isolation and delays.

Input: the graph of :mod:`hmi.studies.explore` (one successor per node, runs starting at
pending nodes). Every run ends in a cycle of that graph (or at the step guard, reported as
Undecided), so its eventual behaviour is known exactly:

* **Defect** — some scan of the run records damage (before or inside its final cycle);
* **Tolerant** — no damage, and the final cycle completes functional cycles: the cell keeps
  working forever;
* **Blocked** — no damage, and the final cycle completes none: the cell has stopped for good.

The diagnosers' side of a run: the first scan a decision holds a label (**detected**), the
first scan it holds exactly one label (**isolated with certainty**, right when that label is
the injected fault, a **misdiagnosis** otherwise), and the decision it ends with (final
ambiguity when it holds several labels).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from hmi.studies.explore import HORIZON, Graph, LoopConfig, Start

DEFECT, BLOCKED, TOLERANT, UNDECIDED = "Defect", "Blocked", "Tolerant", "Undecided"
INF = 1 << 62


@dataclass(frozen=True)
class Outcome:
    """One run of the sweep: a fault at an instant, under one configuration."""

    fault: str
    at_us: int
    extra: str
    outcome: str
    damage_us: int | None
    damage_kind: str | None
    detected_us: int | None  # first scan with a faulty decision
    certain_us: int | None  # first scan with a single-label decision
    certain_label: str | None
    final: tuple[str, ...]  # the decision the run ends with (labels; () normal)
    final_state: str
    # An exact sweep's run stands for every instant from lo_us to hi_us (at_us among them);
    # a grid's for at_us alone (None).
    lo_us: int | None = None
    hi_us: int | None = None

    @property
    def first_us(self) -> int:
        return self.at_us if self.lo_us is None else self.lo_us

    @property
    def last_us(self) -> int:
        return self.at_us if self.hi_us is None else self.hi_us

    @property
    def weight(self) -> int:
        """What the run counts for in a share: its instants in µs (exact), else 1."""
        return 1 if self.lo_us is None or self.hi_us is None else self.hi_us - self.lo_us + 1

    @property
    def isolated(self) -> bool:
        return self.certain_label == self.fault

    @property
    def misdiagnosed(self) -> bool:
        return self.certain_label is not None and self.certain_label != self.fault

    @property
    def delay_us(self) -> int | None:
        """Fault to certain diagnosis (from the latest instant of the run's piece: the
        shortest delay it stands for)."""
        return None if self.certain_us is None or not self.isolated else \
            self.certain_us - self.last_us

    @property
    def longest_delay_us(self) -> int | None:
        return None if self.certain_us is None or not self.isolated else \
            self.certain_us - self.first_us


@dataclass
class _Summary:
    damage: int  # scans to the first damaging scan, INF if none
    kind: str | None
    detect: int
    certain: int
    label: str | None
    cycling: bool
    final: tuple[str, ...]
    state: str
    horizon: bool


def summarise(g: Graph) -> list[_Summary | None]:
    """Per node: what its future holds (functional graph: tails then a cycle)."""
    n = len(g.obs)
    out: list[_Summary | None] = [None] * n
    on_path = [-1] * n
    for origin in range(n):
        if out[origin] is not None:
            continue
        path: list[int] = []
        after: _Summary | None
        node = origin
        while node >= 0 and out[node] is None and on_path[node] < 0:
            on_path[node] = len(path)
            path.append(node)
            node = g.nxt[node]
        if node < 0:  # HORIZON, or SETTLED: nothing changes after the last node
            last = path[-1]
            tail_end = _Summary(INF, None, INF, INF, None, False, g.decision(last),
                                g.state[last], node == HORIZON)
            stop = len(path)
            after = tail_end
        elif out[node] is not None:
            stop = len(path)
            after = out[node]
        else:  # a new cycle: path[on_path[node]:]
            stop = on_path[node]
            cycle = path[stop:]
            _summarise_cycle(g, cycle, out)
            after = None
        for i in range(stop - 1, -1, -1):
            x = path[i]
            nxt_summary = after if i == stop - 1 and after is not None else out[g.nxt[x]]
            assert nxt_summary is not None
            out[x] = _prepend(g, x, nxt_summary)
        for x in path:
            on_path[x] = -1
    return out


def _prepend(g: Graph, x: int, s: _Summary) -> _Summary:
    dec = g.decision(x)
    damage = 0 if g.dmg[x] else (s.damage + 1 if s.damage < INF else INF)
    kind = g.dmg[x] if g.dmg[x] else s.kind
    detect = 0 if dec else (s.detect + 1 if s.detect < INF else INF)
    label: str | None
    if len(dec) == 1:
        certain, label = 0, dec[0]
    else:
        certain = s.certain + 1 if s.certain < INF else INF
        label = s.label
    return _Summary(damage, kind, detect, certain, label, s.cycling, s.final, s.state, s.horizon)


def _summarise_cycle(g: Graph, cycle: list[int], out: list[_Summary | None]) -> None:
    cycling = any(g.cyc[x] for x in cycle)
    decisions = {g.decision(x) for x in cycle}
    final = decisions.pop() if len(decisions) == 1 else tuple(sorted(
        {lab for d in decisions for lab in d}))
    states = {g.state[x] for x in cycle}
    state = states.pop() if len(states) == 1 else "cycling"
    seed = _Summary(INF, None, INF, INF, None, cycling, final, state, False)
    # Two passes backwards around the cycle give every node its first occurrences.
    summaries: dict[int, _Summary] = {}
    current = seed
    for _ in range(2):
        for x in reversed(cycle):
            current = _prepend(g, x, current)
            summaries[x] = current
    for x in cycle:
        out[x] = summaries[x]


def outcomes(g: Graph) -> list[Outcome]:
    """The outcome of every run of the graph, in the order they were explored."""
    summaries = summarise(g)
    period = g.period_us
    result = []
    for s in g.starts:
        summary = summaries[s.node]
        assert summary is not None  # summarise gives every node one
        result.append(outcome_of(s, summary, period))
    return result


def outcome_of(start: Start, s: _Summary, period: int) -> Outcome:
    base = start.k * period  # the pending node is the state after scan k

    def when(dist: int) -> int | None:
        return None if dist >= INF else base + dist * period

    if s.damage < INF:
        outcome = DEFECT
    elif s.horizon:
        outcome = UNDECIDED
    else:
        outcome = TOLERANT if s.cycling else BLOCKED
    # Damage is recorded on the scan leaving a node: it is seen one scan after that node.
    damage = when(s.damage + 1) if s.damage < INF else None
    return Outcome(start.fault, start.at_us, start.extra, outcome, damage, s.kind,
                   when(s.detect), when(s.certain), s.label, s.final, s.state, start.lo_us,
                   start.hi_us)


# --------------------------------------------------------------------------------------------
# Diagnosability on the closed loop, from the runs
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FaultDiagnosis:
    """How the diagnosers fared with one fault over every instant it was injected at (a run
    of an exact sweep stands for its piece of instants: its `weight` in µs)."""

    fault: str
    runs: int
    isolated: int  # runs ending up with exactly this label
    misdiagnosed: tuple[tuple[str, int], ...]  # (wrong label, runs)
    undetected: int  # runs where no decision ever held a label
    ambiguous: tuple[tuple[tuple[str, ...], int], ...]  # final multi-label decision, runs
    delays_us: tuple[int, ...]  # fault -> certain diagnosis, isolated runs, sorted
    detect_us: tuple[int, ...]  # fault -> first faulty decision, detected runs, sorted
    total_weight: int = 0  # the instants (µs of the cycle, or grid instants) the runs cover
    isolated_weight: int = 0
    longest_delay_us: int | None = None  # (an exact sweep: from the earliest instant)

    @property
    def always(self) -> bool:
        return self.isolated == self.runs

    @property
    def ever(self) -> bool:
        return self.isolated > 0

    @property
    def share(self) -> float:
        """The share of the instants at which the fault is isolated."""
        return self.isolated_weight / self.total_weight if self.total_weight else 0.0


@dataclass(frozen=True)
class LoopDiagnosability:
    config: LoopConfig
    faults: tuple[FaultDiagnosis, ...]

    @property
    def isolable(self) -> tuple[str, ...]:
        """Faults the closed loop isolates with certainty at some instant (000's count)."""
        return tuple(f.fault for f in self.faults if f.ever)

    @property
    def guaranteed(self) -> tuple[str, ...]:
        """Faults isolated with certainty whatever the instant they occur at."""
        return tuple(f.fault for f in self.faults if f.always)

    @property
    def dc(self) -> float:
        return len(self.isolable) / len(self.faults) if self.faults else 0.0

    @property
    def dc_guaranteed(self) -> float:
        return len(self.guaranteed) / len(self.faults) if self.faults else 0.0

    @property
    def dc_weighted(self) -> float:
        """Mean share of instants isolated: the chance a fault occurring at a random phase of
        the cycle is isolated (the standard's DC weights by probability; this weights every
        fault alike and every phase alike)."""
        if not self.faults:
            return 0.0
        return sum(f.share for f in self.faults) / len(self.faults)

    def pairs(self) -> list[tuple[tuple[str, str], int]]:
        """Pairs of labels left together in a final decision, with the runs concerned."""
        counts: dict[tuple[str, str], int] = {}
        for f in self.faults:
            for labels, runs in f.ambiguous:
                for a in range(len(labels)):
                    for b in range(a + 1, len(labels)):
                        key = (labels[a], labels[b])
                        counts[key] = counts.get(key, 0) + runs
        return sorted(counts.items(), key=lambda kv: _label_order(kv[0]))

    @property
    def misdiagnoses(self) -> int:
        return sum(n for f in self.faults for _, n in f.misdiagnosed)


def _label_order(pair: tuple[str, str]) -> tuple[tuple[int, str], ...]:
    return tuple((len(x), x) for x in pair)


def diagnosability(config: LoopConfig, runs: Sequence[Outcome],
                   faults: Sequence[str]) -> LoopDiagnosability:
    out = []
    for fault in faults:
        mine = [r for r in runs if r.fault == fault]
        wrong: dict[str, int] = {}
        ambiguous: dict[tuple[str, ...], int] = {}
        for r in mine:
            if r.misdiagnosed and r.certain_label is not None:
                wrong[r.certain_label] = wrong.get(r.certain_label, 0) + 1
            elif not r.isolated and len(r.final) > 1:
                ambiguous[r.final] = ambiguous.get(r.final, 0) + 1
        longest = [r.longest_delay_us for r in mine if r.isolated]
        out.append(FaultDiagnosis(
            fault, len(mine), sum(r.isolated for r in mine), tuple(sorted(wrong.items())),
            sum(r.detected_us is None for r in mine),
            tuple(sorted(ambiguous.items(), key=lambda kv: -kv[1])),
            tuple(sorted(d for r in mine if r.isolated and (d := r.delay_us) is not None)),
            tuple(sorted(r.detected_us - r.last_us for r in mine if r.detected_us is not None)),
            sum(r.weight for r in mine), sum(r.weight for r in mine if r.isolated),
            max((d for d in longest if d is not None), default=None)))
    return LoopDiagnosability(config, tuple(out))


def spread(values: Sequence[int], longest: int | None = None
           ) -> tuple[int, int, int] | None:
    """(min, median, max) of sorted values (the lower median for an even count); `longest`
    the maximum instead when the values are each a piece's shortest."""
    if not values:
        return None
    top = values[-1] if longest is None else max(longest, values[-1])
    return values[0], values[(len(values) - 1) // 2], top
