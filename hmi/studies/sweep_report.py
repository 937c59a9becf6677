"""`plchmi campaign PROJECT --sweep`: Table 1 over every instant of the cycle, in text.

Per configuration and fault: the share of injection instants that end Blocked, Tolerant or
Defect, and the worst instant with why; Table 1 both ways (each fault at the single instant
of campaign.yaml, as the paper did, and each fault at its worst instant); the delays from the
fault to the first decision and to the certain diagnosis (000 §3.3 only says "detectable in a
bounded delay").
"""

from __future__ import annotations

from dataclasses import dataclass

from hmi.studies import loop_sweep
from hmi.studies.campaign import PAPER_TABLE
from hmi.studies.closed_loop import (
    BLOCKED,
    DEFECT,
    TOLERANT,
    UNDECIDED,
    Outcome,
    diagnosability,
    spread,
)
from hmi.studies.loop_sweep import SweepResult, block_units
from hmi.timefmt import format_duration, seconds

OUTCOMES = (BLOCKED, TOLERANT, DEFECT)
SEVERITY = {TOLERANT: 0, BLOCKED: 1, DEFECT: 2, UNDECIDED: 3}


@dataclass(frozen=True)
class FaultSweep:
    fault: str
    counts: dict[str, int]
    runs: int
    worst: Outcome
    single: Outcome | None  # the run at campaign.yaml's instant (its phase in the cycle)

    def share(self, outcome: str) -> float:
        return self.counts.get(outcome, 0) / self.runs if self.runs else 0.0


def per_fault(result: SweepResult, config: str, scenarios) -> list[FaultSweep]:
    out = []
    tabled = {s.fault: s for s in scenarios if s.table}
    for fault in result.faults:
        runs = [r for r in result.of(config) if r.fault == fault]
        counts: dict[str, int] = {}
        for r in runs:  # (an exact sweep's runs weigh their piece of instants, in µs)
            counts[r.outcome] = counts.get(r.outcome, 0) + r.weight
        worst = max(runs, key=lambda r: (SEVERITY[r.outcome], -r.at_us))
        scenario = tabled.get(fault)
        single = result.at_phase(config, fault, scenario.at_us) if scenario else None
        out.append(FaultSweep(fault, counts, sum(r.weight for r in runs), worst, single))
    return out


def why(r: Outcome) -> str:
    if r.outcome == DEFECT:
        return (f"{r.damage_kind} {format_duration(r.damage_us - r.at_us)} after the fault"
                + _decision(r))
    if r.outcome == UNDECIDED:
        return "the run did not settle within the step guard"
    return _decision(r).lstrip("; ") or "no fault diagnosed"


def _decision(r: Outcome) -> str:
    if not r.final:
        return "; never diagnosed" if r.detected_us is None else ""
    return f"; ends in {r.final_state} {{{', '.join(r.final)}}}"


def instant_text(r: Outcome) -> str:
    """`2.969 s`, or a piece of instants: `2.960001 - 2.969999 s`."""
    if r.lo_us is None or r.hi_us is None or r.lo_us == r.hi_us:
        return f"{_at(r.at_us)} s"
    return f"{_at(r.lo_us)} - {_at(r.hi_us)} s"


def _at(us: int) -> str:
    return seconds(us) if us % 1000 == 0 else f"{us / 1e6:.6f}"


