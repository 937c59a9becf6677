"""Graduated explanations (000 §4): what, why, consequences, policies — for each abnormal
situation, the same text for the HMI, the headless run and the journal.

Plain words first: levels 1 to 3 say what an operator says — the device, what is
physically wrong or suspected, what the system did, what happens next — and never name the
model's internals (diagnoser states, constraint names, flags, estimates, timers, stopwatch
parameters, scan numbers). Those are kept one level deeper, in the *engineering detail*.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Policy:
    """A choice open to the operator and what it does; `command` is what choosing it sends."""

    id: str  # continue, stop_device, manual, reset, ...
    label: str  # the button's text
    effect: str  # what choosing it does, in one sentence
    command: Any = None  # an hmi.engine.commands command, or None (nothing to send)
    recommended: bool = False


@dataclass(frozen=True)
class Explanation:
    key: str  # stable identity of the situation (the alarm's key): "constraint:CSs1"
    kind: str  # constraint, safe_state, fallback, diagnosis, reconstruction, masked,
    #            monitor, plant, manual
    severity: str  # high, medium, low
    device: str  # the device as the operator knows it ("Valve V1")
    what: str  # level 1: one plain line
    why: str  # level 2: the evidence
    consequences: str  # level 3: if nothing is done, and what the system already does
    policies: tuple[Policy, ...]  # level 4
    since_scan: int
    since_us: int
    alarm: bool = True  # needs the operator: raises an alarm
    latched: bool = False  # stays until a fault reset (diagnoser fault, safe blocking)
    ambiguous: bool = False
    detail: str = ""  # level 5: the engineering detail (states, constraints, flags, values)

    @property
    def recommended(self) -> Policy | None:
        return next((p for p in self.policies if p.recommended), None)

    @property
    def levels(self) -> tuple[str, str, str, str, str]:
        return (self.what, self.why, self.consequences, self.policies_text(), self.detail)

    def policies_text(self) -> str:
        lines = []
        for policy in self.policies:
            mark = " (recommended)" if policy.recommended else ""
            lines.append(f"- {policy.label}{mark}: {policy.effect}")
        return "\n".join(lines)

    def render(self, levels: int = 4) -> str:
        """The explanation as text, up to `levels` levels (1 = the one line)."""
        titles = ("What", "Why", "Consequences", "Policies", "Engineering detail")
        parts = [f"[{self.severity}] {self.what}"]
        for title, text in list(zip(titles, self.levels, strict=True))[1:levels]:
            indented = "\n".join("    " + line for line in text.splitlines())
            parts.append(f"  {title}:\n{indented}")
        return "\n".join(parts)
