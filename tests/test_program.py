"""The scan program's rules (hmi/program/), each run in both forms printed from its one
lowering: the reference evaluator (hmi.program.evaluate) and the Python the compiled scan
runs (hmi.engine.codegen.print_program, built through codegen's checker). Both must give the
same image and the same state at every step, and the rule's own truth table."""

from __future__ import annotations

import itertools
import operator
from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hmi.engine.codegen import Source, build, print_program
from hmi.logic.expr import Var
from hmi.logic.timers import TimerRuntime
from hmi.program.evaluate import evaluator
from hmi.program.ir import Stmt
from hmi.program.memories import lower_assign, lower_memory
from hmi.program.timers import lower_timer

Runner = Callable[[list, int], None]


@pytest.fixture(autouse=True, scope="module")
def _printed_names() -> None:
    """The names the lowerings tested here print, allowed as an engine allows its stages'
    (hmi.engine.codegen.allow): a run of this module alone builds no engine first."""
    from hmi.engine.codegen import allow
    from hmi.engine.compiled import FRAME
    from hmi.engine.control import ControlRuntime
    from hmi.engine.diagnoser import DiagnosisStage
    from hmi.engine.filter import SafetyFilter
    from hmi.engine.monitors import MonitorStage
    from hmi.engine.recovery import RecoveryStage
    from hmi.engine.stages import Memory

    allow(FRAME.union(*(stage.PRINTED for stage in (
        Memory, ControlRuntime, DiagnosisStage, RecoveryStage, MonitorStage, SafetyFilter))))


def both_forms(program: tuple[Stmt, ...], slots: dict[str, int]) -> dict[str, Runner]:
    """`program` as the evaluator runs it and as the compiled scan runs it."""
    run_evaluated = evaluator(program, slots, {})
    src = Source()
    print_program(src, program, 1, slots, {})
    printed = build(src, "scan", "v, h, now", "<test_program>")
    return {"evaluator": lambda image, now: run_evaluated(image, (), now),
            "python": lambda image, now: printed(image, (), now)}


def timer_outputs(kind: str, steps: list[tuple[bool, int]]) -> list[bool]:
    """Q at each (IN, now) of a timer of preset 100, in both forms, with the same Q in the
    image and the runtime, and the same state, at every step."""
    ran = []
    for form in ("evaluator", "python"):
        runtime = TimerRuntime("T", kind, 100)
        run = both_forms(lower_timer(runtime, 1, Var(0, "IN", 0)), {"IN": 0, "T": 1})[form]
        image = [False, False]
        seen = []
        for x, now in steps:
            image[0] = x
            run(image, now)
            assert image[1] == runtime.q
            seen.append((runtime.q, runtime.since, runtime.elapsed(now)))
        ran.append(seen)
    assert ran[0] == ran[1]
    return [q for q, _, _ in ran[0]]


def test_ton_rises_after_preset_and_resets_when_input_drops():
    assert timer_outputs("TON", [(True, 0), (True, 99), (True, 100), (True, 150), (False, 160),
                                 (True, 170), (True, 269), (True, 270)]) == [
        False, False, True, True, False, False, False, True]


def test_tof_holds_for_preset_after_input_falls():
    assert timer_outputs("TOF", [(False, 0), (True, 10), (False, 20), (False, 119),
                                 (False, 120), (True, 130), (False, 140), (True, 200),
                                 (False, 210), (False, 309), (False, 310)]) == [
        False, True, True, True, False, True, True, True, True, True, False]


SLOTS = {"S": 0, "R": 1, "X": 2}


@pytest.mark.parametrize("set_dominant", [False, True])
def test_a_memory_follows_its_truth_table_in_both_forms(set_dominant):
    program = lower_memory(2, Var(0, "S", 0), Var(0, "R", 0), set_dominant)
    for form, run in both_forms(program, SLOTS).items():
        for s, r, x in itertools.product((False, True), repeat=3):
            image = [s, r, x]
            run(image, 0)
            held = x and not r
            want = (s or held) if set_dominant else (not r and (s or x))
            assert image[2] == want, (form, s, r, x)
            assert image[:2] == [s, r]


def test_an_assignment_in_both_forms():
    for form, run in both_forms(lower_assign(2, Var(0, "S", 0)), SLOTS).items():
        for s in (False, True):
            image = [s, False, not s]
            run(image, 0)
            assert image[2] == s, form


