"""What a SCADA sees of one cell: the address space as plain data, without asyncua.

One object for the cell, one per device, and under them a variable for everything the HMI
shows: each input (its value, and the filter's reading of it), each output (the program's
value, the written value, whether the filter changed it and which constraint did), the
safety constraints, each diagnoser (state, labels, partition flags), each stopwatch monitor
(x, y, state), and the cell's mode, policy, latch, scan count and scan time.

Every :class:`Point` carries how to read its value from a snapshot, so the publisher only
walks a list; the model is built once from the project and the engine's layout. Keeping it
free of asyncua lets the docs, the tests and the publisher agree on one description.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hmi.engine.diagnoser import DiagnoserState
from hmi.engine.filter import Change
from hmi.engine.layout import Layout
from hmi.engine.monitors import MonitorState
from hmi.engine.snapshot import Snapshot
from hmi.project.diagnosers import diagnosers_of
from hmi.project.model import Project
from hmi.project.monitors import monitors_of
from hmi.session.view import CellView

# OPC UA data types the model uses (the server maps them onto asyncua's variant types).
BOOL, STRING, STRINGS, DOUBLE, UINT = "Boolean", "String", "String[]", "Double", "UInt64"

# Engineering units (UNECE Recommendation 20 codes, as OPC UA Part 8 asks).
SECOND, MILLISECOND = "s", "ms"


@dataclass(frozen=True)
class Point:
    """One variable: where it sits below the cell object, what it means, how to read it."""

    path: tuple[str, ...]  # browse names below the cell object; the last is the variable's
    description: str
    kind: str  # BOOL, STRING, STRINGS, DOUBLE, UINT
    read: Callable[[CellView], Any]
    unit: str | None = None
    from_plant: bool = False  # read from the plant: uncertain while it does not answer
    # The historian's record of it ("kind:thing", hmi.history.catalogue.Catalogue.origin):
    # the server answers HistoryRead for it from the cell's history ("" if none).
    history: str = ""

    @property
    def name(self) -> str:
        return self.path[-1]


@dataclass(frozen=True)
class Folder:
    """An object below the cell (a device, or a group such as Inputs), with its meaning."""

    path: tuple[str, ...]
    description: str
    device: bool = False  # a device of the cell: the source of its alarms


@dataclass(frozen=True)
class AddressModel:
    cell: str  # the cell object's browse name: the project's name
    description: str
    folders: tuple[Folder, ...]
    points: tuple[Point, ...]

    def device_path(self, device: str | None) -> tuple[str, ...]:
        """Where a device's object is ((): the cell itself, for what belongs to no device)."""
        return (device,) if device and any(f.path == (device,) and f.device
                                           for f in self.folders) else ()


def build_model(project: Project, layout: Layout) -> AddressModel:
    """The address space of a project, with its descriptions and units."""
    b = _Builder()
    devices = _devices(project)
    for device in devices:
        b.folder((device,), f"Device {device} of cell {project.name}", device=True)
    _status(b, project)
    _inputs(b, project, layout)
    _outputs(b, project, layout)
    _constraints(b, project)
    _diagnosers(b, project)
    _monitors(b, project)
    return AddressModel(project.name, project.description, tuple(b.folders), tuple(b.points))


def _devices(project: Project) -> list[str]:
    """The devices the project names, in the order it first names them."""
    found: dict[str, None] = {}
    for var in (*project.inputs, *project.outputs):
        if var.device:
            found.setdefault(var.device)
    for spec in diagnosers_of(project):
        if spec.device:
            found.setdefault(spec.device)
    for task in monitors_of(project):
        if task.device:
            found.setdefault(task.device)
    return list(found)


