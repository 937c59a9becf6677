"""The declared tolerances as a band of plants: its corners, a seeded sample, and fault-free
runs across it.

A project's devices declare the ranges they are built for (`tolerances:`,
hmi/project/tolerances.py) and its plant how late a scan may start (`scan_jitter:`). A **band
point** is one plant in that band: a value for every varying parameter, a scan jitter, and a
seed for what is drawn inside a run (the scans' lateness, the switches' bounce). The band is
explored by its **corners** (every parameter at either end, the jitter at 0 or its maximum:
where windows are tightest) and a **seeded sample** (uniform inside the ranges, seeded so a
run can be replayed from its point's text).

A run is deterministic: scan k reads its inputs at k * period plus a lateness drawn from the
point's seed, the switches bounce as the seed says, and nothing reads a clock.

**Fault-free runs** (:func:`run_point`): the cell as the project runs it (default control,
policy, diagnosers driving the filter), no fault injected; a healthy plant must never be
diagnosed faulty. Each run reports the first faulty diagnoser state it reaches (with the
transition that led there), the first stopwatch monitor fault, damage, whether the cell kept
cycling, and, per diagnoser transition it took, how long after entering its state (the
windows' use across the band: the margins the design has left).

The exhaustive closed-loop studies (hmi/studies/loop_sweep.py) take the band's points too, but
without scan jitter (the exploration needs a time-invariant loop: scans on their grid, every
edge of a switch bouncing alike): jitter is covered by the fault-free runs here.
"""

from __future__ import annotations

import itertools
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

from hmi.errors import UsageError
from hmi.project.device_models import DEVICE_MODELS
from hmi.project.model import Project
from hmi.timefmt import DurationError, format_duration, parse_duration

if TYPE_CHECKING:
    from hmi.farm.job import Study
    from hmi.farm.run import Farm

JITTER = "scan_jitter"


@dataclass(frozen=True)
class Dimension:
    """One varying quantity of the band: a device's parameter, or the scan jitter."""

    device: str  # "" for the scan jitter
    param: str
    low: float
    high: float
    nominal: float
    kind: str  # "duration" or "number"
    scales: tuple[str, ...] = ()  # parameters that vary in proportion (ParamSpec.scales)
    faults_only: bool = False

    def name(self, prefixed: bool) -> str:
        if not self.device:
            return "jitter"
        return f"{self.device}.{self.param}" if prefixed else self.param

    def show(self, value: float) -> str:
        return _show(value, self.kind)


@dataclass(frozen=True)
class BandPoint:
    """One plant of the band: a value per dimension, and the seed of a run's draws."""

    label: str  # "nominal", "corner 3/16", "sample 12"
    values: tuple[float, ...]  # per dimension of the band it was drawn from
    seed: int

    def text(self, band: Band) -> str:
        """`travel=2.4s,bounce=20ms,delay=0s,jitter=10ms,seed=3`: what `--point` reads."""
        prefixed = band.prefixed
        parts = [f"{d.name(prefixed)}={d.show(v)}"
                 for d, v in zip(band.dimensions, self.values, strict=True)]
        return ",".join([*parts, f"seed={self.seed}"])

    def jitter_us(self, band: Band) -> int:
        for d, v in zip(band.dimensions, self.values, strict=True):
            if not d.device:
                return int(v)
        return 0


