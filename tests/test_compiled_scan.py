"""The compiled scan (hmi/engine/compiled.py: the scan program printed as Python) against the
program's evaluator (hmi/program/evaluate.py), the reference.

Every example project runs twice on its simulated plant, once with the printed scan program
and once with its evaluator (``Engine(compiled=False)``), under the same seeded random
script: a control variant, a policy and a diagnosis mode drawn at the start, then operator
commands at random scans (manual mode and manual orders, policy changes, fault injections
and repairs, fault resets, devices stopped and released, recoveries started and left).
Every deterministic field of every snapshot must be the same (only the measured wall times
differ). The reference also searches every correction afresh, where the compiled engine's
filter gives again a correction it found before (SafetyFilter.remember). The golden traces
(tests/test_golden.py) pin the recorded behaviour; this test pins
the two implementations to each other in situations no golden case scripts.
"""

from __future__ import annotations

import io
import keyword
import random
import re
import tokenize
from collections import deque
from functools import cache

import pytest

from hmi.engine import commands as cmd
from hmi.engine.codegen import PARAMETERS, Source, build
from hmi.engine.diagnoser import MODES
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot
from hmi.logic.expr import compile_bool
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.loader import load_project
from hmi.project.model import POLICIES, Project
from hmi.project.recovery import recoveries_of
from hmi.session.view import CellView
from tests.conftest import PROJECTS

NAMES = ("cispi_valve", "sorting", "palletizer", "conveyor_robot", "cispi_subsystem")
SCANS = 1500


@cache
def load(path):
    return load_project(path)


def comparable(snap: Snapshot) -> Snapshot:
    """The snapshot without what is measured rather than computed."""
    report = snap.filter_report
    if report is not None:
        report = report._replace(solver_us=0.0)
    return snap._replace(scan_wall_us=0.0, filter_wall_us=0.0, filter_report=report)


def comparable_cell(cell: CellView) -> CellView:
    """The session's view of a scan without what is measured: its snapshot's, and the
    time explaining it took."""
    return cell._replace(snapshot=comparable(cell.snapshot), explain_wall_us=0.0)


def random_command(rng: random.Random, project: Project, engine: Engine, now: int
                   ) -> cmd.Command:
    outputs = [v.name for v in project.outputs]
    devices = sorted(engine.devices)
    recoveries = [r.name for r in recoveries_of(project)]
    faults = engine.plant.faults()
    choices: list[cmd.Command] = [
        cmd.SetMode(True), cmd.SetMode(False), cmd.FaultReset(),
        cmd.ManualOutput(rng.choice(outputs), rng.choice((True, False, None))),
        cmd.SetPolicy(rng.choice(POLICIES)), cmd.RepairFaults(),
    ]
    if faults:
        device, code, _ = rng.choice(faults)
        at = now + rng.randrange(0, 2_000_000)
        choices.append(cmd.InjectFault(Injection(code, at, device)))
    if devices:
        choices += [cmd.StopDevice(rng.choice(devices)), cmd.ReleaseDevice(rng.choice(devices))]
    if recoveries:
        choices += [cmd.StartRecovery(rng.choice(recoveries)), cmd.EndRecovery()]
    return rng.choice(choices)


def twin_run(name: str, seed: int) -> int:
    """Run both engines under one script; return how many scans were compared."""
    project = load(PROJECTS / name)
    rng = random.Random(seed)
    control = rng.choice(sorted(project.controls))
    policy = rng.choice(POLICIES)
    diagnosis = rng.choice(MODES)
    engines = [Engine(project, SimPlant(project), control=control, policy=policy,
                      diagnosis=diagnosis, compiled=flag) for flag in (True, False)]
    assert engines[0].compiled.python and not engines[1].compiled.python
    engines[1].safety_filter.remember = False  # the reference searches every correction afresh
    period = project.scan_period_us
    seen: tuple[int, tuple] | None = None
    for k in range(SCANS):
        now = k * period
        if k and rng.random() < 0.02:
            command = random_command(rng, project, engines[1], now)
            results = [e.apply(command) for e in engines]
            assert results[0] == results[1], (name, seed, k, command)
        fast, reference = (e.step(now) for e in engines)
        for engine, snap in zip(engines, (fast, reference), strict=True):
            check_active_bits(engine)
            check_violations(engine, snap.fov)
            check_violations(engine, tuple(rng.random() < 0.5 for _ in snap.fov))
        if comparable(fast) != comparable(reference):
            for field in Snapshot._fields:
                a, b = getattr(comparable(fast), field), getattr(comparable(reference), field)
                assert a == b, f"{name} seed {seed} scan {k}: {field} differs: {a!r} != {b!r}"
        seen = check_marks(fast, seen)
    return SCANS


