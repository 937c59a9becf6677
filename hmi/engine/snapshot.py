"""What one scan leaves behind: an immutable record the UI, traces and tests read.

A snapshot never refers to live engine state: every field is a tuple, a frozen dataclass or
a read-only mapping, so a UI thread can hold one while the engine runs the next scan. It is a
NamedTuple rather than a frozen dataclass because one is built every scan and a NamedTuple is
several times cheaper to build. Its `monitors` field is read lazily (Snapshot.monitors): the
stored value may be a LazyMonitors, itself immutable in meaning, built into the states on
first read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, cast

from hmi.engine.criteria import Wait, waits
from hmi.engine.diagnoser import DiagnoserState
from hmi.engine.filter import FilterReport
from hmi.engine.layout import Layout
from hmi.engine.monitors import LazyMonitors, MonitorState
from hmi.engine.recovery import NO_RECOVERY, RecoveryState
from hmi.logic.timers import TimerState
from hmi.plant.base import PlantEvent, PlantStatus


@dataclass(frozen=True)
class LatchReason:
    """Why the outputs are held in the safe state (until a fault reset)."""

    source: str  # "filter", "plant", "internal", "journal"
    detail: str
    scan: int
    time_us: int

    @property
    def part(self) -> str:
        """For an internal error outside the scan's own handling, what failed, in plain
        words ("reading the plant's events": the detail says "PART failed: ..."); "" for
        the rest. Read from the detail, not stored: traces record every field."""
        if self.source != "internal":
            return ""
        text = self.detail.partition(": ")[2]
        return next((part for part in INTERNAL_PARTS if text.startswith(f"{part} failed: ")),
                    "")


# What can fail outside the scan's own error handling (hmi.engine.scan.Engine._failure).
INTERNAL_PARTS = (
    "reading the diagnosers' states", "settling the monitors", "reading the plant's events",
    "reading the recovery's state", "reading the plant's status", "reading the monitors' states",
    "reading the active steps", "computing the timers' elapsed times",
    "watching the steps' supervision times", "reading the filter's report",
    "reading the plant's state", "reading the plant's counters", "reading the masked outputs",
    "writing the outputs to the plant", "writing the safe outputs to the plant")


class StageState(NamedTuple):
    """What a stage shows in a snapshot (Snapshot.stages): its role and its state, a plain
    scalar (hmi.engine.program_stages, a declaration's `shown`)."""

    role: str
    state: Any


class _Fields(NamedTuple):
    """A snapshot's fields as stored (Snapshot reads some of them lazily)."""

    scan: int
    time_us: int
    period_us: int
    layout: Layout
    values: tuple[Any, ...]  # the whole image at the end of the scan (outputs as written)
    fov: tuple[bool, ...]  # functional output vector, before the filter
    outputs: tuple[bool, ...]  # written to the plant
    active_steps: tuple[str, ...]
    fired: tuple[int, ...]  # GRAFCET transitions fired this scan
    timer_elapsed: tuple[int, ...]  # ET of each timer (its Q is in `values`)
    control_name: str  # the control variant running, by name
    mode: str  # "auto", "manual" or "recovery"
    manual: tuple[tuple[str, bool], ...]  # manual requests in effect
    policy: str
    latched: tuple[LatchReason, ...]
    plant: PlantStatus
    plant_state: tuple[tuple[str, Any], ...] = ()
    plant_counters: tuple[tuple[str, int], ...] = ()
    plant_events: tuple[PlantEvent, ...] = ()  # events that happened during this scan
    # Filled by the safety filter, diagnosers and monitors.
    filter_report: FilterReport | None = None  # the safety filter's, of this scan
    diagnosers: tuple[DiagnoserState, ...] = ()
    monitors: tuple[MonitorState, ...] | LazyMonitors = ()
    reconstructed: tuple[str, ...] = ()  # sensors running on their reconstruction
    masked: tuple[str, ...] = ()  # outputs masked by a faulty actuator's flag
    stopped_devices: tuple[str, ...] = ()  # devices the operator stopped
    recovery: RecoveryState = NO_RECOVERY  # the recovery procedure running, and those needed
    error: str | None = None  # an internal error caught during this scan
    scan_wall_us: float = 0.0  # measured, not deterministic
    filter_wall_us: float = 0.0  # the filter stage's share of it (plchmi bench)
    # Changes whenever any task's monitor changes in anything but its stopwatches (location,
    # attempt, detection, watchdog trip, counts): a reader that only cares about those reads
    # `monitors` when it moved (hmi.engine.monitors).
    monitor_marks: int = 0
    # The active GRAFCET steps past their supervision time, the program running in automatic
    # mode (hmi.engine.grafcet: the program is stuck there; what each waits for: `waits`).
    overdue_steps: tuple[str, ...] = ()
    # What each stage that shows something shows (hmi.engine.program_stages, a declaration's
    # `shown`), by role: an added stage's state at the end of the scan.
    stages: tuple[StageState, ...] = ()


class Snapshot(_Fields):
    __slots__ = ()

    @property
    def monitors(self) -> tuple[MonitorState, ...]:
        """Each task's monitor at the end of the scan, built when first read (the engine
        stores a LazyMonitors while a task runs: most scans' states are never read)."""
        stored = tuple.__getitem__(self, _MONITORS)
        if type(stored) is LazyMonitors:
            return stored.states()
        return cast("tuple[MonitorState, ...]", stored)

    @property
    def waits(self) -> tuple[Wait, ...]:
        """What each active GRAFCET step waits for (hmi.engine.criteria): each transition
        leaving it, its receptivity with the current values of what it reads, the steps of a
        join still inactive. Computed when read, from the snapshot alone."""
        return waits(self.layout.grafcet, self.active_steps, self.value)

    def value(self, name: str) -> Any:
        return self.values[self.layout.slots[name]]

    def named(self, names: tuple[str, ...]) -> dict[str, Any]:
        slots = self.layout.slots
        return {n: self.values[slots[n]] for n in names}

    @property
    def inputs(self) -> dict[str, bool]:
        return self.named(self.layout.inputs)

    @property
    def output_map(self) -> dict[str, bool]:
        return dict(zip(self.layout.outputs, self.outputs, strict=True))

    @property
    def fov_map(self) -> dict[str, bool]:
        return dict(zip(self.layout.outputs, self.fov, strict=True))

    @property
    def timers(self) -> tuple[TimerState, ...]:
        """Timer states, built on demand (a scan only records the elapsed times)."""
        lay = self.layout
        return tuple(TimerState(name, self.values[lay.slots[name]], elapsed, preset)
                     for name, elapsed, preset in zip(lay.timers, self.timer_elapsed,
                                                      lay.timer_presets, strict=True))

    @property
    def time_s(self) -> float:
        return self.time_us / 1_000_000

    @property
    def is_safe_latched(self) -> bool:
        return bool(self.latched)


_MONITORS = Snapshot._fields.index("monitors")
