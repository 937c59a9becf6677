"""The historian's recorder: what it stores is what the scans showed, and it changes nothing.

* Replay: from the samples alone, every Boolean, enum and counter reads at every scan what
  that scan's snapshot held; every number is within its deadband (or settled since).
  Seeded random runs of the example projects (faults, commands, manual mode), so the check
  covers far more than one script.
* The engine only has a listener more: the golden traces are reproduced byte for byte with
  the historian attached (and writing to a real SQLite file).
* Movements: the valve's travel times and operation counts agree with the simulated plant.
* The catalogue names every signal once, whatever the project calls its constraints.
"""

from __future__ import annotations

import random
from bisect import bisect_right

import pytest

from hmi.engine.commands import (
    Acknowledge,
    FaultReset,
    InjectFault,
    ManualOutput,
    RepairFaults,
    SetMode,
    SetPolicy,
)
from hmi.history.catalogue import BOOL, COUNTER, ENUM, LOCATIONS, MODES, NUMBER, catalogue
from hmi.history.historian import Historian
from hmi.history.recorder import HistoryRecorder, SampleQueue
from hmi.history.target import Target
from hmi.project.device_models import DEVICE_MODELS
from hmi.project.injection import Injection
from hmi.project.model import POLICIES
from tests.conftest import PROJECTS, make_session
from tests.golden_traces import CASES, golden_path, run_case

EPOCH = 1_790_000_000_000_000


def _truth(c, snap) -> dict[int, float | None]:
    """What each signal of catalogue `c` is at this scan, read from the snapshot directly
    (not through the recorder's plan)."""
    truth: dict[int, float | None] = {}
    cell, snap = snap, snap.snapshot
    layout = snap.layout
    for s_index, s in enumerate(c.signals):
        name = s.name
        if s.group == "io":
            truth[s_index] = float(bool(snap.values[layout.slots[name]]))
        elif s.group == "fov":
            out = name[:-len(".fov")]
            truth[s_index] = float(bool(snap.fov[layout.outputs.index(out)]))
        elif s.group == "constraint":
            violated = snap.filter_report.violated_names if snap.filter_report else ()
            truth[s_index] = float(name.split(".")[-1] in violated)
        elif s.group == "diagnoser":
            spec = name[:-len(".state")]
            state = next((d.state for d in snap.diagnosers if d.name == spec), None)
            truth[s_index] = None if state is None else float(s.labels.index(state))
        elif name == "cell.mode":
            truth[s_index] = float(MODES.index(snap.mode))
        elif name == "cell.policy":
            truth[s_index] = float(POLICIES.index(snap.policy))
        elif name == "cell.latched":
            truth[s_index] = float(bool(snap.latched))
        elif name == "cell.alarms":
            truth[s_index] = float(len(cell.alarms))
        elif s.group == "monitor":
            task, field = name.rsplit(".", 1)
            m = next(m for m in snap.monitors if m.name == task)
            truth[s_index] = {"x": m.x_us / 1e6, "y": m.y_us / 1e6,
                              "state": float(LOCATIONS.index(m.location))}[field]
    return truth


def _replay(project: str, control: str | None, seed: int, seconds: int) -> None:
    rng = random.Random(seed)
    session = make_session(PROJECTS / project, control=control)
    layout = session.engine.layout
    c = catalogue(session.project, layout)
    queue = SampleQueue(10**9)
    recorder = HistoryRecorder(c, queue, EPOCH)
    truths: list[tuple[int, dict[int, float | None]]] = []

    def listen(cell) -> None:
        recorder.on_scan(cell)
        truths.append((EPOCH + cell.snapshot.time_us, _truth(c, cell)))
    session.scan_listeners.append(listen)
    faults = session.engine.plant.faults()
    commands = [Acknowledge(None), FaultReset(), RepairFaults(), SetMode(True), SetMode(False),
                SetPolicy("block"), SetPolicy("correct")]
    for _ in range(seconds):
        session.run_for(rng.choice((200_000, 1_000_000, 3_000_000)))
        roll = rng.random()
        if roll < 0.15 and faults:
            device, code, _ = rng.choice(faults)
            session.command(InjectFault(Injection(code, session.engine.now, device)))
        elif roll < 0.5:
            session.command(rng.choice(commands))
        elif roll < 0.6 and session.last and session.last.snapshot.mode == "manual":
            session.command(ManualOutput(rng.choice(layout.outputs), rng.random() < 0.5))
    samples: dict[int, list[tuple[int, float]]] = {}
    for i, t, v in queue.take().samples:
        samples.setdefault(i, []).append((t, v))
    checked = 0
    for t, truth in truths:
        for i, expected in truth.items():
            series = samples.get(i, [])
            k = bisect_right(series, (t, float("inf")))
            got = series[k - 1][1] if k else None
            signal = c.signals[i]
            if signal.kind in (BOOL, ENUM, COUNTER) or signal.deadband == 0:
                assert got == expected, (signal.name, t - EPOCH, got, expected)
            else:
                assert expected is not None and got is not None
                settled_at = series[k - 1][0] if k else t
                assert abs(got - expected) < signal.deadband or \
                    t - settled_at < signal.settle_us, (signal.name, t - EPOCH, got, expected)
            checked += 1
    assert checked > 1000


