"""z3 proves that one call of the exported safety program (`PRG_<P>_Safety`), as blark parses
it, is one scan of the engine's scan program, every block taken as any function: the blocks
called in the scan's order, each given the engine's values at its point of the scan, the
output image, the history shifted, the first cycle, the fault reset after the scan, the
program's clock (tests/program_prove.py says how, and what the composition with the block
proofs rests on). Tampered programs are refuted with a counterexample."""

from __future__ import annotations

import time

import pytest

from hmi.export.build import build
from hmi.export.st import write_st
from hmi.project.loader import load_project
from tests.conftest import PROJECTS
from tests.program_prove import prove_program

NAMES = sorted(p.name for p in PROJECTS.iterdir() if (p / "project.yaml").exists())
FIRST = ("the first cycle: the history is the initial image, every block called as at the "
         "engine's first scan")


def _export(name: str):
    project = load_project(PROJECTS / name)
    return project, write_st(build(project))


def _properties(project) -> int:
    """How many properties the proof states: two per block instance (its scan's call, after
    a fault reset; the clock's TON among them), the first cycle, six of the program's
    results and the invariant, the initial values."""
    from hmi.export.source import monitors
    from hmi.project.diagnosers import diagnosers_of
    # the control, the filter, the diagnosers, the monitors, the memory (if any)
    blocks = 2 + len(diagnosers_of(project)) + len(monitors(project)) + bool(
        project.timers or project.observers)
    return 2 * (blocks + 1) + 1 + 6 + 1  # (+ 1: the clock)


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_every_exported_program_is_one_engine_scan(name):
    project, text = _export(name)
    start = time.process_time()
    proofs = prove_program(project, text)
    print(f"\n{name}: {len(proofs)} properties, {time.process_time() - start:.1f} s CPU")
    assert len(proofs) == _properties(project)
    assert [f"{p.name}: {p.detail}" for p in proofs if not p.proved] == []


def test_the_valves_program_is_one_engine_scan():
    project, text = _export("cispi_valve")
    proofs = prove_program(project, text)
    assert len(proofs) == _properties(project) == 18
    assert [f"{p.name}: {p.detail}" for p in proofs if not p.proved] == []


def _replacing(old: str, new: str):
    def tamper(prg: str) -> str:
        assert old in prg
        return prg.replace(old, new, 1)
    return tamper


def _swapping(first: str, second: str, end: str):
    """The program with the statements from `first` to `second` and those from `second` to
    `end` (each starting at its comment) in the other order."""
    def tamper(prg: str) -> str:
        a, b, c = prg.index(first), prg.index(second), prg.index(end)
        assert a < b < c
        return prg[:a] + prg[b:c] + prg[a:b] + prg[c:]
    return tamper


def _broken_from(first: str) -> set[str]:
    """What a wrong value handed to the valve's block `first` breaks: that block's calls,
    those of every block after it, and the program's results."""
    blocks = ["Memory", "Diag_V1", "Control", "Filter"]
    return {*(f"{b}: {what}" for b in blocks[blocks.index(first):] for what in (
        "called once, at its point of the scan, with the engine's values",
        "after a fault reset")),
        "the output image: each output the filter's",
        "the image: timers, observers, flags, filtered sensors, FOV_x as the scan wrote them",
        "the monitors' labels and the filter's words",
        "the history: each value kept d scans back, shifted"}


_VALVE = [
    # two block calls swapped: the diagnoser before the memory it reads (TON1, TON2); the
    # memory reads nothing the diagnoser writes: its own call is the same
    ("memory and diagnoser swapped", _swapping(
        "(* 2. Memory", "(* 3-4. Diagnoser V1", "(* 5. The functional control"),
     _broken_from("Diag_V1")),
    # the diagnoser's reset reads the order of the scan before, not the one just ended
    ("the reset reads prev_O", _replacing("C := C, O := O);", "C := C, O := prev_O);"),
     {"Diag_V1: after a fault reset"}),
    # the history not shifted for C
    ("no shift of C", _replacing("prev_C := C;\n", "\n"),
     {"the history: each value kept d scans back, shifted",
      "a call keeps the state invariant (started; each value kept one scan back is its "
      "global)"}),
    # the filter's latch never released
    ("the filter not reset", _replacing("    Filter(Reset := TRUE);\n", "\n"),
     {"Filter: after a fault reset"}),
    # the operator's FaultReset never cleared
    ("FaultReset kept", _replacing("    FaultReset := FALSE;\n", "\n"),
     {"the inputs and the operator's words kept; a fault reset clears FaultReset"}),
    # the first cycle's history: a sensor taken as 0 rather than as first read
    ("the first history of fso", _replacing("    prev_fso := fso;", "    prev_fso := FALSE;"),
     set()),
    # the scan's time read before this cycle's clock call (the last cycle's)
    ("the clock read before its call", _swapping(
        "Clock(IN := TRUE", "Now := Clock.ET;", "(* 2. Memory"),
     _broken_from("Memory")),
    # the filter bypassed: the program's output written to the plant
    ("the filter bypassed", _replacing("O := Filter.O;", "O := FOV_O;"),
     {"the output image: each output the filter's", "Diag_V1: after a fault reset",
      "the history: each value kept d scans back, shifted"}),
]