_CONTEXTS: dict[int, tuple[Engine, list]] = {}


def _contexts(engine: Engine) -> list:
    """Each constraint's context as hmi.logic.expr compiles it (None: always active): the
    reference the scan program's words are checked against."""
    found = _CONTEXTS.get(id(engine))
    if found is None or found[0] is not engine:
        layout = engine.layout
        found = _CONTEXTS[id(engine)] = (engine, [
            None if row.context_node is None
            else compile_bool(row.context_node, layout.slots, layout.step_times)
            for row in engine.safety_filter.table.rows])
    return found[1]


def check_active_bits(engine: Engine) -> None:
    """active_bits (the corrector's memory key), printed or evaluated, against the contexts
    as hmi.logic.expr evaluates them."""
    image, history = engine.image, engine.history
    expected = sum(1 << k for k, context in enumerate(_contexts(engine))
                   if context is None or context(image, history))
    # (the compiled scan's form, handed to the filter stage: FilterStage.bind)
    assert engine.safety_filter.active_bits is engine.compiled.functions["active_bits"]
    assert engine.safety_filter.active_bits(image, history) == expected


def check_violations(engine: Engine, candidate: tuple[bool, ...]) -> None:
    """The violation word of `candidate`, printed or evaluated, against each row's masks and
    context."""
    image, history = engine.image, engine.history
    packed = sum(1 << k for k, value in enumerate(candidate) if value)
    rows = engine.safety_filter.table.rows
    expected = sum(1 << j for j, (row, context) in enumerate(zip(rows, _contexts(engine),
                                                                 strict=True))
                   if packed & row.pos == row.pos and not packed & row.neg
                   and (context is None or context(image, history)))
    assert engine.safety_filter.violations is engine.compiled.functions["violated"]
    assert engine.safety_filter.violations(image, history, candidate) == expected


def check_marks(snap: Snapshot, seen: tuple[int, tuple] | None) -> tuple[int, tuple] | None:
    """Snapshot.monitor_marks moves whenever a task's monitor changes in anything but its
    stopwatches (readers skip `monitors` otherwise); returns what the next scan compares."""
    if not snap.monitors:
        return seen
    shown = tuple(m._replace(x_us=0, y_us=0) for m in snap.monitors)
    if seen is not None and seen[1] != shown:
        assert snap.monitor_marks != seen[0], (snap.scan, seen[1], shown)
    return snap.monitor_marks, shown


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("seed", (1, 2, 3))
def test_compiled_scan_equals_the_interpreter(name, seed):
    assert twin_run(name, seed) == SCANS


@pytest.mark.parametrize("name", NAMES)
def test_advance_leaves_the_same_state_as_step(name):
    """Engine.advance (no snapshot: the campaign's and the explorer's scans) leaves the
    engine exactly where Engine.step does: the snapshots taken now and then agree."""
    project = load(PROJECTS / name)
    a, b = (Engine(project, SimPlant(project)) for _ in range(2))
    for k in range(1200):
        now = k * project.scan_period_us
        b_snap = b.step(now)
        if k % 97 == 0:
            assert comparable(a.step(now)) == comparable(b_snap)
        else:
            a.advance(now)
            b.plant.take_events()  # a's plant keeps them; b's snapshot took them


