"""Independent checks that the session's fast paths never change what the product does or
says ("it never crashes, never lies").

Three sessions of one project run side by side under one seeded random script of faults,
repairs and operator commands (pause/step, manual mode and orders, policies, fault resets,
acknowledgements, shelving, comments, a situation's policy, devices stopped and released,
recoveries started and left, free inputs set) given at random virtual times:

* ``full``: every scan built, explained and handed to the collector (``run_for`` without
  ``on_quiet``), compiled engine;
* ``quiet``: what ``plchmi run`` does without a trace (``run_for`` with ``on_quiet``: quiet
  scans neither built nor explained), with ``Session.last`` read at random moments, even
  from inside ``on_quiet``;
* ``reference``: the interpreter (``Engine(compiled=False)``) with a corrector that searches
  every correction afresh and an explanation builder that explains every scan afresh,
  every scan built.

Each has its journal recorder and run collector, as ``plchmi run`` has. Compared: every
scan the three built (all deterministic fields, monitors and explanations included), the
command results and the snapshot the command listeners were shown, the journals line by
line, the collectors' figures and the summary ``plchmi run`` prints from them. A scan the
quiet session did not build must also have had nothing to tell: the full session's snapshot
of it shows no event, no alarm change, no new explanation, no latch change, no error.
"""

from __future__ import annotations

import json
import random
from functools import cache
from pathlib import Path
from typing import Any

import pytest

from hmi.engine import commands as cmd
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot
from hmi.explain.journal import Journal
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.loader import load_project
from hmi.project.model import POLICIES, Project
from hmi.project.recovery import recoveries_of
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.run_report import RunCollector, run_summary
from hmi.session.session import Session
from hmi.session.view import CellView
from tests.conftest import PROJECTS

S = 1_000_000
NAMES = ("cispi_valve", "sorting", "palletizer", "conveyor_robot", "cispi_subsystem")
KINDS = ("full", "quiet", "reference")


@cache
def load(name: str) -> Project:
    return load_project(PROJECTS / name)


def comparable(cell: CellView) -> dict[str, Any]:
    """Every field but the measured ones, the session's too; monitors built (a lazy value
    compares as built)."""
    snap = cell.snapshot
    out = {field: getattr(snap, field) for field in Snapshot._fields}
    out.update((field, getattr(cell, field)) for field in CellView._fields
               if field != "snapshot")
    out["scan_wall_us"] = out["filter_wall_us"] = out["explain_wall_us"] = 0.0
    report = out["filter_report"]
    if report is not None:
        out["filter_report"] = report._replace(solver_us=0.0)
    out["monitors"] = tuple(snap.monitors)
    return out


def differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    return [f"{k}: {a[k]!r} != {b[k]!r}" for k in a if a[k] != b[k]]


class Twin:
    """One session with its journal and collector, as `plchmi run` sets them up."""

    def __init__(self, kind: str, project: Project, control: str, policy: str,
                 faults: list[Injection], tmp: Path, period: int | None):
        self.kind = kind
        plant = SimPlant(project)
        for injection in faults:
            plant.inject(injection)
        engine = Engine(project, plant, control=control, policy=policy,
                        compiled=kind != "reference")
        if kind == "reference":
            engine.safety_filter.remember = False
        self.session = Session(engine, period)
        if kind == "reference":  # every scan's situations found afresh (no reuse)
            self.session.explainer.build = self.session.explainer._build  # type: ignore
        self.journal_path = tmp / f"{kind}.jsonl"
        self.recorder = JournalRecorder(self.session, Journal(self.journal_path), "run")
        self.collector = RunCollector()
        self.built: dict[int, dict[str, Any]] = {}
        self.quiet_scans = 0
        self.shown: list[tuple[str, str, bool, str, dict[str, Any] | None]] = []
        self.session.listeners.append(self.on_command)
        # The scans a StepScans command runs are built, and given to the collector too
        # (RunCollector.quiet repeats the last scan it was given: it must be given every
        # built one, in order; run_for gives its own to on_scan after on_quiet).
        self.in_command = False
        self.session.scan_listeners.append(self.on_stepped)
        self.session.idle_checks[self.on_stepped] = lambda: True

    def on_stepped(self, snap: Snapshot) -> None:
        if self.in_command:
            self.on_scan(snap)

    def command(self, command: cmd.Command) -> cmd.CommandResult:
        self.in_command = True
        try:
            return self.session.command(command)
        finally:
            self.in_command = False

    def on_command(self, command, result, snap) -> None:
        self.shown.append((self.kind, repr(command), result.accepted, result.message,
                           comparable(snap) if snap is not None else None))

    def on_scan(self, snap: Snapshot) -> None:
        self.collector.add(snap)
        assert snap.snapshot.scan not in self.built
        self.built[snap.snapshot.scan] = comparable(snap)

    def run_for(self, duration: int, peek: random.Random) -> None:
        session = self.session
        if self.kind != "quiet":
            session.run_for(duration, self.on_scan)
            return

        def on_quiet(count: int) -> None:
            self.quiet_scans += count
            self.collector.quiet(count)
            if peek.random() < 0.2:  # an operator's screen reading the last scan meanwhile
                last = session.last
                assert last is not None and last.snapshot.scan == session.engine.scan
                self.peeked.append(comparable(last))

        self.peeked: list[dict[str, Any]] = []
        session.run_for(duration, self.on_scan, on_quiet)
        for seen in self.peeked:  # a quiet scan read meanwhile is what a full one built
            full = self.twin_full.built.get(seen["scan"])
            assert full is not None and not differences(seen, full), (
                seen["scan"], differences(seen, full or {}))

    twin_full: Twin