@pytest.mark.parametrize(("what", "tamper", "refuted"), _VALVE, ids=[c[0] for c in _VALVE])
def test_a_tampered_valve_program_is_refuted(what, tamper, refuted):
    project, text = _export("cispi_valve")
    proofs = prove_program(project, text, tamper)
    failed = {p.name for p in proofs if not p.proved}
    # (every change shows at the first cycle too)
    assert failed == {FIRST, *refuted}
    assert all("counterexample: " in p.detail for p in proofs if not p.proved)


def test_a_monitor_reading_the_current_value_for_the_previous_is_refuted():
    """The conveyor's monitor reads `prev_d` (rise(d)); wired to `d`, this scan's order,
    where the engine reads the order one scan back."""
    project, text = _export("conveyor_robot")
    proofs = prove_program(project, text, _replacing("prev_d := prev_d,", "prev_d := d,"))
    failed = {p.name for p in proofs if not p.proved}
    assert failed == {FIRST, "Mon_conveyor: called once, at its point of the scan, with the "
                      "engine's values", "Mon_conveyor: after a fault reset",
                      "the monitors' labels and the filter's words"}


def test_a_diagnoser_reading_the_order_not_yet_written_is_proved_the_same():
    """The diagnoser reads O one scan back (`O := prev_O`); during the scan, before the
    filter writes O, the global O is that very value (the state invariant: the history's
    newest entry is its global), so `O := O` there is an equivalent program."""
    project, text = _export("cispi_valve")
    proofs = prove_program(project, text, _replacing("        O := prev_O,\n        TON2",
                                                     "        O := O,\n        TON2"))
    assert [p.name for p in proofs if not p.proved] == []


# A small cell that reads values two scans back (no example project does): a timer on
# prev(o0, 2), an observer reset by prev(i1, 2), constraints on prev(i0, 2), prev(o1, 2).
_DEEP = {
    "name": "deep", "scan_period": "10ms",
    "inputs": {"i0": "input 0", "i1": "input 1", "vfsc": "valve closed",
               "vfso": "valve open"},
    "outputs": {"o0": {"description": "output 0", "safe": 0},
                "o1": {"description": "output 1", "safe": 1},
                "vC": "valve close", "vO": "valve open"},
    "timers": {"t0": {"type": "TON", "input": "prev(o0, 2)", "preset": "30ms"}},
    "observers": {"b1": {"set": "i0 and t0", "reset": "prev(i1, 2)", "initial": 1}},
    "control": {"equations": {"o0": "i0", "o1": "b1"}},
    "constraints": {"c0": "o0 and prev(i0, 2)", "c1": "o1 and not prev(o1, 2)"},
    "plant": {"kind": "sim", "model": "valve",
              "ports": {"fsc": "vfsc", "fso": "vfso", "C": "vC", "O": "vO"}},
    "monitors": {"task": {"start": "rise(i0)", "end": "fall(i0)", "normal": ["10ms", "20ms"],
                          "acceptable": ["10ms", "40ms"]}},
}
_SHIFTED = "the history: each value kept d scans back, shifted"
_DEEP_TAMPERED = [
    # the filter given prev_i0 where its constraint reads prev(i0, 2) (the same at the first
    # cycle: both are i0 as first read)
    ("the filter reads prev for prev2", _replacing("prev2_i0 := prev2_i0,", "prev2_i0 := prev_i0,"),
     {"Filter: called once, at its point of the scan, with the engine's values",
      "Filter: after a fault reset", "the output image: each output the filter's",
      "the monitors' labels and the filter's words", _SHIFTED}),
    # the timer's input prev(o0, 2) given prev_o0: the memory, and all that reads its timer
    ("the memory reads prev for prev2", _replacing("prev2_o0 := prev2_o0,",
                                                   "prev2_o0 := prev_o0,"),
     {f"{b}: {what}" for b in ("Memory", "Control", "Filter") for what in (
         "called once, at its point of the scan, with the engine's values",
         "after a fault reset")} | {
        "the output image: each output the filter's",
        "the image: timers, observers, flags, filtered sensors, FOV_x as the scan wrote them",
        "the monitors' labels and the filter's words", _SHIFTED}),
    # the shift in the wrong order: prev2_i0 takes this scan's i0
    ("the shift's order", _replacing("prev2_i0 := prev_i0;\nprev_i0 := i0;",
                                     "prev_i0 := i0;\nprev2_i0 := prev_i0;"), {_SHIFTED}),
    ("the first cycle's prev2", _replacing("    prev2_i0 := i0;", "    prev2_i0 := FALSE;"),
     {FIRST}),
]


@pytest.fixture(scope="module")
def deep(tmp_path_factory):
    import yaml
    folder = tmp_path_factory.mktemp("deep")
    (folder / "project.yaml").write_text(yaml.safe_dump(_DEEP, sort_keys=False))
    project = load_project(folder)
    return project, write_st(build(project))


def test_a_program_reading_two_scans_back_is_one_engine_scan(deep):
    project, text = deep
    proofs = prove_program(project, text)
    assert "prev2_i0 := prev_i0;" in text  # (what the tampering below changes)
    assert [f"{p.name}: {p.detail}" for p in proofs if not p.proved] == []


@pytest.mark.parametrize(("what", "tamper", "refuted"), _DEEP_TAMPERED,
                         ids=[c[0] for c in _DEEP_TAMPERED])
def test_a_tampered_history_two_scans_back_is_refuted(deep, what, tamper, refuted):
    project, text = deep
    proofs = prove_program(project, text, tamper)
    assert {p.name for p in proofs if not p.proved} == refuted
    assert all("counterexample: " in p.detail for p in proofs if not p.proved)