@pytest.mark.parametrize("name", ("cispi_valve", "cispi_subsystem"))
def test_a_restored_state_runs_as_in_the_interpreter(name):
    """Engine.restore (the explorer's) puts back GRAFCET activation times from before later
    firings, and the image's step times with them: both forms go on from there alike."""
    project = load(PROJECTS / name)
    engines = [Engine(project, SimPlant(project), compiled=flag) for flag in (True, False)]
    period = project.scan_period_us
    fired = False
    for k in range(900):
        if k == 300:
            states = [e.capture() for e in engines]
        if k == 600:
            assert fired, "no step changed between the capture and the restore"
            for engine, state in zip(engines, states, strict=True):
                engine.restore(state)
        fast, reference = (e.step(k * period) for e in engines)
        fired = fired or (k > 300 and bool(fast.fired))
        assert comparable(fast) == comparable(reference), f"{name} scan {k}"


def test_generated_code_holds_only_slots_constants_and_operators():
    """No project text reaches generated code: every name in every function an engine
    generates is a parameter, one of the names its stages declare (their PRINTED, the
    frame's), a handed-over object (k0, k1...) or a keyword, and every literal a number
    (hmi.engine.codegen refuses anything else at build time too; this reads the sources
    independently, token by token)."""
    handed = re.compile(r"k[0-9]+\Z")
    for name in NAMES:
        project = load(PROJECTS / name)
        for control in project.controls:
            engine = Engine(project, SimPlant(project), control=control)
            assert engine.compiled.sources
            assert engine.compiled.held is not None  # (built at manual mode's first scan)
            assert engine.compiled.observed is not None
            for procedure in recoveries_of(project):
                assert engine.compiled.recovery(procedure.name) is not None
            assert any(text.startswith("def held(") for text in engine.compiled.sources)
            names = PARAMETERS.union(engine.compiled.vocabulary)
            for text in engine.compiled.sources:
                for tok in tokenize.generate_tokens(io.StringIO(text).readline):
                    if tok.type == tokenize.NAME and tok.start[0] > 1:  # after the def line
                        assert (tok.string in names.locals or handed.match(tok.string)
                                or keyword.iskeyword(tok.string)
                                or tok.string in names.attributes), (name, tok.string)
                    assert tok.type != tokenize.STRING, (name, tok.string)
                    if tok.type == tokenize.NUMBER:
                        assert tok.string.isdigit(), (name, tok.string)



def test_past_images_read_twice_are_bound_once_and_read_the_same():
    """A generated function reads a past image read more than once from a local bound on
    its first line (codegen._bind_past: a deque's item is a generic subscript), one read
    once where it is; both give what reading the history each time gives."""
    src = Source()
    src.line(1, "return (h[0][1] and not h[0][2]) or (h[1][0] and h[1][3]) or h[2][1]")
    fn = build(src, "f", "v, h", "<binding test>")
    text = fn.__doc__ or ""
    assert text.splitlines()[1] == "    h0 = h[0]; h1 = h[1]" and "h[2][1]" in text
    rng = random.Random(7)
    for _ in range(200):
        history = deque((tuple(rng.random() < 0.5 for _ in range(4)) for _ in range(3)),
                        maxlen=3)
        expected = ((history[0][1] and not history[0][2])
                    or (history[1][0] and history[1][3]) or history[2][1])
        assert fn([], history) == expected


@pytest.mark.parametrize("line", [
    "return __import__('os')", "return v.__class__", "return 'text'", "return 1.5",
    "return (lambda: v)()", "return k0(v, key=h)", "import os", "return [x for x in v]",
    "return {}", "global v", "return v[1:2]", "y = b'x'",
])
def test_the_checker_refuses_what_no_template_writes(line):
    """hmi.engine.codegen.build's own walk of the syntax tree refuses every node, name,
    attribute and literal outside the templates' vocabulary, before anything is compiled."""
    src = Source()
    src.line(1, line)
    with pytest.raises(ValueError, match="generated code"):
        build(src, "f", "v, h", "<checker test>")



