"""The explanation builder reuses the last scan's explanations when every field it reads is
the same (hmi.explain.builder.ExplanationBuilder.build): an operator must read exactly what a
builder explaining every scan afresh gives. Checked scan for scan, on every example project,
with faults that raise situations (constraints, latches, diagnoses, monitors, recoveries)."""

from __future__ import annotations

import pytest

from hmi.engine import commands as cmd
from hmi.explain.builder import ExplanationBuilder
from tests.conftest import PROJECTS
from tests.examples import make_session

S = 1_000_000

RUNS = [
    ("cispi_valve", (), 30),
    ("cispi_valve", ("F5@5s", "F9@12s+2s", "F13@20s"), 30),
    ("sorting", ("table_jam@20s",), 40),
    ("sorting", ("tt_back_stuck1@10s", "left_blocked@25s"), 40),
    ("palletizer", (), 40),
    ("palletizer", ("layer_eye_stuck0@20s",), 40),
    ("conveyor_robot", ("C1.stop@4s+2s", "R1.stop@15s+3s"), 30),
    ("cispi_subsystem", ("P.welded@30s", "V1.F13@12s"), 50),
]


class AlwaysAfresh(ExplanationBuilder):
    """The reference: every scan's situations found again (no reuse of the last scan's)."""

    def build(self, snap):
        return self._build(snap)


# An operator at work: safe blocking and its latch, fault resets, manual mode and unsafe
# requests, a device stopped and released (the situations that change one field at a time).
OPERATOR = [(6, cmd.SetPolicy("block")), (9, cmd.FaultReset()), (10, cmd.SetPolicy("correct")),
            (12, cmd.SetMode(True)), (13, cmd.ManualOutput("O", True)),
            (15, cmd.ManualOutput("C", True)), (17, cmd.ManualOutput("O", None)),
            (19, cmd.SetMode(False)), (21, cmd.StopDevice("Valve V1")),
            (24, cmd.ReleaseDevice("Valve V1")), (25, cmd.SetPolicy("monitor")),
            (28, cmd.FaultReset())]


@pytest.mark.parametrize(("project", "faults", "seconds", "script"), [
    *((*run, ()) for run in RUNS), ("cispi_valve", ("F5@5s",), 30, OPERATOR)])
def test_reused_explanations_are_what_a_fresh_build_gives(project, faults, seconds, script):
    session = make_session(PROJECTS / project, inject=faults)
    reference = AlwaysAfresh(session.project)
    built = session.explainer.build
    seen: set[str] = set()
    differ: list[int] = []  # (an assertion inside would be caught by the session's scan)

    def checked(snap):
        found = built(snap)
        if found != reference.build(snap) or session.explainer.onsets != reference.onsets:
            differ.append(snap.scan)
        seen.update(e.key for e in found)
        return found

    session.explainer.build = checked
    errors = set()
    done = 0
    for at, command in (*script, (seconds, None)):
        session.run_for(at * S - done, lambda snap: errors.add(snap.error))
        done = at * S
        if command is not None:
            assert session.command(command).accepted, command
    assert not differ, f"scans {differ[:5]}..."
    assert errors == {None}
    assert seen or not faults  # the faults did raise situations to explain