class _Handler:
    """What an engine frame calls: a method that raises when told to (step), one that
    records (take); named as the checker of generated code allows."""

    def __init__(self) -> None:
        self.seen: list[object] = []

    def step(self, x: int) -> int:
        if x < 0:
            raise KeyError(x)
        if x == 0:
            raise ValueError("zero")
        return x + 1

    def take(self, what: object) -> None:
        self.seen.append(what)


@pytest.mark.parametrize("x", [-1, 0, 1, 5])
def test_try_and_return_in_both_forms(x):
    """An engine frame's Try (handlers tried in order, the exception bound to a local, the
    rest of the body skipped) and Return (leaving the function from inside a Try's body or
    a handler) mean the same in the evaluator and in the printed Python; an exception no
    handler names goes out of both."""
    from hmi.engine.codegen import build_function
    from hmi.program import ir
    from hmi.program.evaluate import function_evaluator

    results = []
    for form in ("evaluator", "python"):
        handler = _Handler()
        y, exc = ir.Local("y"), ir.Local("exc")
        body = (
            ir.Try((ir.Assign(y, ir.Call(handler, "step", (ir.Local("x"),))),
                    ir.If(ir.Compare(">", y, ir.Const(3)), (ir.Return(y),)),
                    ir.Do(ir.Call(handler, "take", (y,)))),
                   ((ValueError, "exc", (ir.Do(ir.Call(handler, "take", (exc,))),
                                         ir.Return(ir.Const(7)))),)),
            ir.Do(ir.Call(handler, "take", (ir.Const(99),))),
        )
        function = ir.Function("frame", ("x",), body, ir.Const(0))
        run = (function_evaluator(function, {}, {}) if form == "evaluator"
               else build_function(function, {}, {}, "test_program"))
        try:
            result: object = run(x)
        except KeyError as raised:
            result = ("raised", raised.args)
        results.append((result, [s if isinstance(s, int) else repr(s)
                                 for s in handler.seen]))
    assert results[0] == results[1]
    expected = {-1: (("raised", (-1,)), []), 0: (7, ["ValueError('zero')"]),
                1: (0, [2, 99]), 5: (6, [])}
    assert results[0] == expected[x]


class _Constraints:
    """A project's constraint table, a function of it (`function_of`) in both forms, and
    random images and histories over the names its contexts read."""

    def __init__(self, name: str, function_of: Callable) -> None:
        import random

        from hmi.engine.codegen import build_function
        from hmi.program.constraints import lower_constraints
        from hmi.program.evaluate import function_evaluator
        from hmi.project.loader import load_project
        from tests.conftest import PROJECTS

        self.table = table = lower_constraints(load_project(PROJECTS / name))
        self.names = sorted({lit.name for row in table.rows for lit in row.context})
        self.slots = {n: k for k, n in enumerate(self.names)}
        self.depth = max((lit.depth for row in table.rows for lit in row.context), default=0)
        function = function_of(table)
        self.forms = (function_evaluator(function, self.slots, {}),
                      build_function(function, self.slots, {}, "test_program"))
        self.rng = random.Random(32)

    def situation(self) -> tuple[list[bool], list[list[bool]]]:
        rng = self.rng
        return ([rng.random() < 0.5 for _ in self.names],
                [[rng.random() < 0.5 for _ in self.names] for _ in range(max(self.depth, 1))])

    def active(self, row, v, h) -> bool:
        return all((v if lit.depth == 0 else h[lit.depth - 1])[self.slots[lit.name]]
                   == lit.positive for lit in row.context)


@pytest.mark.parametrize("name", ["cispi_valve", "cispi_subsystem", "sorting"])
def test_the_active_constraints_in_both_forms(name):
    """Which constraints are active (the corrector's memory key, the PLC filter's word Act),
    printed and evaluated from the one lowering, against each row's context read literal by
    literal, on seeded random images and histories; a row without a context is always
    active."""
    from hmi.program.constraints import active_function

    c = _Constraints(name, active_function)
    seen = set()
    for _ in range(400):
        v, h = c.situation()
        want = sum(1 << j for j, row in enumerate(c.table.rows) if c.active(row, v, h))
        assert [form(v, h) for form in c.forms] == [want, want]
        seen.add(want)
    assert len(seen) > 1  # the contexts were exercised, not one word throughout


