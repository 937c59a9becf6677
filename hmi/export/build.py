"""A project's safety layer as one PLC model: the POUs, the global variables and the task.

    FB_<P>_Memory       timers and observers                         (scan step 2)
    FB_<P>_Diag_<D>     each local diagnoser, with reconstruction, printed from the scan
                        program (steps 3-4)
    FB_<P>_Control      the control law, printed from the scan program (step 5)
    FB_<P>_Filter       the safety filter                            (step 6)
    FB_<P>_Mon_<T>      each stopwatch monitor, printed from the scan program (after the
                        output scan)
    PRG_<P>_Safety      the cycle: calls them in the engine's order, keeps the previous
                        values (prev_x), applies a fault reset after the scan

Each block is a declared stage's (hmi.engine.program_stages: the stages the engine runs,
built here from the same declarations; hmi.export.stage_blocks builds their blocks).

The global variables (hmi/export/image.py) hold the project's values: the I/O at the plant
map's addresses, timers, observers, flags, filtered sensors, the program's outputs FOV_x.
One task at the project's scan period runs the program.
"""

from __future__ import annotations

from hmi.engine.filter import Solver
from hmi.engine.layout import Layout
from hmi.engine.program_stages import StageContext, build_stages
from hmi.errors import ProjectError
from hmi.export import model as m
from hmi.export import source
from hmi.export.filter_pou import max_distance, vectors_bound
from hmi.export.image import CONTROL, Globals, build_globals
from hmi.export.names import Scope
from hmi.export.program_pou import Blocks, build_program
from hmi.export.sfc import build_chart
from hmi.export.st import time_text
from hmi.export.stage_blocks import ExportContext, stage_calls
from hmi.export.views import Durations
from hmi.program import order
from hmi.project.diagnosers import layout_names
from hmi.project.model import Project
from hmi.timefmt import format_duration


def build(project: Project, control: str | None = None) -> m.PlcProject:
    """The project's control law `control` (its default one: None), filter, diagnosers and
    monitors as one PLC model."""
    if source.scan_period_us(project) % 1000:
        raise ProjectError.single(project.pos, "the scan period is not a whole number of "
                                  "milliseconds", "a scan period in whole milliseconds")
    durations = Durations()
    prefix = Scope().take(source.name(project))
    pous = Scope()
    program_name = pous.take(f"PRG_{prefix}_Safety")
    bound = source.filter_bound(project)
    law = project.control(control)
    layout = Layout.build(project, law, extra=layout_names(project))
    g = build_globals(project, pous.child())
    # The declared stages, built as the engine builds them (the diagnosers in their ftc
    # mode), each with the blocks hmi.export.stage_blocks builds for it (none: not on the PLC)
    context = ExportContext(project, layout, g, prefix, pous, durations, bound)
    stages = build_stages(StageContext(project, layout, law,
                                       tuple(v.safe for v in project.outputs),
                                       Solver(project.solver, project.solver_budget)))
    calls = [(d, called) for d, s in stages
             if (called := stage_calls(d, s, context)) is not None]
    blocks = Blocks(stages=[called for _, called in calls], places=stages.places)
    program, instances = build_program(project, program_name, g, blocks, durations)
    types = {v.name: v.type for v in g.vars}
    chart = build_chart(law, pous.take(f"SFC_{prefix}_Grafcet"), g.idents, types,
                        lambda us: time_text(us // 1000))
    durations.raise_if_any()

    config = m.Configuration(
        "Config0", "Res0", (m.VarBlock("global", g.all),),
        (m.Task("MainTask", source.scan_period_us(project) // 1000, 1),),
        (m.ProgramInstance("Safety", "MainTask", program.name),))
    # the built-in stages' blocks (the filter's and the monitors' among them), the added
    # stages' blocks
    all_pous = [c.block.pou for d, (_, called) in calls if d.place is None for c in called]
    all_pous += [c.block.pou for d, (_, called) in calls if d.place is not None
                 for c in called]
    all_pous.append(program)
    summary = _summary(project, bound, all_pous, g, pous)
    symbols = {name: ident for name, ident in g.idents.items()}
    symbols.update(instances)
    for spec, block in zip(source.diagnosers(project), blocks.of(order.DIAGNOSERS),
                           strict=True):
        symbols.update({f"{spec.name}.{lab}": block.ports[f"label:{lab}"]
                        for lab in spec.labels})
    assert set(CONTROL) <= set(symbols)
    return m.PlcProject(prefix, tuple(all_pous), config, _header(project, law.name, summary),
                        tuple(summary), symbols, (chart,) if chart is not None else ())


def _summary(project: Project, bound: source.FilterBound, pous: list[m.Pou], g: Globals,
             scope: Scope) -> list[str]:
    limit = max_distance(bound)
    constraints = source.constraints(project)
    combined = sum(c.kind == "combined" for c in constraints)
    vectors = vectors_bound(bound.combined_outputs, limit)
    lines = [f"{len(pous)} POUs: " + ", ".join(p.name for p in pous),
             f"task MainTask every {format_duration(source.scan_period_us(project))}",
             f"corrector: at most {vectors} vector{'s' if vectors != 1 else ''} tested per "
             f"scan ({bound.combined_outputs} outputs in combined constraints, search limit "
             f"{limit}: " + ("plchmi check's proven worst case" if bound.proven else
                             "every output, the static check being sampled")
             + f"), each a loop over the {len(constraints)} constraints ({combined} combined)"]
    if source.solver(project) != "exact":
        lines.append(f"the project's corrector strategy is {source.solver(project)}; the "
                     "export implements exact (the same minimal distance, ties broken as "
                     "docs/filter.md says)")
    renamed = {**scope.renamed, **g.scope.renamed}
    if renamed:
        lines.append("renamed for IEC 61131-3: " + ", ".join(
            f"{a} -> {b}" for a, b in sorted(renamed.items())))
    return lines


def _header(project: Project, law_name: str, summary: list[str]) -> str:
    files = ", ".join(source.source_files(project))
    return "\n".join([
        f"plchmi export of project {source.name(project)}: "
        f"{source.description(project)}".rstrip(": "),
        f"Generated from {files}; do not edit, export again.",
        f"The control law {law_name!r}, the safety filter, local diagnosers and stopwatch "
        "monitors, run in the engine's order by the program; see docs/plc-export.md.",
        *summary])
