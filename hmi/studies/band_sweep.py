"""The closed-loop sweep (hmi/studies/loop_sweep.py) over the declared tolerances: one
exhaustive sweep per plant of the band, from which `diagnose` and `campaign --sweep` print
each figure as its range.

The plants are the band's corners and a seeded sample (hmi/studies/band.py) of the dimensions
the exploration can take: every device parameter, each switch bouncing alike at every change
of the same kind (`bounce_pattern: same`: the loop must repeat). The scan jitter cannot be
explored (scans off their grid never repeat), so it is left out here and covered by the
fault-free runs of `plchmi band`.

A parameter that acts through one fault only (the valve's block point, F13's) is varied for
that fault alone: the other faults' runs do not depend on it, so their sweep is made once per
plant of the other dimensions and shared (16 corners cost 8 sweeps of F1-F12 and 16 of F13).
Each sweep is a study of its own (its shards on this machine or a cluster, hmi/farm/) and is
cached on its own, like any closed-loop sweep.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass, replace

from hmi.farm.run import Farm
from hmi.project.device_models import DEVICE_MODELS
from hmi.project.model import Project
from hmi.studies.band import Band, BandPoint
from hmi.studies.explore import LoopConfig, faults_of
from hmi.studies.loop_sweep import SweepResult, sweep


@dataclass
class BandSweep:
    """A sweep per plant of the band (every fault, every configuration), in point order."""

    band: Band
    configs: tuple[LoopConfig, ...]
    points: list[BandPoint]
    results: list[SweepResult]
    cached: bool

    @property
    def states(self) -> int:
        return sum(sum(r.states.values()) for r in self.results)


def exploration_points(band: Band, samples: int, seed: int) -> list[BandPoint]:
    return [band.nominal(), *band.corners(), *band.sample(samples, seed)]


def fault_of(band: Band, project: Project) -> list[str | None]:
    """Per dimension, the one fault it acts through (None: every run)."""
    out: list[str | None] = []
    for d in band.dimensions:
        model = next(s.model for s in project.plant.devices if s.name == d.device)
        spec = DEVICE_MODELS[model].params[d.param]
        out.append(spec.fault if spec.faults_only else None)
    return out


def band_sweep(project: Project, band: Band, configs: Sequence[LoopConfig], counter: str,
               points: Sequence[BandPoint], faults: Sequence[str] | None = None,
               farm: Farm | None = None, compute: bool = True, cache: bool = True
               ) -> BandSweep | None:
    """Every point's exact sweep (None if one is not cached and `compute` is false). Each
    point's bounces are seeded by its values of the dimensions every fault depends on, so
    that a plant shared by several points is one plant (their texts say that seed)."""
    faults = tuple(faults) if faults else faults_of(project)
    owners = fault_of(band, project)
    points = [replace(p, seed=zlib.crc32(repr(tuple(
        v for v, o in zip(p.values, owners, strict=True) if o is None)).encode()) % 100_000)
        for p in points]
    # The sweeps to make: (faults, the point they are made at), shared between points that
    # differ only in dimensions those faults do not depend on.
    sweeps: list[tuple[tuple[str, ...], BandPoint]] = []
    index: dict[tuple[tuple[str, ...], tuple[float, ...]], int] = {}
    per_point: list[list[int]] = []
    for point in points:
        mine = []
        for group, keep in _groups(faults, owners):
            values = tuple(v if keep[k] else band.dimensions[k].nominal
                           for k, v in enumerate(point.values))
            key = (group, values)
            if key not in index:
                index[key] = len(sweeps)
                sweeps.append((group, BandPoint(point.label, values, point.seed)))
            mine.append(index[key])
        per_point.append(mine)
    results: list[SweepResult] = []
    for group, point in sweeps:
        applied = band.apply(project, point, "same")
        options = {"values": list(point.values), "seed": point.seed,
                   "text": point.text(band)}
        result = sweep(applied, configs, counter, farm=farm, exact=True, faults=group,
                       cache=cache, compute=compute, point=options)
        if result is None:
            return None
        results.append(result)
    merged = [_merge([results[k] for k in mine], point.text(band), faults)
              for mine, point in zip(per_point, points, strict=True)]
    return BandSweep(band, tuple(configs), list(points), merged,
                     all(r.cached for r in results))


def _groups(faults: Sequence[str], owners: list[str | None]
            ) -> list[tuple[tuple[str, ...], tuple[bool, ...]]]:
    """(faults, which dimensions they depend on) groups: faults owning a dimension alone,
    the others together."""
    owned = {f for f in owners if f is not None}
    out = []
    rest = tuple(f for f in faults if f not in owned)
    if rest:
        out.append((rest, tuple(o is None for o in owners)))
    for fault in faults:
        if fault in owned:
            out.append(((fault,), tuple(o is None or o == fault for o in owners)))
    return out


def _merge(parts: list[SweepResult], point: str, order: tuple[str, ...]) -> SweepResult:
    """One point's result from the sweeps its faults were made in (faults in `order`)."""
    first = parts[0]
    have = {f for p in parts for f in p.faults}
    faults = tuple(f for f in order if f in have)
    merged = SweepResult(first.project, first.variant, first.configs, faults, first.period_us,
                         first.every, first.extras, first.cycle_start_us, first.cycle_us,
                         exact=True, point=point, cached=all(p.cached for p in parts))
    for c in first.configs:
        merged.runs[c.key] = [r for p in parts for r in p.runs[c.key]]
        merged.states[c.key] = sum(p.states[c.key] for p in parts)
    return merged
