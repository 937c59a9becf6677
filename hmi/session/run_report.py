"""What a headless run prints at its end (`plchmi run`), and the collector that keeps, scan by
scan, what that summary needs without keeping every snapshot."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.timefmt import seconds

if TYPE_CHECKING:
    from hmi.engine.filter import FilterReport
    from hmi.engine.scan import Engine
    from hmi.engine.snapshot import Snapshot
    from hmi.explain.alarms import AlarmEvent
    from hmi.explain.model import Explanation
    from hmi.plant.base import PlantEvent
    from hmi.project.injection import Injection
    from hmi.session.view import CellView


def run_summary(engine: Engine, last: Snapshot, collector: RunCollector,
                injections: Sequence[Injection], wall_s: float,
                trace: tuple[Path, int] | None = None, time_kind: str = "virtual") -> str:
    project = engine.project
    scans = collector.scans
    rate = scans / wall_s if wall_s > 0 else float("inf")
    lines = [
        f"Ran {project.name} (control {engine.control_name}, policy {engine.policy}) for "
        f"{seconds(last.time_us)} s of {time_kind} time: {scans} scans in {wall_s:.2f} s wall "
        f"({rate:,.0f} scans/s)",
    ]
    if last.plant_counters:
        lines.append("Plant: " + ", ".join(f"{k} {v}" for k, v in last.plant_counters))
    if injections:
        lines.append("Faults injected: " + ", ".join(str(i) for i in injections))
    damage = [e for e in collector.events if e.damage]
    if damage:
        lines.append(f"Damage events: {len(damage)}")
        for event in damage[:10]:
            lines.append(f"  {seconds(event.time_us)} s  {event.device}  {event.kind}: "
                         f"{event.detail}")
        if len(damage) > 10:
            lines.append(f"  ... and {len(damage) - 10} more")
    else:
        lines.append("Damage events: none")
    unsafe_verb = "seen (read-only)" if engine.observe else "written"
    if collector.violations or collector.corrections or collector.first_latch:
        total = sum(collector.violations.values())
        lines.append(f"Filter: {total} constraint violations detected in "
                     f"{len(collector.violations)} constraints "
                     f"({', '.join(f'{k} x{v}' for k, v in sorted(collector.violations.items()))})")
        lines.append(f"  scans corrected {collector.corrections}, scans held in the safe state "
                     f"{collector.safe_scans} (of which fallbacks {collector.fallbacks}"
                     f"{_search_stops(collector)}), "
                     f"max Hamming distance {collector.max_distance}, "
                     f"unsafe outputs {unsafe_verb} {collector.unsafe_written}")
    from hmi.studies.monitor_report import monitor_summary_lines
    lines += monitor_summary_lines(collector.monitors)
    if collector.first_latch:
        scan, t, detail = collector.first_latch
        lines.append(f"Outputs latched safe from scan {scan} ({seconds(t)} s): {detail}")
    from hmi.studies.diag_report import summary_lines
    lines += summary_lines(collector.diagnosis, engine, last)
    outputs = " ".join(f"{n}={int(v)}" for n, v in zip(last.layout.outputs, last.outputs,
                                                       strict=True))
    lines.append(f"Final: steps {'+'.join(last.active_steps) or '-'}; outputs {outputs}; "
                 f"latched {'yes' if last.latched else 'no'}")
    if trace:
        path, count = trace
        lines.append(f"Trace: {path} ({count} scans)")
    return "\n".join(lines)


def _search_stops(collector: RunCollector) -> str:
    """", 3 search budget stops" when the corrector's search was cut short, else ""."""
    stops = collector.search_stops
    return f", {stops} at the search budget" if stops else ""


class RunCollector:
    """What a headless run remembers for its summary, without keeping every snapshot."""

    def __init__(self) -> None:
        self.scans = 0
        self.violations: dict[str, int] = {}
        self.corrections = 0
        self.safe_scans = 0
        self.unsafe_written = 0
        self.fallbacks = 0
        self.search_stops = 0  # fallbacks because the corrector's search used its budget
        self.first_latch: tuple[int, int, str] | None = None
        self.events: list[PlantEvent] = []
        self.step_changes = 0
        self.max_distance = 0
        from hmi.studies.monitor_report import MonitorLog
        self.monitors = MonitorLog()
        self.alarm_events: list[AlarmEvent] = []
        self.explanations: dict[str, Explanation] = {}
        from hmi.studies.diag_report import DiagnosisLog
        self.diagnosis = DiagnosisLog()
        # The last filter report that counted nothing (reports are immutable: the same one
        # counts nothing again), and the last scan's added (a quiet scan has the very same).
        self._nothing: FilterReport | None = None
        self._report: FilterReport | None = None

    def add(self, cell: CellView) -> None:
        snap = cell.snapshot
        self.scans += 1
        self.monitors.add(snap)
        self.diagnosis.add(snap)
        if snap.plant_events:
            self.events.extend(snap.plant_events)
        if cell.alarm_events:
            self.alarm_events.extend(cell.alarm_events)
        if cell.explanations:
            for explanation in cell.explanations:
                if explanation.alarm:
                    self.explanations[explanation.key] = explanation
        self._report = snap.filter_report
        self._count(snap.filter_report)
        if snap.latched and self.first_latch is None:
            reason = snap.latched[0]
            self.first_latch = (reason.scan, reason.time_us, reason.detail)

    def quiet(self, count: int = 1) -> None:
        """`count` quiet scans (hmi.session.Session.run_for): their snapshots, not built,
        differ from the last one added only in what moves by itself (time, values, plant
        state, stopwatches): no event, explanation, latch or diagnoser change, and the very
        same filter report, which counts again what it counted, at each of them."""
        self.scans += count
        report = self._report
        if report is not None and report is not self._nothing:
            self._count(report, count)

    def finish(self, last: CellView) -> None:
        """The run's last scan (built at its end if its scan was quiet): the monitors'
        states the summary shows are its."""
        self.monitors.add(last.snapshot)

    def _count(self, report: FilterReport | None, scans: int = 1) -> None:
        """What `scans` scans with this filter report count."""
        # (a report with nothing violated, changed, left or fallen back on counts nothing:
        # most scans' report, tested in a few reads; and a scan that reuses the very report
        # last found so, without reading it again)
        if report is None or report is self._nothing:
            return
        if not (report.violations or report.changes or report.residual or report.fallback
                or report.safe_state or report.distance):
            self._nothing = report
            return
        for name in report.violated_names:
            self.violations[name] = self.violations.get(name, 0) + scans
        if report.safe_state:
            self.safe_scans += scans
        elif any(c.how != "masked" for c in report.changes):  # masks: diagnosers' lines
            self.corrections += scans
        if report.unsafe_written:
            self.unsafe_written += scans
        if report.fallback:
            self.fallbacks += scans
            self.search_stops += scans * bool(report.stopped)
        self.max_distance = max(self.max_distance, report.distance)