class _Builder:
    def __init__(self) -> None:
        self.folders: list[Folder] = []
        self.points: list[Point] = []
        self._seen: set[tuple[str, ...]] = set()

    def folder(self, path: tuple[str, ...], description: str, device: bool = False) -> None:
        if path not in self._seen:
            self._seen.add(path)
            self.folders.append(Folder(path, description, device))

    def point(self, path: tuple[str, ...], description: str, kind: str,
              read: Callable[[Snapshot], Any], unit: str | None = None,
              from_plant: bool = False, history: str = "") -> None:
        """A variable read from the engine's snapshot."""
        self.cell_point(path, description, kind, _of_snapshot(read), unit, from_plant, history)

    def cell_point(self, path: tuple[str, ...], description: str, kind: str,
                   read: Callable[[CellView], Any], unit: str | None = None,
                   from_plant: bool = False, history: str = "") -> None:
        """A variable read from the whole scan (the session's alarms too)."""
        self.points.append(Point(path, description, kind, read, unit, from_plant, history))


def _of_snapshot(read: Callable[[Snapshot], Any]) -> Callable[[CellView], Any]:
    return lambda c: read(c.snapshot)


def _under(device: str | None, group: str, name: str) -> tuple[str, ...]:
    return (device, group, name) if device else (group, name)


def _status(b: _Builder, project: Project) -> None:
    b.folder(("Status",), f"How cell {project.name} runs: mode, policy, latch, scans")
    history = {"Mode": "cell:mode", "Policy": "cell:policy", "Latched": "cell:latched",
               "ScanTime": "cell:scan_time", "ActiveAlarms": "cell:alarms"}
    rows: list[tuple[str, str, str, Callable[[CellView], Any], str | None]] = [
        ("Mode", "auto, or manual (the operator's requests, still filtered)", STRING,
         lambda c: c.snapshot.mode, None),
        ("Policy", "the safety filter's policy: monitor, block or correct", STRING,
         lambda c: c.snapshot.policy, None),
        ("Control", "the control program variant running", STRING,
         lambda c: c.snapshot.control_name, None),
        ("Latched", "the outputs are held in their safe state until a fault reset", BOOL,
         lambda c: bool(c.snapshot.latched), None),
        ("LatchReasons", "why the outputs are held safe (empty when not latched)", STRINGS,
         lambda c: [f"{r.source}: {r.detail}" for r in c.snapshot.latched], None),
        ("ScanCount", "scans run since the start", UINT, lambda c: c.snapshot.scan, None),
        ("ScanTime", "how long the last scan took (measured)", DOUBLE,
         lambda c: round(c.scan_wall_us / 1000, 3), MILLISECOND),
        ("ScanPeriod", "the scan period", DOUBLE, lambda c: c.snapshot.period_us / 1000,
         MILLISECOND),
        ("RunTime", "the run's time at the last scan (virtual in a simulation)", DOUBLE,
         lambda c: c.snapshot.time_us / 1e6, SECOND),
        ("PlantConnected", "the plant answers (always true for a simulated plant)", BOOL,
         lambda c: c.snapshot.plant.connected, None),
        ("Plant", "the plant: simulated, or where the real one is", STRING,
         lambda c: c.snapshot.plant.description, None),
        ("StoppedDevices", "devices the operator stopped (outputs held safe)", STRINGS,
         lambda c: list(c.snapshot.stopped_devices), None),
        ("Error", "an internal error caught during the last scan (empty: none)", STRING,
         lambda c: c.error or "", None),
        ("ActiveAlarms", "alarms in the list (active, or cleared but not acknowledged)", UINT,
         lambda c: len(c.alarms), None),
    ]
    for name, text, kind, read, unit in rows:
        b.cell_point(("Status", name), text, kind, read, unit,
                     history=history.get(name, ""))