def report_lines(result: SweepResult, scenarios, paper: bool, title: str) -> list[str]:
    total = sum(len(v) for v in result.runs.values())
    per_config = total // max(1, len(result.configs))
    grid = format_duration(result.step_us or result.every * result.period_us)
    variant = f" (diagnoser variant {result.variant})" if result.variant else ""
    where = f" at {result.point}" if result.point else ""
    cycle = format_duration(result.cycle_us)
    if result.exact:
        head = (f"Fault campaign of {title}{where}, swept{variant}: {len(result.faults)} faults "
                f"x every instant x {len(result.configs)} configurations ({total:,} runs, one "
                "per piece of instants)")
        instants = (f"  instants: every instant of the {cycle} fault-free cycle (from "
                    f"{seconds(result.cycle_start_us)} s), exactly: the cycle split into the "
                    "pieces of instants that share a run, shares measured in time")
    else:
        head = (f"Fault campaign of {title}{where}, swept{variant}: {len(result.faults)} "
                f"faults x {per_config // max(1, len(result.faults))} instants x "
                f"{len(result.configs)} configurations = {total:,} runs")
        instants = (f"  instants: every {grid} of the {cycle} fault-free cycle (from "
                    f"{seconds(result.cycle_start_us)} s)"
                    + (", and 1 us before and after each diagnoser transition in it"
                       if result.extras else ""))
    lines = [
        head,
        instants,
        "  every run is followed until its loop closes: Defect = damage at any time, Blocked = "
        "the cell never completes a cycle again, Tolerant = it keeps completing them",
        f"  {sum(result.states.values()):,} closed-loop states explored, in shards of "
        + f"{block_units(result.exact)} " + ("scan intervals" if result.exact else "runs")
        + " (how long it took, and where, is on stderr: not part of the report)",
        "",
    ]
    sweeps = {c.key: per_fault(result, c.key, scenarios) for c in result.configs}
    lines.append("Table 1 both ways: faults by their class at the paper's single instant "
                 "(campaign.yaml), and at their worst instant")
    header = [""]
    sub = [""]
    for c in result.configs:
        header += [c.title, "", ""]
        sub += ["paper" if paper else "", "instant", "worst"]
    rows = [header, sub]
    for outcome in OUTCOMES:
        row = [outcome]
        for c in result.configs:
            faults = sweeps[c.key]
            row.append(str(PAPER_TABLE[c.key][outcome]) if paper and c.key in PAPER_TABLE
                       else "")
            row.append(str(sum(1 for f in faults if f.single and f.single.outcome == outcome)))
            row.append(str(sum(1 for f in faults if f.worst.outcome == outcome)))
        rows.append(row)
    lines += _table(rows)
    for c in result.configs:
        lines.append("")
        lines.append(f"{c.title}: share of instants per class, and the worst instant")
        rows = [["fault", "Blocked", "Tolerant", "Defect", "worst instant: why"]]
        for f in sweeps[c.key]:
            w = f.worst
            rows.append([f.fault, *(f"{100 * f.share(o):.1f}%" for o in OUTCOMES),
                         f"{w.outcome} at {instant_text(w)}"
                         + (f" ({w.extra})" if w.extra else "") + f": {why(w)}"])
        lines += _table(rows, "  ", right=(1, 2, 3))
    lines.append("")
    lines.append("Delays over the instants, min / median / max (000 §3.3: \"detectable in a "
                 "bounded delay\", no figure)")
    for c in result.configs:
        if c.diagnosis == "off":
            continue
        d = diagnosability(c, result.of(c.key), result.faults)
        lines.append(f"  {c.title}")
        rows = [["fault", "detected", "fault -> first decision", "isolated",
                 "fault -> certain diagnosis"]]
        for f in d.faults:
            if result.exact:
                detected = sum(r.weight for r in result.of(c.key)
                               if r.fault == f.fault and r.detected_us is not None)
                rows.append([f.fault, f"{100 * detected / max(1, f.total_weight):.1f}%",
                             _spread(f.detect_us), f"{100 * f.share:.1f}%",
                             _spread(f.delays_us, f.longest_delay_us)])
            else:
                rows.append([f.fault, f"{len(f.detect_us)}/{f.runs}", _spread(f.detect_us),
                             f"{f.isolated}/{f.runs}", _spread(f.delays_us)])
        lines += _table(rows, "    ")
    return lines


def _spread(values, longest=None) -> str:
    s = spread(values, longest)
    return "-" if s is None else " / ".join(seconds(v) for v in s) + " s"


def as_dict(result: SweepResult, scenarios) -> dict:
    out: dict = {"project": result.project, "variant": result.variant,
                 "exact": result.exact, "point": result.point,
                 "every_s": None if result.exact else
                 (result.step_us or result.every * result.period_us) / 1e6,
                 "cycle_s": result.cycle_us / 1e6, "cycle_start_s": result.cycle_start_us / 1e6,
                 "states": result.states, "shard_runs": loop_sweep.SHARD_RUNS, "configurations": {}}
    for c in result.configs:
        d = diagnosability(c, result.of(c.key), result.faults)
        faults = {}
        for f, fd in zip(per_fault(result, c.key, scenarios), d.faults, strict=True):
            faults[f.fault] = {
                "runs": f.runs, "counts": f.counts,
                "worst": {"outcome": f.worst.outcome, "at_s": f.worst.at_us / 1e6,
                          "from_s": f.worst.first_us / 1e6, "to_s": f.worst.last_us / 1e6,
                          "why": why(f.worst)},
                "single": None if f.single is None else {
                    "outcome": f.single.outcome, "at_s": f.single.at_us / 1e6},
                "isolated": fd.isolated, "isolated_share": fd.share,
                "misdiagnosed": dict(fd.misdiagnosed),
                "delay_s": _spread_s(fd.delays_us), "detect_s": _spread_s(fd.detect_us),
            }
        out["configurations"][c.key] = {"title": c.title, "faults": faults}
    return out