@dataclass(frozen=True)
class Band:
    """The dimensions a project declares, and what they apply to."""

    project: str
    dimensions: tuple[Dimension, ...]
    prefixed: bool  # several devices: parameters named DEVICE.param

    @property
    def empty(self) -> bool:
        return not self.dimensions

    def nominal(self) -> BandPoint:
        return BandPoint("nominal", tuple(d.nominal for d in self.dimensions), 0)

    def corners(self) -> list[BandPoint]:
        """Every dimension at either end (the jitter at 0 or its maximum)."""
        ends = [(d.low, d.high) for d in self.dimensions]
        combos = list(itertools.product(*ends)) if ends else []
        return [BandPoint(f"corner {k}/{len(combos)}", tuple(values), k)
                for k, values in enumerate(combos, start=1)]

    def some_corners(self, limit: int, seed: int = 1) -> tuple[list[BandPoint], str]:
        """The corners, or at most `limit` of them when there are more (both extremes, then
        a seeded choice); and how to say which."""
        corners = self.corners()
        if len(corners) <= limit:
            return corners, f"its {len(corners)} corners"
        draw = random.Random(f"corners:{seed}")
        inner = sorted(draw.sample(range(1, len(corners) - 1), max(0, limit - 2)))
        chosen = [corners[0], *(corners[k] for k in inner), corners[-1]]
        return chosen, f"{len(chosen)} of its {len(corners)} corners (seed {seed})"

    def sample(self, count: int, seed: int) -> list[BandPoint]:
        """`count` points drawn uniformly inside the ranges, from `seed` (each its own seed
        for the run's draws)."""
        draw = random.Random(f"band:{seed}")
        out = []
        for k in range(1, count + 1):
            values = tuple(_draw(draw, d) for d in self.dimensions)
            out.append(BandPoint(f"sample {k} of seed {seed}", values,
                                 draw.randrange(1 << 31)))
        return out

    def restricted(self, keep: Callable[[Dimension], bool]) -> Band:
        return Band(self.project, tuple(d for d in self.dimensions if keep(d)), self.prefixed)

    def describe(self) -> str:
        """`travel 1.6s to 2.4s, bounce 0s to 20ms, scan jitter up to 10ms`."""
        parts = []
        for d in self.dimensions:
            if not d.device:
                parts.append(f"scan jitter up to {d.show(d.high)}")
            else:
                parts.append(f"{d.name(self.prefixed)} {d.show(d.low)} to {d.show(d.high)}")
        return ", ".join(parts) or "no tolerance declared"

    def parse_point(self, text: str) -> BandPoint:
        """A point from its text (BandPoint.text); dimensions not named keep their nominal
        value. A UsageError says what is wrong."""
        values = {d.name(self.prefixed): d.nominal for d in self.dimensions}
        kinds = {d.name(self.prefixed): d for d in self.dimensions}
        seed = 0
        for part in (p.strip() for p in text.split(",")):
            if not part:
                continue
            name, sep, raw = part.partition("=")
            name, raw = name.strip(), raw.strip()
            if not sep:
                raise UsageError(f"--point: {part!r} is not NAME=VALUE")
            if name == "seed":
                if not (raw.isascii() and raw.isdigit()):
                    raise UsageError(f"--point: seed {raw!r} is not a whole number")
                seed = int(raw)
                continue
            d = kinds.get(name)
            if d is None:
                raise UsageError(f"--point: {name!r} is not a tolerance of {self.project}; "
                                 "it declares " + (", ".join([*kinds, "seed"])))
            value = _parse(raw, d)
            if not d.low <= value <= d.high:
                raise UsageError(f"--point: {name}={raw} is outside the declared band "
                                 f"({d.show(d.low)} to {d.show(d.high)})")
            values[name] = value
        return BandPoint("given", tuple(values[d.name(self.prefixed)] for d in self.dimensions),
                         seed)

    def apply(self, project: Project, point: BandPoint, bounce_pattern: str = "each"
              ) -> Project:
        """The project with the point's plant: its parameters (and those they scale), the
        bounce's seed and pattern on every device that bounces."""
        changes: dict[str, dict[str, Any]] = {}
        for d, value in zip(self.dimensions, point.values, strict=True):
            if not d.device:
                continue
            device = next(s for s in project.plant.devices if s.name == d.device)
            varied = changes.setdefault(d.device, {})
            varied[d.param] = int(value) if d.kind == "duration" else value
            if d.nominal:
                specs = DEVICE_MODELS[device.model].params
                for other in d.scales:
                    base = device.params.get(other, specs[other].default)
                    scaled = base * value / d.nominal
                    varied[other] = round(scaled) if specs[other].kind == "duration" else scaled
        devices = []
        for spec in project.plant.devices:
            params = {**spec.params, **changes.get(spec.name, {})}
            if "bounce_seed" in DEVICE_MODELS[spec.model].params:
                params["bounce_seed"] = point.seed
                params["bounce_pattern"] = bounce_pattern
            devices.append(replace(spec, params=params))
        return replace(project, plant=replace(project.plant, devices=tuple(devices)))


