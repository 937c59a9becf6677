"""The untimed diagnoser of the closed loop's untimed abstraction (hmi/studies/untimed.py):
what an observer that sees only the order of the observation changes can conclude, state by
state — the untimed part of the diagnosers plchmi runs and builds, and the object libFAUDES'
EventDiagnoser builds, so the two can be compared state for state (tests/test_faudes.py).

A state is an *estimate*: the states of the generator the loop can be in after the observed
word (entered by an observable event, or the initial state), each with the failure types that
may have occurred on the way (Sampath et al. 1995). When runs with different failure types
reach the same generator state, the state keeps the types common to all of them plus the
label ``A`` (ambiguous); the next step keeps ``A`` only where it stands alone and no fault
event is on the way (Sampath's label propagation: beside a failure type, or after a fault, the
run is faulty for certain). This is what libFAUDES does, reproduced so the comparison can be
exact. ``N`` (normal) is the empty label set.

Built from the project's own abstraction with its own algorithm (a subset construction over
(state, labels) pairs), it is an independent second construction of what libFAUDES builds:
the two agreeing state for state on the valve's closed loop checks the abstraction's export
and both constructions at once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from hmi.studies.untimed import Generator

AMBIGUOUS = "A"
NORMAL = "N"

Labels = frozenset[str]
Estimate = frozenset[tuple[int, Labels]]


@dataclass
class UntimedDiagnoser:
    """States are estimates; transitions on the generator's observable events."""

    initial: Estimate
    states: list[Estimate] = field(default_factory=list)
    transitions: dict[tuple[int, str], int] = field(default_factory=dict)

    def index(self, estimate: Estimate) -> int:
        return self.states.index(estimate)


def label_text(labels: Labels) -> str:
    """The label set as libFAUDES writes it: `N` when empty, else the sorted names."""
    return " ".join(sorted(labels)) if labels else NORMAL


def _merged(candidates: list[Labels]) -> Labels:
    first = candidates[0]
    if all(c == first for c in candidates):
        return first
    common = frozenset.intersection(*candidates)
    return common | {AMBIGUOUS}


def untimed_diagnoser(gen: Generator, types: Mapping[str, set[str]]) -> UntimedDiagnoser:
    """The diagnoser of `gen` for the failure types `types` (name -> fault events)."""
    type_of = {ev: name for name, evs in types.items() for ev in evs}
    out: dict[int, list[tuple[str, int]]] = {}
    for a, ev, b in gen.transitions:
        out.setdefault(a, []).append((ev, b))

    def unobservable_reach(x: int, labels: Labels) -> set[tuple[int, Labels]]:
        seen = {(x, labels)}
        stack = [(x, labels)]
        while stack:
            y, ls = stack.pop()
            for ev, z in out.get(y, ()):
                if ev in gen.observable:
                    continue
                kind = type_of.get(ev)
                # Sampath's label propagation: a fault on the way makes the state certain
                # of it, so an ambiguity before it is dropped.
                nxt = (z, (ls - {AMBIGUOUS}) | {kind} if kind is not None else ls)
                if nxt not in seen:
                    seen.add(nxt)
                    stack.append(nxt)
        return seen

    def step(estimate: Estimate) -> dict[str, Estimate]:
        found: dict[str, dict[int, list[Labels]]] = {}
        for x, labels in estimate:
            # Sampath's label propagation keeps A only alone ({A}: a fault may or may not
            # have occurred); beside failure types it is dropped.
            start = labels if labels == {AMBIGUOUS} else labels - {AMBIGUOUS}
            for y, ls in unobservable_reach(x, start):
                for ev, z in out.get(y, ()):
                    if ev in gen.observable:
                        found.setdefault(ev, {}).setdefault(z, []).append(ls)
        return {ev: frozenset((z, _merged(c)) for z, c in by_state.items())
                for ev, by_state in found.items()}

    initial: Estimate = frozenset({(gen.initial, frozenset())})
    diag = UntimedDiagnoser(initial, [initial])
    number = {initial: 0}
    todo = [initial]
    while todo:
        estimate = todo.pop()
        for ev, nxt in sorted(step(estimate).items()):
            if nxt not in number:
                number[nxt] = len(diag.states)
                diag.states.append(nxt)
                todo.append(nxt)
            diag.transitions[(number[estimate], ev)] = number[nxt]
    return diag



