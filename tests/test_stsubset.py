"""The tests' ST interpreter is itself right: IEC timers, loops, types, errors.

The export's agreement tests are only as good as this oracle, so it is checked against
behaviour the standard fixes (TON/TOF timing, FOR with BY, EXIT, CASE) and against mistakes
a PLC compiler refuses.
"""

from __future__ import annotations

import pytest

from tests.stsubset import Program, Runtime, StError

CONFIG = """
CONFIGURATION C
    VAR_GLOBAL
        x AT %IX0.0 : BOOL;
        q : BOOL;
        et : TIME;
        n : INT;
        w : DWORD;
    END_VAR
    RESOURCE R ON PLC
        TASK T(INTERVAL := T#10ms, PRIORITY := 1);
        PROGRAM P WITH T : Main;
    END_RESOURCE
END_CONFIGURATION
"""


def run(body: str, decls: str = "", scans=((0, {}),), more: str = "") -> Runtime:
    text = f"""
PROGRAM Main
VAR_EXTERNAL
    x : BOOL; q : BOOL; et : TIME; n : INT; w : DWORD;
END_VAR
VAR
{decls}
END_VAR
{more}
{body}
END_PROGRAM
{CONFIG}"""
    rt = Runtime(Program(text))
    for now, inputs in scans:
        for name, value in inputs.items():
            rt.set(name, value)
        rt.scan(now)
    return rt


def timer(kind: str, preset: str, inputs: list[int]) -> list[tuple[bool, int]]:
    """(Q, ET) of a `kind` timer at each 10 ms scan, IN following `inputs`."""
    rt = run(f"t(IN := x, PT := {preset});\nq := t.Q;\net := t.ET;", f"t : {kind};",
             scans=())
    seen = []
    for k, x in enumerate(inputs):
        rt.set("x", bool(x))
        rt.scan(k * 10_000)
        seen.append((rt.get("q"), rt.get("et")))
    return seen


def test_ton_counts_from_the_rising_edge_and_resets_when_in_falls():
    assert timer("TON", "T#30ms", [0, 1, 1, 1, 1, 1, 0, 1]) == [
        (False, 0), (False, 0), (False, 10_000), (False, 20_000), (True, 30_000),
        (True, 30_000), (False, 0), (False, 0)]


def test_tof_holds_q_for_pt_after_in_falls():
    seen = timer("TOF", "T#20ms", [0, 1, 0, 0, 0, 1, 0])
    assert [q for q, _ in seen] == [False, True, True, True, False, True, True]


def test_loops_case_and_bits():
    rt = run("""
n := 0;
FOR i := 5 TO 1 BY -2 DO
    n := n * 10 + i;
END_FOR;
w := DWORD#16#0;
FOR i := 0 TO 7 DO
    IF i = 3 THEN EXIT; END_IF;
    w := w OR SHL(DWORD#16#1, i);
END_FOR;
k := 0;
WHILE k < 4 DO k := k + 1; END_WHILE;
CASE k OF
    1, 2: q := FALSE;
    4: q := TRUE;
ELSE
    q := FALSE;
END_CASE;
""", "i : INT; k : INT;")
    assert rt.get("n") == 531 and rt.get("w") == 0b111 and rt.get("q") is True


@pytest.mark.parametrize("body,fragment", [
    ("q := w;", "assigning a DWORD to a BOOL"),
    ("n := T#1s;", "assigning a TIME to a INT"),
    ("q := x AND w;", "BOOL AND DWORD"),
    ("IF n THEN q := TRUE; END_IF;", "a condition of type INT"),
    ("z := TRUE;", "unknown name Z"),
    ("c := 2;", "cannot assign"),
    ("t.Q := TRUE;", "cannot assign"),
    ("t(IN := x, XX := T#1s);", "has no input XX"),
    ("q := w < w;", "DWORD < DWORD"),
    ("EXIT;", "EXIT outside a loop"),
])
def test_the_type_checks_refuse_what_a_plc_compiler_refuses(body, fragment):
    with pytest.raises(StError, match=fragment):
        run(body, "t : TON;", more="VAR CONSTANT c : INT := 1; END_VAR")


def test_run_time_errors_are_reported():
    with pytest.raises(StError, match="overflow"):
        run("n := 32767; n := n + 1;")
    with pytest.raises(StError, match="outside"):
        run("a[n + 3] := TRUE;", "a : ARRAY[0..2] OF BOOL;")
    with pytest.raises(StError, match=r"index 3 outside \[0\.\.2\]"):  # a literal index too
        run("a[3] := TRUE;", "a : ARRAY[0..2] OF BOOL;")
    with pytest.raises(StError, match=r"index 0 outside \[1\.\.3\]"):
        run("n := a[n];", "a : ARRAY[1..3] OF INT;")


def test_arrays_with_a_lower_bound_hold_each_element_where_it_is_indexed():
    rt = run("a[1] := 5; a[n + 2] := 6; a[3] := a[1] + a[2]; n := a[n + 3];",
             "a : ARRAY[1..3] OF INT;")
    assert rt.get("n") == 11
    assert rt.get("P.a") == [5, 6, 11]


def test_a_syntax_error_names_its_line():
    with pytest.raises(StError, match="line 3"):
        Program("PROGRAM Main\nVAR x : BOOL; END_VAR\nx := ;\nEND_PROGRAM\n")
