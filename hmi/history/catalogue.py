"""What the historian records of a cell: one :class:`Signal` per value an operator reads.

A signal's name is what an operator types (``plchmi history PROJECT --signals fso,C``) and
what the trend screens list:

==================  =========  =========================================================
name                kind       what
==================  =========  =========================================================
``fso``, ``C``      bool       every Boolean of the image: inputs, outputs as written,
                               timers, observers, memories, GRAFCET steps, the partition
                               flags and filtered sensors (what the chronogram draws)
``C.fov``           bool       an output as the program asked for it (before the filter)
``CSs1``            bool       a safety constraint, violated by the request at that scan
``V1.state``        enum       a local diagnoser's state
``TASK.x``, ``.y``  number s   a stopwatch monitor's elapsed and effective work time
``TASK.state``      enum       waiting, executing, interrupted, faulty
``TASK.duration``   number s   each finished attempt's elapsed time (maintenance)
``TASK.operations`` counter    attempts started
``O.travel``        number s   a device's movement (hmi.project.device_models.Movement):
                               the time from the order's rising edge to the end sensor's
``O.operations``    counter    movements completed
``cell.mode``       enum       auto, manual, recovery
``cell.policy``     enum       monitor, block, correct
``cell.latched``    bool       outputs held safe until a fault reset
``cell.alarms``     number     alarms in the list
``scan.time``       number ms  the longest scan of each second (live runs: a headless run
                               in virtual time does not measure it)
``scan.late``       counter    scans started more than a period late
``plant.KEY``       number     SIMULATION only: the simulated plant's state (a valve's
                               position, a tank's level), numbers and Booleans
==================  =========  =========================================================

A name already taken (a constraint named like a timer) gets its group in front
(``constraint.TON1``). Booleans and enums are stored on change; numbers when they moved by
their deadband since the value last stored (and, for a slow drift, once they have differed
for ``settle_us``); counters on every change. The catalogue also holds the plan the
recorder follows at every scan (which slot of the image, which field of the snapshot), so
that the scan thread walks lists of integers, never names.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from hmi.engine.layout import Layout
from hmi.engine.stopwatch import FAULTY, Phase
from hmi.project.device_models import DEVICE_MODELS
from hmi.project.diagnosers import diagnosers_of
from hmi.project.model import POLICIES, Project
from hmi.project.monitors import monitors_of

BOOL, NUMBER, ENUM, COUNTER = "bool", "number", "enum", "counter"
KINDS = (BOOL, NUMBER, ENUM, COUNTER)
FOV_SUFFIX = ".fov"
MODES = ("auto", "manual", "recovery")
LOCATIONS = (Phase.IDLE.value, Phase.RUNNING.value, Phase.SUSPENDED.value, FAULTY)
STOPWATCH_DEADBAND_S = 0.25  # a running task's x and y: four samples a second
SETTLE_US = 1_000_000  # a number that moved less than its deadband is stored after this
PLANT_DEADBAND = 5.0  # a simulated plant's numbers (%, L, mm): a few units


@dataclass(frozen=True)
class Signal:
    """One recorded value: its name, what it is, how it is stored."""

    name: str
    kind: str  # bool, number, enum, counter
    description: str
    group: str  # io, fov, constraint, diagnoser, monitor, maintenance, cell, simulation
    device: str = ""
    unit: str = ""  # s, ms, or "" (a count, a Boolean, a state)
    labels: tuple[str, ...] = ()  # enum: value i reads labels[i]
    deadband: float = 0.0  # number: the change that is stored at once
    settle_us: int = 0  # number: a smaller change is stored once it has held this long

    @property
    def is_step(self) -> bool:
        """Drawn as steps (held between samples): everything but a moving number."""
        return self.kind != NUMBER

    def text(self, value: float | None) -> str:
        """A stored value as the operator reads it."""
        if value is None:
            return "?"
        if self.kind == BOOL:
            return "1" if value else "0"
        if self.kind == ENUM:
            index = int(value)
            return self.labels[index] if 0 <= index < len(self.labels) else f"#{index}"
        if self.kind == COUNTER:
            return f"{int(value):,}"
        if self.unit == "ms":
            return f"{value:.2f} ms"
        if self.unit == "s":
            return f"{value:.3f} s"
        return f"{value:g}"


@dataclass(frozen=True)
class MonitorPlan:
    order: int  # in Snapshot.monitors
    x: int
    y: int
    state: int
    duration: int
    operations: int


@dataclass(frozen=True)
class MovementPlan:
    order_slot: int  # the written output that starts it
    end_slot: int  # the input that ends it
    travel: int
    operations: int


@dataclass(frozen=True)
class Catalogue:
    """A cell's signals, in the order an engineer reads them, and the recorder's plan."""

    cell: str
    signals: tuple[Signal, ...]
    values: tuple[tuple[int, int], ...]  # (signal, image slot) of the Booleans
    fov: tuple[tuple[int, int], ...]  # (signal, index in Snapshot.fov)
    constraints: tuple[tuple[int, str], ...]  # (signal, constraint name)
    diagnosers: tuple[tuple[int, dict[str, int]], ...]  # by order: (signal, state -> index)
    monitors: tuple[MonitorPlan, ...]
    movements: tuple[MovementPlan, ...]
    mode: int
    policy: int
    latched: int
    alarms: int
    scan_time: int
    scan_late: int
    plant: dict[str, int] = field(default_factory=dict)  # simulated plant's state keys
    # What each signal records, as "kind:thing" (value:fsc, fov:C, constraint:CSs1,
    # diagnoser:V1, monitor.x:TASK, cell:mode...) -> its name: the OPC UA server finds the
    # history of each variable it serves here, whatever name a clash gave the signal.
    origin: dict[str, str] = field(default_factory=dict)
    index: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.index.update({s.name: i for i, s in enumerate(self.signals)})

    def get(self, name: str) -> Signal | None:
        i = self.index.get(name)
        return None if i is None else self.signals[i]

    def devices(self) -> tuple[str, ...]:
        """The devices with a maintenance figure, in the order they were declared."""
        found: dict[str, None] = {}
        for s in self.signals:
            if s.group == "maintenance" and s.device:
                found.setdefault(s.device)
        return tuple(found)

    def maintenance(self, device: str) -> tuple[str, ...]:
        """A device's maintenance signals: its travel times and operation counts."""
        return tuple(s.name for s in self.signals
                     if s.group == "maintenance" and s.device == device)


