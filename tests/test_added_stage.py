"""A stage added to the mode's program is its lowering, its handler and its class named in
hmi.engine.program_stages.ADDED (and, for the PLC, its block's builder in
hmi.export.stage_blocks.BLOCKS): the engine builds it, runs its part where it declares in
both forms, and the exported PLC program calls its block at the same place. The stage here
counts the scans and, every fifth, calls its handler (a rare event)."""

from __future__ import annotations

import re

import pytest

from hmi.engine import program_stages
from hmi.engine.codegen import Vocabulary
from hmi.engine.commands import FaultReset
from hmi.engine.layout import Layout
from hmi.engine.program_stages import Declaration, Moment, Publication, declared
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot, StageState
from hmi.export import model as m
from hmi.export import stage_blocks
from hmi.export.build import build
from hmi.export.names import Scope
from hmi.export.program_st import DINT, Handler, NotPrintable, Place, Places, StPrinter
from hmi.export.st import write_st
from hmi.export.views import Block, Durations
from hmi.plant.sim.plant import SimPlant
from hmi.program import ir, order
from hmi.project.loader import load_project
from hmi.project.model import Project
from hmi.wire import messages
from tests.conftest import PROJECTS

PART = "counting"


class Counting:
    """The handler: the count (its state) and what happens every fifth scan."""

    PLACE = (PART, order.DIAGNOSERS)
    PRINTED = Vocabulary(frozenset({"count", "fifth"}))
    depth = 0

    def __init__(self) -> None:
        self.count = 0
        self.fifths: list[int] = []
        count = ir.Cell(self, "count")
        # the lowering: one more scan; every fifth, the handler
        self.program: tuple[ir.Stmt, ...] = (
            ir.Assign(count, ir.Add(count, ir.Const(1))),
            ir.If(ir.Compare("==", count, ir.Const(5)),
                  (ir.Assign(count, ir.Const(0)), ir.Do(ir.Call(self, "fifth", (ir.Now(),))))),
        )

    @property
    def parts(self) -> dict[str, tuple[ir.Stmt, ...]]:
        return {PART: self.program}

    def fifth(self, now: int) -> None:
        self.fifths.append(now)

    # what a fault reset, an exploration's capture/restore and the snapshot ask of it
    def reset(self, moment: Moment) -> list[str]:
        if not self.count:
            return []
        self.count = 0
        return [f"the count restarted at scan {moment.scan}"]

    def capture(self) -> tuple[int, tuple[int, ...]]:
        return self.count, tuple(self.fifths)

    def restore(self, state: tuple[int, tuple[int, ...]]) -> None:
        self.count, fifths = state
        self.fifths = list(fifths)

    def state(self) -> int:
        return self.count

    @classmethod
    def build(cls, project: Project, layout: Layout) -> Counting:
        return cls()


def counting_block(stage: Counting, layout: Layout, name: str, scope: Scope,
                   durations: Durations) -> Block:
    """Its ST handler: the count a DINT of the block, the fifth scan a comment; a fault
    reset sets the count to 0."""
    sc = scope.child()
    count, reset = sc.take("Count"), sc.take("Reset")
    places = Places(slot=_no_slot, read=_no_read, step_time=_no_read, now=m.Name("Now"))
    places.cell(stage, "count", Place(count, DINT))
    places.handler(stage, "fifth", Handler(print=lambda printer, args: [
        m.Comment("a fifth scan")]))
    body = StPrinter(places, sc, durations, None, "the counting stage").program(stage.program)
    blocks = (m.VarBlock("input", (m.Var("Now", m.TIME), m.Var(reset, m.BOOL))),
              m.VarBlock("local", (m.Var(count, m.DINT),)))
    reset_or_scan = m.if_(m.Name(reset), m.Assign(m.Name(count), m.IntLit(0)),
                          orelse=tuple(body))
    return Block(m.Pou(name, "functionBlock", blocks, (reset_or_scan,), "counts the scans"),
                 {}, {}, {"Now": "Now", "Reset": reset})


def _no_slot(index: int) -> Place:
    raise NotPrintable("no slot")


def _no_read(*args: object) -> m.Expr:
    raise NotPrintable("no read")


@pytest.fixture
def added(monkeypatch):
    monkeypatch.setattr(program_stages, "ADDED", (Counting,))
    monkeypatch.setitem(stage_blocks.BLOCKS, Counting, counting_block)


@pytest.mark.parametrize("compiled", [True, False])
def test_an_added_stage_runs_where_it_declares_in_both_forms(added, compiled):
    project = load_project(PROJECTS / "cispi_subsystem")
    engine = Engine(project, SimPlant(project), compiled=compiled)
    (stage,) = engine.added
    assert isinstance(stage, Counting)
    program = engine.compiled.program
    parts = program.order
    assert parts.index(PART) == parts.index(order.DIAGNOSERS) + 1
    assert program.parts[PART] == stage.program
    period = project.scan_period_us
    for k in range(23):
        engine.step(k * period)
    assert stage.count == 23 % 5
    assert stage.fifths == [k * period for k in (4, 9, 14, 19)]


