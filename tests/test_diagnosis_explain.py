"""What a fault reset would do, previewed in each faulty diagnoser's record (the reset dialog
shows it), and the explanations' robustness before the diagnosis stage first runs.

(The explanations of diagnoser decisions themselves: tests/test_explain_diagnoses.py.)
The valve's diagnoser V1 (projects/cispi_valve/diagnoser.yaml): F1 (fsc stuck at 0) at 10 s
ends in A1 {F1, F13}, ambiguous, at 15.75 s; F9 (unexpected fso rise) at 10 s is isolated
with certainty a glitch later.
"""

from __future__ import annotations

from ui_scenarios import VALVE

from hmi.engine.commands import FaultReset, InjectFault
from hmi.engine.scan import Engine
from hmi.plant.base import PlantError
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.loader import load_project
from hmi.session.session import Session

S = 1_000_000


def run(code: str, until_s: float) -> Session:
    project = load_project(VALVE)
    session = Session(Engine(project, SimPlant(project)))
    session.command(InjectFault(Injection(code, 10 * S)))
    session.run_for(int(until_s * S))
    return session


def test_record_previews_what_a_reset_would_do():
    c = run("F1", 17)
    record = c.last.snapshot.diagnosers[0]
    assert record.resync == "" and record.resync_values == "fsc=0, fso=0, C=0, O=0"
    message = c.command(FaultReset()).message
    assert "stays in A1" in message
    assert c.engine.diagnosis.runtimes[0].state.name == "A1"

    c = run("F9", 11)
    # wait for the valve at rest, open, no order: the rule that re-synchronises to N5
    while not c.last.snapshot.diagnosers[0].resync:
        c.run_for(10_000)
    record = c.last.snapshot.diagnosers[0]
    assert record.resync == "N5" and record.resync_values == "fsc=0, fso=1, C=0, O=0"
    message = c.command(FaultReset()).message
    assert "re-synchronised to N5" in message
    assert c.engine.diagnosis.runtimes[0].state.name == "N5"


def test_normal_records_carry_no_preview():
    c = run("F9", 5)  # before the fault
    record = c.last.snapshot.diagnosers[0]
    assert not record.faulty and record.resync == "" and record.resync_values == ""
    assert not any(e.key.startswith("diagnosis:") for e in c.last.explanations)


def test_explanations_survive_a_first_scan_without_inputs():
    """The diagnosis stage has not run yet (inputs unknown from the first scan): the other
    explanations are still built (the plant's loss)."""
    project = load_project(VALVE)
    plant = SimPlant(project)

    def unreachable(now_us):
        raise PlantError("connection refused")

    plant.read = unreachable
    snap = Session(Engine(project, plant)).scan_once()
    assert snap.error is None
    assert any(e.key.startswith("safe_state:") for e in snap.explanations)