# What a quiet scan (Engine.run returning False) keeps from the scan before.
EVENT_FIELDS = ("filter_report", "latched", "plant", "mode", "manual", "policy", "diagnosers",
                "reconstructed", "masked", "stopped_devices", "recovery", "error",
                "monitor_marks", "control_name")


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("seed", (4, 5))
def test_run_builds_the_snapshot_on_demand_and_says_when_a_scan_has_news(name, seed):
    """Engine.run + Engine.snapshot against Engine.step, under one seeded script of
    commands: a snapshot asked for at any time before the next scan (after a command too)
    is the one step gives, and a scan run() calls quiet has the very filter report of the
    scan before (the policy's clean one, or a remembered correction again), changes none of
    EVENT_FIELDS and has no plant event."""
    project = load(PROJECTS / name)
    rng = random.Random(seed)
    control = rng.choice(sorted(project.controls))
    policy = rng.choice(POLICIES)
    stepped, ran = (Engine(project, SimPlant(project), control=control, policy=policy)
                    for _ in range(2))
    period = project.scan_period_us
    before = None
    quiet = 0
    for k in range(SCANS):
        now = k * period
        command = None
        if k and rng.random() < 0.02:
            command = random_command(rng, project, stepped, now)
            results = [e.apply(command) for e in (stepped, ran)]
            assert results[0] == results[1], (name, seed, k, command)
        expected = stepped.step(now)
        news = ran.run(now)
        if rng.random() < 0.1:  # asked for now, then maybe again after a command
            assert comparable(ran.snapshot()) == comparable(expected), (name, seed, k)
            assert ran.snapshot() is ran.snapshot()
        if before is not None and not news:
            quiet += 1
            assert expected.plant_events == (), (name, seed, k)
            assert expected.filter_report is before.filter_report, (name, seed, k)
            for field in EVENT_FIELDS:
                assert getattr(expected, field) == getattr(before, field), (name, seed, k, field)
        before = expected
    assert quiet > 0, (name, seed)  # (the check above ran)


@pytest.mark.parametrize("name", NAMES)
def test_most_scans_of_a_working_cell_are_quiet(name):
    """The point of Engine.run: a cell working normally has news at few scans."""
    project = load(PROJECTS / name)
    engine = Engine(project, SimPlant(project))
    news = sum(engine.run(k * project.scan_period_us) for k in range(SCANS))
    assert news < SCANS // 2, (name, news)


@pytest.mark.parametrize("name", NAMES)
def test_run_while_quiet_stops_at_the_first_news(name):
    """Engine.run_while_quiet is run() scan after scan, stopping after the first with news:
    the same scans, the same news, the same state as one run() per scan."""
    project = load(PROJECTS / name)
    period = project.scan_period_us
    batched, single = (Engine(project, SimPlant(project)) for _ in range(2))
    news_at = [k for k in range(SCANS) if single.run(k * period)]
    seen = []
    now, end = 0, (SCANS - 1) * period
    while now <= end:
        count, news = batched.run_while_quiet(now, end, period)
        now += count * period
        if news:
            seen.append(now // period - 1)
    assert seen == news_at and news_at, name
    assert comparable(batched.snapshot()) == comparable(single.snapshot())


def test_printed_code_names_only_what_the_stages_declare():
    """The allow-list is the stages' declared names (ProgramStage.PRINTED): a name nobody
    declared is refused at build time, a name that would reach Python's machinery cannot be
    declared, and a stage's statements go only to a part of the mode's program."""
    from hmi.engine.codegen import Vocabulary, allow
    from hmi.engine.compiled import ScanProgram

    src = Source()
    src.line(1, "return v.undeclared_by_any_stage")
    with pytest.raises(ValueError, match="undeclared_by_any_stage"):
        build(src, "f", "v", "<allow-list test>")
    for bad in ("__class__", "k7", "Import", "a.b"):
        with pytest.raises(ValueError, match="not a name"):
            allow(Vocabulary(frozenset({bad})))
        with pytest.raises(ValueError, match="not a name"):
            allow(Vocabulary(locals=frozenset({bad})))

    class Stray:
        PRINTED = Vocabulary()

        @property
        def parts(self) -> dict[str, tuple[()]]:
            return {"filter": ()}  # the engine's own part, not the program's

    project = load(PROJECTS / "cispi_valve")
    engine = Engine(project, SimPlant(project))
    with pytest.raises(ValueError, match="not a part of the mode's program"):
        ScanProgram(engine.layout, [Stray()], None)
