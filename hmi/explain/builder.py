"""From a scan's results to graduated explanations.

Each abnormal situation has a stable key ("constraint:CSs2", "safe_state:filter", "plant")
and an onset (scan, time) kept while it lasts. Texts come from the project's `explanations:`
section when it has them, otherwise from generated defaults built on the variables'
operator-facing descriptions. An explanation is rebuilt only when its situation changes, so a
constraint violated for a thousand scans costs one set of sentences.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from functools import partial

from hmi.engine import commands as cmd
from hmi.engine.filter import Change, FilterReport, Violation
from hmi.engine.snapshot import LatchReason, Snapshot
from hmi.explain.alarms import highest
from hmi.explain.context import ExplanationContext, Levels, Onset
from hmi.explain.device_faults import device_fault_explanations
from hmi.explain.diagnoses import diagnosis_explanations
from hmi.explain.model import Explanation, Policy
from hmi.explain.monitors import monitor_explanations
from hmi.explain.plain import lower_first
from hmi.explain.recovery import recovery_explanations
from hmi.explain.sequence import sequence_explanations
from hmi.project.model import Constraint, Project
from hmi.project.recovery import recoveries_of
from hmi.project.texts import ProjectTexts
from hmi.timefmt import seconds

RULES_NAMED = 3  # rules quoted by name in one sentence; the others are counted


@dataclass(frozen=True, slots=True)
class _Explained:
    """The last scan's explanations and what they were made from: its filter report, the
    fields read from that report (_read), and the other fields read (see build)."""

    report: FilterReport | None
    read: tuple[object, ...] | None
    inputs: tuple[object, ...]
    found: tuple[Explanation, ...]


class ExplanationBuilder(ExplanationContext):
    """Owns the onsets and the cache; `build(snapshot)` runs once per scan, on the scan's
    snapshot: explanations read what the scan left behind, never the live engine."""

    def __init__(self, project: Project, texts: ProjectTexts | None = None):
        super().__init__(project, texts)
        # The project's constraints and the recovery procedures' own (a recovery's filter
        # reports them too).
        self.constraints = {c.name: c for c in (*project.constraints, *(
            c for r in recoveries_of(project) for c in r.constraints))}
        self._last_constraints: tuple[tuple[object, ...], tuple[Explanation, ...]] | None = None
        self._last: _Explained | None = None

    # -- public ------------------------------------------------------------------------------
    def build(self, snap: Snapshot) -> tuple[Explanation, ...]:
        # A scan whose every field read here equals the last scan's explains what the last
        # one did (most scans of a working cell, and a situation that lasts): the situations
        # are found from these fields only, every explanation comes from the cache by a
        # signature made of them, and the scan and time only date a new one. So the last
        # scan's explanations are returned as they are. The filter's report is compared by
        # the fields read from it (not its measured solver time), the monitors by their marks
        # (Snapshot.monitor_marks: a detection, a location, a count changed; their stopwatches
        # explain nothing), and a scan with an error (a stage that did not run) never matches.
        report = snap.filter_report
        inputs = (snap.latched, snap.plant, snap.mode, snap.manual, snap.monitor_marks,
                  snap.diagnosers, snap.recovery, snap.reconstructed, snap.masked, snap.policy,
                  snap.error, snap.overdue_steps,
                  tuple(snap.value(n) for n in self.fault_inputs))
        last = self._last
        if last is not None and snap.error is None and inputs == last.inputs and (
                report is last.report or (report is not None and last.report is not None
                                          and _read(report) == last.read)):
            return last.found
        found = self._build(snap)
        self._last = _Explained(report, None if report is None else _read(report), inputs,
                                found)
        return found

    def _build(self, snap: Snapshot) -> tuple[Explanation, ...]:
        found: list[Explanation] = []
        report = snap.filter_report
        if report is not None and report.violations:
            found.extend(self._constraints(snap, report))
        if report is not None and report.fallback:
            found.append(self._fallback(snap, report))
        latches: dict[str, int] = {}  # reasons of each source so far
        for reason in snap.latched:
            nth = latches[reason.source] = latches.get(reason.source, 0) + 1
            found.append(self._latch(snap, reason, nth))
        status = snap.plant
        if not status.connected and not any(r.source == "plant" for r in snap.latched):
            found.append(self._plant(snap, status.message))
        if snap.mode == "manual" and snap.manual:
            found.append(self._manual(snap))
        # The situations of the stages that have their own explanations.
        found.extend(device_fault_explanations(self, snap))
        found.extend(monitor_explanations(self, snap))
        found.extend(diagnosis_explanations(self, snap))
        found.extend(recovery_explanations(self, snap))
        found.extend(sequence_explanations(self, snap))
        keys = {e.key for e in found}
        for key in list(self.onsets):
            if key not in keys:
                del self.onsets[key]
                self.cache.pop(key, None)
        return tuple(found)

    # -- constraints ------------------------------------------------------------------------
    def _constraints(self, snap: Snapshot, report: FilterReport) -> list[Explanation]:
        # A violation usually lasts many scans: when nothing the texts depend on has changed
        # since the last scan, the explanations are last scan's (what the cache would give).
        whole: tuple[object, ...] = (report.policy, report.violations, report.changes,
                                     bool(snap.latched), snap.mode)
        last = self._last_constraints
        if last is not None and last[0] == whole and all(
                self.cache.get(e.key, (None, None))[1] is e for e in last[1]):
            return list(last[1])
        out: list[Explanation] = []
        changes_by_output = {c.output: c for c in report.changes}
        for violation in report.violations:
            constraint = self.constraints[violation.name]
            changed = tuple(changes_by_output[o] for o in constraint.outputs
                            if o in changes_by_output)
            key = f"constraint:{violation.name}"
            onset = self.onset(key, snap)
            signature = (report.policy, violation.literals, tuple(
                (c.output, c.written, c.how) for c in changed), bool(snap.latched),
                snap.mode)
            out.append(self.cached(key, signature, partial(
                self._constraint, snap, report, violation, constraint, changed, onset)))
        self._last_constraints = (whole, tuple(out))
        return out

    def _action_text(self, report: FilterReport, changed: tuple[Change, ...]) -> str:
        """What the filter did, in words: 'close order blocked', 'open order kept on'."""
        if report.policy == "monitor":
            return "NOT corrected (monitor policy)"
        if report.safe_state:
            return "all outputs held at their safe values"
        if not changed:
            return "corrected"
        parts: list[str] = []
        for change in changed:
            desc = self.plain.name(change.output)
            if change.how == "masked":
                parts.append(f"{desc} withdrawn (the device is suspected faulty)")
            elif change.written:
                parts.append(f"{desc} kept on")
            else:
                parts.append(f"{desc} blocked")
        return ", ".join(parts)

    def _constraint(self, snap: Snapshot, report: FilterReport, violation: Violation,
                    constraint: Constraint, changed: tuple[Change, ...],
                    onset: Onset) -> Explanation:
        device = self.device_of(constraint.outputs)
        rule = constraint.description or "a safety rule of the project"
        if device != self.project.name and rule.lower().startswith(device.lower()):
            rule = rule[len(device):].strip(" :-—,")  # "Valve V1: never ..." in a component
        rule = lower_first(rule)
        quoted = f"\u201c{rule}\u201d"
        action = self._action_text(report, changed)
        source = "the operator's manual request" if snap.mode == "manual" else \
            "the control program"
        values = self.literal_values(violation.literals)
        asked = self.plain.literals(violation.literals)
        why = (f"{source[:1].upper()}{source[1:]} asked for this while {asked}: together they "
               f"break the rule {quoted}. Since {seconds(onset.time_us)} s.")
        detail = (f"Safety constraint {constraint.name} ({constraint.kind}), "
                  f"`{constraint.expr.source}`, was true on {source}'s outputs at scan "
                  f"{snap.scan} ({seconds(snap.time_us)} s): {values}. Violated since scan "
                  f"{onset.scan} ({seconds(onset.time_us)} s).")
        if changed:
            detail += " Filter: " + ", ".join(
                f"{c.output} {int(c.requested)}->{int(c.written)} ({c.how}"
                + (f", by {', '.join(c.by)}" if c.by else "") + ")" for c in changed) + "."
        if report.policy == "monitor":
            consequences = (f"The unsafe orders WERE sent, breaking the rule {quoted}: "
                            "damage is possible. The monitor policy only reports; nothing "
                            "protects the plant.")
            severity = "high"
            policies: tuple[Policy, ...] = (
                Policy("correct", "Switch the filter to correct",
                       "the filter corrects unsafe orders from the next scan on",
                       cmd.SetPolicy("correct"), True),
                self.policy_stop(device), self.policy_manual())
        elif report.safe_state and report.policy != "block" and not snap.latched:
            # The corrector wrote the safe state for this scan only (no safe set of orders,
            # or its search budget ran out): nothing is latched, there is nothing to reset.
            cause = ("the search for safe orders ran out of its budget" if report.stopped
                     else "no set of orders kept every rule")
            consequences = (f"Sent as asked, these orders would break the rule {quoted}. "
                            f"At this scan {cause}, so every output was written at its safe "
                            "value instead; each scan corrects again, so this lasts only "
                            "while the situation does.")
            severity = "medium"
            policies = (
                self.policy_continue("let the filter keep correcting (the safe state is "
                                     "written only while no correction is found)", True),
                self.policy_manual(), self.policy_stop(device))
        elif report.policy == "block" or report.safe_state:
            consequences = (f"Sent as asked, these orders would break the rule {quoted}. "
                            "Safe blocking holds every output at its safe value until a fault "
                            "reset: the cell is stopped, safely.")
            severity = "medium"
            policies = (
                self.policy_reset("release the latch; the program resumes from where it is "
                                  "(check it first: it asked for an unsafe order)", True),
                self.policy_manual(), self.policy_stop(device))
        elif any(c.how == "masked" for c in changed):
            withdrawn = self.plain.orders(c.output for c in changed if c.how == "masked")
            consequences = (f"The diagnosis suspects a fault of {device} and holds its orders "
                            f"off. That withdraws the {withdrawn} although the rule {quoted} "
                            "asks to keep it: a device that may be blocked must not be "
                            "driven. See the diagnosis for what to do.")
            severity = "low"
            flags = ", ".join(sorted({f for c in changed if c.how == "masked" for f in c.by}))
            detail += f" Masked by {flags} (000 eq. 9-10): the mask wins over the filter."
            policies = (
                self.policy_continue("leave the orders withdrawn until the diagnosis is "
                                     "cleared by a fault reset", True),
                self.policy_manual())
        else:
            written = ", ".join(f"{self.plain.name(c.output)} {'on' if c.written else 'off'}"
                                for c in changed) or "safe orders"
            consequences = (f"Sent as asked, these orders would break the rule {quoted}. "
                            f"The filter sent {written} instead, the smallest change that "
                            "keeps every rule. The program is not told and keeps asking while "
                            "the situation lasts; the cell continues safely.")
            severity = "low"
            detail += f" Hamming distance {report.distance} from what was asked."
            if report.note and constraint.kind == "combined":
                detail += f" {report.note}."
            policies = (
                self.policy_continue("let the filter keep correcting this order", True),
                self.policy_manual(), self.policy_stop(device))
        defaults = Levels(what=f"{device}: {action} — {rule}",
                          why=why, consequences=consequences, policies=policies,
                          severity=severity, alarm=True, detail=detail)
        fields = {"device": device, "time": seconds(snap.time_us), "scan": snap.scan,
                  "since_time": seconds(onset.time_us), "since_scan": onset.scan,
                  "action": action, "name": constraint.name, "expr": constraint.expr.source,
                  "description": constraint.description, "values": values,
                  "outputs": ", ".join(constraint.outputs),
                  "changes": ", ".join(f"{c.output} {int(c.requested)}->{int(c.written)}"
                                       for c in changed),
                  "policy": report.policy}
        spec = self.texts.get("constraints", constraint.name)
        level = self.apply_texts(spec, defaults, fields)
        if report.policy == "monitor":
            # Unsafe orders were sent: every such violation is high, whatever the project
            # rates it under a protecting filter (the valve's CSc1, "open and close ordered
            # together", stayed medium under monitor while lesser ones were P1).
            level = replace(level, severity=highest(level.severity, "high"))
        return Explanation(f"constraint:{constraint.name}", "constraint", level.severity,
                           device, level.what, level.why, level.consequences,
                           level.policies, onset.scan, onset.time_us, level.alarm,
                           detail=level.detail)

    # -- safe state, fallback, plant, manual -------------------------------------------------
    def _latch(self, snap: Snapshot, reason: LatchReason, nth: int = 1) -> Explanation:
        """The `nth` latch reason of its source: each its own key (the first keeps the plain
        one), so that two different internal errors, or a plant lost then refusing, are two
        explanations and two alarms, neither hiding the other."""
        key = f"safe_state:{reason.source}" + (f":{nth}" if nth > 1 else "")
        onset = Onset(reason.scan, reason.time_us)
        self.onsets.setdefault(key, onset)

        def make() -> Explanation:
            at = seconds(reason.time_us)
            detail = f"Latch {reason.source} at scan {reason.scan} ({at} s): {reason.detail}."
            if reason.source == "plant" and reason.detail.startswith("plant error"):
                # The device answered, refusing a request (a Modbus exception response).
                named = re.search(r"answered (.+?) \(exception", reason.detail)
                refusal = named.group(1) if named else "an error"
                what = f"Cell: the plant answered {refusal} — outputs held safe"
                why = (f"At {at} s the plant refused a request instead of answering it: the "
                       "inputs could not all be read.")
                consequences = ("Every output is held off while the device refuses; "
                                "automatic operation resumes only after a fault reset.")
                severity = "high"
            elif reason.source == "plant":
                what = "Cell: plant connection lost — outputs held safe"
                cause = reason.detail.split(": ", 1)[-1]
                why = (f"At {at} s the plant stopped answering ({cause}): its inputs can no "
                       "longer be trusted.")
                consequences = ("Every output is held off as soon as the connection is back; "
                                "automatic operation resumes only after a fault reset. What "
                                "the machines did meanwhile is unknown: a device stopped "
                                "halfway may need its recovery.")
                severity = "high"
            elif reason.source == "internal" and reason.part:
                what = (f"Cell: internal error {reason.part} — outputs held "
                        "safe")
                why = (f"At {at} s {reason.part} failed unexpectedly; the engineering detail "
                       "says how, for the engineer.")
                consequences = ("The outputs went to their safe values at once and stay "
                                "there until a fault reset; reset once the cause is gone "
                                "(if it is still there, the error latches again).")
                severity = "high"
            elif reason.source == "internal":
                what = "Cell: internal error — outputs held safe"
                why = (f"At {at} s a part of the scan failed unexpectedly; the engineering "
                       "detail says what, for the engineer.")
                consequences = ("The scan could not be completed safely, so every output went "
                                "to its safe value and stays there until a fault reset.")
                severity = "high"
            elif reason.source == "journal":
                what = "Cell: the journal cannot be written — outputs held safe"
                why = (f"At {at} s the operator journal could not be written (a full disk, "
                       "an input/output error): actions and alarms would not be recorded.")
                consequences = ("Every output is held at its safe value until a fault reset; "
                                "free space or fix the disk first.")
                severity = "high"
            else:
                rule = reason.detail.split(": ", 1)[1] if ": " in reason.detail else ""
                what = "Cell: stopped safe — a safety rule was broken"
                why = (f"Under safe blocking the first unsafe order stops the whole cell: at "
                       f"{at} s the program asked for orders that break "
                       + (f"the rule \u201c{lower_first(rule)}\u201d." if rule
                          else "a safety rule."))
                consequences = ("Every output is held at its safe value until a fault reset; "
                                "production is stopped. Nothing moves unless the operator acts.")
                severity = "medium"
            policies = (self.policy_reset("release the latch and let the control program "
                                          "drive the outputs again", True),
                        self.policy_manual())
            spec = self.texts.get("situations", f"safe_state_{reason.source}")
            level = self.apply_texts(spec, Levels(what=what, why=why,
                                                  consequences=consequences,
                                                  policies=policies, severity=severity,
                                                  alarm=True, detail=detail),
                                     {"device": self.project.name,
                                      "time": seconds(snap.time_us), "scan": snap.scan,
                                      "since_time": seconds(reason.time_us),
                                      "since_scan": reason.scan, "action": "outputs held safe",
                                      "reason": reason.source, "detail": reason.detail})
            return Explanation(key, "safe_state" if reason.source != "plant" else "plant",
                               level.severity, self.project.name, level.what,
                               level.why, level.consequences, level.policies,
                               reason.scan, reason.time_us, level.alarm, latched=True,
                               detail=level.detail)
        return self.cached(key, (reason.detail,), make)

    def _rules(self, names: tuple[str, ...]) -> str:
        """Constraint names as their rules, in words: the first RULES_NAMED described ones
        quoted, the others counted (hundreds of constraints broken at once are a number,
        not "a safety rule" said hundreds of times)."""
        quoted: list[str] = []
        others = 0
        for name in dict.fromkeys(names):
            constraint = self.constraints.get(name)
            text = (f"\u201c{lower_first(constraint.description)}\u201d"
                    if constraint is not None and constraint.description else None)
            if text is not None and len(quoted) < RULES_NAMED:
                if text not in quoted:
                    quoted.append(text)
            else:
                others += 1
        if not others:
            return "; ".join(quoted)
        rest = (f"{others} other safety rule{'s' if others > 1 else ''}" if quoted else
                "a safety rule" if others == 1 else f"{others} safety rules")
        return "; ".join(quoted) + (" and " if quoted else "") + rest

    def _fallback(self, snap: Snapshot, report: FilterReport) -> Explanation:
        if report.stopped:
            return self._search_stopped(snap, report)
        key = "fallback"
        onset = self.onset(key, snap)

        def make() -> Explanation:
            violated = ", ".join(report.violated_names)
            what = "Cell: no safe set of orders — safe state written"
            why = (f"At {seconds(snap.time_us)} s no combination of orders kept every safety "
                   f"rule; the program's orders broke {self._rules(report.violated_names)}. "
                   f"Since {seconds(onset.time_us)} s.")
            consequences = ("Every output is at its safe value while the situation lasts; the "
                            "cell does not progress. The rules may be too strict for this "
                            "situation, or a sensor gives an impossible picture.")
            detail = (f"At scan {snap.scan} the corrector found no output vector satisfying "
                      f"every constraint ({report.fallback}); violated by the program: "
                      f"{violated}. Since scan {onset.scan}.")
            policies = (self.policy_manual(True),
                        Policy("check", "Check sensors",
                               "look for a sensor giving an impossible combination", None))
            return Explanation(key, "fallback", "high", self.project.name, what, why,
                               consequences, policies, onset.scan, onset.time_us,
                               detail=detail)
        return self.cached(key, (report.fallback, report.violated_names), make)

    def _search_stopped(self, snap: Snapshot, report: FilterReport) -> Explanation:
        """The corrector's search was cut short by its budget: the safe state, said plainly,
        with what the engineer can change (the budget is a project setting)."""
        key = "search_budget"
        onset = self.onset(key, snap)

        def make() -> Explanation:
            violated = ", ".join(report.violated_names)
            what = ("Cell: correction not found within the search budget — "
                    "safe state written")
            why = (f"At {seconds(snap.time_us)} s the search for safe orders used up its "
                   "budget of work for one scan; "
                   f"the program's orders broke {self._rules(report.violated_names)}. Since "
                   f"{seconds(onset.time_us)} s.")
            consequences = ("Every output is at its safe value for this scan; nothing unsafe is "
                            "sent. Each scan searches again, so the cell stays stopped only "
                            "while the situation lasts. The search stops at a fixed amount of "
                            "work, counted the same on every machine, set so that "
                            "it never holds up the machine.")
            detail = (f"At scan {snap.scan}: {report.fallback}. Violated by the program: "
                      f"{violated}. Budget {report.budget} steps. Since scan {onset.scan}.")
            policies = [self.policy_manual(True),
                        Policy("budget", "Raise the search budget",
                               "engineering: set solver_budget in the project (or start with "
                               "--solver-budget); `plchmi bench corrector` shows what a search "
                               "costs on this machine", None)]
            if report.strategy == "paper":
                policies.append(Policy("exact", "Use the exact search",
                                       "engineering: start with --solver exact (or solver: exact "
                                       "in the project): it proves infeasibility without "
                                       "enumerating and needs far fewer steps", None))
            return Explanation(key, "fallback", "high", self.project.name, what, why,
                               consequences, tuple(policies), onset.scan, onset.time_us,
                               detail=detail)
        return self.cached(key, (report.fallback, report.violated_names), make)

    def _plant(self, snap: Snapshot, message: str) -> Explanation:
        key = "plant"
        onset = self.onset(key, snap)

        def make() -> Explanation:
            what = f"Cell: plant not connected — {message or 'no connection'}"
            why = (f"{snap.plant.description}: {message or 'no answer'}. Since "
                   f"{seconds(onset.time_us)} s.")
            consequences = ("No output is written until the connection is established; "
                            "inputs are not trusted.")
            return Explanation(key, "plant", "high", self.project.name, what, why,
                               consequences, (self.policy_manual(),), onset.scan,
                               onset.time_us, detail=f"Since scan {onset.scan}.")
        return self.cached(key, (message,), make)

    def _manual(self, snap: Snapshot) -> Explanation:
        key = "manual"
        onset = self.onset(key, snap)
        forces = snap.manual

        def make() -> Explanation:
            listed = ", ".join(f"{self.plain.name(n)} {'on' if v else 'off'}"
                               for n, v in forces)
            what = f"Cell: MANUAL — forces active ({listed})"
            why = f"Manual mode since {seconds(onset.time_us)} s; requested: {listed}."
            consequences = ("The control program waits where it is and does not drive the "
                            "outputs; every request still goes through the safety filter.")
            policies = (Policy("auto", "Leave manual",
                               "release every manual output; the program resumes from the "
                               "steps where it waited and drives them again",
                               cmd.SetMode(False), True),)
            detail = ("Manual requests: " + ", ".join(f"{n}={int(v)}" for n, v in forces)
                      + f"; manual mode since scan {onset.scan}.")
            return Explanation(key, "manual", "low", self.project.name, what, why,
                               consequences, policies, onset.scan, onset.time_us, alarm=False,
                               detail=detail)
        return self.cached(key, forces, make)


def _read(report: FilterReport) -> tuple[object, ...]:
    """The fields of a filter report the explanations read (all but the search's counts and
    its measured time)."""
    return (report.policy, report.strategy, report.violations, report.changes,
            report.distance, report.fallback, report.safe_state, report.note, report.budget,
            report.stopped)
