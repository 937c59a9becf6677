"""An internal error inside the fast paths (the generated scan functions, the straight
automatic-mode cycle, the remembered corrections, a stretch of quiet scans handed to the
engine at once) must do what one in the interpreter does: latch 'internal', write the safe
outputs to the plant at that very scan, explain it, journal it, and never be skipped as a
quiet scan; a fault reset once the cause is gone brings the cell back ("it never
crashes, never lies").

Each case breaks one function once, at a virtual time in the middle of a quiet stretch (a
transient fault: the latch must hold the outputs safe afterwards by itself), in a session
building every scan and in one taking the quiet path (``plchmi run``'s), and compares the
two.

The same holds for an exception raised outside the scan's own error handling (what
Engine.run and Engine.snapshot read of the plant, the timers and the monitors; a write to
the plant raising something other than a PlantError), on each engine path (the compiled
automatic-mode cycle, the general cycle, the interpreter), in ``plchmi run`` and in the HMI:
latched with a reason naming what failed, the safe vector written at once, never a crash;
and two different internal errors are two explanations and two alarms.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

import pytest

from hmi.cli import main
from hmi.engine import commands as cmd
from hmi.engine.scan import Engine
from hmi.engine.stages import OutputScan
from hmi.explain.journal import Journal
from hmi.plant.base import PlantError
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import parse_injection
from hmi.project.loader import load_project
from hmi.project.model import Project
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.session import Session
from tests.conftest import PROJECTS

S = 1_000_000


class Injected(Exception):
    """The fault planted in a fast path."""


@cache
def load(name: str) -> Project:
    return load_project(PROJECTS / name)


class Broken:
    """A session whose engine has one function replaced by one that raises from `at_us`.
    `path` is the engine's way through the scan: "auto" the compiled automatic mode (the
    printed frame when the scans are not timed, else Engine._cycle), "cycle" the general one
    with a device stopped (Engine._cycle, compiled), "interpreter" Engine(compiled=False)."""

    def __init__(self, name: str, where: str, at_us: int, quiet: bool, tmp: Path,
                 times: int = 1, path: str = "auto", inject: str = ""):
        project = load(name)
        self.quiet = quiet
        plant = SimPlant(project)
        if inject:
            plant.inject(parse_injection(inject))
        self.engine = engine = Engine(project, plant, compiled=path != "interpreter")
        self.session = Session(engine)
        if path == "cycle":
            assert self.session.command(cmd.StopDevice(list(engine.devices)[-1])).accepted
        self.journal_path = tmp / f"{where}-{quiet}-{path}.jsonl"
        self.recorder = JournalRecorder(self.session, Journal(self.journal_path), "run")
        self.at_us, self.armed, self.hits, self.times = at_us, True, 0, times
        self.written: list[tuple[int, tuple[bool, ...]]] = []
        self.built: set[int] = set()
        self.first_latched: Any = None  # the first snapshot built with the outputs latched
        real_write = plant.write_vector

        def write_vector(now, names, values):
            self.written.append((now, tuple(values)))
            return real_write(now, names, values)
        plant.write_vector = write_vector  # type: ignore[method-assign]
        owner: Any
        owner, attribute = {
            "core": (engine.compiled, "core"),
            "violated": (engine.safety_filter, "violations"),
            "monitors": (engine.compiled, "monitors"),
            "read_into": (plant, "read_into"),
            # (the filter stage's decision on a violated candidate nothing masks)
            "correction": (engine.filter_stage, "unmasked"),
            "decide": (engine.safety_filter, "decide"),
            "active_bits": (engine.safety_filter, "active_bits"),
            # outside the scan's own error handling (Engine.run, Engine.snapshot)
            "take_events": (plant, "take_events"),
            "state": (plant, "state"),
            "counters": (plant, "counters"),
            "write_vector": (plant, "write_vector"),
            "elapsed": (engine.memory, "elapsed"),
            "settle": (engine.monitors, "settle"),
            "status": (plant, "status"),
            "publish": (engine.diagnosis, "publish"),
            "recovery": (engine.recovery, "state"),
            "capture": (engine.monitors, "capture"),
            "active": (engine.law.grafcet, "active"),
            "masked": (engine, "_masked"),
            "watch": (engine.law.grafcet, "watch"),
        }[where]
        self.where = where
        real = getattr(owner, attribute)
        assert real is not None, f"{name} has no {where}"

        def broken(*args, **kwargs):
            self.fail()
            return real(*args, **kwargs)
        if where == "status":  # an attribute: a property on a class of this plant's own
            plant_class = type(plant)
            plant.__class__ = type("BrokenStatus", (plant_class,), {
                "status": property(lambda this: self.fail() or real)})
        else:
            setattr(owner, attribute, broken)

    def fail(self) -> None:
        """Raise the planted fault, `times` times from `at_us` on, while armed."""
        if self.armed and self.engine.now >= self.at_us and self.hits < self.times:
            self.hits += 1
            raise Injected(f"planted in {self.where}")

    def run_for(self, duration: int) -> None:
        def on_scan(snap):
            self.built.add(snap.snapshot.scan)
            if snap.snapshot.latched and self.first_latched is None:
                self.first_latched = snap
        self.session.run_for(duration, on_scan, (lambda count: None) if self.quiet else None)


CASES = [(name, where) for name in ("cispi_valve", "sorting", "palletizer", "conveyor_robot",
                                    "cispi_subsystem")
         for where in ("core", "violated", "read_into")]
CASES += [(name, "monitors") for name in ("sorting", "palletizer", "conveyor_robot")]
# palletizer's and sorting's laws ask for corrections from about 10 s on, scan after scan
# (the filter remembers them: its memory's key is active_bits)
CASES += [(name, where) for name in ("palletizer", "sorting")
          for where in ("correction", "decide", "active_bits")]


@pytest.mark.parametrize(("name", "where"), CASES)
def test_an_error_inside_a_fast_path_latches_writes_safe_and_is_explained(tmp_path, name,
                                                                          where):
    start = 10 * S if where in ("correction", "decide", "active_bits") else 3 * S
    at_us = start + 3 * load(name).scan_period_us  # inside a stretch of quiet scans
    runs = [Broken(name, where, at_us, quiet, tmp_path) for quiet in (False, True)]
    for run in runs:
        run.run_for(start + 2 * S)
        engine, session = run.engine, run.session
        assert run.hits, f"{where} was never called after {at_us} us"
        latches = [r for r in engine.latched if r.source == "internal"]
        assert latches, "no internal latch"
        first = latches[0]
        assert first.time_us >= at_us and "Injected: planted in" in first.detail
        # the failing scan was built, not counted quiet, and wrote the safe outputs
        assert first.scan in run.built, "the failing scan went by as a quiet one"
        safe = engine.safe_vector
        # (the monitors run after the output scan: the safe vector is written after it)
        at = [values for now, values in run.written if now == first.time_us]
        assert at and at[-1] == safe, at
        after = [values for now, values in run.written if now > first.time_us]
        assert after and all(values == safe for values in after)
        last = session.last
        assert last is not None and last.snapshot.outputs == safe and last.snapshot.is_safe_latched
        keys = [e for e in last.explanations if e.key == "safe_state:internal"]
        assert keys and "Injected" in keys[0].detail
        assert "internal" in " ".join(a.key for a in last.alarms)
    full, quiet = runs
    assert [r.scan for r in full.engine.latched] == [r.scan for r in quiet.engine.latched]
    assert full.written == quiet.written
    # the way back: the cause gone, a fault reset releases the latch and the law runs again
    for run in runs:
        run.armed = False
        assert run.session.command(cmd.FaultReset()).accepted
        run.run_for(3 * S)
        assert not run.engine.latched, run.engine.latched
        run.recorder.close()
    journals = []
    for run in runs:
        entries = [json.loads(line) for line in run.journal_path.read_text().splitlines()]
        for entry in entries:
            entry.pop("wall", None)
            entry.pop("session", None)
            entry.pop("prev", None)  # the chain link: follows the wall time
        journals.append(entries)
        raised = [e for e in entries if e["type"] == "alarm" and e["event"] == "raised"
                  and "internal" in e["key"]]
        assert raised, "the internal error is not in the journal"
    assert journals[0] == journals[1]
    assert full.session.last is not None and quiet.session.last is not None
    assert full.session.last.snapshot.outputs == quiet.session.last.snapshot.outputs


def test_a_persistent_internal_error_keeps_one_latch_and_one_explanation():
    """A fault inside the generated scan that repeats at every scan (a bug in generated
    code would) must leave the operator one reason and one explanation, not one per scan:
    measured on cispi_valve before the fix, 20 s of it left 2,004 latch reasons and 2,004
    explanations with the same key, and each 5 s of scans cost more CPU than the last
    (2.4, 7.4, 12.7, 16.8 CPU s: slower than real time from the first 5 s on, so a live
    session would overrun every scan)."""
    session = make_session("cispi_valve")
    session.run_for(2 * S)
    assert session.engine.compiled is not None

    def broken(*args):
        raise Injected("planted in core, at every scan")
    session.engine.compiled.core = broken
    last = session.run_for(3 * S)
    internal = [r for r in session.engine.latched if r.source == "internal"]
    assert len(internal) == 1, f"{len(internal)} latch reasons for one repeated error"
    shown = [e for e in last.explanations if e.key == "safe_state:internal"]
    assert len(shown) == 1, f"{len(shown)} explanations with the same key"


def make_session(name: str) -> Session:
    project = load(name)
    return Session(Engine(project, SimPlant(project)))


# Outside the scan's own error handling: what Engine.run reads after the cycle, the output
# scan's write raising something other than a PlantError, and what Engine.snapshot reads.
# where -> (what the latch names, in plain words; whether only a snapshot reads it)
OUTSIDE = {
    "take_events": ("reading the plant's events", False),
    "status": ("reading the plant's status", False),
    "write_vector": ("writing the outputs to the plant", False),
    "settle": ("settling the monitors", False),
    "state": ("reading the plant's state", True),
    "counters": ("reading the plant's counters", True),
    "elapsed": ("computing the timers' elapsed times", True),
    "capture": ("reading the monitors' states", True),
    "active": ("reading the active steps", True),
    "masked": ("reading the masked outputs", True),
    # cispi_valve, its valve jammed mid-travel (F13): the diagnoser faulty, a recovery needed
    "publish": ("reading the diagnosers' states", False),
    "recovery": ("reading the recovery's state", False),
}
PATHS = ("auto", "cycle", "interpreter")
JAMMED = ("publish", "recovery")


@pytest.mark.parametrize("where", OUTSIDE)
def test_an_error_outside_the_scans_handling_latches_writes_safe_and_is_explained(
        tmp_path, where):
    """palletizer (plant events, timers, monitors, devices; cispi_valve jammed for the
    diagnosers' and the recovery's states), on each engine path, building every scan
    (Engine.step) and on the quiet path (plchmi run's): the error latches, naming what
    failed, the safe vector is written at once and held, it is explained and journalled
    once, and a fault reset brings the cell back; never an exception out of the run. What
    only a snapshot reads fails where a snapshot is built: at that very scan when every
    scan is built, at the next scan with news (or when the last is read) on the quiet
    path."""
    part, snapshot_only = OUTSIDE[where]
    jammed = where in JAMMED
    name, start, paths = (("cispi_valve", 13 * S, ("auto", "interpreter")) if jammed
                          else ("palletizer", S, PATHS))
    at_us = start + 3 * load(name).scan_period_us
    runs = {(path, quiet): Broken(name, where, at_us, quiet, tmp_path, path=path,
                                  inject="F13@10.4s" if jammed else "")
            for path in paths for quiet in (False, True)}
    for (path, quiet), run in runs.items():
        case = f"{path}, {'quiet' if quiet else 'every scan built'}"
        run.run_for(start + S)
        engine, session = run.engine, run.session
        assert run.hits == 1, case
        latches = [r for r in engine.latched if r.source == "internal"]
        assert len(latches) == 1, (case, engine.latched)
        first = latches[0]
        assert first.part == part and f"{part} failed: Injected: planted in" in first.detail
        assert first.time_us >= at_us
        if not (snapshot_only and quiet):
            assert first.time_us == at_us, case  # at the very scan
            assert first.scan in run.built, f"{case}: the failing scan went by as a quiet one"
        safe = engine.safe_vector
        before = [values for now, values in run.written if now < first.time_us]
        assert any(values != safe for values in before), f"{case}: nothing to make safe"
        # the safe vector written at the failing scan's time (after the scan's own outputs
        # when they were written), and nothing else since
        at = [values for now, values in run.written if now == first.time_us]
        assert at and at[-1] == safe, (case, at)
        after = [values for now, values in run.written if now > first.time_us]
        assert all(values == safe for values in after), case
        assert after or first.time_us == engine.now, case
        last = session.last
        assert last is not None and last.snapshot.outputs == safe and last.snapshot.is_safe_latched
        # the failing scan's snapshot shows the outputs it left the plant with: safe
        snap = run.first_latched if run.first_latched is not None else last
        assert snap.snapshot.scan == first.scan and snap.snapshot.outputs == safe, case
        assert tuple(snap.snapshot.named(snap.snapshot.layout.outputs).values()) == safe, case
        if engine.scan - snap.snapshot.scan < len(engine.history):  # the next scans read it so
            assert engine.history[engine.scan - snap.snapshot.scan] == snap.snapshot.values, case
        shown = [e for e in last.explanations if e.key.startswith("safe_state:internal")]
        assert len(shown) == 1, (case, [e.key for e in last.explanations])
        assert part in shown[0].what and part in shown[0].why
        assert "Injected" in shown[0].detail and "Injected" not in shown[0].why
        assert shown[0].key in {a.key for a in last.alarms}
    full = {path: runs[path, False] for path in paths}
    # the interpreter and the compiled scan fail at the same scan and write the same
    assert full["auto"].written == full["interpreter"].written
    assert [r.scan for r in full["auto"].engine.latched] == \
        [r.scan for r in full["interpreter"].engine.latched]
    if not snapshot_only:  # the quiet path fails at the same scan, and writes the same
        for path in paths:
            assert runs[path, True].written == full[path].written, path
            assert [r.scan for r in runs[path, True].engine.latched] == \
                [r.scan for r in full[path].engine.latched], path
    # the way back: the cause gone, a fault reset releases the latch and the law runs again
    # (the jammed valve's outputs stay masked by its diagnoser: no latch, though)
    for (path, quiet), run in runs.items():
        run.armed = False
        assert run.session.command(cmd.FaultReset()).accepted
        reset_at = run.engine.now
        run.run_for(S)
        assert not run.engine.latched, (path, quiet, run.engine.latched)
        assert jammed or any(values != run.engine.safe_vector for now, values in run.written
                             if now > reset_at), (path, quiet)
        run.recorder.close()
        entries = [json.loads(line) for line in run.journal_path.read_text().splitlines()]
        raised = [e for e in entries if e["type"] == "alarm" and e["event"] == "raised"
                  and e["key"].startswith("safe_state:internal")]
        assert len(raised) == 1, (path, quiet, raised)
        assert part in json.dumps(raised[0])


@pytest.mark.parametrize("path", PATHS)
def test_a_write_the_plant_refuses_is_the_plants_latch_as_the_output_stage_says_it(path):
    """A PlantError from the plant's write (a link that drops the writes) is the plant's,
    not an internal error, on each engine path: latched once as 'plant' with the detail
    OutputScan.write gives for it (Engine._output_scan writes the stage's way itself), the
    safe vector written from the next scan on, no error in the scan."""
    project = load("palletizer")
    plant = SimPlant(project)
    engine = Engine(project, plant, compiled=path != "interpreter")
    session = Session(engine)
    if path == "cycle":
        assert session.command(cmd.StopDevice(list(engine.devices)[-1])).accepted
    real = plant.write_vector
    written: list[tuple[int, tuple[bool, ...]]] = []

    def refused(now, names, values):
        written.append((now, tuple(values)))
        if 2 * S <= now < 2 * S + 50_000:
            raise PlantError("connection lost")
        return real(now, names, values)
    plant.write_vector = refused  # type: ignore[method-assign]
    snaps = []
    session.run_for(3 * S, snaps.append)
    at_scan = 2 * S // project.scan_period_us + 1
    assert [(r.source, r.scan) for r in engine.latched] == [("plant", at_scan)]
    expected = OutputScan(plant, engine.layout).write(2 * S, engine.safe_vector)
    assert expected is not None and engine.latched[0].detail == expected
    assert all(s.error is None for s in snaps)
    assert all(values == engine.safe_vector for now, values in written if now > 2 * S)
    assert any(values != engine.safe_vector for now, values in written if now < 2 * S)


def test_two_different_internal_errors_are_two_explanations_and_two_alarms(tmp_path):
    """Neither hides the other: each its own key, explanation and alarm, both journalled;
    the same error again adds none."""
    run = Broken("palletizer", "take_events", 3 * S, False, tmp_path, times=3)
    run.run_for(3 * S + S // 2)
    assert run.hits == 3
    engine = run.engine
    assert engine.compiled is not None
    real = engine.compiled.core

    def broken(*args):
        raise RuntimeError("a second, different error")
    engine.compiled.core = broken
    last = run.session.run_for(S // 2)
    assert [r.source for r in engine.latched] == ["internal", "internal"]
    keys = [e.key for e in last.explanations if e.kind == "safe_state"]
    assert keys == ["safe_state:internal", "safe_state:internal:2"], keys
    details = [e.detail for e in last.explanations if e.kind == "safe_state"]
    assert "reading the plant's events failed" in details[0]
    assert "a second, different error" in details[1]
    assert set(keys) <= {a.key for a in last.alarms}
    engine.compiled.core = real
    run.armed = False
    assert run.session.command(cmd.FaultReset()).accepted
    assert not run.session.run_for(S).snapshot.latched
    run.recorder.close()
    entries = [json.loads(line) for line in run.journal_path.read_text().splitlines()]
    raised = [e["key"] for e in entries if e["type"] == "alarm" and e["event"] == "raised"
              and e["key"].startswith("safe_state:")]
    assert raised == keys


@pytest.mark.parametrize("where", ["take_events", "write_vector"])
@pytest.mark.parametrize("trace", [False, True], ids=["quiet", "trace"])
def test_plchmi_run_latches_an_error_outside_the_scan_and_ends_normally(
        tmp_path, capsys, monkeypatch, where, trace):
    """The command line, headless, without a trace (the quiet path) and with one (every
    scan built): the run goes on to its end with the outputs held safe, says so, journals
    the alarm, and writes no crash report."""
    part = OUTSIDE[where][0]
    monkeypatch.setenv("PLCHMI_DATA", str(tmp_path / "data"))
    real = getattr(SimPlant, where)
    calls = {"n": 0}

    def broken(self, *args):
        calls["n"] += 1
        if calls["n"] == 150:  # once, at about 1.5 s
            raise Injected(f"planted in {where}")
        return real(self, *args)
    monkeypatch.setattr(SimPlant, where, broken)
    journal = tmp_path / "j.jsonl"
    extra = ["--trace", str(tmp_path / "t.jsonl")] if trace else []
    assert main(["run", str(PROJECTS / "cispi_valve"), "--for", "3s", "--journal",
                 str(journal), *extra]) == 0
    out = capsys.readouterr()
    assert calls["n"] > 150 and "Traceback" not in out.err
    assert f"internal error at scan 150: {part} failed: Injected" in out.out  # plchmi run's
    assert "latched yes" in out.out
    entries = [json.loads(line) for line in journal.read_text().splitlines()]
    raised = [e for e in entries if e.get("event") == "raised"
              and e.get("key") == "safe_state:internal"]
    assert len(raised) == 1 and part in json.dumps(raised[0])
    assert entries[-1]["event"] == "stop" and "ended normally" in entries[-1]["message"]
    assert not list((tmp_path / "data").glob("crash-*"))


async def test_the_hmi_latches_an_error_outside_the_scan_and_the_operator_resets_it(
        tmp_path, monkeypatch):
    """The HMI (pilot, virtual time): reading the plant's state fails once; the app keeps
    running, shows the outputs held safe and the alarm in plain words, journals it; the
    operator's fault reset (r, y) brings the valve back."""
    from ui_harness import region_text, run_for, screen_text, wait_for_main
    from ui_scenarios import make_app

    from hmi.ui.dialogs import ConfirmDialog
    from hmi.ui.headless import press, wait_for_screen
    app = make_app()
    engine = app.link.session.engine
    recorder = JournalRecorder(app.link.session, Journal(tmp_path / "j.jsonl"), "test")
    real = engine.plant.state
    calls = {"n": 0}

    def broken():
        calls["n"] += 1
        if engine.now >= S and calls["n"] < 1000:
            calls["n"] = 1000
            raise Injected("planted in the plant's state")
        return real()
    monkeypatch.setattr(engine.plant, "state", broken)
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 2.0)
        assert app.is_running and calls["n"] > 1000
        assert [r.source for r in engine.latched] == ["internal"]
        assert engine.latched[0].time_us == S
        assert app.link.session.last.snapshot.outputs == engine.safe_vector
        assert "SAFE STATE" in region_text(app, "#status")
        assert "internal error reading the plant's" in screen_text(app)
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        said = " ".join(getattr(line, "plain", str(line)) for line in app.screen.lines)
        assert "outputs held safe: internal error reading the plant's state" in said
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine.latched == []
        shown = set()
        for _ in range(12):
            await run_for(pilot, 0.5)
            shown.add(app.link.session.last.snapshot.outputs)
        assert engine.latched == [] and "SAFE STATE" not in region_text(app, "#status")
        assert shown - {engine.safe_vector}, "the valve does not cycle again"
    recorder.close()
    entries = [json.loads(line) for line in (tmp_path / "j.jsonl").read_text().splitlines()]
    raised = [e for e in entries if e.get("event") == "raised"
              and e.get("key") == "safe_state:internal"]
    assert len(raised) == 1 and "reading the plant's state" in json.dumps(raised[0])


@pytest.mark.parametrize("where", ["take_events", "state", "write_vector"])
def test_the_live_scan_thread_latches_an_error_outside_the_scan_and_keeps_scanning(
        tmp_path, where):
    """The HMI's own scan loop (LiveRunner, as fast as it can: no wall-clock pacing): the
    thread does not die of it (it would end the HMI abnormally), the outputs are held safe,
    and the scans go on to the end."""
    from hmi.session.live import run_live_for
    part = OUTSIDE[where][0]
    run = Broken("cispi_valve", where, S // 2, False, tmp_path)
    run.session.state.speed = None
    runner = run_live_for(run.session, 2 * S)
    assert runner.error is None and not runner.alive
    assert run.hits == 1 and run.engine.now >= 2 * S
    assert [r.part for r in run.engine.latched] == [part]
    last = run.session.last
    assert last is not None and last.snapshot.outputs == run.engine.safe_vector
    assert "safe_state:internal" in {a.key for a in last.alarms}


@pytest.mark.parametrize("times", [2, 10**9], ids=["twice", "for good"])
def test_a_write_that_fails_and_the_safe_write_too_are_both_said(tmp_path, times):
    """Writing the scan's outputs raises, and so does writing the safe vector at once: two
    reasons, two explanations (neither hides the other); the scans go on, the safe vector
    tried again at every scan; a plant whose writes fail for good adds no reason per scan."""
    at_us = 3 * S
    run = Broken("palletizer", "write_vector", at_us, True, tmp_path, times=times)
    run.run_for(4 * S)
    engine = run.engine
    assert [(r.part, r.time_us) for r in engine.latched] == [
        ("writing the outputs to the plant", at_us),
        ("writing the safe outputs to the plant", at_us)]
    last = run.session.last
    assert last is not None and last.snapshot.outputs == engine.safe_vector
    keys = [e.key for e in last.explanations if e.kind == "safe_state"]
    assert keys == ["safe_state:internal", "safe_state:internal:2"]
    written = [values for now, values in run.written if now >= at_us]
    if times == 2:  # the next scan's write went through, and was safe
        assert written and all(values == engine.safe_vector for values in written)
    else:
        assert not written and run.hits > 100


def test_an_error_watching_the_steps_supervision_latches_on_every_path(tmp_path):
    """conveyor_robot (supervised steps): watching the supervision times after a scan (a
    firing, or a deadline past: the supervision stage's publication, Engine._conclude) that
    raises latches an internal error naming it, at the same scan and with the same writes on
    each engine path, building every scan or not; the outputs go safe and a fault reset
    brings the cell back."""
    name, part = "conveyor_robot", "watching the steps' supervision times"
    at_us = 2 * S
    runs = {(path, quiet): Broken(name, "watch", at_us, quiet, tmp_path, path=path)
            for path in ("auto", "interpreter") for quiet in (False, True)}
    for run in runs.values():
        run.run_for(3 * S)
        assert run.hits == 1
        (latch,) = [r for r in run.engine.latched if r.source == "internal"]
        assert latch.part == part and latch.time_us >= at_us
        assert run.session.last is not None and run.session.last.snapshot.outputs == \
            run.engine.safe_vector
    first = runs["auto", False]
    for run in runs.values():
        assert run.written == first.written
        assert [r.scan for r in run.engine.latched] == [r.scan for r in first.engine.latched]
    for run in runs.values():
        run.armed = False
        assert run.session.command(cmd.FaultReset()).accepted
        reset_at = run.engine.now
        run.run_for(S)
        assert not run.engine.latched
        assert any(values != run.engine.safe_vector for now, values in run.written
                   if now > reset_at)
        run.recorder.close()
