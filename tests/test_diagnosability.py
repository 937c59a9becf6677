"""Automaton reachability (000 §3.3's figure, read off the diagram): labels, states, DC and its
band, for the paper-faithful valve diagnoser and the improved one. What the closed loop really
isolates is in tests/test_closed_loop.py."""

from __future__ import annotations

import pytest

from hmi.cli import main
from hmi.project.loader import load_project
from hmi.studies.diagnosability import analyse, iso_band
from tests.conftest import PROJECTS
from tests.test_diagnoser_format import DIAG, write


@pytest.fixture(scope="module")
def valve():
    return analyse(load_project(PROJECTS / "cispi_valve", "paper").diagnosers[0])


@pytest.fixture(scope="module")
def improved():
    return analyse(load_project(PROJECTS / "cispi_valve").diagnosers[0])


def test_the_improved_diagram_has_every_label_but_f13_in_a_single_label_state(improved):
    assert improved.certain_labels == tuple(f"F{k}" for k in range(1, 13))
    assert round(100 * improved.dc, 1) == 92.3 and improved.band == "medium"
    f13 = next(lab for lab in improved.labels if lab.label == "F13")
    assert {a.labels for a in f13.ambiguities} == {("F1", "F13"), ("F3", "F13")}


def test_valve_isolates_ten_labels_of_thirteen_with_certainty(valve):
    assert valve.certain_labels == ("F2", "F4", "F5", "F6", "F7", "F8", "F9", "F10", "F11",
                                    "F12")
    assert len(valve.labels) == 13 and all(lab.detected for lab in valve.labels)
    assert round(100 * valve.dc, 1) == 76.9 and valve.band == "low"


def test_valve_ambiguities_are_f1_f13_and_f3_f13_final(valve):
    finals = {a.labels for a in valve.ambiguous_decisions if a.final}
    assert finals == {("F1", "F13"), ("F3", "F13")}
    f13 = next(lab for lab in valve.labels if lab.label == "F13")
    assert not f13.certain and {a.labels for a in f13.ambiguities} == finals


def test_valve_has_nine_normal_and_eighteen_abnormal_states(valve):
    # The paper's 16 plus R7 {F2, F7} and R9 {F4, F9} (see docs/cispi_valve.md).
    assert len(valve.normal) == 9 and valve.abnormal == 18
    assert len(valve.certain_states) == 10
    assert sorted(valve.intermediate) == ["B1", "B2", "B3", "B4", "R7", "R9"]
    assert sorted(valve.final_ambiguous) == ["A1", "A3"]
    assert valve.unreachable == ()


@pytest.mark.parametrize("dc,band", [(0.0, "none"), (0.599, "none"), (0.60, "low"),
                                     (0.769, "low"), (0.899, "low"), (0.90, "medium"),
                                     (0.989, "medium"), (0.99, "high"), (1.0, "high")])
def test_iso_13849_bands(dc, band):
    assert iso_band(dc) == band


def test_figures_follow_the_automaton_not_a_table(tmp_path):
    """Remove the state that isolates F2 and the figures change accordingly."""
    project = load_project(write(tmp_path / "p"))
    before = analyse(project.diagnosers[0])
    assert before.certain_labels == ("F1", "F2") and before.dc == pytest.approx(2 / 3)
    diag = DIAG.replace("      - {from: N2, to: S2, after: 300ms}\n", "")
    after = analyse(load_project(write(tmp_path / "q", diag=diag)).diagnosers[0])
    assert after.certain_labels == ("F1",) and after.unreachable == ("S2",)
    f2 = next(lab for lab in after.labels if lab.label == "F2")
    assert not f2.detected and after.band == "none"
    f5 = next(lab for lab in after.labels if lab.label == "F5")
    assert [(a.labels, a.final) for a in f5.ambiguities] == [(("F1", "F5"), False)]


def test_check_and_diagnose_print_the_figures(capsys, monkeypatch):
    # The automaton's figures only: the closed loop's are tests/test_closed_loop.py's.
    monkeypatch.setattr("hmi.studies.diag_report.closed_loop_lines", lambda *a, **k: [])
    assert main(["check", str(PROJECTS / "cispi_valve"), "--diagnoser", "paper"]) == 0
    out = capsys.readouterr().out
    assert "Automaton reachability of V1 (an upper bound" in out
    assert "labels with a single-label state in the diagram: 10/13; others: 3 (F1, F3, F13)" \
        in out
    assert "final ambiguities: {F1, F13}, {F3, F13}" in out
    assert "states: 9 normal, 18 abnormal (10 isolating one label, 8 ambiguous of which 6 " \
           "intermediate)" in out
    assert "DC read from the diagram = 10/13 = 76.9 %: ISO 13849-1 band low" in out
    assert main(["diagnose", str(PROJECTS / "cispi_valve"), "--diagnoser", "paper"]) == 0
    out = capsys.readouterr().out
    assert "B2   ambiguous, intermediate  {F2, F5}" in out
    assert "A1   ambiguous, final         {F1, F13}" in out
    assert "DC read from the diagram = 10/13 = 76.9 %" in out
