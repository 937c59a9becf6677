"""The `high_level:` section: the High Level Diagnoser's global specifications (000 §2.1,
construction step 4: "a High Level Diagnoser from global specifications is done for
uncertainty cases").

    high_level:
      V2_shut_or_jammed:
        description: With the pump on the transfer line, T2 fills fast only if V2 is shut
        diagnoser: V2
        decision: [F1, F13]              # the ambiguous local decision it refines
        rules:                           # tried in order at each scan while it holds
          - when: rise(LH2) and T2_timed and not T2_slow
            decide: F1
            because: T2 filled from its low to its high level in under 2.8 s ...
          - {when: T2_slow, decide: F13, because: ...}

A local diagnoser sees one device; a global specification relates several (the pump, the
tanks' levels, the other valve), so it can tell apart what one device's switches cannot.
Each scan, after the local diagnosers, a specification whose diagnoser's decision is exactly
`decision` tries its rules in order; the first whose condition holds replaces the decision
by its label, with its reason, until the local diagnoser moves or a fault reset: the flags
follow the refined decision (a sensor label unmasks the device's orders and reconstructs the
sensor). Conditions read what a diagnoser reads: inputs, timers, observers, and the outputs
written at the previous scan.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hmi.logic.names import NAME_RE
from hmi.project.diagnosers import DIAG_CONTEXT, DIAG_KINDS
from hmi.project.model import DiagnoserSpec, HighLevelRule, HighLevelSpec

if TYPE_CHECKING:
    from hmi.project.reader import ProjectReader

KEYS = {"description", "diagnoser", "decision", "rules"}
RULE_KEYS = {"when", "decide", "because"}


def parse_high_level(reader: ProjectReader, diagnosers: tuple[DiagnoserSpec, ...]
                     ) -> tuple[HighLevelSpec, ...]:
    """Read the section after the diagnosers; report problems, never raise."""
    by_name = {d.name: d for d in diagnosers}
    out = []
    for name, node, kpos in reader.section_items("high_level"):
        name = str(name)
        what = f"high level specification {name!r}"
        if not NAME_RE.match(name):
            reader.diag.error(kpos, f"{name!r} is not a valid specification name",
                              "letters, digits and _, not starting with a digit")
            continue
        fields = reader.guard(lambda n=node, w=what: n.check_keys(
            w, KEYS, ["diagnoser", "decision", "rules"]))
        if fields is None:
            continue
        description = reader.guard(lambda f=fields: f["description"].as_str("description"),
                                   "") if "description" in fields else ""
        dname = reader.guard(lambda f=fields: f["diagnoser"].as_str("diagnoser"))
        spec = by_name.get(dname or "")
        if dname is not None and spec is None:
            reader.diag.error(fields["diagnoser"].pos, f"{what}: no diagnoser {dname!r}",
                              "one of " + (", ".join(sorted(by_name)) or "none declared"))
            continue
        items = reader.guard(lambda f=fields: f["decision"].as_seq("decision"), [])
        decision = []
        for item in items:
            label = reader.guard(lambda i=item: i.as_str("a label"))
            if label is None:
                continue
            if spec is not None and label not in spec.labels:
                reader.diag.error(item.pos, f"{what}: diagnoser {spec.name} has no label "
                                  f"{label!r}", "one of " + ", ".join(spec.labels))
                continue
            decision.append(label)
        if len(set(decision)) < 2:
            reader.diag.error(fields["decision"].pos, f"{what} refines no ambiguity",
                              "decision: [two or more labels of the diagnoser]")
            continue
        if spec is None:
            continue
        order = list(spec.labels)
        labels = tuple(sorted(set(decision), key=order.index))
        if not any(tuple(sorted(s.labels, key=order.index)) == labels for s in spec.states):
            reader.diag.warning(fields["decision"].pos, f"{what}: no state of diagnoser "
                                f"{spec.name} decides {{{', '.join(labels)}}}: it never "
                                "applies")
        rules = []
        for k, rnode in enumerate(reader.guard(lambda f=fields: f["rules"].as_seq("rules"),
                                               []), start=1):
            rwhat = f"rule {k} of {what}"
            rf = reader.guard(lambda r=rnode, w=rwhat: r.check_keys(w, RULE_KEYS, RULE_KEYS))
            if rf is None:
                continue
            when = reader.expr(rf["when"], f"the condition of {rwhat}", DIAG_KINDS,
                               context=DIAG_CONTEXT.replace("a diagnoser",
                                                            "a high level specification"))
            decide = reader.guard(lambda f=rf: f["decide"].as_str("decide"))
            because = reader.guard(lambda f=rf: f["because"].as_str("because"), "")
            if decide is not None and decide not in labels:
                reader.diag.error(rf["decide"].pos, f"{rwhat} decides {decide!r}, not one of "
                                  "the decision it refines", "one of " + ", ".join(labels))
                continue
            if when is None or decide is None:
                continue
            rules.append(HighLevelRule(when, decide, because or "", rnode.pos))
        if not rules:
            reader.diag.error(fields["rules"].pos, f"{what} has no rule",
                              "rules: [{when: ..., decide: LABEL, because: ...}]")
            continue
        out.append(HighLevelSpec(name, description, spec.name, labels, tuple(rules), kpos))
    return tuple(out)
