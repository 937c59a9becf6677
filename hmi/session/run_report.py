"""Plain-text reports printed by the headless commands (check, run)."""

from __future__ import annotations

from hmi.project.model import Constraint, ControlLaw, Project
from hmi.timefmt import format_duration, seconds


def _table(rows: list[list[str]], indent: str = "  ") -> list[str]:
    if not rows:
        return []
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = []
    for row in rows:
        cells = [cell.ljust(widths[i]) for i, cell in enumerate(row)]
        lines.append((indent + "  ".join(cells)).rstrip())
    return lines


def constraint_meaning(c: Constraint) -> str:
    """What a constraint forces, in the papers' words (h0: must be 0, h1: must be 1)."""
    if c.kind == "combined":
        return "combined over " + ", ".join(c.outputs)
    ctx = " and ".join(str(lit) for lit in c.context_literals) or "always"
    if c.output_positive:
        return f"{c.outputs[0]} must be 0 when {ctx}"
    return f"{c.outputs[0]} must be 1 when {ctx}"


def _law_summary(law: ControlLaw) -> str:
    parts = []
    if law.grafcet:
        g = law.grafcet
        initial = ", ".join(s.name for s in g.steps if s.initial)
        parts.append(f"GRAFCET {len(g.steps)} steps (initial {initial}), "
                     f"{len(g.transitions)} transitions")
        supervised = [f"{s.name} {format_duration(s.supervision_us)}" for s in g.steps
                      if s.supervision_us is not None]
        if supervised:
            parts.append("supervision " + ", ".join(supervised))
    if law.equations:
        parts.append(f"{len(law.equations)} equations")
    return "; ".join(parts)


def check_report(project: Project, sections: list[list[str]] = ()) -> str:
    lines = [f"Project {project.name}: {project.description}".rstrip(": "),
             "  files: " + ", ".join(project.files),
             f"  scan period {format_duration(project.scan_period_us)}, "
             f"filter policy {project.policy}, plant {project.plant.kind}"
             + (": " + ", ".join(f"{d.name} ({d.model})" for d in project.plant.devices)
                if project.plant.devices else ""),
             ""]
    lines.append(f"Inputs ({len(project.inputs)})")
    lines += _table([[v.name, str(v.address or ""), v.description] for v in project.inputs])
    lines.append(f"Outputs ({len(project.outputs)})")
    lines += _table([[v.name, str(v.address or ""), f"safe {int(v.safe)}", v.description]
                     for v in project.outputs])
    if project.memories:
        lines.append(f"Memories ({len(project.memories)})")
        lines += _table([[v.name, f"initial {int(v.safe)}", v.description]
                         for v in project.memories])
    lines.append(f"Timers ({len(project.timers)})")
    lines += _table([[t.name, t.kind, format_duration(t.preset_us), f"input {t.input}",
                      t.description] for t in project.timers])
    lines.append(f"Observers ({len(project.observers)})")
    rows = []
    for o in project.observers:
        body = str(o.expr) if o.expr else f"set {o.set}, reset {o.reset}"
        rows.append([o.name, body, o.description])
    lines += _table(rows)
    lines.append(f"Control law ({len(project.controls)} variant"
                 f"{'s' if len(project.controls) != 1 else ''})")
    lines += _table([[name + (" (default)" if name == project.default_control else ""),
                      _law_summary(law), law.description]
                     for name, law in project.controls.items()])
    simple = len(project.simple_constraints)
    combined = len(project.combined_constraints)
    lines.append(f"Safety constraints ({len(project.constraints)}: {simple} simple, "
                 f"{combined} combined)")
    lines += _table([[c.name, c.kind, c.expr.source, constraint_meaning(c)]
                     for c in project.constraints])
    from hmi.monitor_report import monitor_check_lines
    monitor_lines = monitor_check_lines(project)
    if monitor_lines:
        lines += ["", *monitor_lines]
    for section in (*project.check_sections, *sections):
        lines.append("")
        lines.extend(section)
    warnings = project.warnings
    if warnings:
        lines.append("")
        lines.append(f"Warnings ({len(warnings)})")
        lines += [f"  {w}" for w in warnings]
    lines.append("")
    lines.append("OK: the project is valid")
    return "\n".join(lines)


def run_summary(engine, last, collector, injections, wall_s: float, trace=None,
                time_kind: str = "virtual") -> str:
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
    monitors = getattr(collector, "monitors", None)
    if monitors is not None:
        from hmi.monitor_report import monitor_summary_lines
        lines += monitor_summary_lines(monitors)
    if collector.first_latch:
        scan, t, detail = collector.first_latch
        lines.append(f"Outputs latched safe from scan {scan} ({seconds(t)} s): {detail}")
    diagnosis = getattr(collector, "diagnosis", None)
    if diagnosis is not None:
        from hmi.diag_report import summary_lines
        lines += summary_lines(diagnosis, engine, last)
    outputs = " ".join(f"{n}={int(v)}" for n, v in zip(last.layout.outputs, last.outputs,
                                                       strict=True))
    lines.append(f"Final: steps {'+'.join(last.active_steps) or '-'}; outputs {outputs}; "
                 f"latched {'yes' if last.latched else 'no'}")
    if trace:
        path, count = trace
        lines.append(f"Trace: {path} ({count} scans)")
    return "\n".join(lines)


def _search_stops(collector) -> str:
    """", 3 search budget stops" when the corrector's search was cut short, else ""."""
    stops = getattr(collector, "search_stops", 0)
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
        self.events = []
        self.step_changes = 0
        self.max_distance = 0
        from hmi.monitor_report import MonitorLog
        self.monitors = MonitorLog()
        self.alarm_events = []
        self.explanations = {}
        from hmi.diag_report import DiagnosisLog
        self.diagnosis = DiagnosisLog()
        self._nothing = None  # the last filter report that counted nothing (reports are
        # immutable: the same one counts nothing again)
        self._report = None  # the last scan's added (a quiet scan has the very same)

    def add(self, snap) -> None:
        self.scans += 1
        self.monitors.add(snap)
        self.diagnosis.add(snap)
        if snap.plant_events:
            self.events.extend(snap.plant_events)
        if snap.alarm_events:
            self.alarm_events.extend(snap.alarm_events)
        if snap.explanations:
            for explanation in snap.explanations:
                if explanation.alarm:
                    self.explanations[explanation.key] = explanation
        self._report = snap.filter
        self._count(snap.filter)
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

    def finish(self, last) -> None:
        """The run's last snapshot (built at its end if its scan was quiet): the monitors'
        states the summary shows are its."""
        self.monitors.add(last)

    def _count(self, report, scans: int = 1) -> None:
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
            self.search_stops += scans * bool(getattr(report, "stopped", ""))
        self.max_distance = max(self.max_distance, report.distance)