@pytest.mark.parametrize("project,control,seed", [
    ("cispi_valve", "faulty", 1), ("cispi_valve", None, 2), ("cispi_subsystem", None, 3),
    ("conveyor_robot", None, 4), ("sorting", "faulty", 5), ("palletizer", None, 6)])
def test_the_samples_replay_every_scan(project, control, seed):
    _replay(project, control, seed, 25)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(10, 30))
def test_the_samples_replay_every_scan_long(seed):
    project = ("cispi_valve", "cispi_subsystem", "conveyor_robot", "sorting",
               "palletizer")[seed % 5]
    _replay(project, "faulty" if seed % 2 and project != "conveyor_robot" else None, seed, 80)


@pytest.mark.parametrize("name", ["valve_commands", "valve_f13", "subsystem_v1_jam",
                                  "conveyor_paper", "sorting_commands"])
def test_the_golden_traces_are_the_same_with_the_historian(name, tmp_path):
    case = next(c for c in CASES if c.name == name)
    historians = []

    def attach(session, journal):
        historian = Historian(session, Target("sqlite", str(tmp_path / "h.sqlite")),
                              journal=journal, flush_s=0.05).attach()
        historians.append(historian)
        return historian.close
    assert run_case(case, attach) == golden_path(name).read_text(encoding="utf-8")
    status = historians[0].status
    assert status.written > 100 and status.failures == 0 and not historians[0].failure


def test_valve_travel_times_and_operations_agree_with_the_plant():
    session = make_session(PROJECTS / "cispi_valve")
    c = catalogue(session.project, session.engine.layout)
    queue = SampleQueue(10**9)
    recorder = HistoryRecorder(c, queue, 0)
    session.scan_listeners.append(recorder.on_scan)
    session.run_for(120_000_000)
    counters = dict(session.last.snapshot.plant_counters)
    taken = queue.take().samples
    index = {s.name: i for i, s in enumerate(c.signals)}
    travel = [v for i, _, v in taken if i == index["O.travel"]]
    opened = [v for i, _, v in taken if i == index["O.operations"]]
    closing = [v for i, _, v in taken if i == index["C.travel"]]
    # the plant's own count of completed openings; its travel is 2 s from end to end, the
    # switch made within switch_band (40 ms) of the end (the simulation's valve starts at
    # its closed end: the first opening is the longest)
    assert opened[-1] == counters["opens"] == len(travel) > 10
    assert all(1.90 <= t <= 2.0 for t in travel + closing), (travel, closing)
    assert len(closing) >= len(travel) - 1


def test_every_movement_names_ports_of_its_model():
    for model in DEVICE_MODELS.values():
        for movement in model.movements:
            assert movement.order in model.actuators and movement.end in model.sensors


def test_names_are_unique_even_when_the_project_reuses_one(tmp_path, valve_project):
    from dataclasses import replace

    from hmi.engine.layout import Layout
    # a constraint named like a timer, and like a cell signal
    renamed = (replace(valve_project.constraints[0], name="TON1"),
               replace(valve_project.constraints[1], name="cell.mode"),
               *valve_project.constraints[2:])
    project = replace(valve_project, constraints=renamed)
    c = catalogue(project, Layout.build(project, project.control()))
    names = [s.name for s in c.signals]
    assert len(names) == len(set(names))
    assert "constraint.TON1" in names and "TON1" in names
    assert "constraint.cell.mode" in names or "cell.mode" in names
    assert {s.kind for s in c.signals} <= {BOOL, NUMBER, ENUM, COUNTER}
