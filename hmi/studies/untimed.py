"""The untimed abstraction of the explored closed loop, its diagnosability, and its export to
libFAUDES (the independent cross-check of tests/test_faudes.py).

**The abstraction.** An observer that sees the order of the observation changes but not when
they happen: an event is a new observation vector (inputs read and outputs written,
`o_fsc1_fso0_C0_O1`), a scan that changes nothing is the unobservable `tau`, a fault is an
unobservable event `F1`..`F13`. It is built from the exploration (hmi/studies/explore.py, run
without settled sinks so every run's future is complete):

* the fault-free run, kept node by node where a fault is injected or the observation changes
  (the nodes in between only repeat the observation: `tau` chains, contracted);
* from each injection node, the fault event into the *untimed future* of the run it starts:
  the sequence of observation changes that follows, which is a lasso (the run ends in a
  cycle). Futures are interned (two runs with the same future share its states), so the
  generator stays small. A cycle whose observation never changes becomes an observable
  `quiet` self-loop: the run has stopped changing, and every state has a successor (the
  language is live, and there is no cycle of unobservable events).

**Its soundness** for diagnosability: every word of the generator is the untimed observation
of a real run of the discretised closed loop with at most one fault (and conversely, for the
injection instants explored), so a fault the abstraction calls diagnosable is distinguished
by the order of observations alone; one it calls non-diagnosable may still be told apart by
timing (the timed analysis of hmi/studies/closed_loop.py, and the diagnosers' windows, use it).

**Diagnosability** (Sampath et al. 1995, failure types): type T is diagnosable when no pair of
runs with the same observation, one with T and one without, extends forever. The verifier
pairs two copies that agree on every observable event; T is non-diagnosable exactly when a
cycle of pairs has T in one copy and not in the other (Jiang, Huang, Chandra, Kumar 2001).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hmi.studies.explore import Graph

# A pair of runs of the twin plant: (state, fault bits) of each.
_Pair = tuple[int, int, int, int]

TAU = "tau"
QUIET = "quiet"


@dataclass
class Generator:
    """A finite automaton: integer states, (source, event, target) transitions."""

    initial: int = 0
    states: int = 0
    transitions: list[tuple[int, str, int]] = field(default_factory=list)
    observable: set[str] = field(default_factory=set)
    faults: set[str] = field(default_factory=set)

    def add_state(self) -> int:
        self.states += 1
        return self.states - 1

    def without_faults(self, keep: Iterable[str]) -> Generator:
        """The same generator where only the faults in `keep` can occur."""
        kept = set(keep)
        return Generator(self.initial, self.states,
                         [t for t in self.transitions if t[1] not in self.faults or t[1] in kept],
                         set(self.observable), self.faults & kept)


def obs_name(g: Graph, obs: int) -> str:
    return "o_" + "_".join(f"{name}{obs >> k & 1}" for k, name in enumerate(g.obs_names))


def abstraction(g: Graph) -> Generator:
    """The untimed generator of an explored graph (see the module docstring)."""
    if any(n < 0 for n in g.nxt):
        raise ValueError("the untimed abstraction needs complete runs (explore with "
                         "settle=False and no run cut at the step guard)")
    gen = Generator()
    futures = _Futures(g, gen)
    # The fault-free run: keep injection nodes and observation changes (every change is at a
    # kept node, so between two kept nodes the only possible change is at the second).
    injected = {s.k for s in g.starts}
    prefix = g.prefix
    last = len(prefix) - 1

    def changes_at(i: int) -> bool:  # the observation changes when node i is reached
        before = prefix[i - 1] if i else None
        if i == g.cycle_start and i:  # reached from the prefix's last node too
            return g.obs[prefix[i]] != g.obs[prefix[i - 1]] or \
                g.obs[prefix[i]] != g.obs[prefix[last]]
        return before is not None and g.obs[prefix[i]] != g.obs[before]

    keep = sorted({0, g.cycle_start, *injected,
                   *(i for i in range(1, len(prefix)) if changes_at(i))})
    state_of = {i: gen.add_state() for i in keep}
    gen.initial = state_of[0]
    for a, b in zip(keep, [*keep[1:], None], strict=True):
        if b is None:  # the end of the fault-free run loops back to the cycle's start
            source, target = prefix[last], prefix[g.cycle_start]
            b = g.cycle_start
        else:
            source, target = prefix[b - 1], prefix[b]
        event = obs_name(g, g.obs[target]) if g.obs[target] != g.obs[source] else TAU
        gen.transitions.append((state_of[a], event, state_of[b]))
    gen.observable.add(QUIET)
    for name in {obs_name(g, g.obs[n]) for n in range(len(g.obs))}:
        gen.observable.add(name)
    for s in g.starts:
        gen.faults.add(s.fault)
        gen.transitions.append((state_of[s.k], s.fault, futures.state(s.node)))
    gen.transitions = sorted(set(gen.transitions))
    return gen


class _Futures:
    """Interned untimed futures of the graph's nodes, each a state of the generator."""

    def __init__(self, g: Graph, gen: Generator):
        self.g, self.gen = g, gen
        self.of_node: dict[int, int] = {}
        self.by_key: dict[tuple[object, ...], int] = {}

    def _intern(self, key: tuple[object, ...]) -> tuple[int, bool]:
        found = self.by_key.get(key)
        if found is not None:
            return found, False
        state = self.gen.add_state()
        self.by_key[key] = state
        return state, True

    def state(self, node: int) -> int:
        g = self.g
        path: list[int] = []
        seen: dict[int, int] = {}
        x = node
        while x not in self.of_node and x not in seen:
            seen[x] = len(path)
            path.append(x)
            x = g.nxt[x]
        if x in seen:  # a new cycle
            self._cycle(path[seen[x]:])
            path = path[:seen[x]]
        for y in reversed(path):
            nxt = g.nxt[y]
            if g.obs[nxt] == g.obs[y]:
                self.of_node[y] = self.of_node[nxt]
            else:
                state, new = self._intern(("step", g.obs[y], self.of_node[nxt]))
                if new:
                    self.gen.transitions.append((state, obs_name(g, g.obs[nxt]),
                                                 self.of_node[nxt]))
                self.of_node[y] = state
        return self.of_node[node]

    def _cycle(self, cycle: list[int]) -> None:
        g = self.g
        changes = [k for k in range(len(cycle))
                   if g.obs[cycle[k]] != g.obs[cycle[k - 1]]]
        if not changes:  # the observation never changes again
            state, new = self._intern(("quiet", g.obs[cycle[0]]))
            if new:
                self.gen.transitions.append((state, QUIET, state))
            for x in cycle:
                self.of_node[x] = state
            return
        seq = [g.obs[cycle[k]] for k in changes]  # the observations, cyclically destuttered
        period = _period(seq)
        base = seq[:period]
        rotations = [tuple(base[i:] + base[:i]) for i in range(period)]
        states = []
        for i in range(period):
            state, new = self._intern(("cycle", rotations[i]))
            states.append((state, new))
        for i, (state, new) in enumerate(states):
            if new:
                target = states[(i + 1) % period][0]
                self.gen.transitions.append((state, obs_name(g, base[(i + 1) % period]),
                                             target))
            self.by_key.setdefault(("step", base[i], states[(i + 1) % period][0]), state)
        # Each node of the cycle has the future of the last change at or before it (the
        # observation has not changed since), cyclically.
        j = len(changes) - 1
        for k, x in enumerate(cycle):
            while j + 1 < len(changes) and changes[j + 1] <= k:
                j += 1
            if k < changes[0]:
                j = len(changes) - 1
            elif changes[j] > k:
                j = 0
            self.of_node[x] = states[j % period][0]


