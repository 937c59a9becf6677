"""Explanation texts written in the project, with placeholders.

A project may give, per constraint / diagnoser label / partition / monitor / situation kind,
any of the levels (`what`, `why`, `consequences`, `policies`, and the engineering `detail`),
a `severity` and whether
it raises an `alarm`. Texts use `{placeholder}` fields; the placeholders each kind offers are
listed in PLACEHOLDERS and checked when the project loads, so a typo is a file:line:column
error and never a half-filled sentence in front of an operator.
"""

from __future__ import annotations

import string
from dataclasses import dataclass, field
from typing import Any

from hmi.errors import SourcePos

COMMON = ("device", "time", "scan", "since_time", "since_scan", "action")
PLACEHOLDERS: dict[str, tuple[str, ...]] = {
    "constraints": (*COMMON, "name", "expr", "description", "values", "outputs", "changes",
                    "policy"),
    "labels": (*COMMON, "label", "labels", "label_text", "state", "state_text", "diagnoser",
               "transition", "values"),
    "partitions": (*COMMON, "partition", "sensor", "estimate", "outputs", "labels"),
    "monitors": (*COMMON, "task", "label", "x", "y", "alpha", "beta", "gamma", "reason"),
    "situations": (*COMMON, "reason", "detail"),
}
LEVELS = ("what", "why", "consequences", "detail")
SEVERITIES = ("high", "medium", "low")  # damage possible / degraded / information
POLICY_IDS = ("continue", "stop_device", "manual", "reset", "check", "recovery",
              "leave_recovery")


@dataclass(frozen=True)
class TextSpec:
    """What the project says about one situation; None fields fall back to defaults."""

    what: str | None = None
    why: str | None = None
    consequences: str | None = None
    detail: str | None = None
    policies: dict[str, str] = field(default_factory=dict)  # policy id -> effect text
    recommend: str | None = None
    severity: str | None = None
    alarm: bool | None = None
    pos: SourcePos | None = None


@dataclass(frozen=True)
class ProjectTexts:
    """The project's `explanations:` section, by kind then name."""

    by_kind: dict[str, dict[str, TextSpec]] = field(default_factory=dict)

    def get(self, kind: str, name: str) -> TextSpec:
        return self.by_kind.get(kind, {}).get(name, TextSpec())


def fields_of(template: str) -> list[str]:
    """The placeholder names a template uses (ValueError if it is malformed)."""
    names = []
    for _, name, spec, conversion in string.Formatter().parse(template):
        if name is None:
            continue
        if spec or conversion or not name.isidentifier():
            raise ValueError(f"placeholder {{{name}{'!' + conversion if conversion else ''}"
                             f"{':' + spec if spec else ''}}} is not a plain name")
        names.append(name)
    return names


class _Values(dict[str, Any]):
    def __missing__(self, key: str) -> str:
        return "{" + key + "}"


def fill(template: str, values: dict[str, Any]) -> str:
    """Fill placeholders; an unknown one stays visible (the loader refuses those anyway)."""
    return string.Formatter().vformat(template, (), _Values(values))
