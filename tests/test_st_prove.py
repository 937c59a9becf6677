"""The symbolic executor of tests/st_prove.py on small function blocks: a path that indexes an
array out of bounds is refuted with a counterexample when some input takes it, and dropped
when none does; a state invariant bounds a loop over kept state (every test here can fail:
the feasible variant of each block is refuted)."""

from __future__ import annotations

import pytest
import z3

from tests.st_prove import (
    Symbolic,
    Unsupported,
    VarType,
    declarations,
    execute_cases,
    in_bounds,
    parse_fb,
)

# K counts up to X (at most 3 passes); at K = 3 the block writes A[3], out of bounds, on the
# path `guard`: infeasible when the guard contradicts K < X, feasible otherwise.
_COUNTING = """FUNCTION_BLOCK FB_T
VAR_INPUT
    X : INT;
END_VAR
VAR
    A : ARRAY[0..2] OF INT;
    K : INT;
END_VAR
K := 0;
WHILE (K < X) AND (K < 3) DO
    K := K + 1;
    IF (K = 3) AND ({guard}) THEN
        A[K] := 1;
    END_IF;
END_WHILE;
END_FUNCTION_BLOCK
"""


@pytest.mark.parametrize(("guard", "proved"), [("X < 3", True), ("X > 4", False)])
def test_a_constant_index_out_of_bounds_is_refuted_only_on_a_path_some_input_takes(guard,
                                                                                  proved):
    cases = execute_cases(parse_fb(_COUNTING.format(guard=guard)), frozenset())
    proof = in_bounds(cases)
    assert proof.proved is proved, proof.detail
    if not proved:
        # the counterexample takes the path: X past 3 and the guard
        value = int(proof.detail.split("X = ")[1].split(",")[0])
        assert value > 4


# `next` counts C up to 2 from its kept value: without a bound on that state the loop has no
# bound the executor can see; with C >= 0 assumed, it runs at most three times.
_KEPT = """FUNCTION_BLOCK FB_K
VAR
    C : ARRAY[0..0] OF INT;
    Runs : INT;
END_VAR
Runs := 0;
WHILE C[0] < 2 DO
    C[0] := C[0] + 1;
    Runs := Runs + 1;
END_WHILE;
END_FUNCTION_BLOCK
"""


def test_a_state_invariant_bounds_a_loop_over_kept_state():
    fb = parse_fb(_KEPT)
    with pytest.raises(Unsupported, match="runs more than"):
        execute_cases(fb, frozenset(), loop_limit=20, unchecked=2)
    decl = declarations(fb)
    assert decl.types["C"].low == 0
    c0 = z3.Int("C[0]")
    (case,) = execute_cases(fb, frozenset(), loop_limit=20, assume=(c0 >= 0,), unchecked=2)
    runs, kept = case.out["RUNS"], case.out["C"][0]
    solver = z3.Solver()
    solver.add(c0 >= 0, z3.Not(z3.And(runs <= 2, kept >= 0, kept == z3.If(c0 < 2, 2, c0))))
    assert solver.check() == z3.unsat
    solver = z3.Solver()  # and the bound is tight: C[0] = 0 runs twice
    solver.add(c0 == 0, runs != 2)
    assert solver.check() == z3.unsat


# A WHILE whose pass first counts a kept element up to 2 (as a next-subset step reading a
# Comb element left from an earlier call does), then steps J to 3: merged at each branch, the
# worlds are out of step and J ends a term over every one of them; split per pass (`stale`),
# each world runs to the loop's end and J is 3 in all of them.
_OUT_OF_STEP = """FUNCTION_BLOCK FB_S
VAR
    C : ARRAY[0..0] OF INT;
    J : INT;
    Runs : INT;
    More : BOOL;
END_VAR
J := 0;
Runs := 0;
More := TRUE;
WHILE More DO
    Runs := Runs + 1;
    IF C[0] < 2 THEN
        C[0] := C[0] + 1;
    ELSE
        J := J + 1;
        More := J < 3;
    END_IF;
END_WHILE;
END_FUNCTION_BLOCK
"""


@pytest.mark.parametrize("stale", [False, True])
def test_a_pass_branching_on_kept_state_runs_once_per_world_to_the_loops_end(stale):
    fb = parse_fb(_OUT_OF_STEP)
    c0 = z3.Int("C[0]")
    (case,) = execute_cases(fb, frozenset(), loop_limit=20, assume=(c0 >= 0,), unchecked=2,
                            stale=frozenset({"C"} if stale else ()))
    runs, j, kept = case.out["RUNS"], case.out["J"], case.out["C"][0]
    solver = z3.Solver()  # the same values either way, for every kept C[0] >= 0
    solver.add(c0 >= 0, z3.Not(z3.And(j == 3, kept == z3.If(c0 < 2, 2, c0),
                                      runs == 3 + z3.If(c0 < 2, 2 - c0, 0))))
    assert solver.check() == z3.unsat
    # split, J is the literal 3 (the worlds agree term for term); merged, a term over them
    assert (z3.is_int_value(j) and j.as_long() == 3) is stale


# A program calling an instance of a block twice: the second call gives A only (B keeps the
# value the first gave it), reads its output between the calls, and the block writes a
# global it reads (VAR_EXTERNAL).
_PROGRAM = """PROGRAM P
VAR_EXTERNAL
    G : INT;
END_VAR
VAR
    Adder : FB_ADD;
    X : INT;
    Y : INT;
END_VAR
Adder(A := 1, B := G);
X := Adder.S;
Adder(A := {second});
Y := Adder.S;
END_PROGRAM
"""


class _Adder:
    """FB_ADD: S := A + B, N counts the calls, the global G counted up too."""

    def __init__(self) -> None:
        self.variables = {v: VarType("INT") for v in ("A", "B", "S", "N")}
        self.reads = self.writes = ("G",)

    def call(self, variables, globals_):
        return ({**variables, "S": variables["A"] + variables["B"], "N": variables["N"] + 1},
                {"G": globals_["G"] + 1})


def test_a_program_calls_block_instances_an_input_not_given_keeping_its_value():
    sym = Symbolic(parse_fb(_PROGRAM.format(second="2")), blocks={"FB_ADD": _Adder()})
    out = sym.run()
    g, n = z3.Int("G"), z3.Int("ADDER.N")  # (the instance's N before)
    solver = z3.Solver()
    solver.add(z3.Not(z3.And(out["X"] == 1 + g, out["Y"] == 2 + g, out["G"] == g + 2,
                             out["ADDER.N"] == n + 2, out["ADDER.B"] == g)))
    assert solver.check() == z3.unsat


def test_a_call_of_a_port_the_block_does_not_have_is_not_modelled():
    with pytest.raises(Unsupported, match="no port"):
        Symbolic(parse_fb(_PROGRAM.format(second="2, C := 3")),
                 blocks={"FB_ADD": _Adder()}).run()
