"""Plain words first: levels 1 to 3 of every explanation name no internal
identifier; the engineering detail (level 5) keeps them.

Every situation of every example project is built: each safety constraint violated under each
policy (and withdrawn by a diagnoser's mask), each faulty state of each diagnoser with what
its flags do, each stopwatch monitor's fault (each rule, interrupted or not), each safe-state
latch, the plant lost or refusing, the corrector's fallback and its budget, manual mode, and
each recovery procedure needed, running, done and failed. Their texts come from the same
builder the HMI uses, on snapshots made from a real first scan.
"""

from __future__ import annotations

import re

import pytest

from hmi.engine.filter import Change, FilterReport
from hmi.engine.monitors import MonitorState
from hmi.engine.recovery import RecoveryState
from hmi.engine.scan import Engine
from hmi.engine.snapshot import LatchReason
from hmi.engine.stopwatch import Detection
from hmi.explain.builder import ExplanationBuilder
from hmi.plant.base import PlantStatus
from hmi.plant.sim.plant import SimPlant
from hmi.project.diagnosers import diagnosers_of
from hmi.project.loader import load_project
from hmi.project.monitors import monitors_of
from hmi.project.recovery import recoveries_of
from hmi.session.session import Session
from tests.conftest import PROJECTS

PROJECT_NAMES = sorted(p.name for p in PROJECTS.iterdir() if (p / "project.yaml").exists())
# Words of the model an operator does not use, whatever the project.
PATTERNS = (r"_hat\b", r"\bdef_", r"\bTON\d*\b", r"\bTOF\d*\b", r"\balpha\b", r"\bbeta\b",
            r"\bgamma\b", r"\bprev\(", r"\brise\(", r"\bfall\(", r"_filter\b", r"\bscan \d",
            r"`", r"\bresync", r"Hamming")


def identifiers(project) -> set[str]:
    """The project's internal names: constraints, timers, observers, memories, diagnoser
    states, labels, flags, estimates, filtered sensors, GRAFCET steps, monitor labels,
    recovery procedures and their constraints; minus the words of its devices and I/O
    (what the operator reads on the machine and in the I/O table)."""
    names = {c.name for c in project.constraints}
    names |= {t.name for t in project.timers} | {o.name for o in project.observers}
    names |= {m.name for m in project.memories}
    for spec in diagnosers_of(project):
        names |= {s.name for s in spec.states} | set(spec.labels)
        for p in spec.partitions:
            names |= {n for n in (p.flag, p.filtered, p.estimate) if n}
    names |= {m.label for m in monitors_of(project)}
    for law in project.controls.values():
        if law.grafcet:
            names |= {s.name for s in law.grafcet.steps}
    for r in recoveries_of(project):
        names |= {r.name} | {c.name for c in r.constraints}
    operator_words = {v.name for v in (*project.inputs, *project.outputs)}
    for v in (*project.inputs, *project.outputs):
        operator_words |= set(re.findall(r"\w+", f"{v.device or ''} {v.description}"))
    return names - operator_words


def any_name(names: set[str]) -> re.Pattern[str]:
    """One pattern matching where any of `names` stands as a word (the names tried one by
    one, 60,000 searches for cispi_subsystem, cost more than the rest of the test)."""
    words = "|".join(re.escape(n) for n in sorted(names, key=len, reverse=True))
    return re.compile(rf"(?<![\w.])(?:{words})(?!\w)")


def offences(text: str, names: set[str], named: re.Pattern[str]) -> list[str]:
    """The model's words in `text`; `named` is any_name(names): each name is looked for
    one by one only when one of them is in the text."""
    found = [m.group(0) for p in PATTERNS for m in re.finditer(p, text)]
    if names and named.search(text):
        found += [n for n in names if re.search(rf"(?<![\w.]){re.escape(n)}(?!\w)", text)]
    return found


