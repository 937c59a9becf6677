"""Golden traces: recorded runs of every example project that the engine must reproduce.

The safety net of refactorings that must not change behaviour: each case runs a
project headless in virtual time (a control variant, a filter policy, a diagnosis mode, fault
injections and, for some, a script of operator commands) and records, scan by scan, every
deterministic field of the snapshot (the trace row of ``plchmi run --trace``, the filter's
report, diagnosers, monitors, explanations at all four levels, alarms and their transitions,
latches, plant counters and events), the commands' results and the journal's entries
(without their wall-clock stamps). A scan's line holds only the fields that changed since the
previous scan, so the files stay small and a difference points at the scan and the field.

``tests/test_golden.py`` replays every case and compares the bytes. When a change is *meant*
to change behaviour (a better corrector, a new diagnoser), re-record and say why in the commit:

    .venv/bin/python tests/golden_traces.py --record            # every case
    .venv/bin/python tests/golden_traces.py --record valve_f13   # some cases

and look at ``git diff --stat tests/golden`` (and the diff itself) before committing.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = Path(__file__).resolve().parent / "golden"
sys.path.insert(0, str(ROOT))

from hmi.engine import commands as cmd  # noqa: E402
from hmi.project.injection import parse_injection  # noqa: E402
from hmi.session.trace import _row  # noqa: E402

S = 1_000_000

# A scripted command: at a virtual time, either a command or a function of the last snapshot
# giving one (so a script can act on "the first alarm" without naming it in advance).
Script = tuple[tuple[int, Any], ...]


@dataclass(frozen=True)
class Case:
    name: str
    project: str
    seconds: float
    control: str | None = None
    policy: str | None = None
    diagnosis: str = "ftc"
    inject: tuple[str, ...] = ()
    scenario: str | None = None
    solver: str | None = None
    script: Script = field(default=())


def _first_alarm(snap) -> Any:
    alarm = next((a for a in snap.alarms if a.explanation is not None), None)
    if alarm is None:
        return cmd.Acknowledge(None)
    recommended = alarm.explanation.recommended or alarm.explanation.policies[0]
    return cmd.ChoosePolicy(alarm.key, recommended.id)


def _first_alarm_ack(snap) -> Any:
    return cmd.Acknowledge(snap.alarms[0].key if snap.alarms else "nothing")


VALVE_SCRIPT: Script = (
    (2 * S, cmd.SetMode(True)),
    (2 * S, cmd.ManualOutput("O", True)),
    (4 * S, cmd.ManualOutput("C", True)),  # CSc1: refused by the filter
    (5 * S, cmd.ManualOutput("O", None)),
    (6 * S, cmd.SetMode(False)),
    (7 * S, cmd.SetPolicy("block")),
    (9 * S, _first_alarm_ack),
    (10 * S, cmd.FaultReset()),
    (10 * S, cmd.SetPolicy("monitor")),
    (12 * S, cmd.SetPolicy("correct")),
    (12 * S, cmd.Acknowledge(None)),
    (13 * S, cmd.StopDevice("Valve V1")),
    (15 * S, cmd.ReleaseDevice("Valve V1")),
    (16 * S, cmd.InjectFault(parse_injection("F13@16.5s"))),
    (16 * S, cmd.InjectFault(parse_injection("F13@17s"))),  # refused: already scheduled
    (20 * S, _first_alarm),
    (22 * S, cmd.RepairFaults()),
    (23 * S, cmd.FaultReset()),
    (24 * S, cmd.Pause()),
    (24 * S, cmd.StepScans(3)),
    (24 * S, cmd.Resume()),
    (25 * S, cmd.ManualOutput("O", True)),  # refused: not in manual mode
    (25 * S, cmd.SetInput("fsc", True)),  # refused: driven by the plant
)

SORTING_SCRIPT: Script = (
    (5 * S, cmd.SetMode(True)),
    (5 * S, cmd.ManualOutput("ROT90", True)),
    (6 * S, cmd.ManualOutput("CONV_E", True)),
    (8 * S, cmd.SetMode(False)),
    (12 * S, _first_alarm),
    (14 * S, cmd.Acknowledge(None)),
    (15 * S, cmd.FaultReset()),
)

CASES: tuple[Case, ...] = (
    # cispi_valve: the filter's three policies, the diagnoser under its three modes.
    Case("valve_normal", "cispi_valve", 10),
    Case("valve_faulty_monitor", "cispi_valve", 10, "faulty", "monitor"),
    Case("valve_faulty_block", "cispi_valve", 10, "faulty", "block"),
    Case("valve_faulty_correct", "cispi_valve", 12, "faulty", "correct"),
    Case("valve_faulty_paper", "cispi_valve", 8, "faulty", "correct", solver="paper"),
    Case("valve_f1", "cispi_valve", 20, inject=("F1@12s",)),
    Case("valve_f4_early", "cispi_valve", 16, inject=("F4@10s",)),
    Case("valve_f9", "cispi_valve", 16, inject=("F9@9.5s",)),
    Case("valve_f13", "cispi_valve", 16, inject=("F13@10.4s",)),
    Case("valve_f13_observe", "cispi_valve", 16, diagnosis="observe", inject=("F13@10.4s",)),
    Case("valve_f13_off", "cispi_valve", 16, diagnosis="off", inject=("F13@10.4s",)),
    Case("valve_f4_monitor", "cispi_valve", 18, policy="monitor", inject=("F4@12s",)),
    Case("valve_f8_block", "cispi_valve", 16, policy="block", inject=("F8@8.2s",)),
    Case("valve_commands", "cispi_valve", 27, "faulty", "correct", script=VALVE_SCRIPT),
    # cispi_subsystem: two diagnosers, a pump and tanks.
    Case("subsystem_normal", "cispi_subsystem", 20),
    Case("subsystem_faulty_monitor", "cispi_subsystem", 12, "faulty", "monitor"),
    Case("subsystem_faulty_block", "cispi_subsystem", 12, "faulty", "block"),
    Case("subsystem_faulty_correct", "cispi_subsystem", 20, "faulty", "correct"),
    Case("subsystem_v1_jam", "cispi_subsystem", 32, scenario="v1_jam"),
    Case("subsystem_v1_jam_observe", "cispi_subsystem", 30, diagnosis="observe",
         scenario="v1_jam"),
    Case("subsystem_v1_jam_off", "cispi_subsystem", 30, diagnosis="off", scenario="v1_jam"),
    Case("subsystem_v2_fso_stuck", "cispi_subsystem", 28, scenario="v2_fso_stuck"),
    Case("subsystem_pump_welded", "cispi_subsystem", 36, scenario="pump_welded"),
    # sorting: monitors on timed tasks, combined constraints.
    Case("sorting_normal", "sorting", 10),
    Case("sorting_faulty_monitor", "sorting", 8, "faulty", "monitor"),
    Case("sorting_faulty_block", "sorting", 8, "faulty", "block"),
    Case("sorting_faulty_correct", "sorting", 12, "faulty", "correct"),
    Case("sorting_left_blocked", "sorting", 22, scenario="left_blocked"),
    Case("sorting_table_jam", "sorting", 24, scenario="table_jam"),
    Case("sorting_tt_back_stuck1", "sorting", 24, scenario="tt_back_stuck1"),
    Case("sorting_commands", "sorting", 18, script=SORTING_SCRIPT),
    # palletizer: observers, memories, monitors.
    Case("palletizer_normal", "palletizer", 20),
    Case("palletizer_faulty_monitor", "palletizer", 12, "faulty", "monitor"),
    Case("palletizer_faulty_block", "palletizer", 12, "faulty", "block"),
    Case("palletizer_faulty_correct", "palletizer", 20, "faulty", "correct"),
    Case("palletizer_plate_closed_stuck1", "palletizer", 30, scenario="plate_closed_stuck1"),
    Case("palletizer_clamp_closed_stuck1", "palletizer", 28,
         scenario="clamp_closed_stuck1"),
    Case("palletizer_elevator_jam", "palletizer", 28, scenario="elevator_jam"),
    # conveyor_robot: stopwatch monitors (002 §4).
    *(Case(f"conveyor_{name.replace('-', '_')}", "conveyor_robot", 12, scenario=name)
      for name in ("paper", "normal", "short-stop", "slipping-belt", "robot-stop",
                   "robot-long-stop", "missing-part")),
    Case("conveyor_monitor_policy", "conveyor_robot", 12, policy="monitor",
         scenario="paper"),
    Case("conveyor_block_policy", "conveyor_robot", 12, policy="block", scenario="paper"),
)

# Runs through the command line (`plchmi run ... --trace`): the trace file's SHA-256.
CLI_CASES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("cli_valve_f13", ("cispi_valve", "--for", "14s", "--inject", "F13@10.4s")),
    ("cli_valve_faulty_block", ("cispi_valve", "--for", "10s", "--control", "faulty",
                                "--policy", "block")),
    ("cli_sorting_left_blocked", ("sorting", "--scenario", "left_blocked", "--for", "16s")),
    ("cli_subsystem_observe", ("cispi_subsystem", "--scenario", "v1_jam", "--for", "30s",
                               "--diagnosis", "observe")),
)


# -- what is recorded -----------------------------------------------------------------------

_MEMO: dict[int, tuple[Any, Any]] = {}  # id -> (frozen object, its plain form)


def plain(value: Any) -> Any:
    """A JSON-able copy of a snapshot field (NamedTuples and dataclasses as dicts)."""
    convert = _CONVERTERS.get(type(value))
    if convert is None:
        convert = _CONVERTERS[type(value)] = _converter(type(value))
    return convert(value)


def _converter(kind: type) -> Callable[[Any], Any]:
    """How `plain` turns a value of this type into its plain form, found once per type (the
    recorder converts every field of every scan: asking dataclasses and isinstance again for
    each value was most of a case's time)."""
    if kind is type(None) or issubclass(kind, str | int | float | bool):
        return _same
    if issubclass(kind, Enum):
        return lambda value: value.value
    fields = getattr(kind, "_fields", None)
    if fields is not None:  # a NamedTuple
        return lambda value: dict(zip(fields, map(plain, value), strict=True))
    if dataclasses.is_dataclass(kind):
        if issubclass(kind, cmd.Command):
            return cmd.describe
        names = tuple(f.name for f in dataclasses.fields(kind))
        frozen = kind.__dataclass_params__.frozen  # type: ignore[attr-defined]

        def from_dataclass(value: Any) -> Any:
            hit = _MEMO.get(id(value))
            if hit is not None and hit[0] is value:
                return hit[1]
            out = {name: plain(getattr(value, name)) for name in names}
            if frozen:
                _MEMO[id(value)] = (value, out)
            return out
        return from_dataclass
    if issubclass(kind, list | tuple):
        return lambda value: [plain(v) for v in value]
    if issubclass(kind, dict):
        return lambda value: {str(k): plain(v) for k, v in value.items()}
    return _same


def _same(value: Any) -> Any:
    return value


_CONVERTERS: dict[type, Callable[[Any], Any]] = {}


def _filter(report) -> Any:
    if report is None:
        return None
    return {k: plain(v) for k, v in report._asdict().items() if k != "solver_us"}


def _alarms(alarms) -> Any:
    return [{k: v for k, v in plain(a).items() if k != "explanation"} for a in alarms]


def snapshot_fields(cell) -> list[tuple[str, Any, Callable[[Any], Any]]]:
    """Every deterministic field of a scan, the session's view of it (measured times left
    out): (name, the raw value, how to make it plain). Raw values are compared first: most
    do not change."""
    snap = cell.snapshot
    fields: list[tuple[str, Any, Callable[[Any], Any]]] = [
        ("row", snap, _row),
        ("filter", snap.filter_report, _filter),
        ("steps", (snap.active_steps, snap.fired, snap.timer_elapsed), plain),
        ("mode", (snap.control_name, snap.mode, snap.manual, snap.policy, snap.stopped_devices),
         plain),
        ("latched", snap.latched, plain),
        ("plant", snap.plant, plain),
        ("plant_counters", snap.plant_counters, plain),
        ("plant_events", snap.plant_events, plain),
        ("diagnosers", len(snap.diagnosers), plain),
        ("monitors", len(snap.monitors), plain),
        ("flags", (snap.reconstructed, snap.masked), plain),
        ("explanations", cell.explanations, plain),
        ("alarms", cell.alarms, _alarms),
        ("alarm_events", cell.alarm_events, plain),
        ("error", cell.error, plain),
    ]
    fields += [(f"diagnosers.{k}", d, plain) for k, d in enumerate(snap.diagnosers)]
    fields += [(f"monitors.{k}", m, plain) for k, m in enumerate(snap.monitors)]
    return fields


def _dump(obj: Any) -> str:
    return json.dumps(obj, ensure_ascii=False, separators=(",", ":"))


# -- running a case -------------------------------------------------------------------------

def open_session(case: Case):
    """The session of a case: its project on the simulated plant, as `plchmi run` does."""
    from hmi.engine.scan import Engine
    from hmi.plant.sim.plant import SimPlant
    from hmi.project.loader import load_project
    from hmi.project.scenarios import find_scenario
    from hmi.session.session import Session

    project = load_project(ROOT / "projects" / case.project)
    plant = SimPlant(project)
    injections = [parse_injection(text) for text in case.inject]
    if case.scenario:
        injections = [*find_scenario(project, case.scenario).injections, *injections]
    for injection in injections:
        plant.inject(injection)
    engine = Engine(project, plant, control=case.control, policy=case.policy,
                    solver=case.solver, diagnosis=case.diagnosis)
    return Session(engine)


def open_journal(session, path: Path):
    from hmi.explain.journal import Journal
    from hmi.session.journal_recorder import JournalRecorder
    return JournalRecorder(session, Journal(path), "golden")


# Fields that move at almost every scan (the clock, timers' elapsed time, stopwatches): kept
# out of the scan lines, which would otherwise repeat them at every scan, but folded into the
# running digest written every CHECKPOINT scans, so any difference in them is still caught
# (and located to within CHECKPOINT scans).
CONTINUOUS = ("row.scan", "row.time_s", "steps.2.", "monitors.")
CONTINUOUS_LEAVES = (".x_us", ".y_us")
CHECKPOINT = 250


_MISSING = object()


def leaves(value: Any, path: str, out: dict[str, Any]) -> None:
    """Every scalar of a plain value by its dotted path (an empty container is a leaf)."""
    if isinstance(value, dict) and value:
        for k, v in value.items():
            leaves(v, f"{path}.{k}", out)
    elif isinstance(value, list) and value:
        for k, v in enumerate(value):
            leaves(v, f"{path}.{k}", out)
    else:
        out[path] = value


def diff(old: Any, new: Any, path: str, changed: dict[str, Any], gone: dict[str, Any]
         ) -> None:
    """The leaves that differ between two plain values; equal subtrees are skipped whole
    (compared here before descending: most of a snapshot's subtrees are equal to the last
    scan's, and a call per equal leaf was most of the recording's time)."""
    if type(old) is type(new) and old == new:
        return
    if isinstance(old, dict) and isinstance(new, dict) and old and new:
        get = old.get
        for k, v in new.items():
            was = get(k, _MISSING)
            if type(was) is not type(v) or was != v:
                diff(was, v, f"{path}.{k}", changed, gone)
        for k, v in old.items():
            if k not in new:
                leaves(v, f"{path}.{k}", gone)
        return
    if isinstance(old, list) and isinstance(new, list) and old and new:
        count = len(old)
        for k, v in enumerate(new):
            was = old[k] if k < count else _MISSING
            if type(was) is not type(v) or was != v:
                diff(was, v, f"{path}.{k}", changed, gone)
        for k in range(len(new), count):
            leaves(old[k], f"{path}.{k}", gone)
        return
    if old is not _MISSING:
        leaves(old, path, gone)
    leaves(new, path, changed)


def _continuous(path: str, value: Any) -> bool:
    """A clock-like field (or a physical quantity: floats), left to the digest."""
    return isinstance(value, float) or (path.startswith(CONTINUOUS) and (
        not path.startswith("monitors.") or path.endswith(CONTINUOUS_LEAVES)))


def run_case(case: Case, attach: Callable[[Any, Any], Callable[[], None]] | None = None
             ) -> str:
    """The golden text of a case: one line per scan (changed fields), commands, journal.
    `attach(session, journal recorder)`: something more listening to the run (the
    historian, tests/test_history_recorder.py), which must change nothing; it returns what
    closes it."""
    _MEMO.clear()
    session = open_session(case)
    lines: list[str] = []
    previous: dict[str, tuple[Any, Any]] = {}  # field -> (raw, plain) at the previous scan
    digest = hashlib.sha256()
    with tempfile.TemporaryDirectory() as folder:
        journal_path = Path(folder) / "journal.jsonl"
        recorder = open_journal(session, journal_path)
        close = attach(session, recorder) if attach is not None else None
        script = list(case.script)
        end = int(case.seconds * S)

        def on_scan(cell) -> None:
            snap = cell.snapshot
            changed: dict[str, Any] = {}
            gone: dict[str, Any] = {}
            for key, raw, make in snapshot_fields(cell):
                last = previous.get(key)
                if last is not None and key != "row" and type(last[0]) is type(raw) and \
                        last[0] == raw:
                    continue
                value = make(raw)
                diff(last[1] if last is not None else _MISSING, value, key, changed, gone)
                previous[key] = (raw, value)
            removed = [k for k in gone if k not in changed]
            digest.update(_dump([snap.scan, changed, removed]).encode())
            line: dict[str, Any] = {"scan": snap.scan}
            shown = {k: v for k, v in changed.items() if not _continuous(k, v)}
            if shown:
                line["set"] = shown
            shown_gone = [k for k in removed if not _continuous(k, gone[k])]
            if shown_gone:
                line["del"] = shown_gone
            if snap.scan % CHECKPOINT == 0:
                line["digest"] = digest.hexdigest()[:16]
            if len(line) > 1 or snap.scan == 1:
                lines.append(_dump(line))

        session.scan_listeners.append(on_scan)
        while session.next_time <= end:
            while script and script[0][0] <= session.next_time:
                _, command = script.pop(0)
                if callable(command) and not isinstance(command, cmd.Command):
                    command = command(session.last)
                result = session.command(command)
                lines.append(_dump({"command": cmd.describe(command),
                                    "accepted": result.accepted, "message": result.message}))
            session.scan_once()
        recorder.close()
        if close is not None:
            close()
        lines.append(_dump({"end": session.engine.scan, "digest": digest.hexdigest()}))
        for line in journal_path.read_text(encoding="utf-8").splitlines():
            entry = json.loads(line)
            entry.pop("wall", None)
            entry.pop("session", None)
            entry.pop("prev", None)  # the chain link: follows the wall time
            lines.append(_dump({"journal": entry}))
    return "\n".join(lines) + "\n"


def run_cli_case(args: tuple[str, ...]) -> str:
    """SHA-256 of the trace `plchmi run` writes for these arguments."""
    import contextlib
    import io

    from hmi.cli import main
    with tempfile.TemporaryDirectory() as folder:
        trace = Path(folder) / "trace.csv"
        argv = ["run", str(ROOT / "projects" / args[0]), *args[1:], "--trace", str(trace),
                "--journal", str(Path(folder) / "journal.jsonl")]
        with contextlib.redirect_stdout(io.StringIO()):
            status = main(argv)
        if status != 0:
            raise RuntimeError(f"plchmi {' '.join(argv)} exited {status}")
        return hashlib.sha256(trace.read_bytes()).hexdigest()


def golden_path(name: str) -> Path:
    return GOLDEN / f"{name}.jsonl"


CLI_DIGESTS = GOLDEN / "cli_traces.json"


def record(names: list[str]) -> None:
    GOLDEN.mkdir(exist_ok=True)
    for case in CASES:
        if names and case.name not in names:
            continue
        golden_path(case.name).write_text(run_case(case), encoding="utf-8")
        print(f"recorded {case.name}", flush=True)
    digests = json.loads(CLI_DIGESTS.read_text()) if CLI_DIGESTS.exists() else {}
    for name, args in CLI_CASES:
        if names and name not in names:
            continue
        digests[name] = run_cli_case(args)
        print(f"recorded {name}", flush=True)
    CLI_DIGESTS.write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    argv = sys.argv[1:]
    if not argv or argv[0] != "--record":
        print(__doc__)
        raise SystemExit(2)
    record(argv[1:])
