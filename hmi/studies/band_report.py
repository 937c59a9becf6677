"""Fault-free runs across the declared tolerances, in text: `plchmi band`, and the section
(and warnings) `plchmi check` adds.

`check` runs a project's diagnosers across its band: the nominal plant, the band's corners
and up to CHECK_SAMPLES seeded points, runs of at most CHECK_LENGTH_US, CHECK_SCANS scans of a
device in all (a scan of a cell of five devices counts five; a seeded choice of corners, and
fewer points, when they do not all fit: check stays a matter of a second or two), once per
version of the project and of plchmi (cached like the closed-loop exploration). A design that
diagnoses a healthy plant faulty somewhere in the band it declares is told at the transition
that fired, with the run that does it and the command that replays it. `plchmi band` runs
every corner and as many points as asked, and checks stopwatch monitors too.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hmi.errors import Diagnostic
from hmi.project.model import Project
from hmi.studies.band import (
    Band,
    BandPoint,
    BandRuns,
    Event,
    PointRun,
    band_of,
    counter_of,
    fault_free_points,
    run_point,
    variant_of,
)
from hmi.timefmt import format_duration, seconds

CHECK_SAMPLES = 16
CHECK_SCANS = 150_000  # check's budget in scans of one device: the valve's 33 runs, 0.7 s
CHECK_LENGTH_US = 40_000_000
CHECK_SEED = 1
DEFAULT_LENGTH_US = 60_000_000  # a run's length without a campaign to say it
CACHE_VERSION = 1


def run_length(project: Project) -> int:
    """A fault-free run lasts the campaign's length (enough cycles to judge), else 60 s."""
    return project.campaign.length_us if project.campaign is not None else DEFAULT_LENGTH_US


def fault_free_band(project: Project) -> Band:
    """The band of a fault-free run: the dimensions that act without a fault."""
    return band_of(project).restricted(lambda d: not d.faults_only)


