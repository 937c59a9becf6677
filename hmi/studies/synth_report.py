"""`plchmi diagnose PROJECT --build DEVICE`: the diagnoser built from the models
(hmi/studies/synthesis.py) beside the project's own, on the same closed loop.

Both are put in the loop in turn and swept the way `plchmi diagnose` sweeps a diagnoser
(every fault every 200 ms of the cycle and 1 us around each of the diagnoser's transitions,
each run until its loop closes, under the configurations where the diagnoser runs); the
report gives, per configuration, what each isolates (at some instant, whatever the instant,
the share of instants), the DC and its band, misdiagnoses, the pairs left ambiguous, and per
fault the runs isolated and the median delay, then what the built one does better or worse.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from hmi.project.model import DiagnoserSpec, Project
from hmi.studies.closed_loop import FaultDiagnosis, LoopDiagnosability, diagnosability, spread
from hmi.studies.diag_report import _table
from hmi.studies.diagnosability import analyse, iso_band
from hmi.studies.synthesis import Diagnoser
from hmi.timefmt import format_duration, seconds

# The comparison runs on a grid (every 200 ms of the cycle, and 1 us around each diagnoser
# transition), the same for both diagnosers: `diagnose` gives the project's own at every
# instant, exactly.
CLOSED_LOOP_EVERY_US = 200_000


def state_counts(spec: DiagnoserSpec) -> str:
    report = analyse(spec)
    faulty = len(spec.states) - len(report.normal)
    return (f"{len(report.normal)} normal, {faulty} faulty ({len(report.certain_states)} "
            f"certain, {len(report.intermediate) + len(report.final_ambiguous)} ambiguous of "
            f"which {len(report.final_ambiguous)} final), {len(spec.transitions)} transitions")


def loop_figures(project: Project, farm: Any = None, every_us: int = CLOSED_LOOP_EVERY_US
                 ) -> list[LoopDiagnosability]:
    from hmi.studies.loop_sweep import DIAGNOSIS_CONFIGS, sweep
    spec = project.campaign
    counter = spec.counter if spec is not None else "cycles"
    result = sweep(project, DIAGNOSIS_CONFIGS, counter, every_us, True, farm=farm)
    assert result is not None
    return [diagnosability(c, result.of(c.key), result.faults) for c in result.configs]


def comparison_lines(name: str, own: DiagnoserSpec | None, built: DiagnoserSpec,
                     own_loop: Sequence[LoopDiagnosability] | None,
                     built_loop: Sequence[LoopDiagnosability],
                     every_us: int = CLOSED_LOOP_EVERY_US) -> list[str]:
    lines = [f"Diagnoser {name}: the project's beside the one built from the models",
             "  states: project's " + (state_counts(own) if own else "none")
             + "; built " + state_counts(built),
             f"  Closed loop: every fault every {format_duration(every_us)} of the cycle and "
             "1 us before and after each transition of the diagnoser in the loop, each run "
             "until its loop closes"]
    olds: list[LoopDiagnosability | None] = list(own_loop) if own_loop else \
        [None] * len(built_loop)
    for mine, new in zip(olds, built_loop, strict=True):
        lines.append(f"  {new.config.title}:")
        rows = [["", "project's", "built"]]

        def both(f: Callable[[LoopDiagnosability], str],
                 mine: LoopDiagnosability | None = mine,
                 new: LoopDiagnosability = new) -> list[str]:
            return [f(mine) if mine is not None else "-", f(new)]

        rows.append(["isolated at some instant", *both(
            lambda d: f"{len(d.isolable)}/{len(d.faults)}, DC {100 * d.dc:.1f} % "
                      f"({iso_band(d.dc)})")])
        rows.append(["isolated whatever the instant", *both(
            lambda d: f"{len(d.guaranteed)}/{len(d.faults)}")])
        rows.append(["share of instants isolated", *both(
            lambda d: f"{100 * d.dc_weighted:.1f} %")])
        rows.append(["misdiagnoses", *both(lambda d: str(d.misdiagnoses))])
        rows.append(["pairs left ambiguous (runs)", *both(
            lambda d: ", ".join(f"{{{a}, {b}}} {n}" for (a, b), n in d.pairs()) or "none")])
        lines += _table(rows, "    ")
        rows = [["fault", "isolated (project's / built)", "median delay (project's / built)"]]
        for k, f in enumerate(new.faults):
            old = mine.faults[k] if mine is not None else None
            rows.append([f.fault, f"{old.isolated if old else '-'}/{old.runs if old else '-'}"
                         f" / {f.isolated}/{f.runs}",
                         f"{_median(old.delays_us) if old else '-'} / {_median(f.delays_us)}"])
        lines += _table(rows, "    ")
        if mine is not None:
            lines += ["    " + line for line in verdict(mine, new)]
    return lines


def verdict(mine: LoopDiagnosability, new: LoopDiagnosability) -> list[str]:
    """What the built diagnoser does better or worse, fault by fault."""
    gained = [f.fault for a, f in zip(mine.faults, new.faults, strict=True) if f.ever and
              not a.ever]
    lost = [f.fault for a, f in zip(mine.faults, new.faults, strict=True) if a.ever and
            not f.ever]
    # The two loops have their own instants (1 us around each diagnoser's own transitions):
    # compare the share of runs isolated, not the count.
    more = [f"{f.fault} ({_share(a)} -> {_share(f)})" for a, f in
            zip(mine.faults, new.faults, strict=True) if f.isolated * a.runs > a.isolated * f.runs]
    fewer = [f"{f.fault} ({_share(a)} -> {_share(f)})" for a, f in
             zip(mine.faults, new.faults, strict=True)
             if f.isolated * a.runs < a.isolated * f.runs]
    faster, slower = [], []
    for a, f in zip(mine.faults, new.faults, strict=True):
        if a.delays_us and f.delays_us:
            ma, mf = spread(a.delays_us)[1], spread(f.delays_us)[1]  # type: ignore[index]
            if mf < ma:
                faster.append(f"{f.fault} ({seconds(ma)} -> {seconds(mf)} s)")
            elif mf > ma:
                slower.append(f"{f.fault} ({seconds(ma)} -> {seconds(mf)} s)")
    out = [f"the built one isolates every fault the project's does: "
           f"{'yes' if not lost else 'NO, not ' + ', '.join(lost)}"
           + (f"; and {', '.join(gained)} besides" if gained else "")]
    if more or fewer:
        out.append("share of runs isolated: more for " + (", ".join(more) or "none")
                   + "; fewer for " + (", ".join(fewer) or "none"))
    if faster or slower:
        out.append("median delay: shorter for " + (", ".join(faster) or "none")
                   + "; longer for " + (", ".join(slower) or "none"))
    return out


def _share(f: FaultDiagnosis) -> str:
    return f"{100 * f.isolated / f.runs:.1f} %" if f.runs else "-"


def _median(values: Sequence[int]) -> str:
    s = spread(values)
    return "-" if s is None else f"{seconds(s[1])} s"


def build_report(project: Project, name: str, out_file: Path, farm: Any = None,
                 every_us: int | None = None) -> tuple[str, int]:
    """Build, write, compare (on a grid of `every_us`, default CLOSED_LOOP_EVERY_US): the
    report and the exit status (0, or 1 when the built diagnoser misdiagnoses or did not
    converge)."""
    from hmi.studies.synth_build import synthesise
    built, text, loaded = synthesise(project, name)
    out_file.write_text(text)
    spec = next(s for s in loaded.diagnosers if s.name == built.target.name)
    own = built.target.existing
    every = every_us or CLOSED_LOOP_EVERY_US
    mine = loop_figures(project, farm, every) if own is not None else None
    new = loop_figures(loaded, farm, every)
    lines = [header(built, out_file), ""]
    lines += comparison_lines(built.target.name, own, spec, mine, new, every)
    bad = sum(d.misdiagnoses for d in new)
    status = 0 if built.converged and not bad else 1
    return "\n".join(lines), status


def header(built: Diagnoser, out_file: Path) -> str:
    t = built.target
    return (f"Built the diagnoser {t.name} of {t.operator_name or t.device} (device "
            f"{t.device}, model {t.model}) from its plant model, its {len(t.faults)} fault "
            f"models and the control law, on the closed loop: {built.runs_used} runs (every "
            f"fault every {format_duration(built.grid_us)} and around each normal event), "
            f"{built.iterations} rounds under FTC"
            + (" (converged)" if built.converged else " (NOT converged)")
            + f"; written to {out_file}")
