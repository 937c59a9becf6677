"""What headless commands say about stopwatch monitors: `check` lists them, `run` reports
each fault beside the instant a plain watchdog would have given on the same run."""

from __future__ import annotations

from dataclasses import dataclass

from hmi.engine.monitors import MonitorState
from hmi.engine.snapshot import Snapshot
from hmi.engine.stopwatch import Detection, WatchdogTrip, Window
from hmi.project.model import Project, TaskMonitor
from hmi.project.monitors import monitors_of
from hmi.project.scenarios import scenarios_of
from hmi.timefmt import format_duration, seconds

MAX_FAULTS_SHOWN = 10


def _signals(m: TaskMonitor) -> str:
    parts = [f"start {m.start}", f"end {m.end}"]
    if m.interrupted is not None:
        parts.append(f"interrupted while {m.interrupted}")
    elif m.interrupt is not None:
        parts.append(f"interrupt {m.interrupt}, resume {m.resume}")
    else:
        parts.append("never interrupted")
    return "; ".join(parts)


def monitor_check_lines(project: Project) -> list[str]:
    """The `check` report's sections for monitors and scenarios (empty when none)."""
    lines: list[str] = []
    monitors = monitors_of(project)
    if monitors:
        lines.append(f"Monitors ({len(monitors)}: stopwatch, fault as soon as the task can no "
                     "longer end inside [alpha, gamma))")
        for m in monitors:
            device = f" [{m.device}]" if m.device else ""
            lines.append(f"  {m.name}  {m.windows_text()}  label {m.label}{device}")
            lines.append(f"    {m.title}")
            lines.append(f"    {_signals(m)}")
    scenarios = scenarios_of(project)
    if scenarios:
        lines.append(f"Scenarios ({len(scenarios)}: plchmi run PROJECT --scenario NAME)")
        for s in scenarios:
            inject = ", ".join(str(i) for i in s.injections) or "no fault"
            length = f", {format_duration(s.duration_us)}" if s.duration_us else ""
            lines.append(f"  {s.name}  [{inject}{length}]  {s.description}".rstrip())
    return lines


@dataclass(frozen=True)
class FaultReport:
    """One faulty attempt of a task and what a plain watchdog did on the same attempt."""

    name: str
    label: str
    title: str
    window: Window
    detection: Detection
    watchdog: WatchdogTrip | None
    attempt_open: bool  # the attempt had not ended when the run stopped

    @property
    def earlier_us(self) -> int | None:
        if self.watchdog is None:
            return None
        return self.watchdog.time_us - self.detection.time_us


class MonitorLog:
    """Follows the monitors through a run's snapshots without keeping them.

    A scan whose `monitor_marks` are those of the last one read (and no error) changed no
    detection, trip, location or count: its states are not read at all (a snapshot builds
    them on first read, hmi.engine.monitors.LazyMonitors); `last` is the latest snapshot's.
    """

    def __init__(self) -> None:
        self.detections: dict[tuple[str, int], Detection] = {}
        self.trips: dict[tuple[str, int], WatchdogTrip] = {}
        self._marks: int | None = None  # monitor_marks of the last states read
        self._latest: Snapshot | None = None  # the latest snapshot with the monitors' states

    @property
    def last(self) -> tuple[MonitorState, ...]:
        """The monitors' states at the latest scan that had them."""
        return self._latest.monitors if self._latest is not None else ()

    def add(self, snap: Snapshot) -> None:
        marks = snap.monitor_marks
        if marks == self._marks and snap.error is None:  # only stopwatches ran on
            self._latest = snap
            return
        states = snap.monitors
        if not states:  # no monitors (then never read again), or a failed monitor stage
            if snap.error is None:
                self._marks = marks
                self._latest = snap
            return
        for m in states:
            d = m.last_detection
            if d is not None and (m.name, d.attempt) not in self.detections:
                self.detections[(m.name, d.attempt)] = d
            w = m.watchdog
            if w is not None and (m.name, w.attempt) not in self.trips:
                self.trips[(m.name, w.attempt)] = w
        self._marks = marks
        self._latest = snap

    def detection(self, name: str, attempt: int) -> Detection | None:
        return self.detections.get((name, attempt))

    def trip(self, name: str, attempt: int) -> WatchdogTrip | None:
        return self.trips.get((name, attempt))

    def faults(self) -> list[FaultReport]:
        by_name = {m.name: m for m in self.last}
        out = []
        for (name, attempt), d in sorted(self.detections.items(),
                                         key=lambda kv: (kv[1].time_us, kv[0])):
            m = by_name[name]
            window = Window(m.alpha_us, m.beta_us, m.gamma_us)
            out.append(FaultReport(name, m.label, m.title, window, d,
                                   self.trip(name, attempt),
                                   m.attempt == attempt and m.running))
        return out


def watchdog_text(report: FaultReport) -> str:
    gamma = format_duration(report.window.gamma_us)
    w = report.watchdog
    if w is None:
        if report.attempt_open:
            return f"plain watchdog (x reaches gamma {gamma}): not yet when the run stopped"
        return (f"plain watchdog (x reaches gamma {gamma}): never fires on this attempt "
                "(it ended before gamma)")
    earlier = report.earlier_us or 0
    verdict = (f"the monitor was {seconds(earlier)} s earlier" if earlier > 0
               else "same scan as the monitor")
    return (f"plain watchdog (x reaches gamma {gamma}): {seconds(w.time_us)} s, "
            f"x = {seconds(w.x_us)} s -> {verdict}")


def monitor_summary_lines(log: MonitorLog) -> list[str]:
    """The `run` summary's lines about monitors (empty for a project without monitors)."""
    if not log.last:
        return []
    faults = log.faults()
    lines = [f"Monitors: {len(log.last)} tasks, {len(faults)} faulty attempt"
             f"{'s' if len(faults) != 1 else ''}"]
    for r in faults[:MAX_FAULTS_SHOWN]:
        d = r.detection
        lines.append(f"  {r.label} at {seconds(d.time_us)} s: x = {seconds(d.x_us)} s, "
                     f"y = {seconds(d.y_us)} s ({r.name} attempt {d.attempt}, started "
                     f"{seconds(d.attempt_start_us)} s)")
        lines.append(f"    {d.explain(r.window)}")
        lines.append(f"    {watchdog_text(r)}")
    if len(faults) > MAX_FAULTS_SHOWN:
        lines.append(f"  ... and {len(faults) - MAX_FAULTS_SHOWN} more")
    for m in log.last:
        state = f"{m.label} latched" if m.faulty else m.location
        lines.append(f"  {m.name}: {m.attempt} starts, {m.completed} in time, {m.faults} "
                     f"faulty; now {state}")
    return lines