class _Builder:
    def __init__(self) -> None:
        self.signals: list[Signal] = []
        self.names: set[str] = set()
        self.origin: dict[str, str] = {}

    def add(self, signal: Signal, origin: str = "") -> int:
        """Add a signal; a name already taken (a constraint named like a timer, a task like
        an output) gets its group in front: ``constraint.TON1``."""
        name = signal.name
        if name in self.names:
            base = f"{signal.group}.{signal.name}"
            name, n = base, 2
            while name in self.names:
                name, n = f"{base}.{n}", n + 1
            signal = replace(signal, name=name)
        self.names.add(name)
        self.signals.append(signal)
        if origin:
            self.origin[origin] = name
        return len(self.signals) - 1


BOOLEAN_KINDS = ("output", "input", "timer", "observer", "memory", "step", "flag", "filtered")


def catalogue(project: Project, layout: Layout, simulated: bool = False,
              plant_state: tuple[tuple[str, object], ...] = ()) -> Catalogue:
    """The signals of `project` as the engine lays it out. `plant_state`: a simulated
    plant's state at the start (its keys and value types), recorded as SIMULATION."""
    b = _Builder()
    devices = {v.name: v.device or "" for v in (*project.inputs, *project.outputs)}
    steps = {s.name: s.description for s in layout.grafcet.steps} if layout.grafcet else {}
    values: list[tuple[int, int]] = []
    kinds = dict(zip(layout.names, layout.kinds, strict=True))
    ordered = [*layout.outputs, *layout.inputs, *layout.timers, *layout.observers,
               *layout.memories, *layout.steps,
               *(n for k in ("flag", "filtered") for n in layout.extra.get(k, ()))]
    for name in ordered:
        if kinds[name] not in BOOLEAN_KINDS:
            continue
        what = steps.get(name) or project.describe(name)
        if name in steps:
            what = f"GRAFCET step {name}: {what}" if what != name else f"GRAFCET step {name}"
        i = b.add(Signal(name, BOOL, what, "io", devices.get(name, "")), f"value:{name}")
        values.append((i, layout.slots[name]))
    fov = []
    for k, name in enumerate(layout.outputs):
        i = b.add(Signal(name + FOV_SUFFIX, BOOL,
                         f"{project.describe(name)}, as the program asked (before the filter)",
                         "fov", devices.get(name, "")), f"fov:{name}")
        fov.append((i, k))
    constraints = []
    for c in project.constraints:
        i = b.add(Signal(c.name, BOOL, f"{c.description or c.name} (violated by the request)",
                         "constraint"), f"constraint:{c.name}")
        constraints.append((i, c.name))
    diagnosers = []
    for spec in diagnosers_of(project):
        labels = tuple(s.name for s in spec.states)
        i = b.add(Signal(f"{spec.name}.state", ENUM,
                         f"{spec.device or spec.name}: the diagnoser's state", "diagnoser",
                         spec.device or "", labels=labels), f"diagnoser:{spec.name}")
        diagnosers.append((i, {name: k for k, name in enumerate(labels)}))
    monitors = []
    for order, task in enumerate(monitors_of(project)):
        device = task.device or ""
        x = b.add(Signal(f"{task.name}.x", NUMBER, f"{task.title}: time since it started",
                         "monitor", device, "s", deadband=STOPWATCH_DEADBAND_S,
                         settle_us=SETTLE_US), f"monitor.x:{task.name}")
        y = b.add(Signal(f"{task.name}.y", NUMBER, f"{task.title}: effective work time",
                         "monitor", device, "s", deadband=STOPWATCH_DEADBAND_S,
                         settle_us=SETTLE_US), f"monitor.y:{task.name}")
        state = b.add(Signal(f"{task.name}.state", ENUM, f"{task.title}: its monitor's state",
                             "monitor", device, labels=LOCATIONS), f"monitor.state:{task.name}")
        duration = b.add(Signal(f"{task.name}.duration", NUMBER,
                                f"{task.title}: time each attempt took", "maintenance",
                                device, "s"))
        operations = b.add(Signal(f"{task.name}.operations", COUNTER,
                                  f"{task.title}: attempts started", "maintenance", device))
        monitors.append(MonitorPlan(order, x, y, state, duration, operations))
    movements = []
    for unit in project.plant.devices:
        model = DEVICE_MODELS.get(unit.model)
        if model is None:
            continue
        for movement in model.movements:
            order_name = unit.ports.get(movement.order, movement.order)
            end_name = unit.ports.get(movement.end, movement.end)
            if order_name not in layout.slots or end_name not in layout.slots:
                continue
            device = devices.get(order_name) or unit.name
            travel = b.add(Signal(
                f"{order_name}.travel", NUMBER,
                f"{device}: {movement.name} time ({order_name} to {end_name})",
                "maintenance", device, "s"))
            count = b.add(Signal(f"{order_name}.operations", COUNTER,
                                 f"{device}: {movement.name}s completed", "maintenance",
                                 device))
            movements.append(MovementPlan(layout.slots[order_name], layout.slots[end_name],
                                          travel, count))
    mode = b.add(Signal("cell.mode", ENUM, "auto, manual or recovery mode", "cell",
                        labels=MODES), "cell:mode")
    policy = b.add(Signal("cell.policy", ENUM, "the safety filter's policy", "cell",
                          labels=tuple(POLICIES)), "cell:policy")
    latched = b.add(Signal("cell.latched", BOOL, "outputs held safe until a fault reset",
                           "cell"), "cell:latched")
    alarms = b.add(Signal("cell.alarms", NUMBER, "alarms in the list", "cell"), "cell:alarms")
    scan_time = b.add(Signal("scan.time", NUMBER, "the longest scan of each second "
                             "(measured in live runs)", "cell", unit="ms", deadband=0.1),
                      "cell:scan_time")
    scan_late = b.add(Signal("scan.late", COUNTER, "scans started more than a period late",
                             "cell"))
    plant: dict[str, int] = {}
    if simulated:
        for key, value in plant_state:
            if isinstance(value, bool):
                kind, deadband, settle = BOOL, 0.0, 0
            elif isinstance(value, int | float):
                kind, deadband, settle = NUMBER, PLANT_DEADBAND, SETTLE_US
            else:
                continue
            plant[key] = b.add(Signal(f"plant.{key}", kind, f"SIMULATION: the plant's {key}",
                                      "simulation", deadband=deadband, settle_us=settle))
    return Catalogue(project.name, tuple(b.signals), tuple(values), tuple(fov),
                     tuple(constraints), tuple(diagnosers), tuple(monitors), tuple(movements),
                     mode, policy, latched, alarms, scan_time, scan_late, plant, b.origin)
