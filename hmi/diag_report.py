"""Plain-text reports about diagnosers: `plchmi check`, `plchmi diagnose`, `plchmi run`.

Kept apart from hmi/report.py so the diagnoser feature adds lines to the shared reports
through two calls (check sections, run summary lines) rather than by editing them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hmi.engine.diagnosability import analyse
from hmi.project.diagnosers import DiagnoserSpec, diagnosers_of
from hmi.project.model import Project
from hmi.timefmt import format_duration, seconds


def _table(rows: list[list[str]], indent: str = "  ") -> list[str]:
    if not rows:
        return []
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return [(indent + "  ".join(c.ljust(widths[i]) for i, c in enumerate(r))).rstrip()
            for r in rows]


def _partition_lines(spec: DiagnoserSpec) -> list[str]:
    rows = []
    for p in spec.partitions:
        if p.sensor:
            drives = f"{p.filtered} = not {p.flag} and {p.sensor} or {p.flag} and {p.estimate}"
        else:
            drives = "masks " + ", ".join(p.actuators)
        rows.append([p.flag, "{" + ", ".join(p.labels) + "}", drives])
    return _table(rows, "    ")


def check_sections(project: Project) -> list[list[str]]:
    """For `plchmi check`: each diagnoser in brief, then its diagnosability."""
    sections = []
    for spec in diagnosers_of(project):
        normal = sum(1 for s in spec.states if not s.faulty)
        lines = [f"Diagnoser {spec.name}: {spec.description}".rstrip(": "),
                 f"  {len(spec.states)} states ({normal} normal, {len(spec.states) - normal} "
                 f"faulty), {len(spec.transitions)} transitions, initial {spec.initial}, "
                 f"{len(spec.labels)} labels in {len(spec.partitions)} partitions:"]
        lines += _partition_lines(spec)
        sections.append(lines)
        sections.append(analyse(spec).lines())
    return sections


def diagnose_report(project: Project) -> str:
    """For `plchmi diagnose`: the automaton in full, then its diagnosability."""
    specs = diagnosers_of(project)
    if not specs:
        return f"Project {project.name} declares no diagnoser."
    out: list[str] = []
    for spec in specs:
        report = analyse(spec)
        kind = {}
        for name in report.normal:
            kind[name] = "normal"
        for name in report.certain_states:
            kind[name] = "certain"
        for name in report.intermediate:
            kind[name] = "ambiguous, intermediate"
        for name in report.final_ambiguous:
            kind[name] = "ambiguous, final"
        out.append(f"Diagnoser {spec.name}" + (f" ({spec.device})" if spec.device else "")
                   + (f": {spec.description}" if spec.description else ""))
        out.append("  Partitions (flag, labels, what the flag drives)")
        out += _partition_lines(spec)
        out.append(f"  States ({len(spec.states)}; initial {spec.initial})")
        out += _table([[s.name, kind.get(s.name, "unreachable"),
                         "{" + ", ".join(s.labels) + "}" if s.labels else "-", s.description]
                        for s in spec.states], "    ")
        out.append(f"  Transitions ({len(spec.transitions)}, tried in this order; outputs are "
                   "the orders written at the previous scan; windows [tmin, tmax))")
        out += _table([[str(t.index), t.source, "->", t.target,
                        f"after {format_duration(t.after_us or 0)}" if t.is_timeout
                        else str(t.when), "" if t.is_timeout else t.window_text(),
                        t.description] for t in spec.transitions], "    ")
        if spec.resync:
            out.append("  Fault reset: re-synchronise to the first normal state whose "
                       "condition holds")
            out += _table([[str(r.when), "->", r.target] for r in spec.resync], "    ")
        out.append("")
        out += report.lines()
        out.append("")
    return "\n".join(out).rstrip()


@dataclass
class DiagnosisLog:
    """What a headless run remembers about its diagnosers, for the summary."""

    changes: list[tuple[int, str, str, tuple[str, ...], str, str]] = field(
        default_factory=list)  # (time, diagnoser, state, labels, via, flags set)
    normal_moves: int = 0
    masked_requests: int = 0  # scans where the program asked for an order the mask withdrew
    reconstructed_since: dict[str, int] = field(default_factory=dict)
    masked_since: dict[str, int] = field(default_factory=dict)
    _last: tuple = ()

    def add(self, snap) -> None:
        records = snap.diagnosers
        if records is not self._last:
            previous = {d.name: d for d in self._last}
            for d in records:
                before = previous.get(d.name)
                if before is not None and before.state == d.state and \
                        before.since_us == d.since_us:
                    continue
                if d.faulty or (before is not None and before.faulty):
                    flags = ", ".join(name for name, on in d.flags if on)
                    self.changes.append((snap.time_us, d.name, d.state, d.labels, d.via,
                                         flags))
                elif before is not None:
                    self.normal_moves += 1
            self._last = records
        for name in snap.reconstructed:
            self.reconstructed_since.setdefault(name, snap.time_us)
        for name in snap.masked:
            self.masked_since.setdefault(name, snap.time_us)
        if snap.masked and any(snap.fov_map[name] for name in snap.masked):
            self.masked_requests += 1


def summary_lines(log: DiagnosisLog, engine, last) -> list[str]:
    """Diagnoser lines of the run summary: faulty states reached, flags, what they drive."""
    stage = engine.diagnosis
    if stage is None:
        return []
    lines = [f"Diagnosers ({stage.mode}): {log.normal_moves} normal transitions"]
    shown = log.changes[:20]
    for t, name, state, labels, via, flags in shown:
        decision = ("{" + ", ".join(labels) + "}") if labels else "normal"
        lines.append(f"  {seconds(t)} s  {name} -> {state} {decision}"
                     + (f"  flags {flags}" if flags else "") + (f"  ({via})" if via else ""))
    if len(log.changes) > len(shown):
        lines.append(f"  ... and {len(log.changes) - len(shown)} more")
    for d in last.diagnosers:
        on = [n for n, v in d.flags if v]
        lines.append(f"  final: {d.what()}; flags " + (", ".join(f"{n}=1" for n in on)
                                                        if on else "all 0"))
    specs = {p.sensor: p for s in diagnosers_of(engine.project) for p in s.partitions
             if p.sensor}
    if log.reconstructed_since:
        for sensor, since in log.reconstructed_since.items():
            p = specs.get(sensor)
            source = f" from {p.estimate}" if p else ""
            now = "" if sensor in last.reconstructed else " (no longer)"
            lines.append(f"  reconstructed: {sensor}{source} since {seconds(since)} s{now}")
    if log.masked_since:
        lines.append("  masked: " + ", ".join(f"{n} since {seconds(t)} s"
                                              for n, t in log.masked_since.items())
                     + f" ({log.masked_requests} scans withdrew an order the program asked for)")
    elif stage.mode == "ftc":
        lines.append("  masked: none")
    return lines
