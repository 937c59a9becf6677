"""The soak farm: ``plchmi soak PROJECT --seeds 1-1000``, one soak session per seed, each a
shard (hmi/farm/: local processes or a Dask cluster), every failing seed shrunk where it ran.

A shard is one seed: the soak's own session (:func:`hmi.soak.runner.session`, the same that
``plchmi soak --seed N`` runs) and, when an invariant broke, its own shrinker bounded by a
number of replays — not by seconds, so that the shrunk list, like everything in the report,
is the same whatever machine ran it. The report: the seeds' figures added up, then each
failing seed with its invariant and the step list that reproduces it.
"""

from __future__ import annotations

import asyncio
import itertools
import tempfile
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from hmi.farm.bundle import Bundle
from hmi.farm.job import Study, make_job
from hmi.farm.run import Farm
from hmi.project.model import Project
from hmi.soak.runner import ShrinkStopped, SoakConfig, session, shrink, what_raised
from hmi.soak.steps import format_steps, steps_header


@dataclass(frozen=True)
class SeedResult:
    """One seed's session, as plain data (what a worker sends back and the store keeps)."""

    seed: int
    steps: int
    virtual_us: int
    scans: int
    gestures: dict[str, int]
    commands: dict[str, int]
    refused: int
    raised: int
    transitions: int
    journal_lines: int
    max_alarms: int
    checks: dict[str, int]
    skipped: int
    broken: str | None = None  # the first broken invariant, in words
    invariant: str | None = None
    shrunk: str | None = None  # the step list that reproduces it (steps.py's text form)
    shrunk_steps: int = 0
    replays: int = 0
    error: str | None = None  # what raised: the session (no figures then) or a shrink replay

    @property
    def ok(self) -> bool:
        return self.broken is None


def farm_study(project: Project, config: SoakConfig, seeds: list[int],
               shrink_replays: int) -> Study:
    """One shard per seed; `config` is the template (its seed replaced by each)."""
    bundle = Bundle.of(project)
    options = {"project_file": bundle.project_file, "control": config.control,
               "size": list(config.size), "minutes": config.minutes,
               "max_steps": config.max_steps, "shrink_replays": shrink_replays,
               "split": config.split}
    shards = tuple(seeds)
    job = make_job("soak", bundle, _setup, _work, options, shards)
    return Study(f"the soak farm of {project.name}", job, shards, tuple(1 for _ in shards),
                 _encode, _decode)


def run_farm(project: Project, config: SoakConfig, seeds: list[int], shrink_replays: int,
             farm: Farm | None = None) -> list[SeedResult]:
    return (farm or Farm()).run(farm_study(project, config, seeds, shrink_replays))


def _setup(project: Project, options: dict[str, Any]) -> tuple[SoakConfig, int]:
    size = tuple(options["size"])
    config = SoakConfig(project.path / options["project_file"], options["control"],
                        (int(size[0]), int(size[1])), options["minutes"], 1,
                        options["max_steps"], split=bool(options["split"]))
    return config, int(options["shrink_replays"])


def _work(state: tuple[SoakConfig, int], seed: int) -> SeedResult:
    """One seed. What raises in it is that seed's failure, reported as such: the other
    seeds' results, and the farm, go on."""
    template, replays_allowed = state
    config = replace(template, seed=seed)
    try:
        with tempfile.TemporaryDirectory(prefix="plchmi-soak-farm-") as folder:
            result = asyncio.run(session(config, journal_dir=Path(folder)))
    except Exception as exc:
        raised = f"the session raised {what_raised(exc)}"
        return SeedResult(seed, 0, 0, 0, {}, {}, 0, 0, 0, 0, 0, {}, 0, broken=raised,
                          invariant="raised", error=raised)
    g = result.gestures
    base = SeedResult(seed, len(result.steps), result.virtual_us, result.scans,
                      dict(sorted(g.items())), dict(sorted(result.commands.items())),
                      result.refused, result.raised, result.transitions, result.journal_lines,
                      result.max_alarms, dict(sorted(result.checks.items())), result.skipped)
    if result.ok:
        return base
    broken = result.broken[0]
    steps, replays = result.steps, 0
    error: str | None = None
    if replays_allowed > 0 and len(steps) > 1:
        try:
            steps, replays = asyncio.run(shrink(config, steps, broken.invariant, float("inf"),
                                                replays_allowed))
        except ShrinkStopped as stop:
            steps, replays, error = stop.best, stop.replays, f"the shrink stopped: {stop}"
    return replace(base, broken=str(broken), invariant=broken.invariant,
                   shrunk=format_steps(steps), shrunk_steps=len(steps), replays=replays,
                   error=error)


