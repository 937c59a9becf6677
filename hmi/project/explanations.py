"""Parsing the `explanations:` section: texts for the operator, checked at load time.

    explanations:
      constraints:
        CSc1:
          what: "{device}: open and close ordered together - {action}"
          consequences: "The motor would be driven both ways ..."
          severity: high
          policies: {stop_device: "stop the valve: both orders held at 0"}
          recommend: stop_device
      situations:
        safe_state_filter: {what: "..."}

Kinds: constraints, labels, partitions, monitors, situations. Every placeholder must be one
the kind offers (hmi.project.texts.PLACEHOLDERS) and every name must exist.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hmi.project.texts import (
    LEVELS,
    PLACEHOLDERS,
    POLICY_IDS,
    SEVERITIES,
    ProjectTexts,
    TextSpec,
    fields_of,
)
from hmi.project.yamlnodes import NodeError, YNode, text_start

SITUATIONS = ("safe_state_filter", "safe_state_plant", "safe_state_internal")
SPEC_KEYS = {*LEVELS, "policies", "recommend", "severity", "alarm"}


def parse_explanations(node: YNode, guard: Callable[..., Any], known: dict[str, set[str]],
                       error: Callable[..., None]) -> ProjectTexts:
    """`known[kind]` is the set of names a kind may describe (constraint names...)."""
    kinds = guard(lambda: node.check_keys("explanations", set(PLACEHOLDERS)), {})
    by_kind: dict[str, dict[str, TextSpec]] = {}
    for kind, knode in kinds.items():
        entries = guard(lambda n=knode, k=kind: n.as_map(f"explanations of {k}"), {})
        names = known.get(kind, set()) if kind != "situations" else \
            set(SITUATIONS) | known.get("situations", set())
        for name, enode in entries.items():
            pos = knode.key_pos[name]
            if name not in names:
                error(pos, f"explanations for unknown {kind[:-1]} {name!r}",
                      "one of " + (", ".join(sorted(names)) or f"(this project has no {kind})"))
                continue
            spec = guard(lambda n=enode, k=kind, nm=name: _spec(n, k, nm))
            if spec is not None:
                by_kind.setdefault(kind, {})[name] = spec
    return ProjectTexts(by_kind)


def _spec(node: YNode, kind: str, name: str) -> TextSpec:
    what = f"the explanation of {name}"
    fields = node.check_keys(what, SPEC_KEYS)
    texts: dict[str, str] = {}
    for level in LEVELS:
        if level in fields:
            texts[level] = _template(fields[level], kind, f"{level} of {name}")
    policies: dict[str, str] = {}
    if "policies" in fields:
        pnode = fields["policies"]
        for pid, vnode in pnode.check_keys(f"the policies of {name}", set(POLICY_IDS)).items():
            policies[pid] = _template(vnode, kind, f"policy {pid} of {name}")
    recommend = None
    if "recommend" in fields:
        recommend = fields["recommend"].as_str("recommend")
        if recommend not in POLICY_IDS:
            raise NodeError(fields["recommend"].pos, f"unknown policy {recommend!r}",
                            "one of " + ", ".join(POLICY_IDS))
    severity = None
    if "severity" in fields:
        severity = fields["severity"].as_str("severity")
        if severity not in SEVERITIES:
            raise NodeError(fields["severity"].pos, f"severity {severity!r} is not known",
                            "high, medium or low")
    alarm = fields["alarm"].as_bool("alarm") if "alarm" in fields else None
    return TextSpec(texts.get("what"), texts.get("why"), texts.get("consequences"),
                    texts.get("detail"), policies, recommend, severity, alarm, node.pos)


def _template(node: YNode, kind: str, what: str) -> str:
    text = node.as_str(what)
    try:
        names = fields_of(text)
    except ValueError as exc:
        raise NodeError(node.pos, f"{what}: {exc}", "{name} placeholders") from None
    allowed = PLACEHOLDERS[kind]
    for name in names:
        if name not in allowed:
            offset = text.find("{" + name)
            pos = text_start(node, text).shifted(offset)
            raise NodeError(pos, f"{what}: unknown placeholder {{{name}}}",
                            "one of " + ", ".join("{" + a + "}" for a in allowed))
    return text
