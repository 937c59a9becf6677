"""Plain-text reports about diagnosers: `plchmi check`, `plchmi diagnose`, `plchmi run`.

Kept apart from hmi/session/run_report.py so the diagnoser feature adds lines to the shared reports
through two calls (check sections, run summary lines) rather than by editing them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hmi.project.diagnosers import diagnosers_of
from hmi.project.model import DiagnoserSpec, Project
from hmi.studies.diagnosability import analyse
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


def check_sections(project: Project, closed_loop: bool = False) -> list[list[str]]:
    """For `plchmi check`: each diagnoser in brief, then its diagnosability.

    The closed-loop figures take an exploration (seconds to a minute): `check` prints them
    when asked (`--closed-loop`) or when an earlier `diagnose` left them in the cache, and
    otherwise says how to get them, so that checking a project stays instant."""
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
    closed = closed_loop_lines(project, compute=closed_loop)
    if closed:
        sections.append(closed)
    return sections


def diagnose_report(project: Project, farm=None, compute: bool = True) -> str:
    """For `plchmi diagnose`: the automaton in full, then its diagnosability (the diagram's
    upper bound, then the closed loop's)."""
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
    out += closed_loop_lines(project, farm=farm, compute=compute)
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


# -- diagnosability on the closed loop (hmi/studies/loop_sweep.py) ------------------------------

CLOSED_LOOP_EVERY_US = 200_000  # check / diagnose: every 200 ms of the cycle (+ transitions)


def closed_loop_lines(project, every_us: int = CLOSED_LOOP_EVERY_US, farm=None,
                      compute: bool = True, extras: bool = True) -> list[str]:
    """Per configuration where the diagnosers run: isolated with certainty (at some instant,
    and whatever the instant), delays, misdiagnoses, pairs left ambiguous, DC and band."""
    from hmi.project.campaign import campaign_of
    from hmi.studies.closed_loop import diagnosability
    from hmi.studies.diagnosability import iso_band
    from hmi.studies.loop_sweep import DIAGNOSIS_CONFIGS, sweep
    from hmi.studies.loopstate import Unsupported

    spec = campaign_of(project)
    if spec is None or not diagnosers_of(project):
        return []
    title = "Diagnosability on the closed loop"
    try:
        result = sweep(project, DIAGNOSIS_CONFIGS, spec.counter, every_us, extras, farm=farm,
                       compute=compute)
    except Unsupported as exc:
        return [f"{title}: not computed ({exc})"]
    if result is None:
        return [f"{title}: not computed yet; `plchmi diagnose {project.path}` computes it "
                "(or `plchmi check --closed-loop`), then `check` shows it too"]
    variant = f", diagnoser variant {result.variant}" if result.variant else ""
    grid = format_duration(result.every * result.period_us)
    lines = [f"{title} (plant model + control law + filter + diagnosers{variant}): every "
             f"fault injected every {grid} of the {format_duration(result.cycle_us)} cycle"
             + (" and 1 us before and after each diagnoser transition" if result.extras else "")
             + ", each run followed until its loop closes"]
    for config in result.configs:
        d = diagnosability(config, result.of(config.key), result.faults)
        lines.append(f"  {config.title} (diagnosers {config.diagnosis}, filter "
                     f"{config.policy or project.policy}):")
        rows = [["fault", "isolated", "fault -> certain (min/median/max)", "otherwise"]]
        for f in d.faults:
            delays = _spread_text(f.delays_us)
            other = [f"{{{', '.join(labels)}}} {n}" for labels, n in f.ambiguous]
            other += [f"MISDIAGNOSED {label} {n}" for label, n in f.misdiagnosed]
            if f.undetected:
                other.append(f"undetected {f.undetected}")
            rows.append([f.fault, f"{f.isolated}/{f.runs}", delays, ", ".join(other)])
        lines += _table(rows, "    ")
        n = len(d.faults)
        lines.append(f"    isolated with certainty at some instant: {len(d.isolable)}/{n}, DC "
                     f"{100 * d.dc:.1f} % (ISO 13849-1 band {iso_band(d.dc)}); whatever the "
                     f"instant: {len(d.guaranteed)}/{n}, {100 * d.dc_guaranteed:.1f} % "
                     f"({iso_band(d.dc_guaranteed)}); share of instants: "
                     f"{100 * d.dc_weighted:.1f} % ({iso_band(d.dc_weighted)})")
        pairs = d.pairs()
        lines.append("    pairs left ambiguous (runs): " + (", ".join(
            f"{{{a}, {b}}} {runs}" for (a, b), runs in pairs) or "none")
                     + f"; misdiagnoses: {d.misdiagnoses}")
    lines.append(f"  ({sum(result.states.values()):,} closed-loop states explored)")
    return lines


def _spread_text(values) -> str:
    from hmi.studies.closed_loop import spread
    s = spread(values)
    if s is None:
        return "-"
    return " / ".join(seconds(v) for v in s) + " s"
