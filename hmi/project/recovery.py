"""The `recovery:` section: declared ways back from a fault.

A fault can leave a device where neither the control program nor the operator can move it:
a valve stopped between its end positions (a jam, repaired; a lost plant connection) is
refused by the constraints that start a travel only from an end. A *recovery procedure* is
the way back the engineer declares for such a case: a short sequence of steps that brings a
device (or the whole cell) to its initial position, with its own safety constraints. The
operator runs it in recovery mode, entered with a confirmation (GEMMA's A5/A6: prepare the
restart after a failure, bring the machine to its initial state).

    recovery:
      V1_home:
        device: Valve V1
        description: Close valve V1 (its initial position)
        needed:                       # optional: when the cell needs it (shown, advised)
          when: not fsc and not fso and not C and not O
          for: 500ms
          text: seen between its end positions (no end switch made), its position unknown
        steps:                        # a linear sequence; the last `until` ends it
          - {description: Closing, do: [C], until: fsc}   # `for: 1s`: until held that long
        timeout: 2.5s                 # not done by then: outputs safe, recovery failed
        relaxes: [CSs3, CSs4, CSs5, CSs6]   # project constraints suspended while it runs
        resets: []                    # observers back to their initial value once done
        constraints:                  # its own, in force while it runs
          R_V1_closed: {expr: C and fsc, description: never push the closed end stop}

While a procedure runs, the outputs it drives follow its steps and every other output is held
at its safe value; they are filtered by the project's constraints except the ones it
`relaxes`, plus its own. A condition reads the inputs of the scan and the orders written at
the previous scan (like the GRAFCET's receptivities); `do` items are output names or
`{do: NAME, if: CONDITION}`.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING

from hmi.errors import SourcePos
from hmi.logic.names import NAME_RE
from hmi.project.constraints import parse_constraint
from hmi.project.model import (
    Constraint,
    Observer,
    RecoveryAction,
    RecoveryNeed,
    RecoveryProcedure,
    RecoveryStep,
    Variable,
)
from hmi.project.yamlnodes import YNode

if TYPE_CHECKING:
    from hmi.project.model import Project
    from hmi.project.reader import ProjectReader

RECOVERY_KEYS = {"device", "description", "needed", "steps", "timeout", "relaxes",
                 "constraints", "resets"}
NEEDED_KEYS = {"when", "for", "text"}
STEP_KEYS = {"description", "do", "until", "for"}
# The situations a project's explanations may word, per procedure: `<prefix>_<procedure>`.
RECOVERY_SITUATIONS = ("recovery_needed", "recovery", "recovery_failed")
CONDITION_KINDS = {"input", "output", "timer", "observer", "flag", "filtered"}
CONDITION_CONTEXT = ("in a recovery procedure (it may read inputs, outputs, timers, observers "
                     "and flags)")


def recoveries_of(project: Project) -> tuple[RecoveryProcedure, ...]:
    return project.recovery


def parse_recovery(loader: ProjectReader, constraints: list[Constraint],
                   outputs: list[Variable], observers: list[Observer]
                   ) -> tuple[RecoveryProcedure, ...]:
    """Read the `recovery:` section once every name and constraint is known; report, never
    raise."""
    node = loader.sections.get("recovery")
    if node is None:
        return ()
    items = loader.guard(lambda: node.as_map("the recovery section"), {})
    known = {c.name for c in constraints}
    devices = {v.name: v.device or "" for v in outputs}
    memorised = {o.name for o in observers if o.expr is None}
    own: dict[str, SourcePos] = {}
    out = []
    for name, item in items.items():
        kpos = node.key_pos.get(name, item.pos)
        if not NAME_RE.match(str(name)):
            loader.diag.error(kpos, f"{name!r} is not a valid recovery procedure name",
                              "letters, digits and _, not starting with a digit")
            continue
        procedure = _procedure(loader, str(name), item, kpos, known, own, devices, memorised)
        if procedure is not None:
            out.append(procedure)
    return tuple(out)


def _procedure(loader: ProjectReader, name: str, node: YNode, kpos: SourcePos,
               known: set[str], own: dict[str, SourcePos], devices: dict[str, str],
               memorised: set[str]) -> RecoveryProcedure | None:
    what = f"recovery procedure {name!r}"
    fields = loader.guard(lambda: node.check_keys(what, RECOVERY_KEYS,
                                                  ["description", "steps", "timeout"]))
    if fields is None:
        return None
    description = loader.guard(lambda: fields["description"].as_str("description"), "")
    device = loader.guard(lambda: fields["device"].as_str("device"), "") \
        if "device" in fields else ""
    timeout = loader.guard(lambda: fields["timeout"].as_duration(f"the timeout of {what}"))
    outputs = set(devices)
    steps = [loader.guard(lambda s=s, k=k: _step(loader, what, k, s, outputs))
             for k, s in enumerate(loader.guard(
                 lambda: fields["steps"].as_seq(f"the steps of {what}"), []), start=1)]
    if not steps:
        loader.diag.error(fields["steps"].pos, f"{what} has no steps",
                          "a list of steps: {description, do, until}")
    relaxes = _names(loader, fields, "relaxes", what, known, "a constraint name",
                     "a constraint of the project")
    mine: list[Constraint] = []
    if "constraints" in fields:
        for cname, cnode in loader.guard(lambda: fields["constraints"].as_map(
                f"the constraints of {what}"), {}).items():
            cpos = fields["constraints"].key_pos.get(cname, cnode.pos)
            cname = str(cname)
            if cname in known or cname in own:
                first = own.get(cname)
                loader.diag.error(cpos, f"constraint name {cname!r} is already used"
                                  + (f" at {first}" if first else " by the project"),
                                  "a name of its own (it shows in the filter's report)")
                continue
            constraint = parse_constraint(loader, cname, cnode, cpos)
            if constraint is not None:
                own[cname] = cpos
                mine.append(constraint)
    resets = _names(loader, fields, "resets", what, memorised, "an observer name",
                    "an observer with set and reset")
    needed = _needed(loader, what, fields["needed"]) if "needed" in fields else None
    if timeout is None or any(s is None for s in steps) or not steps or (
            "needed" in fields and needed is None):
        return None
    if not device:
        named = {devices[a.output] for s in steps if s for a in s.actions} - {""}
        device = named.pop() if len(named) == 1 else ""
    return RecoveryProcedure(name, device, description, tuple(s for s in steps if s),
                             timeout, tuple(relaxes), tuple(mine), needed, kpos,
                             tuple(resets))


def _names(loader: ProjectReader, fields: dict[str, YNode], key: str, what: str,
           allowed: Collection[str], one: str, kind: str) -> list[str]:
    """The names listed under `key` (relaxes, resets), each one of `allowed`; any other is an
    error at its own line and column, with the names that would do."""
    names: list[str] = []
    if key not in fields:
        return names
    for item in loader.guard(lambda: fields[key].as_seq(f"what {what} {key}"), []):
        name = loader.guard(lambda i=item: i.as_str(one))
        if name is None:
            continue
        if name not in allowed:
            loader.diag.error(item.pos, f"{what} {key} {name!r}, which is not {kind}",
                              "one of " + (", ".join(sorted(allowed)) or "(none)"))
            continue
        names.append(name)
    return names


def _needed(loader: ProjectReader, what: str, node: YNode) -> RecoveryNeed | None:
    fields = loader.guard(lambda: node.check_keys(f"when {what} is needed", NEEDED_KEYS,
                                                  ["when", "text"]))
    if fields is None:
        return None
    when = loader.expr(fields["when"], f"when {what} is needed", CONDITION_KINDS,
                       context=CONDITION_CONTEXT)
    text = loader.guard(lambda: fields["text"].as_str("text"))
    for_us = loader.guard(lambda: fields["for"].as_duration("for", allow_zero=True), None) \
        if "for" in fields else 0
    if when is None or text is None or for_us is None:
        return None
    return RecoveryNeed(when, for_us, text)


def _step(loader: ProjectReader, what: str, number: int, node: YNode, outputs: set[str]
          ) -> RecoveryStep | None:
    where = f"step {number} of {what}"
    fields = node.check_keys(where, STEP_KEYS, ["do", "until"])
    description = fields["description"].as_str("description") if "description" in fields \
        else f"step {number}"
    until = loader.expr(fields["until"], f"the end condition of {where}", CONDITION_KINDS,
                        context=CONDITION_CONTEXT)
    for_us = fields["for"].as_duration(f"how long the end condition of {where} must hold",
                                       allow_zero=True) if "for" in fields else 0
    actions = []
    ok = until is not None
    for item in fields["do"].as_seq(f"the outputs {where} drives"):
        condition = None
        if item.kind == "map":
            afields = item.check_keys(f"an action of {where}", {"do", "if"}, ["do"])
            target_node = afields["do"]
            if "if" in afields:
                condition = loader.expr(afields["if"], f"the condition of an action of {where}",
                                        CONDITION_KINDS, context=CONDITION_CONTEXT)
                ok = ok and condition is not None
        else:
            target_node = item
        target = target_node.as_str("an output name")
        if target not in outputs:
            loader.diag.error(target_node.pos, f"{where} drives {target!r}, which is not an "
                              "output", "one of " + ", ".join(sorted(outputs)))
            ok = False
            continue
        actions.append(RecoveryAction(target, condition))
    if not ok or until is None:
        return None
    return RecoveryStep(description, tuple(actions), until, for_us)