def check_points(band: Band, runs: int) -> tuple[list[BandPoint], str]:
    """What `check` runs (about `runs` runs, at least the nominal plant, two corners and two
    seeded points), and how to say it."""
    samples = min(CHECK_SAMPLES, max(2, runs // 2))
    chosen, which = band.some_corners(max(2, runs - 1 - samples), CHECK_SEED)
    points = [band.nominal(), *chosen, *band.sample(samples, CHECK_SEED)]
    return points, f"the nominal plant, {which}, {samples} seeded points"


def check_band(project: Project) -> tuple[list[str], list[Diagnostic]]:
    """The `check` section on the declared tolerances, and its warnings."""
    band = band_of(project)
    if band.empty:
        return [], []
    title = "Tolerances (the band the project is built for): " + _declared(project)
    if not project.diagnosers:
        return [title, f"  (`plchmi band {project.path}` runs the cell across it: stopwatch "
                "monitors, damage, cycles)"], []
    runnable = fault_free_band(project)
    length = min(run_length(project), CHECK_LENGTH_US)
    devices = max(1, len(project.plant.devices))
    points, what = check_points(runnable, CHECK_SCANS // (length // project.scan_period_us + 1)
                                // devices)
    key = _key(project, "check", [p.text(runnable) for p in points], length)
    data = _load(key)
    if data is None:
        # Here, on the project as loaded: a study's workers would load it again from a
        # copy of its files (hmi/farm/bundle.py), which check has no need of.
        counter = counter_of(project)
        runs = BandRuns(runnable, length, [run_point(project, runnable, point, length, counter)
                                           for point in points])
        data = _summary(runs, project)
        _store(key, data)
    lines = [title, f"  fault-free across it: {data['runs']} runs of "
             f"{format_duration(length)} ({what}): " + _verdict(data)]
    lines.append(f"  (`plchmi band {project.path}` runs every corner and more points, and "
                 "shows how much of each diagnoser window the band uses)")
    warnings = [_warning(project, problem, data["runs"]) for problem in data["problems"]]
    return lines, warnings


def _declared(project: Project) -> str:
    parts = []
    for device in project.plant.devices:
        if device.tolerances:
            parts.append(f"{device.name}: " + ", ".join(
                f"{t.param} {t.span()}" + (f" ({t.text})" if "%" in t.text else "")
                for t in device.tolerances))
    if project.plant.scan_jitter_us:
        parts.append(f"scan jitter up to {format_duration(project.plant.scan_jitter_us)}")
    return "; ".join(parts)


KINDS = (("diagnosis", "is diagnosed faulty"), ("monitor", "raises a monitor fault"),
         ("damage", "records damage"), ("stopped", "stops cycling"))


def _summary(runs: BandRuns, project: Project) -> dict[str, Any]:
    """What `check` prints, as plain data (it is cached as JSON)."""
    band = runs.band
    problems = []
    groups = {"diagnosis": runs.diagnosed, "monitor": runs.monitored, "damage": runs.damaged,
              "stopped": runs.stopped}
    for kind, _ in KINDS:
        bad = groups[kind]
        if not bad:
            continue
        first = bad[0]
        event = getattr(first, kind) if kind != "stopped" else None
        problems.append({
            "kind": kind, "count": len(bad), "label": first.point.label,
            "point": first.point.text(band),
            "event": None if event is None else [event.time_us, event.who, event.what,
                                                 event.via, event.transition]})
    return {"runs": len(runs.runs), "problems": problems}


def _verdict(data: dict[str, Any]) -> str:
    if not data["problems"]:
        return "no fault diagnosed, no monitor fault, no damage, every run kept cycling"
    return "; ".join(f"{p['count']} {what}" for p in data["problems"] for kind, what in KINDS
                     if p["kind"] == kind) + " (warnings below)"


def _warning(project: Project, problem: dict[str, Any], total: int) -> Diagnostic:
    kind = problem["kind"]
    event = problem["event"]
    pos = project.plant.pos
    if kind == "diagnosis":
        time_us, who, what, via, number = event
        spec = next((s for s in project.diagnosers if s.name == who), None)
        if spec is not None and number:
            pos = next((t.pos for t in spec.transitions if t.index == number), pos)
        happened = f"{who} -> {what} at {seconds(time_us)} s ({via})"
    elif kind == "monitor":
        time_us, who, what, _, _ = event
        pos = next((m.pos for m in project.monitors if m.name == who), pos)
        happened = f"{what} of {who} at {seconds(time_us)} s"
    elif kind == "damage":
        time_us, who, what, _, _ = event
        happened = f"{who}: {what} at {seconds(time_us)} s"
    else:
        happened = "no cycle completed in the second half of the run"
    text = {k: w for k, w in KINDS}[kind]
    message = (f"a fault-free run in the declared tolerances {text}: {happened}, in "
               f"{problem['label']} ({problem['point']}); {problem['count']} of {total} runs. "
               f"Replay: plchmi band {project.path} --point '{problem['point']}'")
    return Diagnostic(pos, message, None, "warning")


# -- plchmi band ------------------------------------------------------------------------------


def band_lines(project: Project, runs: BandRuns, samples: int, seed: int) -> list[str]:
    band = runs.band
    n = len(runs.runs)
    lines = [f"Fault-free runs of {project.name} across its declared tolerances "
             f"(control {project.default_control}, policy {project.policy}"
             + (", diagnosers driving the filter" if project.diagnosers else "")
             + ", no fault injected)",
             f"  band: {band.describe()}",
             f"  {n:,} runs of {format_duration(runs.length_us)}: the nominal plant, "
             f"{len(band.corners())} corners, {samples:,} points drawn with seed {seed}"]
    groups = (("diagnosed faulty", runs.diagnosed, "diagnosis"),
              ("monitor faults", runs.monitored, "monitor"),
              ("damage", runs.damaged, "damage"), ("stopped cycling", runs.stopped, None))
    for title, bad, attr in groups:
        if not bad:
            lines.append(f"  {title}: none")
            continue
        lines.append(f"  {title}: {len(bad):,} runs, the first {min(5, len(bad))}:")
        for run in bad[:5]:
            event = getattr(run, attr) if attr else None
            lines.append(f"    {run.point.label} ({run.point.text(band)}): "
                         + (_event_text(event) if event else
                            f"{run.late_progress} cycles in the second half"))
    progress = [r.progress for r in runs.runs]
    if progress:
        lines.append(f"  cycles per run: {min(progress)} to {max(progress)}")
    lines += window_lines(project, runs)
    return lines


def _event_text(event: Event) -> str:
    text = f"{event.who} -> {event.what} at {seconds(event.time_us)} s"
    return text + (f" ({event.via})" if event.via else "")


def window_lines(project: Project, runs: BandRuns) -> list[str]:
    """Per diagnoser transition a fault-free plant takes: when it fired across the band,
    against its window, and the margins left."""
    used = runs.windows()
    lines: list[str] = []
    for spec in project.diagnosers:
        rows = [["#", "transition", "fired after", "window", "margin below / above"]]
        for tr in spec.transitions:
            seen = used.get((spec.name, tr.index))
            if seen is None:
                continue
            low, high = seen
            if tr.is_timeout:
                window = f"after {format_duration(tr.after_us or 0)}"
                margins = "-"
            else:
                upper = "inf" if tr.tmax_us is None else format_duration(tr.tmax_us)
                window = f"[{format_duration(tr.tmin_us)}, {upper})"
                below = _ms(low - tr.tmin_us) if tr.tmin_us else "-"
                above = _ms(tr.tmax_us - high) if tr.tmax_us is not None else "-"
                margins = f"{below} / {above}"
            head = f"{tr.source} -> {tr.target}" + (f" on {tr.when}" if tr.when else "")
            rows.append([str(tr.index), head, f"{_s(low)} to {_s(high)} s", window, margins])
        if len(rows) > 1:
            lines.append(f"  Diagnoser {spec.name}: the transitions a healthy plant takes, "
                         "how long after entering their state, against their windows")
            lines += _table(rows, "    ")
    return lines


def _s(us: int) -> str:
    return f"{us / 1e6:.3f}"


def _ms(us: int) -> str:
    return f"{us / 1000:.0f} ms"


def _table(rows: list[list[str]], indent: str) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return [(indent + "  ".join(c.ljust(widths[i]) for i, c in enumerate(r))).rstrip()
            for r in rows]


def point_lines(project: Project, band: Band, point: BandPoint, length_us: int) -> list[str]:
    """One run, replayed: what every diagnoser did, and what went wrong."""
    from hmi.studies.band import run_point_log
    run, log = run_point_log(project, band, point, length_us, counter_of(project))
    lines = [f"Fault-free run of {project.name} at {point.text(band)} for "
             f"{format_duration(length_us)}:"]
    lines += [f"  {seconds(t)} s  {line}" for t, line in log]
    lines.append("  " + _run_verdict(run))
    return lines


def _run_verdict(run: PointRun) -> str:
    parts = []
    if run.diagnosis:
        parts.append("diagnosed faulty: " + _event_text(run.diagnosis))
    if run.monitor:
        parts.append("monitor fault: " + _event_text(run.monitor))
    if run.damage:
        parts.append("damage: " + _event_text(run.damage))
    parts.append(f"{run.progress} cycles, {run.late_progress} in the second half")
    return "; ".join(parts)


# -- the cache (as the closed-loop exploration's) ---------------------------------------------


def _key(project: Project, what: str, points: list[str], length: int) -> str:
    import hashlib

    from hmi.farm.bundle import digest_of
    from hmi.farm.version import code_version
    variant = variant_of(project)
    text = json.dumps([CACHE_VERSION, what, length, points, digest_of(project, variant),
                       code_version().digest])
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _path(key: str) -> Path:
    from hmi.studies.loop_sweep import cache_folder
    return cache_folder() / "band" / f"{key}.json"


def _load(key: str) -> dict[str, Any] | None:
    try:
        data = json.loads(_path(key).read_text())
        return data if isinstance(data, dict) and "problems" in data else None
    except (OSError, ValueError):
        return None


def _store(key: str, data: dict[str, Any]) -> None:
    path = _path(key)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(path)
    except OSError:
        pass  # a cache that cannot be written only costs time


__all__ = ["band_lines", "check_band", "fault_free_band", "fault_free_points",
           "point_lines", "run_length", "run_point"]