def _period(seq: Sequence[int]) -> int:
    n = len(seq)
    for p in range(1, n + 1):
        if n % p == 0 and all(seq[i] == seq[i % p] for i in range(n)):
            return p
    return n


# --------------------------------------------------------------------------------------------
# The project's own diagnosability check (verifier), and the libFAUDES one
# --------------------------------------------------------------------------------------------


def diagnosable(gen: Generator, types: dict[str, set[str]]) -> bool:
    """Every failure type in `types` (name -> fault events) diagnosable, by the verifier."""
    names = sorted(types)
    bit = {ev: 1 << i for i, name in enumerate(names) for ev in types[name]}
    out: dict[int, list[tuple[str, int]]] = {}
    for a, ev, b in gen.transitions:
        out.setdefault(a, []).append((ev, b))
    # (state of the first copy, its fault bits, state of the second, its fault bits)
    start: _Pair = (gen.initial, 0, gen.initial, 0)
    succ: dict[_Pair, list[_Pair]] = {}
    stack = [start]
    succ[start] = []
    while stack:
        v = stack.pop()
        x, fx, y, fy = v
        nexts: list[_Pair] = []
        for ev, x2 in out.get(x, ()):
            if ev not in gen.observable:
                nexts.append((x2, fx | bit.get(ev, 0), y, fy))
        for ev, y2 in out.get(y, ()):
            if ev not in gen.observable:
                nexts.append((x, fx, y2, fy | bit.get(ev, 0)))
        for ev, x2 in out.get(x, ()):
            if ev in gen.observable:
                for ev2, y2 in out.get(y, ()):
                    if ev2 == ev:
                        nexts.append((x2, fx, y2, fy))
        succ[v] = nexts
        for w in nexts:
            if w not in succ:
                succ[w] = []
                stack.append(w)
    for i in range(len(names)):
        mask = 1 << i
        region = {v for v in succ if (v[1] ^ v[3]) & mask}
        if has_cycle(region, succ):
            return False
    return True


