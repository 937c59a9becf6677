"""The fault campaign (000 §3.3, Table 1): every fault, three configurations, classified.

Configurations (000 Table 1's columns):

* **Diag no Filter** — the diagnosers run and set their flags, but nothing uses them (no
  reconstruction, no masking) and the filter only monitors (it passes every order through);
* **No Diag Filter** — the filter corrects (the project's policy), the diagnosers do not run:
  every flag stays 0 and every x_filter = x;
* **FTC (Diag and Filter)** — both, interacting: flags drive reconstruction and masking.

Classification of one run, by objective criteria only (docs/cispi_valve.md):

* **Defect** — the plant recorded a damaging event (for the valve: `both_orders`,
  `end_stop_overrun`, `stall`);
* **Blocked** — no damage, but the functional cycle stopped: the project's cycle counter did
  not advance during the last `window` of the run;
* **Tolerant** — no damage and the cycle kept going (possibly degraded).

Runs are in virtual time on the simulated plant; each is exactly repeatable.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from hmi.engine.build import EngineOptions, build_engine
from hmi.engine.snapshot import Snapshot
from hmi.farm.bundle import Bundle
from hmi.farm.job import Study, make_job
from hmi.farm.run import Farm
from hmi.plant.base import PlantEvent
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.model import CampaignScenario, CampaignSpec, Project
from hmi.timefmt import format_duration, seconds

DEFECT, BLOCKED, TOLERANT = "Defect", "Blocked", "Tolerant"
OUTCOMES = (BLOCKED, TOLERANT, DEFECT)  # the paper's row order


@dataclass(frozen=True)
class Config:
    key: str
    title: str
    policy: str | None  # None: the project's policy
    diagnosis: str  # hmi.engine.diagnoser.MODES
    high_level: bool = True  # the project's High Level Diagnoser runs (if it has one)


CONFIGS = (
    Config("diag_no_filter", "Diag no Filter", "monitor", "observe"),
    Config("filter_no_diag", "No Diag Filter", None, "off"),
    Config("ftc", "FTC (Diag and Filter)", None, "ftc"),
)

# A project with a High Level Diagnoser also runs the configurations where diagnosers run
# without it: its effect, before and after (not in the table).
WITHOUT_HLD = (
    Config("diag_no_filter_no_hld", "Diag no Filter, without the HLD", "monitor", "observe",
           False),
    Config("ftc_no_hld", "FTC, without the HLD", None, "ftc", False),
)


def configs_of(project: Project) -> tuple[Config, ...]:
    return CONFIGS + (WITHOUT_HLD if project.high_level else ())


# 000 Table 1, as published: (Blocked, Tolerant, Defect) per configuration.
PAPER_TABLE = {
    "diag_no_filter": {BLOCKED: 8, TOLERANT: 1, DEFECT: 4},
    "filter_no_diag": {BLOCKED: 9, TOLERANT: 0, DEFECT: 4},
    "ftc": {BLOCKED: 7, TOLERANT: 4, DEFECT: 2},
}


def classify(damage: list[PlantEvent], cycle_times_us: list[int], length_us: int,
             window_us: int) -> tuple[str, str]:
    """The outcome of one run and its objective reason (damage first, then progress).

    `cycle_times_us` are the instants the cycle counter advanced. A run is Blocked when none
    of them falls inside the last `window_us` of the run, i.e. after `length_us - window_us`.
    """
    harmful = [e for e in damage if e.damage]
    if harmful:
        first = harmful[0]
        more = f" (+{len(harmful) - 1} more)" if len(harmful) > 1 else ""
        return DEFECT, f"{first.kind} at {seconds(first.time_us)} s: {first.detail}{more}"
    start = length_us - window_us
    recent = [t for t in cycle_times_us if t > start]
    if not recent:
        last = (f"the last completed at {seconds(cycle_times_us[-1])} s" if cycle_times_us
                else "none completed")
        return BLOCKED, (f"no cycle in the last {format_duration(window_us)} ({last})")
    return TOLERANT, f"{len(recent)} cycles in the last {format_duration(window_us)}"


@dataclass(frozen=True)
class RunResult:
    scenario: CampaignScenario
    config: Config
    outcome: str
    reason: str  # the objective reason of the outcome
    context: str  # what the diagnoser / filter were doing at the end, for the reader
    damage: tuple[PlantEvent, ...]
    cycles: int  # completed during the whole run
    detected_us: int | None  # first scan a diagnoser left its normal states
    decision: tuple[str, ...]  # the final decision (labels) of the diagnoser(s)
    states: tuple[str, ...]  # the final state of each diagnoser
    # The High Level Diagnoser's refinement, if any: (the local decision it refined, the
    # label it chose, when the local decision started, when it was refined).
    refined: tuple[tuple[str, ...], str, int, int] | None = None

    def line(self) -> str:
        return f"{self.outcome}: {self.reason}" + (f"; {self.context}" if self.context else "")

    def as_dict(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario.name, "fault": self.scenario.fault,
            "device": self.scenario.device, "at_s": self.scenario.at_us / 1e6,
            "phase": self.scenario.phase, "table": self.scenario.table,
            "config": self.config.key, "outcome": self.outcome, "reason": self.reason,
            "context": self.context, "cycles": self.cycles,
            "damage": [{"time_s": e.time_us / 1e6, "kind": e.kind, "detail": e.detail}
                       for e in self.damage],
            "detected_s": None if self.detected_us is None else self.detected_us / 1e6,
            "decision": list(self.decision), "states": list(self.states),
            "refined": None if self.refined is None else {
                "from": list(self.refined[0]), "to": self.refined[1],
                "ambiguous_s": self.refined[2] / 1e6, "refined_s": self.refined[3] / 1e6},
        }


@dataclass
class CampaignResult:
    project: str
    spec: CampaignSpec
    runs: list[RunResult] = field(default_factory=list)

    def table(self, config: str) -> dict[str, int]:
        counts = dict.fromkeys(OUTCOMES, 0)
        for run in self.runs:
            if run.config.key == config and run.scenario.table:
                counts[run.outcome] += 1
        return counts

    def result(self, scenario: CampaignScenario, config: str) -> RunResult:
        return next(r for r in self.runs if r.scenario == scenario and r.config.key == config)

    def as_dict(self) -> dict[str, Any]:
        return {
            "project": self.project, "length_s": self.spec.length_us / 1e6,
            "window_s": self.spec.window_us / 1e6, "counter": self.spec.counter,
            "configurations": [{"key": c.key, "title": c.title, "policy": c.policy,
                                "diagnosis": c.diagnosis} for c in CONFIGS],
            "table": {c.key: self.table(c.key) for c in CONFIGS},
            "paper": PAPER_TABLE if self.spec.paper else None,
            "runs": [r.as_dict() for r in self.runs],
        }


def run_one(project: Project, spec: CampaignSpec, scenario: CampaignScenario, config: Config,
            period_us: int | None = None, jitter_us: int = 0, seed: int = 0) -> RunResult:
    """One scenario under one configuration, in virtual time (each scan up to `jitter_us`
    late, drawn from `seed`: a band point's, hmi/studies/band.py)."""
    plant = SimPlant(project)
    plant.inject(Injection(scenario.fault, scenario.at_us, scenario.device))
    engine = build_engine(project, plant, EngineOptions(
        policy=config.policy, diagnosis=config.diagnosis, high_level=config.high_level))
    period = period_us or project.scan_period_us
    refined: tuple[tuple[str, ...], str, int, int] | None = None
    damage: list[PlantEvent] = []
    cycle_times: list[int] = []
    counter_index: int | None = None
    count = 0
    detected: int | None = None
    snap = None
    times: Sequence[int] = range(0, spec.length_us + 1, period)
    if jitter_us:
        import random
        late = random.Random(f"jitter:{seed}")
        times = [t + late.randrange(jitter_us) for t in times]
    last = times[-1]
    stage = engine.diagnosis
    for now in times:
        # Only the last scan's snapshot is read (the context); the others only advance the
        # engine, and the plant's events, counters and the diagnosers are read where they
        # are (what Engine.step would have copied into a snapshot, with the same values).
        if now == last:
            snap = engine.step(now)
            events = snap.plant_events
        else:
            engine.advance(now)
            events = plant.take_events()
        if events:
            damage.extend(e for e in events if e.damage)
        counters = plant.counters()
        if counter_index is None:
            counter_index = next(k for k, (name, _) in enumerate(counters)
                                 if name == spec.counter)
        value = counters[counter_index][1]
        if value != count:
            cycle_times.extend([now] * (value - count))
            count = value
        if detected is None and stage is not None and stage.faulty:
            detected = now  # (stage.faulty: some record of stage.current is faulty)
        if refined is None and stage is not None and stage.high_level:
            for rt in stage.runtimes:
                if rt.refined is not None:
                    local = rt.spec.states[rt.current]
                    refined = (local.labels, rt.refined[0][0], rt.since_us or 0, now)
    assert snap is not None
    outcome, reason = classify(damage, cycle_times, spec.length_us, spec.window_us)
    decision = tuple(lab for d in snap.diagnosers for lab in d.labels)
    return RunResult(scenario, config, outcome, reason, _context(snap, config, detected),
                     tuple(damage), count, detected, decision,
                     tuple(d.state for d in snap.diagnosers), refined)


def _context(snap: Snapshot, config: Config, detected: int | None) -> str:
    """What the FTC machinery was doing at the end of the run, in a few words."""
    if config.diagnosis == "off":
        parts = ["diagnosers off"]
    else:
        faulty = [d for d in snap.diagnosers if d.faulty]
        if not faulty:
            parts = ["no fault diagnosed"]
        else:
            when = f" from {seconds(detected)} s" if detected is not None else ""
            parts = [f"{d.state} {{{', '.join(d.labels)}}}{when}" for d in faulty]
            if config.diagnosis == "observe":
                parts.append("flags unused")
    if snap.reconstructed:
        parts.append(", ".join(snap.reconstructed) + " reconstructed")
    if snap.masked:
        parts.append(", ".join(snap.masked) + " masked")
    if snap.latched:
        parts.append("outputs latched safe")
    return "; ".join(parts)


# A shard of the campaign holds runs for this many scans or more: a scan costs the valve
# about 4 us of CPU, so a shard is 0.2 s or more of work, and Dask's per-task cost stays
# negligible (docs/studies.md): 48 runs of 40 s, 3 shards of 16.
SHARD_SCANS = 50_000


def run_campaign(project: Project, spec: CampaignSpec,
                 progress: Callable[[int, int, RunResult], None] | None = None,
                 period_us: int | None = None, farm: Farm | None = None,
                 variant: str | None = None) -> CampaignResult:
    """Every scenario under every configuration, in shards of a few runs (hmi/farm/: this
    process, local processes or a cluster, as `farm` says; default the local processes).

    Each run is deterministic and independent, so where the shards run changes nothing but
    the wall time; results are kept in scenario order whatever order they finish in.
    `variant` is the diagnoser variant `project` was loaded with (the workers load it too).
    """
    study = campaign_study(project, spec, period_us, variant)
    done = 0

    def each(index: int, runs: list[RunResult]) -> None:
        nonlocal done
        for run in runs:
            done += 1
            if progress is not None:
                progress(done, study.total_runs, run)

    parts = (farm or Farm()).run(study, each)
    result = CampaignResult(project.name, spec)
    result.runs = [run for part in parts for run in part]
    return result


def campaign_study(project: Project, spec: CampaignSpec, period_us: int | None = None,
                   variant: str | None = None) -> Study:
    configs = configs_of(project)
    tasks = [(i, j) for i in range(len(spec.scenarios)) for j in range(len(configs))]
    period = period_us or project.scan_period_us
    per = max(1, -(-SHARD_SCANS // (spec.length_us // period + 1)))  # runs, at least
    n = max(1, len(tasks) // per)  # shards of `per` runs or more, as even as can be
    bounds = [len(tasks) * k // n for k in range(n + 1)]
    shards = tuple(tuple(tasks[a:b]) for a, b in itertools.pairwise(bounds))
    job = make_job("campaign", Bundle.of(project, variant), _setup, _work,
                   {"period_us": period_us}, shards)

    def decode(shard: tuple[tuple[int, int], ...], data: list[dict[str, Any]]
               ) -> list[RunResult]:
        return [_run_of(spec.scenarios[i], configs[j], r)
                for (i, j), r in zip(shard, data, strict=True)]

    return Study(f"the fault campaign of {project.name}", job, shards,
                 tuple(len(s) for s in shards), _same, decode)


def _setup(project: Project, options: dict[str, Any]) -> tuple[Project, CampaignSpec, Any]:
    from hmi.project.campaign import campaign_of
    spec = campaign_of(project)
    assert spec is not None, "the study was made from this project's campaign"
    return project, spec, options["period_us"]


def _work(state: tuple[Project, CampaignSpec, int | None],
          shard: tuple[tuple[int, int], ...]) -> list[dict[str, Any]]:
    """A shard's runs as plain data (the client rebuilds them with its own scenarios)."""
    project, spec, period = state
    configs = configs_of(project)
    return [_data_of(run_one(project, spec, spec.scenarios[i], configs[j], period))
            for i, j in shard]


def _data_of(r: RunResult) -> dict[str, Any]:
    """A run as plain data (the client rebuilds it with its own scenarios: _run_of)."""
    return {"outcome": r.outcome, "reason": r.reason, "context": r.context,
            "damage": [asdict(e) for e in r.damage], "cycles": r.cycles,
            "detected_us": r.detected_us, "decision": list(r.decision),
            "states": list(r.states),
            "refined": None if r.refined is None else
            [list(r.refined[0]), r.refined[1], r.refined[2], r.refined[3]]}


def _same(data: Any) -> Any:
    return data


def _run_of(scenario: CampaignScenario, config: Config, r: dict[str, Any]) -> RunResult:
    refined = r.get("refined")
    return RunResult(scenario, config, r["outcome"], r["reason"], r["context"],
                     tuple(PlantEvent(**e) for e in r["damage"]), r["cycles"],
                     r["detected_us"], tuple(r["decision"]), tuple(r["states"]),
                     None if refined is None else
                     (tuple(refined[0]), refined[1], refined[2], refined[3]))


# -- the campaign over the declared tolerances -------------------------------------------------


@dataclass
class BandCampaign:
    """The campaign at every plant of a band (hmi/studies/band.py), in point order."""

    band: Any  # hmi.studies.band.Band
    points: list[Any]  # BandPoint
    results: list[CampaignResult]
    which: str = ""  # which corners: "its 32 corners", "64 of its 1024 corners (seed 1)"

    def as_dict(self) -> dict[str, Any]:
        return {"band": self.band.describe(), "which": self.which,
                "plants": [{"point": p.text(self.band), "label": p.label,
                            "table": {c.key: r.table(c.key) for c in CONFIGS},
                            "runs": [{"scenario": run.scenario.name, "config": run.config.key,
                                      "outcome": run.outcome, "reason": run.reason}
                                     for run in r.runs]}
                           for p, r in zip(self.points, self.results, strict=True)]}


def run_campaign_band(project: Project, spec: CampaignSpec, band: Any, points: list[Any],
                      farm: Farm | None = None, variant: str | None = None,
                      which: str = "") -> BandCampaign:
    """Every scenario under every configuration at every point: the point's plant, its
    scans late by up to its jitter (each run deterministic, from the point's seed), in
    shards of a few runs like the campaign's."""
    tasks = [(p, i, j) for p in range(len(points)) for i in range(len(spec.scenarios))
             for j in range(len(CONFIGS))]
    per = max(1, -(-SHARD_SCANS // (spec.length_us // project.scan_period_us + 1)))
    shards = tuple(tuple(tasks[k:k + per]) for k in range(0, len(tasks), per))
    options = {"dimensions": [d.name(True) for d in band.dimensions],
               "points": [[list(p.values), p.seed] for p in points]}
    job = make_job("campaign-band", Bundle.of(project, variant), _band_setup, _band_work,
                   options, shards)

    def decode(shard: tuple[tuple[int, int, int], ...], data: list[dict[str, Any]]
               ) -> list[tuple[int, RunResult]]:
        return [(p, _run_of(spec.scenarios[i], CONFIGS[j], r))
                for (p, i, j), r in zip(shard, data, strict=True)]

    study = Study(f"the fault campaign of {project.name} across its tolerances", job, shards,
                  tuple(len(s) for s in shards), _same, decode)
    parts = (farm or Farm()).run(study)
    results = [CampaignResult(project.name, spec) for _ in points]
    for part in parts:
        for p, run in part:
            results[p].runs.append(run)
    return BandCampaign(band, list(points), results,
                        which or f"its {len(band.corners())} corners")


def _band_setup(project: Project, options: dict[str, Any]) -> tuple[Any, ...]:
    from hmi.project.campaign import campaign_of
    from hmi.studies.band import BandPoint, band_of
    names = options["dimensions"]
    band = band_of(project).restricted(lambda d: d.name(True) in names)
    points = [BandPoint("", tuple(values), seed) for values, seed in options["points"]]
    spec = campaign_of(project)
    assert spec is not None, "the study was made from this project's campaign"
    return [band.apply(project, p) for p in points], spec, band, points


def _band_work(state: tuple[Any, ...], shard: tuple[tuple[int, int, int], ...]
               ) -> list[dict[str, Any]]:
    cells, spec, band, points = state
    out = []
    for p, i, j in shard:
        r = run_one(cells[p], spec, spec.scenarios[i], CONFIGS[j],
                    jitter_us=points[p].jitter_us(band), seed=points[p].seed)
        out.append(_data_of(r))
    return out


SEVERITY = {TOLERANT: 0, BLOCKED: 1, DEFECT: 2}


def band_report_lines(nominal: CampaignResult, over: BandCampaign, samples: int,
                      seed: int) -> list[str]:
    """Table 1 over the band: each count as its range, worst first, and per scenario the
    classes it takes across the band, worst first."""
    band = over.band
    lines = [f"Over the declared tolerances: {len(over.points)} plants ({band.describe()}: "
             f"{over.which} and {samples} points drawn with seed {seed}), every scenario "
             "at each; counts worst .. best"]
    header = ["", *[c.title for c in CONFIGS]]
    rows = [header]
    for outcome in OUTCOMES:
        row = [outcome]
        for c in CONFIGS:
            values = [r.table(c.key)[outcome] for r in over.results]
            worst, best = (max, min) if outcome != TOLERANT else (min, max)
            low, high = worst(values), best(values)
            row.append(str(low) if low == high else f"{low} .. {high}")
        rows.append(row)
    lines += _table(rows)
    lines.append("")
    lines.append("Per scenario, the classes across the band (plants), worst first; the worst "
                 "plant named when it is worse than the nominal class")
    for scenario in [s for s in nominal.spec.scenarios if s.table]:
        cells = []
        for c in CONFIGS:
            seen: dict[str, int] = {}
            for r in over.results:
                outcome = r.result(scenario, c.key).outcome
                seen[outcome] = seen.get(outcome, 0) + 1
            cells.append(", ".join(f"{o} {n}" for o, n in sorted(
                seen.items(), key=lambda kv: -SEVERITY[kv[0]])))
        lines.append(f"  {scenario.name:<10} " + " | ".join(cells))
        for c in CONFIGS:
            base = nominal.result(scenario, c.key).outcome
            for p, r in zip(over.points, over.results, strict=True):
                run = r.result(scenario, c.key)
                if SEVERITY[run.outcome] > SEVERITY[base]:
                    lines.append(f"      {c.title}: {run.outcome} at {p.label} "
                                 f"({p.text(band)}): {run.reason}")
                    break
    return lines


def report_lines(result: CampaignResult) -> list[str]:
    spec = result.spec
    ran = [s for s in spec.scenarios if any(r.scenario == s for r in result.runs)]
    tabled = [s for s in ran if s.table]
    extra = [s for s in ran if not s.table]
    lines = [f"Fault campaign of {result.project}: {len(tabled)} scenarios"
             + (f" (+{len(extra)} extra)" if extra else "")
             + f" x {len(CONFIGS)} configurations, {format_duration(spec.length_us)} of "
             f"virtual time each",
             f"  Defect: a damaging plant event; Blocked: no '{spec.counter}' completed in the "
             f"last {format_duration(spec.window_us)}; Tolerant: otherwise",
             ""]
    header = ["", *[c.title for c in CONFIGS]]
    if spec.paper:
        rows = [header, ["", *["plchmi  paper" for _ in CONFIGS]]]
        for outcome in OUTCOMES:
            row = [outcome]
            for c in CONFIGS:
                row.append(f"{result.table(c.key)[outcome]:>6}  {PAPER_TABLE[c.key][outcome]:>5}")
            rows.append(row)
        lines += _table(rows)
        lines.append("  (paper: 000 Table 1, ProcesSim; plchmi: this project's model, counted "
                     "over the scenarios of the table)")
    else:
        rows = [header] + [[outcome, *[str(result.table(c.key)[outcome]) for c in CONFIGS]]
                           for outcome in OUTCOMES]
        lines += _table(rows)
        lines.append("  (counted over the scenarios of the table, one per fault)")
    if len(configs_of_result(result)) > len(CONFIGS):
        lines.append("")
        lines += hld_lines(result)
    lines.append("")
    lines.append("Per scenario (" + " | ".join(c.title for c in CONFIGS) + ")")
    width = max([10, *(len(s.name) for s in ran)])
    for group, title in ((tabled, None), (extra, "Extra scenarios (not counted in the table)")):
        if not group:
            continue
        if title:
            lines.append("")
            lines.append(title)
        for scenario in group:
            runs = [result.result(scenario, c.key) for c in CONFIGS]
            outcomes = " | ".join(f"{r.outcome:<8}" for r in runs)
            lines.append(f"  {scenario.name:<{width}} {outcomes}"
                         + (f"  {scenario.phase}" if scenario.phase else ""))
            for c, r in zip(CONFIGS, runs, strict=True):
                lines.append(f"      {c.title}: {r.line()}")
    return lines


def configs_of_result(result: CampaignResult) -> tuple[Config, ...]:
    keys = {r.config.key for r in result.runs}
    return tuple(c for c in CONFIGS + WITHOUT_HLD if c.key in keys)


def isolated(result: CampaignResult, config: str) -> list[str]:
    """The scenarios (every one, extras too) whose run ends with exactly the injected fault
    as its diagnosis."""
    return [r.scenario.name for r in result.runs if r.config.key == config
            and r.decision == (r.scenario.fault.split(".")[-1],)]


def hld_lines(result: CampaignResult) -> list[str]:
    """The High Level Diagnoser's effect: faults isolated before and after, per
    configuration where the diagnosers run, and the ambiguities it resolved, how fast."""
    scenarios = sorted({r.scenario.name for r in result.runs})
    n = len(scenarios)
    lines = [f"High Level Diagnoser: its effect over the {n} scenarios (extras included): "
             "runs ending with the injected fault alone as their diagnosis"]
    rows = [["", "without the HLD", "with the HLD"]]
    for before, after in (("diag_no_filter_no_hld", "diag_no_filter"),
                          ("ftc_no_hld", "ftc")):
        title = next(c.title for c in CONFIGS if c.key == after)
        a, b = isolated(result, before), isolated(result, after)
        rows.append([title, f"{len(a)}/{n}, DC {100 * len(a) / n:.1f} %",
                     f"{len(b)}/{n}, DC {100 * len(b) / n:.1f} %"])
    lines += _table(rows)
    resolved = [r for r in result.runs if r.refined is not None and
                r.config.key in ("diag_no_filter", "ftc")]
    if not resolved:
        lines.append("  it resolved no ambiguity in these scenarios")
    for r in resolved:
        local, label, since, at = r.refined  # type: ignore[misc]
        right = "right" if label == r.scenario.fault.split(".")[-1] else "WRONG"
        lines.append(f"  {r.scenario.name} ({r.config.title}): {{{', '.join(local)}}} -> "
                     f"{label} ({right}) at {seconds(at)} s, {seconds(at - since)} s after "
                     "the local decision")
    return lines


def _table(rows: list[list[str]], indent: str = "  ") -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return [(indent + "  ".join(c.rjust(widths[i]) if i else c.ljust(widths[i])
                                for i, c in enumerate(r))).rstrip() for r in rows]
