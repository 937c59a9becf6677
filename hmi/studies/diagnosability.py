"""Automaton reachability of a local diagnoser: the figure 000 §3.3 reads off Fig. 3.

Nothing here is typed in: the figures come from the states reachable *in the diagram* from
the initial state (or a resync target) and their decisions. It is an upper bound, not the
diagnosability of the running cell: it ignores the guards (a state whose guard can never
hold still counts), the time windows and the masking that stops the valve (hmi/engine/
closed_loop.py computes what the closed loop really isolates). `plchmi check` prints both.

* A label is **detected** when some reachable faulty state's decision holds it.
* It is **isolated with certainty** when some reachable state's decision is exactly {label}.
* Otherwise it is **ambiguous**, with the multi-label decisions it appears in, each marked
  *final* (no transition leaves the state: the ambiguity stays until a fault reset) or
  *intermediate* (the state may still refine to a smaller decision).
* **Diagnostic Coverage** = labels isolated with certainty / all labels, placed in its ISO
  13849-1 band: < 60 % none, 60 % to < 90 % low, 90 % to < 99 % medium, >= 99 % high.

DC here follows 000 §3.3, which counts labels (it has no failure rates): 10/13 = 76.9 % for
the valve. The standard's DC weights dangerous failures by their probability.
"""

from __future__ import annotations

from dataclasses import dataclass

from hmi.project.diagnosers import reachable_states
from hmi.project.model import DiagnoserSpec

BANDS = ((0.99, "high"), (0.90, "medium"), (0.60, "low"), (0.0, "none"))


def iso_band(dc: float) -> str:
    """The ISO 13849-1 DC band of a coverage in [0, 1]."""
    for threshold, name in BANDS:
        if dc >= threshold:
            return name
    return "none"


@dataclass(frozen=True)
class Ambiguity:
    labels: tuple[str, ...]
    states: tuple[str, ...]
    final: bool


@dataclass(frozen=True)
class LabelReport:
    label: str
    text: str
    partition: str
    detected: bool
    certain_in: tuple[str, ...]  # states whose decision is exactly {label}
    ambiguities: tuple[Ambiguity, ...]  # multi-label decisions holding the label

    @property
    def certain(self) -> bool:
        return bool(self.certain_in)


@dataclass(frozen=True)
class Diagnosability:
    name: str
    labels: tuple[LabelReport, ...]
    normal: tuple[str, ...]
    certain_states: tuple[str, ...]
    intermediate: tuple[str, ...]  # ambiguous states that may refine
    final_ambiguous: tuple[str, ...]
    unreachable: tuple[str, ...]

    @property
    def abnormal(self) -> int:
        return len(self.certain_states) + len(self.intermediate) + len(self.final_ambiguous)

    @property
    def certain_labels(self) -> tuple[str, ...]:
        return tuple(lab.label for lab in self.labels if lab.certain)

    @property
    def dc(self) -> float:
        return len(self.certain_labels) / len(self.labels) if self.labels else 0.0

    @property
    def band(self) -> str:
        return iso_band(self.dc)

    @property
    def ambiguous_decisions(self) -> tuple[Ambiguity, ...]:
        seen: dict[tuple[str, ...], Ambiguity] = {}
        for lab in self.labels:
            for amb in lab.ambiguities:
                seen.setdefault(amb.labels, amb)
        return tuple(seen.values())

    def lines(self) -> list[str]:
        certain = len(self.certain_labels)
        total = len(self.labels)
        lines = [f"Automaton reachability of {self.name} (an upper bound: states reachable in "
                 "the diagram, guards, timing and masking ignored; the closed loop below says "
                 "what is really isolated)"]
        rows = [["label", "partition", "detected", "isolation", "what"]]
        for lab in self.labels:
            if lab.certain:
                how = "certain (" + ", ".join(lab.certain_in) + ")"
            elif lab.detected:
                how = "ambiguous"
            else:
                how = "never detected"
            if lab.ambiguities:
                how += ("; in " if lab.certain else ": ") + ", ".join(
                    f"{{{', '.join(a.labels)}}} {'final' if a.final else 'intermediate'}"
                    for a in sorted(lab.ambiguities, key=lambda a: not a.final))
            rows.append([lab.label, lab.partition, "yes" if lab.detected else "NO", how,
                         lab.text])
        lines += _table(rows)
        finals = [a for a in self.ambiguous_decisions if a.final]
        lines.append(f"  labels with a single-label state in the diagram: {certain}/{total}; "
                     f"others: {total - certain} ("
                     + ", ".join(lab.label for lab in self.labels if not lab.certain) + ")")
        lines.append("  final ambiguities: " + (", ".join(
            "{" + ", ".join(a.labels) + "}" for a in finals) or "none"))
        lines.append(f"  states: {len(self.normal)} normal, {self.abnormal} abnormal "
                     f"({len(self.certain_states)} isolating one label, "
                     f"{len(self.intermediate) + len(self.final_ambiguous)} ambiguous of which "
                     f"{len(self.intermediate)} intermediate)"
                     + (f"; unreachable: {', '.join(self.unreachable)}" if self.unreachable
                        else ""))
        lines.append(f"  DC read from the diagram = {certain}/{total} = {100 * self.dc:.1f} %: "
                     f"ISO 13849-1 band {self.band} (an upper bound)")
        return lines


def analyse(spec: DiagnoserSpec) -> Diagnosability:
    reached = reachable_states(spec)
    leaves = {tr.source for tr in spec.transitions}
    states = [s for s in spec.states if s.name in reached]
    normal = tuple(s.name for s in states if not s.faulty)
    certain_states = tuple(s.name for s in states if len(s.labels) == 1)
    multi = [s for s in states if len(s.labels) > 1]
    intermediate = tuple(s.name for s in multi if s.name in leaves)
    final = tuple(s.name for s in multi if s.name not in leaves)
    reports = []
    for label, text in spec.labels.items():
        partition = spec.partition_of(label)
        holding = [s for s in states if label in s.labels]
        certain_in = tuple(s.name for s in holding if s.labels == (label,))
        ambiguities: dict[tuple[str, ...], list[str]] = {}
        finals: dict[tuple[str, ...], bool] = {}
        for s in holding:
            if len(s.labels) > 1:
                key = tuple(s.labels)
                ambiguities.setdefault(key, []).append(s.name)
                finals[key] = finals.get(key, True) and s.name not in leaves
        reports.append(LabelReport(
            label, text, partition.name if partition else "-", bool(holding), certain_in,
            tuple(Ambiguity(k, tuple(v), finals[k]) for k, v in ambiguities.items())))
    unreachable = tuple(s.name for s in spec.states if s.name not in reached)
    return Diagnosability(spec.name, tuple(reports), normal, certain_states, intermediate,
                          final, unreachable)


def _table(rows: list[list[str]], indent: str = "  ") -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return [(indent + "  ".join(c.ljust(widths[i]) for i, c in enumerate(r))).rstrip()
            for r in rows]
