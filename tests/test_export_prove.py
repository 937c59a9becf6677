"""z3 proves that the exported safety filter, as blark parses it, is the engine's filter for
every input and every state, on every example project (tests/st_prove.py says how).

What is proved, for one call of FB_<P>_Filter with every input (the FOV, the values the
constraints and masks read, Policy as any integer, Reset, Ftc) and every value of the
variables it keeps (Latched, the outputs, every local): the violation word; the block latch;
the fault reset; the monitor and block policies and a clean candidate; under `correct` the
F0/F1 forcing and its conflict, the exact strategy's unique vector (minimum Hamming distance,
fewest outputs switched on, the outputs declared first spared) within MAX_DISTANCE or the
safe state past it (the engine searches without that limit: docs/plc-export.md, "The scan
budget", says where they can differ); the masks; every array index in bounds. The other
blocks are proved in tests/test_export_prove_blocks.py, the program that calls them in
tests/test_export_prove_program.py.
"""

from __future__ import annotations

import time

import pytest

from hmi.export import source
from hmi.export.build import build
from hmi.export.filter_pou import max_distance
from hmi.export.st import write_st
from hmi.project.loader import load_project
from tests.conftest import PROJECTS
from tests.st_prove import prove_filter

pytestmark = pytest.mark.slow  # a long study: tests/conftest.py, _studies_left_out

NAMES = sorted(p.name for p in PROJECTS.iterdir() if (p / "project.yaml").exists())


def _proofs(name: str, tamper=None, at_once: bool = False):
    project = load_project(PROJECTS / name)
    text = write_st(build(project))
    return prove_filter(project, text, max_distance(source.filter_bound(project)), tamper,
                        at_once=at_once)


@pytest.mark.parametrize("name", NAMES)
def test_the_exported_filter_is_the_engines_for_every_input_and_state(name):
    start = time.process_time()
    proofs = _proofs(name)
    print(f"\n{name}: {proofs[0].detail}, {time.process_time() - start:.0f} s CPU")
    failed = [f"{p.name}: {p.detail}" for p in proofs if not p.proved]
    assert not failed, "\n".join(failed)
    assert len(proofs) == 8  # the seven properties and the array bounds


@pytest.mark.parametrize(("old", "new", "refuted"), [
    # the candidate's forcing: F0 and F1 swapped
    ("Mem := (Cand AND NOT F0) OR F1;", "Mem := (Cand AND NOT F1) OR F0;",
     {"correct: the exact strategy's unique vector, masked, or the safe state"}),
    # a context's literal in the detection (the printed violation word): AND read as OR
    ("<> DWORD#16#0) AND NOT prev_G AND NOT e THEN",
     "<> DWORD#16#0) AND NOT prev_G OR NOT e THEN",
     {"the violation word is the constraints violated by the candidate",
      "the block latch is set by a violation and kept",
      "monitor, block and a clean candidate: the candidate, masked, the latch safe"}),
    # the repair applied with OR instead of XOR (an output the repair switches off stays on)
    ("OutV := Mem XOR Best;", "OutV := Mem OR Best;",
     {"correct: the exact strategy's unique vector, masked, or the safe state"}),
])
def test_a_wrong_filter_is_refuted_with_a_counterexample(old, new, refuted):
    """The proof can fail: each tampered filter is refuted, on the properties it breaks. (The
    tie-break inverted is not among them: this cell's two constraints never meet a tie, and
    z3 proves that block equal too; the mutation study lists it.)"""
    def tamper(text: str) -> str:
        assert old in text
        return text.replace(old, new)
    proofs = _proofs("conveyor_robot", tamper)
    assert {p.name for p in proofs if not p.proved} == refuted
    assert all("counterexample" in p.detail for p in proofs if not p.proved)
    # as the mutation study asks: refuted at the first counterexample, named by a property
    # that counterexample breaks (one of those refuted one by one)
    (first,) = _proofs("conveyor_robot", tamper, at_once=True)
    assert not first.proved and first.name in refuted and "counterexample" in first.detail


def test_an_equivalent_change_is_proved_equivalent():
    """`OnCount < BestOn` read as `<=`: a tie then sets Better, which the tie-break just after
    decides again: the same block, proved (the mutation study lists it as equivalent)."""
    def tamper(text: str) -> str:
        return text.replace("(OnCount < BestOn)", "(OnCount <= BestOn)")
    proofs = _proofs("conveyor_robot", tamper)
    assert all(p.proved for p in proofs)
    at_once = _proofs("conveyor_robot", tamper, at_once=True)
    assert [p.name for p in at_once] == [p.name for p in proofs]
    assert all(p.proved for p in at_once)