def _inputs(b: _Builder, project: Project, layout: Layout) -> None:
    filtered = {p.sensor: p for spec in diagnosers_of(project) for p in spec.partitions
                if p.sensor}
    for var in project.inputs:
        b.folder(_under(var.device, "Inputs", var.name)[:-1],
                 f"Inputs of {var.device or project.name}")
        base = _under(var.device, "Inputs", var.name)
        b.folder(base, var.description or var.name)
        slot = layout.slots[var.name]
        b.point((*base, "Value"), f"{var.description or var.name}: the value read",
                BOOL, _value_at(slot), from_plant=True, history=f"value:{var.name}")
        partition = filtered.get(var.name)
        if partition is not None and partition.filtered is not None \
                and partition.filtered in layout.slots:
            fslot = layout.slots[partition.filtered]
            b.point((*base, "FilteredValue"), f"{var.description or var.name}, as the safety "
                    "filter reads it (the estimate while the diagnoser distrusts it)", BOOL,
                    _value_at(fslot), history=f"value:{partition.filtered}")
            b.point((*base, "Reconstructed"), "the filter reads the estimate instead of the "
                    "sensor", BOOL, _named_in(var.name, lambda s: s.reconstructed))


def _outputs(b: _Builder, project: Project, layout: Layout) -> None:
    index = {name: i for i, name in enumerate(layout.outputs)}
    for var in project.outputs:
        b.folder(_under(var.device, "Outputs", var.name)[:-1],
                 f"Outputs of {var.device or project.name}")
        base = _under(var.device, "Outputs", var.name)
        b.folder(base, var.description or var.name)
        i = index[var.name]
        what = var.description or var.name
        b.point((*base, "ProgramValue"), f"{what}: what the program (or the operator in "
                "manual mode) asked for", BOOL, _output_at(i, lambda s: s.fov),
                history=f"fov:{var.name}")
        b.point((*base, "WrittenValue"), f"{what}: what the safety filter wrote to the plant",
                BOOL, _output_at(i, lambda s: s.outputs), history=f"value:{var.name}")
        b.point((*base, "FilterChanged"), "the filter wrote something else than asked", BOOL,
                _changed(var.name))
        b.point((*base, "FilterConstraint"), "the constraints (or safe state) that changed it "
                "(empty when unchanged)", STRING,
                _changed_by(var.name))
        b.point((*base, "Masked"), "masked because the diagnoser distrusts its actuator",
                BOOL, _named_in(var.name, lambda s: s.masked))


def _value_at(slot: int) -> Callable[[Snapshot], bool]:
    """The reader of one slot of the process image."""
    return lambda s: bool(s.values[slot])


def _output_at(index: int, vector: Callable[[Snapshot], tuple[bool, ...]]
               ) -> Callable[[Snapshot], bool]:
    """The reader of one output in an output vector (the program's, or the written one)."""
    return lambda s: bool(vector(s)[index])


def _named_in(name: str, names: Callable[[Snapshot], tuple[str, ...]]
              ) -> Callable[[Snapshot], bool]:
    """The reader of "`name` is among the names a snapshot lists" (masked, reconstructed)."""
    return lambda s: name in names(s)


def _changed(output: str) -> Callable[[Snapshot], bool]:
    return lambda s: _change(s, output) is not None


def _changed_by(output: str) -> Callable[[Snapshot], str]:
    return lambda s: _change_by(s, output)


def _violated(name: str) -> Callable[[Snapshot], bool]:
    return lambda s: name in s.filter_report.violated_names if s.filter_report else False


def _diagnoser(order: int, field: Callable[[DiagnoserState], Any]
               ) -> Callable[[Snapshot], Any]:
    """The reader of one field of the diagnoser at `order` in the snapshot."""
    return lambda s: field(s.diagnosers[order])


def _monitor(order: int, field: Callable[[MonitorState], Any]) -> Callable[[Snapshot], Any]:
    """The reader of one field of the stopwatch monitor at `order` in the snapshot."""
    return lambda s: field(s.monitors[order])


def _change(snapshot: Snapshot, output: str) -> Change | None:
    report = snapshot.filter_report
    if report is None:
        return None
    return next((c for c in report.changes if c.output == output), None)


def _change_by(snapshot: Snapshot, output: str) -> str:
    change = _change(snapshot, output)
    return ", ".join(change.by) if change is not None else ""


