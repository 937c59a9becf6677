"""Plain-text reports about diagnosers: `plchmi check`, `plchmi diagnose`, `plchmi run`.

Kept apart from hmi/session/run_report.py so the diagnoser feature adds lines to the shared reports
through two calls (check sections, run summary lines) rather than by editing them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING

from hmi.project.diagnosers import diagnosers_of
from hmi.project.model import DiagnoserSpec, Project
from hmi.studies.diagnosability import analyse
from hmi.timefmt import format_duration, seconds

if TYPE_CHECKING:
    from hmi.engine.diagnoser import DiagnoserState
    from hmi.engine.scan import Engine
    from hmi.engine.snapshot import Snapshot
    from hmi.farm.run import Farm
    from hmi.studies.band import Band, BandPoint
    from hmi.studies.band_sweep import BandSweep
    from hmi.studies.closed_loop import LoopDiagnosability
    from hmi.studies.loop_sweep import SweepResult

    # A figure over the band: its name, how to read it, how to say a value, and whether
    # lower is better.
    Figure = tuple[str, Callable[[LoopDiagnosability], float], Callable[[float], str], bool]


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


def diagnose_report(project: Project, farm: Farm | None = None, compute: bool = True,
                    band: bool = False,
                    samples: int = 0, seed: int = 1) -> str:
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
    out += closed_loop_lines(project, farm=farm, compute=compute, band=band, samples=samples,
                             seed=seed)
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
    _last: tuple[DiagnoserState, ...] = ()

    def add(self, snap: Snapshot) -> None:
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


def summary_lines(log: DiagnosisLog, engine: Engine, last: Snapshot) -> list[str]:
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


def closed_loop_lines(project: Project, farm: Farm | None = None, compute: bool = True,
                      band: bool = False,
                      samples: int = 0, seed: int = 1, every_us: int | None = None,
                      extras: bool = True) -> list[str]:
    """Per configuration where the diagnosers run: isolated with certainty (at some instant,
    and whatever the instant), delays, misdiagnoses, pairs left ambiguous, DC and band; at
    every instant of the cycle (an exact sweep). With `band`, the same over the project's
    declared tolerances (its corners and `samples` seeded points), each figure as its range,
    worst first. `every_us`: a grid instead (and the extras around transitions), for
    quick looks and tests."""
    from hmi.project.campaign import campaign_of
    from hmi.studies.loop_sweep import DIAGNOSIS_CONFIGS, sweep
    from hmi.studies.loopstate import Unsupported

    spec = campaign_of(project)
    if spec is None or not diagnosers_of(project):
        return []
    title = "Diagnosability on the closed loop"
    try:
        result = sweep(project, DIAGNOSIS_CONFIGS, spec.counter, every_us, extras, farm=farm,
                       compute=compute, exact=every_us is None)
    except Unsupported as exc:
        return [f"{title}: not computed ({exc})"]
    if result is None:
        return [f"{title}: not computed yet; `plchmi diagnose {project.path}` computes it "
                "(or `plchmi check --closed-loop`), then `check` shows it too"]
    lines = nominal_lines(project, result)
    if band:
        from hmi.studies.band import exploration_band
        from hmi.studies.band_sweep import band_sweep, exploration_points
        explored = exploration_band(project)
        if not explored.empty:
            points = exploration_points(explored, samples, seed)
            try:
                over = band_sweep(project, explored, DIAGNOSIS_CONFIGS, spec.counter, points,
                                  farm=farm, compute=compute)
            except Unsupported as exc:
                return [*lines, f"  over the declared tolerances: not computed ({exc})"]
            if over is None:
                lines.append(f"  over the declared tolerances: not computed yet (`plchmi "
                             f"diagnose {project.path}` computes it)")
            else:
                lines += ["", *band_lines(project, over, samples, seed)]
    return lines


def nominal_lines(project: Project, result: SweepResult) -> list[str]:
    """The closed loop's figures at one plant (the project's own, or a band point)."""
    from hmi.studies.closed_loop import diagnosability
    from hmi.studies.diagnosability import iso_band

    variant = f", diagnoser variant {result.variant}" if result.variant else ""
    where = f" at {result.point}" if result.point else ""
    lines = [f"Diagnosability on the closed loop{where} (plant model + control law + filter + "
             f"diagnosers{variant}): " + instants_text(result)
             + ", each run followed until its loop closes"]
    for config in result.configs:
        d = diagnosability(config, result.of(config.key), result.faults)
        lines.append(f"  {config.title} (diagnosers {config.diagnosis}, filter "
                     f"{config.policy or project.policy}):")
        rows = [["fault", "isolated" + (" (share of instants)" if result.exact else ""),
                 "fault -> certain (min/median/max)", "otherwise"]]
        for f in d.faults:
            delays = _spread_text(f.delays_us, f.longest_delay_us if result.exact else None)
            other = [f"{{{', '.join(labels)}}} {n}" for labels, n in f.ambiguous]
            other += [f"MISDIAGNOSED {label} {n}" for label, n in f.misdiagnosed]
            if f.undetected:
                other.append(f"undetected {f.undetected}")
            isolated = f"{100 * f.share:.1f} %" if result.exact else f"{f.isolated}/{f.runs}"
            rows.append([f.fault, isolated, delays, ", ".join(other)])
        lines += _table(rows, "    ")
        n = len(d.faults)
        lines.append(f"    isolated with certainty at some instant: {len(d.isolable)}/{n}, DC "
                     f"{100 * d.dc:.1f} % (ISO 13849-1 band {iso_band(d.dc)}); whatever the "
                     f"instant: {len(d.guaranteed)}/{n}, {100 * d.dc_guaranteed:.1f} % "
                     f"({iso_band(d.dc_guaranteed)}); share of instants: "
                     f"{100 * d.dc_weighted:.1f} % ({iso_band(d.dc_weighted)})")
        pairs = d.pairs()
        what = "pieces" if result.exact else "runs"
        lines.append(f"    pairs left ambiguous ({what}): " + (", ".join(
            f"{{{a}, {b}}} {runs}" for (a, b), runs in pairs) or "none")
                     + f"; misdiagnoses: {d.misdiagnoses}")
    lines.append(f"  ({sum(result.states.values()):,} closed-loop states explored)")
    return lines


def instants_text(result: SweepResult) -> str:
    """How the sweep chose its instants, in words."""
    cycle = format_duration(result.cycle_us)
    if result.exact:
        pieces = len(next(iter(result.runs.values()))) // max(1, len(result.faults))
        return (f"every fault injected at every instant of the {cycle} cycle, exactly (the "
                f"cycle split into the pieces of instants that share a run: {pieces:,} per "
                "fault on average)")
    grid = format_duration(result.step_us or result.every * result.period_us)
    return (f"every fault injected every {grid} of the {cycle} cycle"
            + (" and 1 us before and after each diagnoser transition" if result.extras else ""))


def band_lines(project: Project, over: BandSweep, samples: int, seed: int) -> list[str]:
    """The closed loop's figures over the band: each as its range, worst first, with the
    point that gives the worst and the nominal value."""
    from hmi.studies.closed_loop import diagnosability
    from hmi.studies.diagnosability import iso_band

    band = over.band
    lines = [f"Over the declared tolerances: {len(over.points)} plants ({band.describe()}: "
             f"the nominal one, {len(band.corners())} corners, {samples} points drawn with "
             f"seed {seed}; scans on their grid, every switch change bouncing alike: the "
             "scan jitter is covered by `plchmi band`), every instant of each; each figure "
             "worst .. best, the worst plant named"]
    for config in over.configs:
        per = [(point, diagnosability(config, r.of(config.key), r.faults))
               for point, r in zip(over.points, over.results, strict=True)]
        n = len(per[0][1].faults)
        lines.append(f"  {config.title}:")
        figures: list[Figure] = [
            ("isolated with certainty at some instant", lambda d: len(d.isolable),
             partial(_of_with_dc, n), False),
            ("isolated whatever the instant", lambda d: len(d.guaranteed),
             partial(_of, n), False),
            ("share of instants isolated", lambda d: d.dc_weighted,
             lambda v: f"{100 * v:.1f} % ({iso_band(v)})", False),
            ("wrong certain diagnoses (pieces of instants)", lambda d: d.misdiagnoses,
             lambda v: str(v), True),
        ]
        for name, value, show, lower_is_better in figures:
            lines.append("    " + name + ": " + range_text(per, value, show, lower_is_better,
                                                          band))
        rows = [["fault", "share of instants isolated, worst .. best", "worst at"]]
        for k, fault in enumerate(per[0][1].faults):
            shares = [(point, d.faults[k].share) for point, d in per]
            worst = min(shares, key=lambda ps: ps[1])
            best = max(s for _, s in shares)
            rows.append([fault.fault, f"{100 * worst[1]:.1f} .. {100 * best:.1f} %",
                         _point_name(worst[0], band) if worst[1] < best else "-"])
        lines += _table(rows, "    ")
        pairs: dict[tuple[str, str], int] = {}
        for _, d in per:
            for pair, _runs in d.pairs():
                pairs[pair] = pairs.get(pair, 0) + 1
        lines.append("    pairs left ambiguous somewhere in the band (plants): " + (", ".join(
            f"{{{a}, {b}}} {count}" for (a, b), count in sorted(pairs.items())) or "none"))
    lines.append(f"  ({over.states:,} closed-loop states explored)")
    return lines


def _of(n: int, v: float) -> str:
    return f"{v}/{n}"


def _of_with_dc(n: int, v: float) -> str:
    from hmi.studies.diagnosability import iso_band
    return f"{v}/{n}, DC {100 * v / n:.1f} % ({iso_band(v / n)})"


def range_text(per: Sequence[tuple[BandPoint, LoopDiagnosability]],
               value: Callable[[LoopDiagnosability], float], show: Callable[[float], str],
               lower_is_better: bool, band: Band) -> str:
    """`worst .. best (worst at POINT; nominal V)` over the band's plants."""
    values = [(point, value(d)) for point, d in per]
    pick = max if lower_is_better else min
    worst = pick(values, key=lambda pv: pv[1])
    best = (min if lower_is_better else max)(v for _, v in values)
    nominal = next((v for p, v in values if p.label == "nominal"), None)
    text = show(worst[1]) if worst[1] == best else f"{show(worst[1])} .. {show(best)}"
    if worst[1] != best:
        text += f" (worst at {_point_name(worst[0], band)})"
    if nominal is not None and worst[1] != best:
        text += f"; nominal {show(nominal)}"
    return text


def _point_name(point: BandPoint, band: Band) -> str:
    return f"{point.label}: {point.text(band)}"


def _spread_text(values: Sequence[int], longest: int | None = None) -> str:
    from hmi.studies.closed_loop import spread
    s = spread(values, longest)
    if s is None:
        return "-"
    return " / ".join(seconds(v) for v in s) + " s"