@pytest.mark.parametrize("name", ["cispi_valve", "cispi_subsystem", "sorting"])
def test_the_violation_word_in_both_forms(name):
    """Which constraints a candidate violates (the filter's first question, the PLC filter's
    word Violations), printed and evaluated from the one lowering, against each row's masks
    and context, on seeded random candidates, images and histories."""
    from hmi.program.constraints import violations_function

    c = _Constraints(name, violations_function)
    rows, rng = c.table.rows, c.rng
    seen = set()
    for _ in range(400):
        v, h = c.situation()
        # mostly candidates that make some row's output literals true
        row = rng.choice(rows)
        f = tuple(bool(row.pos >> k & 1) if (row.pos | row.neg) >> k & 1
                  else rng.random() < 0.5 for k in range(len(c.table.outputs)))
        packed = sum(1 << k for k, value in enumerate(f) if value)
        want = sum(1 << j for j, r in enumerate(rows) if packed & r.pos == r.pos
                   and not packed & r.neg and c.active(r, v, h))
        assert [form(v, h, f) for form in c.forms] == [want, want]
        seen.add(want)
    assert len(seen) > 2 and 0 in seen  # rows violated and not, not one word throughout


def test_the_policy_in_both_forms():
    """The policy (hmi.program.constraints.lower_policy), printed and evaluated, for every
    code, latch and word: `block` calls its handler when latched or violated, any other code
    but monitor corrects a violated candidate, monitor reports it, and a clean candidate
    with no latch calls nothing (None)."""
    from hmi.engine.codegen import build_function
    from hmi.program.constraints import (
        BLOCK,
        CORRECT,
        MONITOR,
        policy_function,
    )
    from hmi.program.evaluate import function_evaluator

    class Handler:
        def blocked(self, v, h, f, w, latched):
            return ("blocked", f, w, latched)

        def corrected(self, v, h, f, w):
            return ("corrected", f, w)

        def monitored(self, f, w):
            return ("monitored", f, w)

    handler = Handler()
    function = policy_function(handler)
    forms = (function_evaluator(function, {}, {}),
             build_function(function, {}, {}, "test_program"))
    f = (True, False)
    for p, latched, w in itertools.product((MONITOR, BLOCK, CORRECT, 7), (False, True),
                                           (0, 0b101)):
        if p == BLOCK:
            want = ("blocked", f, w, latched) if latched or w else None
        elif w:
            want = ("monitored", f, w) if p == MONITOR else ("corrected", f, w)
        else:
            want = None
        assert [form([], (), f, w, p, latched) for form in forms] == [want, want], (p, latched, w)


_LITERALS = [(k, positive) for k in range(4) for positive in (True, False)]


@settings(max_examples=150, deadline=None)
@given(st.lists(st.lists(st.sampled_from(_LITERALS), min_size=1, max_size=4),
                min_size=3, max_size=12))
def test_a_word_of_bits_printed_grouped_is_the_same_word(terms):
    """The printer gathers the ifs that or bits into one word (the violation word, the
    active constraints) under the first operand of their tests, recursively
    (codegen._grouped); printed that way the word is the evaluator's for every assignment of
    the operands, tests repeated, prefixes of each other or alone included."""
    from hmi.engine.codegen import build_function
    from hmi.program import ir
    from hmi.program.evaluate import function_evaluator

    f, w = ir.Local("f"), ir.Local("w")

    def literal(k: int, positive: bool) -> ir.Value:
        return ir.Item(f, k) if positive else ir.Not(ir.Item(f, k))

    body = (ir.Assign(w, ir.Const(0)),
            *(ir.If(ir.all_of(*(literal(k, p) for k, p in term)),
                    (ir.Assign(w, ir.BitOr(w, ir.Bit(j))),)) for j, term in enumerate(terms)))
    function = ir.Function("violated", ("f",), body, w)
    forms = (function_evaluator(function, {}, {}),
             build_function(function, {}, {}, "test_program"))
    for f_values in itertools.product((False, True), repeat=4):
        want = sum(1 << j for j, term in enumerate(terms)
                   if all(f_values[k] == p for k, p in term))
        assert [form(f_values) for form in forms] == [want, want]


class _Task:
    """A monitor's automaton as the printed code sees it: its phase, compared by identity."""

    def __init__(self, phase: object) -> None:
        self.phase = phase