def situations(project):
    """(what, snapshot) for every situation of the project."""
    session = Session(Engine(project, SimPlant(project)))
    base = session.scan_once().snapshot  # the engine's part: no explanations, no alarms
    outputs = base.layout.outputs
    for c in project.constraints:
        violation = next(v for v in session.engine.safety_filter.compiled if v.constraint is c
                         ).violation
        out = c.outputs[0]
        for policy, how, written in (("correct", "F0", False), ("correct", "F1", True),
                                     ("block", "safe state", False),
                                     ("monitor", "", True),
                                     ("correct", "masked", False)):
            changes = () if policy == "monitor" else (
                Change(out, not written, written, ("def_x",) if how == "masked" else (c.name,),
                       how),)
            report = FilterReport(policy, "exact", (violation,), changes, 1,
                                  safe_state=policy == "block", note="tie-break note")
            yield f"constraint {c.name} {policy} {how}", base._replace(filter_report=report,
                                                                       policy=policy)
    for spec in diagnosers_of(project):
        index = next(k for k, d in enumerate(base.diagnosers) if d.name == spec.name)
        for state in spec.states:
            if not state.labels:
                continue
            record = base.diagnosers[index].__class__(
                spec.name, spec.device, state.name, state.description, state.labels,
                tuple(spec.label_text(lab) for lab in state.labels), 5, 50_000,
                "N7 -> A1 after 1.93s", (), final=True)
            flagged = [p for p in spec.partitions if set(p.labels) & set(state.labels)]
            sensors = tuple(p.sensor for p in flagged if p.sensor)
            masked = tuple(o for p in flagged for o in p.actuators)
            diagnosers = list(base.diagnosers)
            diagnosers[index] = record
            for mode, rec, mask in (("ftc", sensors, masked), ("observe", (), ())):
                yield (f"diagnoser {spec.name} {state.name} {mode}",
                       base._replace(diagnosers=tuple(diagnosers), reconstructed=rec,
                                     masked=mask))
    for m in monitors_of(project):
        for rule in ("cannot_finish", "deadline", "overrun", "late_end", "too_fast"):
            for location, running in (("interrupted", True), ("executing", True),
                                      ("waiting", False)):
                d = Detection(rule, 3_000_000, 300, 3_000_000, 1_000_000, 1, 0)
                state = MonitorState(m.name, m.label, m.title, m.device, location, 3_000_000,
                                     1_000_000, m.alpha_us, m.beta_us, m.gamma_us, 1, 0,
                                     running, d, d, None, 1, 0)
                yield (f"monitor {m.name} {rule} {location}",
                       base._replace(monitors=(state,)))
    for source, detail in (("filter", "safe blocking on X: never do that"),
                           ("plant", "plant connection lost: timed out"),
                           ("plant", "plant error: the device answered illegal address "
                                     "(exception 2)"),
                           ("internal", "internal error at scan 3: KeyError: 'O'"),
                           ("journal", "journal.jsonl: disk full")):
        yield f"latch {source}", base._replace(latched=(LatchReason(source, detail, 3, 30),))
    yield "plant not connected", base._replace(plant=PlantStatus("modbus", "modbus x",
                                                                 False, "refused"))
    names = tuple(c.name for c in project.constraints[:2])
    violations = tuple(v.violation for v in session.engine.safety_filter.compiled
                       if v.constraint.name in names)
    for stopped in ("", "budget"):
        report = FilterReport("correct", "paper", violations, fallback="no safe vector",
                              stopped=stopped)
        yield f"fallback {stopped}", base._replace(filter_report=report)
    yield "manual", base._replace(mode="manual", manual=((outputs[0], True),))
    grafcet = base.layout.grafcet
    for step in grafcet.steps if grafcet is not None else ():
        # a step past its supervision time (every step: their receptivities read timers,
        # memories, step times, other steps; a step with none written says 0)
        yield (f"step {step.name} overdue",
               base._replace(active_steps=(step.name,), overdue_steps=(step.name,)))
    for r in recoveries_of(project):
        needed = ((r.name, r.device, r.description, r.needed.text if r.needed else "x"),)
        yield f"recovery {r.name} needed", base._replace(recovery=RecoveryState(needed=needed))
        for status in ("running", "done", "failed"):
            state = RecoveryState(r.name, r.device, r.description, status, 1, len(r.steps),
                                  r.steps[0].description, 0, 1_000_000, r.timeout_us,
                                  f"{status} in 1.000 s: {r.description}")
            yield f"recovery {r.name} {status}", base._replace(mode="recovery", recovery=state)


