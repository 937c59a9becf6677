"""Plain words for the first three levels of an explanation.

An operator reads "the closed end switch of valve V1 is on", not `fsc_filter=1`, and "the
estimated closed position", not `fsc_hat (TON2, or fsc while trusted)`. These helpers turn
the model's names into the words of its descriptions: a variable's description without its
device's name and without the parenthesised engineering note; a filtered sensor as its
sensor; a partition flag as "<part> distrusted". Identifiers stay in the engineering detail.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import TYPE_CHECKING

from hmi.project.diagnosers import diagnosers_of
from hmi.project.model import Project

if TYPE_CHECKING:
    from hmi.engine.snapshot import LatchReason

_PARENS = re.compile(r"\s*\([^()]*\)")


def lower_first(text: str) -> str:
    """'Valve V1' stays, 'Close order' becomes 'close order' (a proper name keeps its
    capital: two capitals in the first word, or a digit)."""
    if not text:
        return text
    first = text.split(" ", 1)[0]
    if any(c.isdigit() for c in first) or sum(c.isupper() for c in first) > 1:
        return text
    return text[:1].lower() + text[1:]


def without_notes(text: str) -> str:
    """A description without its parenthesised notes (where engineers put identifiers)."""
    previous = None
    while previous != text:
        previous, text = text, _PARENS.sub("", text)
    return text.strip()


class PlainNames:
    """The operator's word for each name of a project."""

    def __init__(self, project: Project):
        self.project = project
        self.devices = {v.name: v.device for v in (*project.inputs, *project.outputs)
                        if v.device}
        self.filtered: dict[str, str] = {}
        self.flags: dict[str, str] = {}
        for spec in diagnosers_of(project):
            for p in spec.partitions:
                if p.filtered and p.sensor:
                    self.filtered[p.filtered] = p.sensor
                self.flags[p.flag] = f"{p.description or 'part'} distrusted"
        self.outputs = {v.name for v in project.outputs}

    def name(self, name: str) -> str:
        """'closed end switch', 'close order', 'estimated closed position'."""
        if name in self.filtered:
            return self.name(self.filtered[name])
        if name in self.flags:
            return self.flags[name]
        text = without_notes(self.project.describe(name))
        device = self.devices.get(name)
        if device and text.lower().startswith(device.lower()):
            text = text[len(device):].strip(" :-—,")
        return lower_first(text) or name

    def literal(self, literal: str) -> str:
        """A literal of a violated constraint (true, by definition), in words:
        `not fso_filter` -> 'open end switch off', `prev(C)` -> 'close order on a scan ago'."""
        negated = literal.startswith("not ")
        core = literal[4:] if negated else literal
        when = ""
        for fn, words in (("prev(", " just before"), ("rise(", " just switched on"),
                          ("fall(", " just switched off")):
            if core.startswith(fn):
                core = core[len(fn):].split(",")[0].rstrip(")")
                if fn != "prev(":
                    return f"{self.name(core)}{words}"
                when = words
        return f"{self.name(core)} {'off' if negated else 'on'}{when}"

    def literals(self, literals: Iterable[tuple[str, object]]) -> str:
        return ", ".join(self.literal(text) for text, _ in literals)

    def orders(self, names: Iterable[str]) -> str:
        return " and ".join(self.name(n) for n in names)


def latch_words(reason: LatchReason) -> str:
    """Why the outputs are held safe (a LatchReason), in the operator's words: the rule the
    program broke by its description, not "safe blocking on CSs1"; the reason's own detail
    (constraint names, exception texts) is the engineering detail."""
    detail = reason.detail
    match reason.source:
        case "filter":
            rule = detail.split(": ", 1)[1] if ": " in detail else ""
            return "a safety rule was broken" + (f" — {lower_first(rule)}" if rule else "")
        case "plant" if detail.startswith("plant error"):
            return "the plant refused a request"
        case "plant":
            return "the plant connection was lost"
        case "internal":
            return "internal error" + (f" {reason.part}" if reason.part else "")
        case "journal":
            return "the journal cannot be written"
    return detail