@pytest.mark.parametrize("compiled", [True, False])
def test_an_added_stage_is_reset_captured_and_shown_by_its_declaration(added, compiled):
    project = load_project(PROJECTS / "cispi_subsystem")
    engine = Engine(project, SimPlant(project), compiled=compiled)
    (stage,) = engine.added
    period = project.scan_period_us
    shown = [engine.step(k * period).stages for k in range(7)]
    # the snapshot shows its state at the end of each scan, by its role
    assert shown == [((PART, (k + 1) % 5),) for k in range(7)]
    # and a screen receives it (hmi.wire)
    snap = engine.snapshot()
    wire = messages.codec(layout=lambda: engine.layout)
    assert wire.loads(wire.dumps(snap, Snapshot), Snapshot).stages == ((PART, 2),)
    # the fault reset resets it and says so
    said = engine.apply(FaultReset()).message
    assert "the count restarted at scan 7" in said and stage.count == 0
    assert engine.apply(FaultReset()).message == "fault reset: nothing was latched"

    # capture, run on, restore: the same scans again, the stage's state included
    def run_on(start: int) -> list[tuple[object, ...]]:
        return [(snap.stages, snap.values, snap.outputs)
                for snap in (engine.step(k * period) for k in range(start, start + 9))]

    state = engine.capture()
    first = run_on(7)
    assert stage.fifths == [4 * period, 11 * period]
    engine.restore(state)
    assert stage.count == 0 and stage.fifths == [4 * period]
    assert run_on(7) == first
    assert stage.fifths == [4 * period, 11 * period]


class Laps(Counting):
    """The counting stage, whose laps (every fifth scan) make a scan news."""

    PRINTED = Vocabulary(frozenset({"count", "fifth", "laps"}))

    def __init__(self) -> None:
        super().__init__()
        self.laps: tuple[StageState, ...] = ()  # a new object at each lap only

    def fifth(self, now: int) -> None:
        super().fifth(now)
        self.laps = (StageState(PART, len(self.fifths)),)


def _laps(stage: Laps, image: object, history: object, now: int) -> tuple[StageState, ...]:
    return stage.laps


# Its declaration: the added stage's, and what it gives a scan with news (Snapshot.stages),
# what a quiet scan gives (its laps, unchanged) and no test of its own for the printed frame
LAPS: Declaration[Laps] = Declaration(
    PART, lambda c: Laps(), place=Laps.PLACE,
    news=Publication("stages", _laps, "reading the laps", lambda stage: (),
                     lambda stage, diagnosis: (None, ir.Cell(stage, "laps"))))


def _news(engine: Engine, scans: int) -> list[int]:
    """The scans Engine.run says have news, of `scans` from 0 on."""
    period = engine.project.scan_period_us
    return [k for k in range(scans) if engine.run(k * period)]


@pytest.mark.parametrize("compiled", [True, False])
def test_what_a_declared_stage_publishes_decides_news_in_both_paths(monkeypatch, compiled):
    """A declaration's `news`, with no edit of the engine or of the printed frame: the scans
    with news are those the cell has anyway and those where the stage gave something new;
    its snapshot field shows what it gave. Both of the engine's paths: the printed frame
    (compiled, scans untimed) and the general one."""
    project = load_project(PROJECTS / "cispi_subsystem")
    monkeypatch.setattr(program_stages, "ADDED", (Counting,))
    plain = Engine(project, SimPlant(project), compiled=compiled)
    monkeypatch.setattr(program_stages, "ADDED", (LAPS,))
    engine = Engine(project, SimPlant(project), compiled=compiled)
    assert engine.compiled.program.parts[PART] == engine.added[0].program
    for e in (plain, engine):
        e.wall_times = False  # (the printed frame runs untimed scans)
    scans = 60
    without, with_laps = _news(plain, scans), _news(engine, scans)
    laps = [k for k in range(scans) if k % 5 == 4]
    assert set(with_laps) == set(without) | set(laps)
    assert set(laps) - set(without)  # (the laps alone made some scans news)
    assert engine.snapshot().stages == ((PART, len(laps)),)
    # the frame printed the stage's quiet value, and no test of its own
    assert not compiled or any("laps" in source for source in engine.compiled.sources)
    # an AddedStage class declares no news: what it shows is no news
    assert declared(Counting).news is None


def test_an_added_stage_is_called_by_the_plc_program_at_its_place(added):
    text = write_st(build(load_project(PROJECTS / "cispi_subsystem")))
    program = text[text.index("PROGRAM PRG_"):]
    calls = [line.strip().split("(")[0] for line in program.splitlines()
             if re.match(r"\s*\w+\(", line)]
    # the scan's calls, in order (before the fault reset's): the diagnosers, then the stage
    scan = calls[:calls.index("Filter") + 1]
    assert scan == ["Clock", "Memory", "Diag_V1", "Diag_V2", "Stage_counting", "Control",
                    "Filter"]
    assert "Stage_counting : FB_cispi_subsystem_Counting;" in program
    block = text[text.index("FUNCTION_BLOCK FB_cispi_subsystem_Counting"):]
    assert "Count := Count + 1;" in block and "(* a fifth scan *)" in block
    # a fault reset calls it again with Reset, after the scan
    assert "Stage_counting(Now := Now, Reset := FALSE);" in program
    fault_reset = program[program.index("IF FaultReset THEN"):]
    assert "Stage_counting(Reset := TRUE);" in fault_reset


def test_an_added_part_is_placed_once_after_a_part_of_the_scan():
    assert order.placed(order.PROGRAM, [("a", order.MEMORY), ("b", order.MEMORY),
                                        ("c", "a")])[:4] == (order.MEMORY, "a", "c", "b")
    with pytest.raises(ValueError, match="already"):
        order.placed(order.PROGRAM, [(order.LAW, order.MEMORY)])
    with pytest.raises(ValueError, match="not a part"):
        order.placed(order.PROGRAM, [("a", "nowhere")])