@pytest.mark.parametrize("read_after", [False, True])
@pytest.mark.parametrize("idle", [False, True])
def test_a_cell_tested_by_identity_is_printed_without_its_local_where_nothing_reads_it(
        idle, read_after):
    """``p = cell; if p is x: A else: B`` (a monitor's phase test) is printed as ``if cell
    is x: A else: p = cell; B`` when nothing after reads p, as it is otherwise; both print
    what the evaluator does."""
    from hmi.engine.codegen import Vocabulary, allow, build_function
    from hmi.program import ir
    from hmi.program.evaluate import function_evaluator

    allow(Vocabulary(frozenset({"phase"}), frozenset({"p"})))
    waiting, working = object(), object()
    results, texts = [], []
    for form in ("evaluator", "python"):
        handler, task = _Handler(), _Task(waiting if idle else working)
        p = ir.Local("p")
        body = (ir.Assign(p, ir.Cell(task, "phase")),
                ir.If(ir.Compare("is", p, ir.Ref(waiting)),
                      (ir.Do(ir.Call(handler, "take", (ir.Const(1),))),),
                      (ir.Do(ir.Call(handler, "take", (p,))),)),
                *((ir.Do(ir.Call(handler, "take", (p,))),) if read_after else ()))
        function = ir.Function("frame", ("x",), body)
        if form == "evaluator":
            run = function_evaluator(function, {}, {})
        else:
            run = build_function(function, {}, {}, "test_program")
            texts.append(run.__doc__ or "")
        run(0)
        results.append([s if isinstance(s, int) else s is working for s in handler.seen])
    assert results[0] == results[1] == ([1] if idle else [True]) + (
        [idle is False] if read_after else [])
    lines = texts[0].splitlines()
    assert (lines[1].strip() == "p = k0.phase") is read_after, texts[0]
    assert ("if k0.phase is k1:" in texts[0]) is not read_after, texts[0]


@settings(max_examples=200, deadline=None)
@given(st.integers(-10**7, 10**7), st.integers(-10**7, 10**7), st.integers(0, 10**7),
       st.integers(0, 10**7), st.sampled_from(["<", "<=", ">", ">=", "==", "!="]))
def test_a_sum_with_a_difference_against_a_constant_is_printed_folded(a, b, c1, c2, op):
    """``a + (c1 - b) op c2`` (a monitor's cannot-finish rule) is printed ``(a - b) op
    c2 - c1`` (unless that constant is negative: printed code holds none): the same truth as
    the evaluator's, on any integers."""
    from hmi.engine.codegen import Vocabulary, allow, build_function
    from hmi.program import ir
    from hmi.program.evaluate import function_evaluator

    allow(Vocabulary(locals=frozenset({"x", "y"})))
    x, y = ir.Local("x"), ir.Local("y")
    test = ir.Compare(op, ir.Add(x, ir.Sub(ir.Const(c1), y)), ir.Const(c2))
    function = ir.Function("frame", ("x", "y"), (), test)
    printed = build_function(function, {}, {}, "test_program")
    folded = f"(x - y) {op} {c2 - c1}" in (printed.__doc__ or "")
    assert folded is (c2 >= c1)
    expected = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge,
                "==": operator.eq, "!=": operator.ne}[op](a + (c1 - b), c2)
    assert printed(a, b) == function_evaluator(function, {}, {})(a, b) == expected


def test_a_function_without_parameters_is_built_and_runs_as_evaluated():
    """A function of no parameters that calls a handler prints ``def f(k0=k0)`` (the
    handler bound as a default), not ``def f(, k0=k0)``; it runs as the evaluator does."""
    from hmi.engine.codegen import build_function
    from hmi.program import ir
    from hmi.program.evaluate import function_evaluator

    class Handler:
        def __init__(self) -> None:
            self.calls = 0

        def take(self) -> int:
            self.calls += 1
            return 7

    results = []
    for form in ("evaluator", "python"):
        handler = Handler()
        function = ir.Function("tick", (), (ir.Do(ir.Call(handler, "take")),),
                               ir.Call(handler, "take"))
        run = (function_evaluator(function, {}, {}) if form == "evaluator"
               else build_function(function, {}, {}, "test_program"))
        results.append((run(), handler.calls))
    assert results == [(7, 2), (7, 2)]