def variant_of(project: Project) -> str | None:
    """The diagnoser variant the project was loaded with, or the diagnosers file given in
    place of its own (`--diagnoser FILE.yaml`, wherever it lies); None: the default. A study
    sends this with the project (hmi/farm/bundle.py), so its workers load the same."""
    if project.diagnosers_file:
        return project.diagnosers_file
    return next((s.variant for s in project.diagnosers if s.variant), None)


def exploration_band(project: Project) -> Band:
    """The dimensions the closed-loop exploration varies (hmi/studies/band_sweep.py): all
    but the scan jitter (scans off their grid never repeat)."""
    return band_of(project).restricted(lambda d: bool(d.device))


def plant_at(project: Project, point: dict[str, Any]) -> Project:
    """The project with an exploration band point's plant (its values and seed, as a sweep's
    options carry them), every switch change of a kind bouncing alike."""
    band = exploration_band(project)
    return band.apply(project, BandPoint("", tuple(point["values"]), int(point["seed"])),
                      "same")


def band_of(project: Project) -> Band:
    """The band a project declares: its devices' tolerances, then the scan jitter."""
    dims = []
    for device in project.plant.devices:
        model = DEVICE_MODELS[device.model]
        for t in device.tolerances:
            spec = model.params[t.param]
            dims.append(Dimension(device.name, t.param, t.low, t.high, t.nominal, t.kind,
                                  spec.scales, spec.faults_only))
    jitter = project.plant.scan_jitter_us
    if jitter:
        dims.append(Dimension("", JITTER, 0, jitter, 0, "duration"))
    return Band(project.name, tuple(dims), len(project.plant.devices) > 1)