def _constraints(b: _Builder, project: Project) -> None:
    b.folder(("Constraints",), f"The safety constraints of cell {project.name}: each must be "
             "false at the end of every scan")
    b.point(("Constraints", "Violated"), "constraints the program's (or operator's) request "
            "violated at the last scan, before the filter", STRINGS,
            lambda s: list(s.filter_report.violated_names) if s.filter_report else [])
    for c in project.constraints:
        b.point(("Constraints", c.name), f"{c.description or c.name} (true: violated by the "
                "request at the last scan)", BOOL,
                _violated(c.name), history=f"constraint:{c.name}")


def _diagnosers(b: _Builder, project: Project) -> None:
    for order, spec in enumerate(diagnosers_of(project)):
        group = _under(spec.device, "Diagnosers", spec.name)
        b.folder(group[:-1], f"Local diagnosers of {spec.device or project.name}")
        b.folder(group, spec.description or spec.name)
        rows: list[tuple[str, str, str, Callable[[Snapshot], Any]]] = [
            ("State", "the diagnoser's state", STRING,
             _diagnoser(order, lambda d: d.state)),
            ("StateDescription", "what the state means", STRING,
             _diagnoser(order, lambda d: d.description)),
            ("Labels", "the fault labels of its decision (empty: normal)", STRINGS,
             _diagnoser(order, lambda d: list(d.labels))),
            ("LabelTexts", "the faults, in words", STRINGS,
             _diagnoser(order, lambda d: list(d.label_texts))),
            ("Faulty", "a fault is detected", BOOL,
             _diagnoser(order, lambda d: d.faulty)),
            ("Certain", "exactly one fault label: isolated with certainty", BOOL,
             _diagnoser(order, lambda d: d.certain)),
        ]
        for name, text, kind, read in rows:
            b.point((*group, name), text, kind, read,
                    history=f"diagnoser:{spec.name}" if name == "State" else "")
        b.folder((*group, "Flags"), "partition flags: the filter distrusts these components")
        for p in spec.partitions:
            b.point((*group, "Flags", p.flag), f"{p.description or p.name} distrusted", BOOL,
                    _diagnoser(order, _flag(p.flag)))


def _flag(flag: str) -> Callable[[DiagnoserState], bool]:
    """The reader of one partition flag of a diagnoser."""
    return lambda d: any(value for name, value in d.flags if name == flag)


def _monitors(b: _Builder, project: Project) -> None:
    for order, task in enumerate(monitors_of(project)):
        group = _under(task.device, "Monitors", task.name)
        b.folder(group[:-1], f"Stopwatch monitors of {task.device or project.name}")
        b.folder(group, task.title)
        rows: list[tuple[str, str, str, Callable[[Snapshot], Any], str | None]] = [
            ("X", "time since the task started", DOUBLE,
             _monitor(order, lambda m: m.x_us / 1e6), SECOND),
            ("Y", "effective work time (frozen while interrupted)", DOUBLE,
             _monitor(order, lambda m: m.y_us / 1e6), SECOND),
            ("State", "waiting, executing, interrupted or faulty", STRING,
             _monitor(order, lambda m: m.location), None),
            ("Alpha", "the shortest normal work time (y)", DOUBLE,
             _monitor(order, lambda m: m.alpha_us / 1e6), SECOND),
            ("Beta", "the longest normal work time (y)", DOUBLE,
             _monitor(order, lambda m: m.beta_us / 1e6), SECOND),
            ("Gamma", "the task must end before this elapsed time (x)", DOUBLE,
             _monitor(order, lambda m: m.gamma_us / 1e6), SECOND),
            ("Faults", "faulty attempts so far", UINT,
             _monitor(order, lambda m: m.faults), None),
        ]
        recorded = {"X": "monitor.x", "Y": "monitor.y", "State": "monitor.state"}
        for name, text, kind, read, unit in rows:
            b.point((*group, name), text, kind, read, unit,
                    history=f"{recorded[name]}:{task.name}" if name in recorded else "")