def random_command(rng: random.Random, project: Project, session: Session, now: int
                   ) -> cmd.Command:
    engine = session.engine
    outputs = [v.name for v in project.outputs]
    devices = sorted(engine.devices)
    recoveries = [r.name for r in recoveries_of(project)]
    faults = engine.plant.faults()
    keys = sorted(session.alarms.alarms) + sorted(session.alarms.shelved)
    choices: list[cmd.Command] = [
        cmd.SetMode(True), cmd.SetMode(False), cmd.FaultReset(), cmd.Pause(), cmd.Resume(),
        cmd.StepScans(rng.randint(1, 3)), cmd.Acknowledge(None),
        cmd.ManualOutput(rng.choice(outputs), rng.choice((True, False, None))),
        cmd.ManualOutput(rng.choice(outputs), True),
        cmd.SetPolicy(rng.choice(POLICIES)), cmd.RepairFaults(),
    ]
    free = sorted(getattr(engine.plant, "free_inputs", {}))
    if free:
        choices.append(cmd.SetInput(rng.choice(free), rng.random() < 0.5))
    if faults:
        device, code, _ = rng.choice(faults)
        at = now + rng.randrange(0, 3 * S)
        duration = rng.choice((None, None, rng.randrange(S // 10, 4 * S)))
        choices += [cmd.InjectFault(Injection(code, at, device, duration))] * 3
    if devices:
        choices += [cmd.StopDevice(rng.choice(devices)), cmd.ReleaseDevice(rng.choice(devices))]
    if recoveries:
        choices += [cmd.StartRecovery(rng.choice(recoveries)), cmd.EndRecovery()] * 2
    if keys:
        key = rng.choice(keys)
        choices += [cmd.Acknowledge(key), cmd.Acknowledge(key),
                    cmd.Shelve(key, rng.choice((None, rng.randrange(S // 2, 5 * S)))),
                    cmd.Unshelve(key), cmd.CommentAlarm(key, f"seen at {now}")]
    offered = [(e.key, p.id) for e in session.explanations for p in e.policies]
    if offered:
        key, policy = rng.choice(offered)
        choices += [cmd.ChoosePolicy(key, policy)] * 3
    return rng.choice(choices)


def check_quiet_scans_told_nothing(full: Twin, quiet: Twin) -> None:
    """Each scan the quiet session did not build: the full session's snapshot of it has
    nothing the journal, the alarm list or the operator's explanations would show new."""
    previous = None
    after_command = {snap["scan"] + 1 for _, _, _, _, snap in full.shown if snap is not None}
    for scan in sorted(full.built):
        snap = full.built[scan]
        if scan not in quiet.built and previous is not None:
            assert previous["scan"] == scan - 1  # every scan of the full session was built
            where = f"scan {scan} was quiet but"
            if scan in after_command:  # a comment changes the list between scans (its
                # journal entry is written then): the quiet scan shows the list as it is
                previous = {**previous, "alarms": snap["alarms"], "shelved": snap["shelved"]}
            assert not snap["alarm_events"], f"{where} raised alarm events {snap['alarm_events']}"
            assert not snap["plant_events"], f"{where} had plant events {snap['plant_events']}"
            assert snap["error"] is None, f"{where} had an error {snap['error']}"
            for field in ("explanations", "alarms", "shelved", "latched", "mode", "manual",
                          "policy", "diagnosers", "recovery", "masked", "reconstructed",
                          "stopped_devices", "plant", "filter_report"):
                assert snap[field] == previous[field], f"{where} its {field} changed"
            moved = [(m._replace(x_us=0, y_us=0), n._replace(x_us=0, y_us=0))
                     for m, n in zip(snap["monitors"], previous["monitors"], strict=True)]
            assert all(m == n for m, n in moved), f"{where} a monitor changed"
        previous = snap


def journal(path: Path) -> list[dict]:
    entries = [json.loads(line) for line in path.read_text().splitlines()]
    for entry in entries:
        entry.pop("wall", None)
        entry.pop("session", None)
        entry.pop("prev", None)  # the chain link: follows the wall time
    return entries


def summary(twin: Twin, last: Snapshot) -> str:
    text = run_summary(twin.session.engine, last.snapshot, twin.collector, [], 0.0)
    return "\n".join(line.split(" scans in ")[0] if line.startswith("Ran ") else line
                     for line in text.splitlines())


def trio_run(name: str, seed: int, tmp: Path, segments: int = 28) -> dict[str, int]:
    project = load(name)
    rng = random.Random(seed)
    peek = random.Random(seed * 7919 + 1)
    control = rng.choice(sorted(project.controls))
    policy = rng.choice(POLICIES)
    period = rng.choice((None, None, None, project.scan_period_us * rng.choice((2, 3))))
    catalogue = SimPlant(project).faults()
    faults = []
    for _ in range(rng.randint(0, 2)):
        device, code, _ = rng.choice(catalogue)
        faults.append(Injection(code, rng.randrange(S, 20 * S), device,
                                rng.choice((None, rng.randrange(S // 5, 5 * S)))))
    twins = {kind: Twin(kind, project, control, policy, faults, tmp, period) for kind in KINDS}
    full, quiet, reference = twins["full"], twins["quiet"], twins["reference"]
    quiet.twin_full = full
    step = full.session.period_us
    for _ in range(segments):
        duration = rng.choice((0, step, rng.randrange(step, 4 * S)))
        for twin in twins.values():
            twin.run_for(duration, peek)
        engine_scans = {t.session.engine.scan for t in twins.values()}
        assert len(engine_scans) == 1, engine_scans
        lasts = {kind: comparable(t.session.last) for kind, t in twins.items()}
        for kind in ("quiet", "reference"):
            assert not differences(lasts[kind], lasts["full"]), (
                name, seed, kind, differences(lasts[kind], lasts["full"]))
        command = random_command(rng, project, full.session, full.session.engine.now)
        results = [t.command(command) for t in twins.values()]
        assert results[1] == results[0] and results[2] == results[0], (command, results)
    for kind in ("quiet", "reference"):
        other = twins[kind]
        assert [s[1:] for s in other.shown] == [s[1:] for s in full.shown], kind
    # every scan any session built, against the full session's
    for scan, snap in reference.built.items():
        assert not differences(snap, full.built[scan]), (scan, differences(snap,
                                                                           full.built[scan]))
    assert reference.built.keys() == full.built.keys()
    for scan, snap in quiet.built.items():
        assert not differences(snap, full.built[scan]), (scan, differences(snap,
                                                                           full.built[scan]))
    check_quiet_scans_told_nothing(full, quiet)
    assert len(quiet.built) + quiet.quiet_scans == len(full.built)
    # what plchmi run prints and journals at the end
    lasts_snap = {}
    for kind, twin in twins.items():
        last = twin.session.last
        assert last is not None
        twin.collector.finish(last)
        twin.recorder.close()
        lasts_snap[kind] = last
    texts = {kind: summary(t, lasts_snap[kind]) for kind, t in twins.items()}
    assert texts["quiet"] == texts["full"] == texts["reference"]
    figures = ("scans", "violations", "corrections", "safe_scans", "unsafe_written",
               "fallbacks", "max_distance", "first_latch", "events", "alarm_events",
               "step_changes", "explanations")
    for field in figures:
        values = [getattr(t.collector, field) for t in twins.values()]
        assert values[0] == values[1] == values[2], (field, values)
    assert quiet.collector.monitors.last == full.collector.monitors.last
    assert quiet.collector.monitors.detections == full.collector.monitors.detections
    journals = {kind: journal(t.journal_path) for kind, t in twins.items()}
    assert journals["quiet"] == journals["full"]
    assert journals["reference"] == journals["full"]
    return {"scans": len(full.built), "quiet": quiet.quiet_scans,
            "commands": len(full.shown)}


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("seed", (11, 12, 13))
def test_quiet_full_and_interpreted_sessions_say_the_same(tmp_path, name, seed):
    figures = trio_run(name, seed, tmp_path)
    assert figures["commands"] >= 28  # every segment ended with a command
    assert figures["quiet"] > 0  # the quiet path was taken (else nothing was compared)


@pytest.mark.parametrize("name", ["cispi_valve", "sorting", "cispi_subsystem"])
def test_a_headless_run_takes_the_printed_frame_and_leaves_it_when_timed_or_stopped(name):
    """The automatic mode's printed frame (hmi.engine.compiled.auto_frame) runs the quiet
    scans of a headless run (what the fast-path comparisons above rely on: a frame never
    taken would compare the general path with itself); a device stopped or wall times
    measured send the scans back to the general path."""
    project = load_project(PROJECTS / name)
    engine = Engine(project, SimPlant(project))
    frame = engine._frame
    assert frame is not None
    calls = [0]

    def counted(now: int) -> bool:
        calls[0] += 1
        return frame(now)
    engine._frame = counted
    session = Session(engine)
    session.run_for(2 * S, lambda snap: None, lambda count: None)
    taken = calls[0]
    assert taken > 0.9 * 2 * S / project.scan_period_us
    period = project.scan_period_us
    engine.wall_times = True  # (the HMI's: the scan's wall time measured)
    engine.run(engine.now + period)
    assert calls[0] == taken and engine.snapshot().scan_wall_us > 0
    engine.wall_times = False
    engine.run(engine.now + period)
    assert calls[0] == taken + 1
    taken = calls[0]
    assert session.command(cmd.StopDevice(list(engine.devices)[-1])).accepted
    assert not engine._fast
    engine.run(engine.now + period)
    assert calls[0] == taken