def _draw(draw: random.Random, d: Dimension) -> float:
    if d.kind == "duration":
        # whole 100 µs: a value its text gives back exactly
        return 100 * draw.randint(int(d.low) // 100, int(d.high) // 100)
    return round(draw.uniform(d.low, d.high), 4)


def _show(value: float, kind: str) -> str:
    if kind != "duration":
        return f"{value:g}"
    us = int(value)
    text = format_duration(us)
    try:
        return text if parse_duration(text) == us else f"{us}us"
    except DurationError:
        return f"{us}us"


def _parse(raw: str, d: Dimension) -> float:
    if d.kind == "duration":
        try:
            return parse_duration(raw)
        except DurationError as exc:
            raise UsageError(f"--point: {d.param}={raw}: {exc.reason}") from None
    try:
        return float(raw)
    except ValueError:
        raise UsageError(f"--point: {d.param}={raw} is not a number") from None


# --------------------------------------------------------------------------------------------
# Fault-free runs across the band
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Event:
    """Something a fault-free run should never show, where it first did."""

    time_us: int
    who: str  # the diagnoser, monitor or device
    what: str  # "A3 {F3, F13}", "monitor fault", "stall: ..."
    via: str = ""  # the diagnoser's transition
    transition: int = 0  # its number (DiagTransition.index), 0 if none


@dataclass
class PointRun:
    """One fault-free run at one band point."""

    point: BandPoint
    diagnosis: Event | None = None  # the first faulty diagnoser state
    monitor: Event | None = None
    damage: Event | None = None
    progress: int = 0  # the counter's advance during the run
    late_progress: int = 0  # ... during its second half
    # (diagnoser, transition number) -> (least, most) time in its state when it fired
    windows: dict[tuple[str, int], tuple[int, int]] = field(default_factory=dict)

    @property
    def stopped(self) -> bool:
        return self.late_progress == 0

    @property
    def clean(self) -> bool:
        return self.diagnosis is None and self.monitor is None and self.damage is None \
            and not self.stopped


def counter_of(project: Project) -> str | None:
    """The counter that says the cell works: the campaign's, else the plant's first."""
    if project.campaign is not None:
        return project.campaign.counter
    return None


def run_point_log(project: Project, band: Band, point: BandPoint, length_us: int,
                  counter: str | None = None) -> tuple[PointRun, list[tuple[int, str]]]:
    """:func:`run_point`, and what happened in it: (time, line) of every diagnoser state
    change, the first monitor fault and the first damage."""
    log: list[tuple[int, str]] = []
    return run_point(project, band, point, length_us, counter, log=log), log


def run_point(project: Project, band: Band, point: BandPoint, length_us: int,
              counter: str | None = None, diagnosis: str = "ftc",
              log: list[tuple[int, str]] | None = None) -> PointRun:
    """The cell at `point`, fault-free, for `length_us` of virtual time (scans late by up to
    the point's jitter, drawn from its seed)."""
    from hmi.engine.build import EngineOptions, build_engine
    from hmi.plant.sim.plant import SimPlant

    cell = band.apply(project, point)
    plant = SimPlant(cell)
    engine = build_engine(cell, plant, EngineOptions(diagnosis=diagnosis))
    period = cell.scan_period_us
    jitter = point.jitter_us(band)
    late = random.Random(f"jitter:{point.seed}")
    result = PointRun(point)
    stage = engine.diagnosis
    runtimes = stage.runtimes if stage is not None else []
    numbers = [{tr.text(): tr.index for tr in rt.spec.transitions} for rt in runtimes]
    current = [rt.current for rt in runtimes]
    since = [0] * len(runtimes)
    monitors = engine.monitors
    names = [name for name, _ in plant.counters()]
    index = names.index(counter) if counter in names else None
    half = length_us // 2
    start = at_half = None
    scans = length_us // period + 1
    for k in range(scans):
        now = k * period + (late.randrange(jitter) if jitter else 0)
        engine.advance(now)
        for i, rt in enumerate(runtimes):
            if rt.current != current[i]:
                number = numbers[i].get(rt.via, 0)
                if number:
                    elapsed = now - since[i]
                    key = (rt.spec.name, number)
                    seen = result.windows.get(key)
                    result.windows[key] = (elapsed, elapsed) if seen is None else \
                        (min(seen[0], elapsed), max(seen[1], elapsed))
                state = rt.spec.states[rt.current]
                if log is not None:
                    labels = " {" + ", ".join(state.labels) + "}" if state.faulty else ""
                    log.append((now, f"{rt.spec.name} -> {state.name}{labels} ({rt.via})"))
                if state.faulty and result.diagnosis is None:
                    result.diagnosis = Event(now, rt.spec.name, f"{state.name} {{"
                                             + ", ".join(state.labels) + "}", rt.via, number)
                current[i], since[i] = rt.current, now
        for event in plant.take_events():
            if event.damage and result.damage is None:
                result.damage = Event(event.time_us, event.device, f"{event.kind}: "
                                      f"{event.detail}")
                if log is not None:
                    log.append((event.time_us, f"damage: {event.device} {event.kind}: "
                                f"{event.detail}"))
        if monitors is not None and result.monitor is None:
            for m in monitors.current(now):
                if m.faults:
                    result.monitor = Event(now, m.name, f"monitor fault ({m.title})")
                    if log is not None:
                        log.append((now, f"monitor {m.name}: fault ({m.title})"))
                    break
        counters = plant.counters()
        value = counters[index][1] if index is not None else sum(v for _, v in counters)
        if start is None:
            start = value
        if at_half is None and now >= half:
            at_half = value
        last = value
    result.progress = last - (start or 0)
    result.late_progress = last - (at_half if at_half is not None else last)
    return result


@dataclass
class BandRuns:
    """Fault-free runs over a band: every point's run, in the order of the points."""

    band: Band
    length_us: int
    runs: list[PointRun]

    @property
    def diagnosed(self) -> list[PointRun]:
        return [r for r in self.runs if r.diagnosis is not None]

    @property
    def monitored(self) -> list[PointRun]:
        return [r for r in self.runs if r.monitor is not None]

    @property
    def damaged(self) -> list[PointRun]:
        return [r for r in self.runs if r.damage is not None]

    @property
    def stopped(self) -> list[PointRun]:
        return [r for r in self.runs if r.stopped]

    def windows(self) -> dict[tuple[str, int], tuple[int, int]]:
        """Per (diagnoser, transition number): the least and most time in state it fired
        after, over every run."""
        out: dict[tuple[str, int], tuple[int, int]] = {}
        for r in self.runs:
            for key, (low, high) in r.windows.items():
                seen = out.get(key)
                out[key] = (low, high) if seen is None else (min(seen[0], low),
                                                              max(seen[1], high))
        return out


def fault_free_points(band: Band, samples: int, seed: int) -> list[BandPoint]:
    """The nominal plant, every corner, and `samples` seeded points, of the dimensions that
    act without a fault."""
    return [band.nominal(), *band.corners(), *band.sample(samples, seed)]


# A shard holds this many runs (30 ms each for the valve, 0.1-0.3 s for the cells): a few
# tenths of a second of work, far above a Dask task's cost.
SHARD_POINTS = 8


def run_band(project: Project, band: Band, points: Sequence[BandPoint], length_us: int,
             farm: Farm | None = None, counter: str | None = None) -> BandRuns:
    """A fault-free run at every point, in shards (hmi/farm/: this process, local processes
    or a cluster, as `farm` says; the results do not depend on where they ran)."""
    from hmi.farm.run import Farm
    study = band_study(project, band, points, length_us, counter or counter_of(project))
    parts = (farm or Farm()).run(study)
    return BandRuns(band, length_us, [run for part in parts for run in part])


def band_study(project: Project, band: Band, points: Sequence[BandPoint], length_us: int,
               counter: str | None) -> Study:
    from hmi.farm.bundle import Bundle
    from hmi.farm.job import Study, make_job
    shards = tuple(tuple(range(k, min(k + SHARD_POINTS, len(points))))
                   for k in range(0, len(points), SHARD_POINTS))
    options = {"dimensions": [d.name(True) for d in band.dimensions],
               "points": [[list(p.values), p.seed, p.label] for p in points],
               "length_us": length_us, "counter": counter}
    job = make_job("band", Bundle.of(project, variant_of(project)), _setup, _work, options,
                   shards)
    return Study(f"the fault-free runs of {project.name} across its tolerances", job, shards,
                 tuple(len(s) for s in shards), _encode, _decode)


def _setup(project: Project, options: dict[str, Any]) -> dict[str, Any]:
    names = options["dimensions"]
    band = band_of(project).restricted(lambda d: d.name(True) in names)
    points = [BandPoint(label, tuple(values), seed) for values, seed, label in options["points"]]
    return {"project": project, "band": band, "points": points,
            "length": options["length_us"], "counter": options["counter"]}


def _work(state: dict[str, Any], shard: tuple[int, ...]) -> list[PointRun]:
    return [run_point(state["project"], state["band"], state["points"][k], state["length"],
                      state["counter"]) for k in shard]


def _encode(runs: list[PointRun]) -> list[dict[str, Any]]:
    def event(e: Event | None) -> list[Any] | None:
        return None if e is None else [e.time_us, e.who, e.what, e.via, e.transition]
    return [{"point": [list(r.point.values), r.point.seed, r.point.label],
             "diagnosis": event(r.diagnosis), "monitor": event(r.monitor),
             "damage": event(r.damage), "progress": r.progress,
             "late_progress": r.late_progress,
             "windows": [[name, number, low, high]
                         for (name, number), (low, high) in r.windows.items()]}
            for r in runs]


def _decode(shard: Any, data: list[dict[str, Any]]) -> list[PointRun]:
    def event(e: list[Any] | None) -> Event | None:
        return None if e is None else Event(int(e[0]), e[1], e[2], e[3], int(e[4]))
    out = []
    for r in data:
        values, seed, label = r["point"]
        out.append(PointRun(BandPoint(label, tuple(values), int(seed)), event(r["diagnosis"]),
                            event(r["monitor"]), event(r["damage"]), int(r["progress"]),
                            int(r["late_progress"]),
                            {(name, int(number)): (int(low), int(high))
                             for name, number, low, high in r["windows"]}))
    return out