def _encode(result: SeedResult) -> dict[str, Any]:
    return dict(result.__dict__)


def _decode(seed: int, data: dict[str, Any]) -> SeedResult:
    result = SeedResult(**data)
    if result.seed != seed:
        raise ValueError(f"kept result of seed {result.seed} where seed {seed} belongs")
    return result


def report_lines(results: list[SeedResult], project: Project, config: SoakConfig,
                 typed_path: str, shrink_replays: int) -> list[str]:
    """The farm's report: deterministic (no wall time, no path but the one typed)."""
    broken = [r for r in results if not r.ok]
    seeds = [r.seed for r in results]
    total = Counter[str]()
    for r in results:
        total.update(r.commands)
    checks = Counter[str]()
    for r in results:
        checks.update(r.checks)
    raised = sum(1 for r in broken if r.shrunk is None)
    limit = f" or {config.max_steps} steps" if config.max_steps else ""
    options = ((f" --control {config.control}" if config.control else "")
               + (" --split" if config.split else "")
               + f" --size {config.size[0]}x{config.size[1]}")
    lines = [
        f"Soak farm of {project.name} (control {config.control or 'default'}, "
        f"{config.size[0]}x{config.size[1]}{', over the socket' if config.split else ''}): "
        f"{len(results)} seeds ({_ranges(seeds)}), "
        f"{config.minutes:g} virtual minutes{limit} each",
        f"  {len(results) - len(broken)} kept every invariant, {len(broken) - raised} broke one"
        + (f", {raised} raised" if raised else ""),
        f"  in all: {sum(r.virtual_us for r in results) / 1e6:,.1f} s virtual in "
        f"{sum(r.steps for r in results):,} steps and {sum(r.scans for r in results):,} "
        f"scans; {sum(r.skipped for r in results):,} steps not possible",
        "  commands accepted: " + (", ".join(f"{k} {n:,}" for k, n in sorted(total.items()))
                                   or "none")
        + f"; refused {sum(r.refused for r in results):,}",
        f"  alarms: {sum(r.raised for r in results):,} raised, "
        f"{sum(r.transitions for r in results):,} state changes, at most "
        f"{max((r.max_alarms for r in results), default=0)} listed at once; journals "
        f"{sum(r.journal_lines for r in results):,} lines",
        "  invariants checked: " + ", ".join(f"{k} {n:,}" for k, n in sorted(checks.items())),
    ]
    for r in broken:
        if r.shrunk is None:  # the session itself raised: no step list, the seed re-runs it
            lines += ["", f"Seed {r.seed}: RAISED {r.error}",
                      f"  run again: plchmi soak {typed_path}{options} --seed {r.seed} "
                      f"--minutes {config.minutes:g}"
                      + (f" --steps {config.max_steps}" if config.max_steps else "")]
            continue
        lines += ["", f"Seed {r.seed}: BROKEN {r.broken}",
                  f"  after {r.steps} steps; shrunk to {r.shrunk_steps} in {r.replays} replays "
                  f"(at most {shrink_replays}):"]
        if r.error:
            lines.insert(-1, f"  {r.error}")
        lines += [f"    {line}" for line in r.shrunk.splitlines()]
        lines.append(f"  replay: plchmi soak {typed_path}{options} --replay seed{r.seed}.steps")
    return lines


def save_steps(folder: Path, results: list[SeedResult], typed_path: str,
               config: SoakConfig) -> list[Path]:
    """Each failing seed's shrunk list as a file ``--replay`` reads."""
    saved = []
    for r in results:
        if r.ok or r.shrunk is None:
            continue
        path = folder / f"seed{r.seed}.steps"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(steps_header(typed_path, config.control, config.size, r.seed,
                                     str(r.broken), split=config.split) + r.shrunk,
                        encoding="utf-8")
        saved.append(path)
    return saved


def _ranges(seeds: list[int]) -> str:
    """1-200, or 1-5, 9, 12-14 (seeds in increasing order)."""
    parts = []
    for _, group in itertools.groupby(enumerate(seeds), lambda pair: pair[1] - pair[0]):
        run = [seed for _, seed in group]
        parts.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
    return ", ".join(parts)