def has_cycle(region: set[_Pair], succ: dict[_Pair, list[_Pair]]) -> bool:
    """A cycle inside `region` (Kahn: what cannot be peeled off lies on or before a cycle)."""
    indegree = dict.fromkeys(region, 0)
    for v in region:
        for w in succ[v]:
            if w in region:
                indegree[w] += 1
    queue = [v for v, d in indegree.items() if d == 0]
    removed = 0
    while queue:
        v = queue.pop()
        removed += 1
        for w in succ[v]:
            if w in region:
                indegree[w] -= 1
                if indegree[w] == 0:
                    queue.append(w)
    return removed < len(region)


def to_faudes(gen: Generator) -> Any:  # a faudes.System (faudes ships no types)
    """The generator as a libFAUDES System (the `faudes` package, a test dependency)."""
    import faudes
    system = faudes.System()
    events = {ev for _, ev, _ in gen.transitions}
    for ev in sorted(events):
        if ev in gen.observable:
            system.InsObservableEvent(ev)
        else:
            system.InsUnobservableEvent(ev)
    for state in range(gen.states):
        system.InsState(f"s{state}")
    system.SetInitState(f"s{gen.initial}")
    for a, ev, b in gen.transitions:
        system.SetTransition(f"s{a}", ev, f"s{b}")
    return system


def failure_types(types: Mapping[str, set[str]]) -> Any:  # a faudes.FailureTypeMap
    """The failure types (name -> fault events) as a libFAUDES FailureTypeMap."""
    import faudes
    mapping = faudes.FailureTypeMap()
    for name, evs in sorted(types.items()):
        events = faudes.EventSet()
        for ev in sorted(evs):
            events.Insert(ev)
        mapping.AddFailureTypeMapping(name, events)
    return mapping


def faudes_diagnosable(gen: Generator, types: dict[str, set[str]]) -> bool:
    import faudes
    return bool(faudes.IsEventDiagnosable(to_faudes(gen), failure_types(types)))