def _spread_s(values):
    s = spread(values)
    return None if s is None else [v / 1e6 for v in s]


def _table(rows: list[list[str]], indent: str = "  ", right: tuple[int, ...] = ()) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    out = []
    for r in rows:
        cells = [c.rjust(widths[i]) if (i in right or (not right and i)) else c.ljust(widths[i])
                 for i, c in enumerate(r)]
        out.append((indent + "  ".join(cells)).rstrip())
    return out


# -- over the declared tolerances (hmi/studies/band_sweep.py) ----------------------------------


def band_lines(over, scenarios, paper: bool, samples: int, seed: int) -> list[str]:
    """Table 1 at the worst instant, and each fault's shares of instants per class, as their
    ranges over the band's plants, worst first, with the plant that gives the worst."""
    band = over.band
    lines = [f"Over the declared tolerances: {len(over.points)} plants ({band.describe()}: "
             f"the nominal one, {len(band.corners())} corners, {samples} points drawn with "
             f"seed {seed}; scans on their grid, every switch change bouncing alike: the scan "
             "jitter is covered by `plchmi band`), every instant of each; each figure worst "
             ".. best"]
    sweeps = [{c.key: per_fault(r, c.key, scenarios) for c in over.configs}
              for r in over.results]
    lines.append("Table 1, each fault at its worst instant")
    rows = [["", *[c.title for c in over.configs]]]
    for outcome in OUTCOMES:
        row = [outcome]
        for c in over.configs:
            values = [sum(1 for f in s[c.key] if f.worst.outcome == outcome) for s in sweeps]
            worst, best = (min, max) if outcome == TOLERANT else (max, min)
            low, high = worst(values), best(values)
            row.append(str(low) if low == high else f"{low} .. {high}")
        rows.append(row)
    lines += _table(rows, "  ")
    for c in over.configs:
        lines.append("")
        lines.append(f"{c.title}: share of instants per class, worst .. best, and the worst "
                     "plant for the worst class")
        rows = [["fault", "Blocked", "Tolerant", "Defect", "worst plant"]]
        for k, fault in enumerate(over.results[0].faults):
            per = [(p, s[c.key][k]) for p, s in zip(over.points, sweeps, strict=True)]
            cells = []
            for outcome in OUTCOMES:
                shares = [f.share(outcome) for _, f in per]
                worst, best = (min, max) if outcome == TOLERANT else (max, min)
                if outcome == BLOCKED:
                    worst, best = min, max
                low, high = worst(shares), best(shares)
                cells.append(f"{100 * low:.1f}%" if low == high else
                             f"{100 * low:.1f} .. {100 * high:.1f}%")
            worst_point = max(per, key=lambda pf: (SEVERITY[pf[1].worst.outcome],
                                                   pf[1].share(DEFECT), -pf[1].share(TOLERANT)))
            name = "-" if all(_same_shares(f, per[0][1]) for _, f in per) else \
                f"{worst_point[0].label}: {worst_point[0].text(band)}"
            rows.append([fault, *cells, name])
        lines += _table(rows, "  ", right=(1, 2, 3))
    lines.append(f"  ({over.states:,} closed-loop states explored)")
    return lines


def _same_shares(a: FaultSweep, b: FaultSweep) -> bool:
    return all(abs(a.share(o) - b.share(o)) < 1e-12 for o in OUTCOMES)


def band_as_dict(over, scenarios) -> dict:
    return {"band": over.band.describe(),
            "plants": [{"point": p.text(over.band), "label": p.label,
                        "sweep": as_dict(r, scenarios)}
                       for p, r in zip(over.points, over.results, strict=True)]}