@pytest.mark.parametrize("name", PROJECT_NAMES)
def test_levels_one_to_three_name_no_internal_identifier(name):
    project = load_project(PROJECTS / name)
    names = identifiers(project)
    named = any_name(names)
    problems = []
    seen_kinds = set()
    count = 0
    for what, snap in situations(project):
        builder = ExplanationBuilder(project)
        explanations = builder.build(snap)
        assert explanations, f"{what}: no explanation"
        for e in explanations:
            count += 1
            seen_kinds.add(e.kind)
            for level, text in (("what", e.what), ("why", e.why),
                                ("consequences", e.consequences)):
                bad = offences(text, names, named)
                if bad:
                    problems.append(f"{what} / {e.key} / {level}: {sorted(set(bad))}: {text}")
            labels = [p.label for p in e.policies]
            if len(set(labels)) != len(labels):  # an operator's choice is offered once
                problems.append(f"{what} / {e.key} / policies offered twice: {labels}")
    assert not problems, f"{len(problems)} texts name identifiers (or repeat a choice):\n" \
        + "\n".join(problems[:40])
    assert count > 0 and {"constraint", "safe_state", "plant", "fallback"} <= seen_kinds


def test_the_engineering_detail_keeps_the_identifiers():
    project = load_project(PROJECTS / "cispi_valve")
    snap = next(s for what, s in situations(project) if what == "diagnoser V1 A1 ftc")
    builder = ExplanationBuilder(project)
    diagnosis = next(e for e in builder.build(snap) if e.key == "diagnosis:V1")
    assert diagnosis.what.startswith("Valve V1: ")
    assert "A1" in diagnosis.detail and "N7 -> A1" in diagnosis.detail
    assert "F1, F13" in diagnosis.detail and "def_V masks C, O" in diagnosis.detail
    assert "A1" not in diagnosis.what + diagnosis.why + diagnosis.consequences
    assert diagnosis.render(5).splitlines()[-2].strip() == "Engineering detail:"


@pytest.mark.parametrize("name", PROJECT_NAMES)
def test_the_reset_and_recovery_dialogs_and_output_reasons_name_no_internal_identifier(name):
    """Every situation's fault reset dialog (what it releases, what stays and why), each
    recovery procedure's confirmation, why an output was not written as the program asked
    (the I/O table, the message line) and each simulated fault as the operator view names
    it: plain words; the engineering view's lines keep the names."""
    from hmi.plant.sim.plant import SimPlant
    from hmi.session.view import CellView
    from hmi.ui.fault_dialog import fault_words
    from hmi.ui.reset import recovery_lines, reset_lines
    from hmi.ui.verdict import output_changes

    project = load_project(PROJECTS / name)
    names = identifiers(project)
    named = any_name(names)

    def bad_words(text: str) -> list[str]:  # a scan number is a count the screen may quote
        return [b for b in offences(text, names, named) if not b.startswith("scan ")]
    problems = []
    engineering = ""
    for what, snap in situations(project):
        cell = CellView(snap)
        texts = [("reset", str(getattr(line, "plain", line))) for line in reset_lines(cell)]
        engineering += " ".join(getattr(line, "plain", str(line))
                                for line in reset_lines(cell, engineering=True))
        for written in (True, False):  # every output changed, by this situation's report
            changed = snap._replace(outputs=tuple(not v for v in snap.fov) if written
                                    else snap.outputs)
            texts += [("output", why) for why in output_changes(changed, False, True).values()]
        problems += [f"{what} / {kind}: {sorted(set(bad))}: {text}" for kind, text in texts
                     if (bad := bad_words(text))]
    for r in recoveries_of(project):
        for line in recovery_lines(project, r):
            if bad := bad_words(line):
                problems.append(f"recovery {r.name}: {sorted(set(bad))}: {line}")
    plant = SimPlant(project)
    for device in plant.devices:
        for spec in device.FAULTS.values():
            text = fault_words(device.name, spec.description, len(plant.devices) > 1)
            if bad := bad_words(text):
                problems.append(f"fault {device.name}.{spec.code}: {sorted(set(bad))}: {text}")
    assert not problems, f"{len(problems)} texts name identifiers:\n" + "\n".join(problems[:40])
    if diagnosers_of(project):  # the engineering view names the states it resets
        assert any(s.name in engineering for spec in diagnosers_of(project)
                   for s in spec.states if s.labels)