def faudes_untimed_diagnoser(gen: Generator, types: Mapping[str, set[str]]
                             ) -> UntimedDiagnoser:
    """libFAUDES' EventDiagnoser of `gen` (the `faudes` package, a test dependency), read
    back from its own text form into the same shape, in the generator's state numbers."""
    import faudes

    from hmi.studies.untimed import failure_types, to_faudes
    system = to_faudes(gen)
    result = faudes.Diagnoser()
    faudes.EventDiagnoser(system, failure_types(types), result)
    tokens: list[str] = str(result.ToString()).split()

    def section(tag: str) -> list[str]:
        if f"<{tag}/>" in tokens:  # written empty
            return []
        start = tokens.index(f"<{tag}>") + 1
        return tokens[start:tokens.index(f"</{tag}>", start)]

    def state_number(token: str) -> int:
        return int(system.StateName(int(token))[1:])  # to_faudes names state n "sn"

    estimates: dict[str, Estimate] = {}
    body = section("States")
    i = 0
    while i < len(body):
        name, i = body[i], i + 1
        pairs: set[tuple[int, Labels]] = set()
        if i < len(body) and body[i] == "<StateEstimates>":
            i += 1
            while body[i] != "</StateEstimates>":
                state, i = state_number(body[i]), i + 2  # the number, then <DiagLabels>
                labels: list[str] = []
                while body[i] != "</DiagLabels>":
                    labels.append(body[i])
                    i += 1
                i += 1
                pairs.add((state, frozenset(x for x in labels if x != NORMAL)))
            i += 1
        elif i < len(body) and body[i] == "<StateEstimates/>":
            i += 1
        estimates[name] = frozenset(pairs)
    init_states = section("InitStates")
    if not init_states:  # libFAUDES' precondition (Sampath's): no unobservable cycle
        raise ValueError("libFAUDES built no diagnoser: the generator has a cycle of "
                         "unobservable events")
    (init,) = init_states
    diag = UntimedDiagnoser(estimates[init], list(estimates.values()))
    number = {name: k for k, name in enumerate(estimates)}
    rel = section("TransRel")
    for k in range(0, len(rel), 3):
        diag.transitions[(number[rel[k]], rel[k + 1])] = number[rel[k + 2]]
    return diag


def differences(ours: UntimedDiagnoser, theirs: UntimedDiagnoser, limit: int = 5) -> list[str]:
    """Where two untimed diagnosers differ, walking both from their initial states on the
    same events: an estimate, or an event one allows and the other not, or a state of one
    paired with two of the other. Empty when they are the same automaton state for state."""
    found: list[str] = []
    pair = {ours.index(ours.initial): theirs.index(theirs.initial)}
    back = {v: k for k, v in pair.items()}
    todo = list(pair.items())
    out_ours: dict[int, dict[str, int]] = {}
    out_theirs: dict[int, dict[str, int]] = {}
    for (a, ev), b in ours.transitions.items():
        out_ours.setdefault(a, {})[ev] = b
    for (a, ev), b in theirs.transitions.items():
        out_theirs.setdefault(a, {})[ev] = b
    while todo and len(found) < limit:
        a, b = todo.pop()
        if ours.states[a] != theirs.states[b]:
            found.append(f"estimate {sorted(ours.states[a])} != {sorted(theirs.states[b])}")
        ea, eb = out_ours.get(a, {}), out_theirs.get(b, {})
        if set(ea) != set(eb):
            found.append(f"events {sorted(set(ea) ^ set(eb))} in one only")
        for ev in sorted(set(ea) & set(eb)):
            x, y = ea[ev], eb[ev]
            if pair.get(x, y) != y or back.get(y, x) != x:
                found.append(f"after {ev}: state paired twice")
            elif x not in pair:
                pair[x], back[y] = y, x
                todo.append((x, y))
    if not found and (len(pair) != len(ours.states) or len(back) != len(theirs.states)):
        found.append(f"{len(ours.states)} states against {len(theirs.states)}")
    return found
