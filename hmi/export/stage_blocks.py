"""The PLC side of each declared stage (hmi.engine.program_stages): its function blocks and
how the PLC program calls them, declared once.

The export builds the very stages the engine runs, from the same declarations
(hmi.engine.program_stages.build_stages: one list of stages, printed as the engine's Python
and here as a PLC program). For each stage a builder gives its blocks as
:class:`StageCall`: the block (hmi.export.views.Block: the stage's lowering printed by
hmi.export.program_st, its inputs by (name, depth), its outputs by name), its instance's
name in the program, what its ports receive and what its results are copied to. The PLC
program (hmi.export.program_pou) calls them, in the scan's order, at the part
:func:`stage_calls` gives (hmi.program.order), and again with ``Reset`` on a fault reset when
they say so: the builder named here is all the PLC side of a stage needs.

A built-in stage's builder is named by its role in :data:`BUILT_IN` (the memory, the
diagnosers, the control law, the safety filter, the stopwatch monitors); a stage with none
(the recovery procedures: no recovery mode on the PLC; the steps' supervision) is not
exported. An added stage's is named by its class in :data:`BLOCKS`: it builds one block,
called at the stage's ``PLACE`` (and after a fault reset if the block has a port ``Reset``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hmi.engine.control import ControlRuntime
from hmi.engine.diagnoser import DiagnosisStage
from hmi.engine.filter_stage import FilterStage
from hmi.engine.layout import Layout
from hmi.engine.monitors import MonitorStage
from hmi.engine.program_stages import DIAGNOSERS, FILTER, LAW, MEMORY, MONITORS, Declaration
from hmi.engine.stages import Memory
from hmi.export import model as m
from hmi.export import source
from hmi.export.control_pou import build_control
from hmi.export.diagnoser_pou import build_diagnoser, ftc_mode
from hmi.export.filter_pou import build_filter
from hmi.export.image import Globals
from hmi.export.memory_pou import build_memory
from hmi.export.names import Scope
from hmi.export.program_st import NotPrintable
from hmi.export.stopwatch_pou import build_monitor
from hmi.export.views import Block, Durations
from hmi.program import order
from hmi.project.model import Project


@dataclass(frozen=True)
class StageCall:
    """One block of a stage as the PLC program calls it: ``key(Now := ..., consts...,
    reads..., its inputs wired)``, then its outputs and results to the globals."""

    key: str  # its instance in the program (the name, if it can be)
    comment: str | None  # (None: none, the block one of several the comment before says)
    block: Block
    now: bool = True  # its port Now gets the scan's time
    consts: tuple[tuple[str, m.Expr], ...] = ()  # (port, value)
    reads: tuple[tuple[str, str], ...] = ()  # (port, the global it reads)
    # an output is read as written at the previous scan (what the plant received)
    outputs_back: bool = False
    # a fault reset calls it again, its port Reset TRUE, reading its block's reset_reads
    resets: bool = False
    # (the global, its port) each copied from the block after the call, after its outputs
    results: tuple[tuple[str, str], ...] = ()
    # its block holds the safe-state latch (the filter's): a fault reset calls it first, as
    # Engine.fault_reset releases the latch before the stages
    latch: bool = False


@dataclass(frozen=True)
class ExportContext:
    """What a stage's blocks are built from."""

    project: Project
    layout: Layout
    g: Globals
    prefix: str  # the POU names' (FB_<prefix>_...)
    pous: Scope  # the POU names
    durations: Durations
    bound: source.FilterBound  # the corrector's search limit (plchmi check's)


StageBlocks = Callable[[Any, ExportContext], list[StageCall]]
BlockBuilder = Callable[[Any, Layout, str, Scope, Durations], Block]


def _memory(stage: Memory, c: ExportContext) -> list[StageCall]:
    block = build_memory(stage, c.project, c.layout, c.pous.take(f"FB_{c.prefix}_Memory"), c.pous,
                         c.durations)
    return [] if block is None else [
        StageCall("Memory", "2. Memory: timers and observers", block)]


def _diagnosers(stage: DiagnosisStage, c: ExportContext) -> list[StageCall]:
    names = [c.pous.take(f"FB_{c.prefix}_Diag_{rt.spec.name}") for rt in stage.runtimes]
    return [StageCall(
        f"Diag_{rt.spec.name}",
        f"3-4. Diagnoser {rt.spec.name}: an output is read as written at the previous scan",
        build_diagnoser(stage, k, c.layout, name, c.pous, c.durations, c.project.high_level),
        consts=(("Reset", m.FALSE),), reads=(("Mode", "DiagnosisMode"),), outputs_back=True,
        resets=True)
        for k, (rt, name) in enumerate(zip(stage.runtimes, names, strict=True))]


def _law(stage: ControlRuntime, c: ExportContext) -> list[StageCall]:
    # (with the step times: nothing before reads them)
    block = build_control(stage, c.project, c.layout, c.g,
                          c.pous.take(f"FB_{c.prefix}_Control"), c.pous, c.durations)
    return [StageCall("Control", "5. The functional control writes the FOV_ variables",
                      block)]


def _filter(stage: FilterStage, c: ExportContext) -> list[StageCall]:
    block = build_filter(stage, c.project, c.pous.take(f"FB_{c.prefix}_Filter"), c.pous,
                         c.bound)
    g = c.g
    return [StageCall(
        "Filter", "6. The safety filter", block, now=False,
        consts=(("Reset", m.FALSE), ("Policy", g.name("FilterPolicy")),
                ("Ftc", ftc_mode(g.name("DiagnosisMode"))),
                *((f"FOV_{v.name}", g.name(f"FOV_{v.name}")) for v in source.outputs(c.project))),
        resets=True, latch=True,
        results=(("Violations", "Violations"), ("FilterLatched", "Latched"),
                 ("FilterFallback", "Fallback")))]


def _monitors(stage: MonitorStage, c: ExportContext) -> list[StageCall]:
    calls = []
    for k, task in enumerate(source.monitors(c.project)):
        block = build_monitor(stage, k, task, c.layout,
                              c.pous.take(f"FB_{c.prefix}_Mon_{task.name}"), c.pous,
                              c.durations)
        calls.append(StageCall(
            f"Mon_{task.name}", None if k else (
                "7. The output scan (the PLC writes the outputs after the cycle); 8. the "
                "stopwatch monitors, on the I/O of this scan"),
            block, consts=(("Reset", m.FALSE),), resets=True,
            results=((task.label, "Fault"),)))
    return calls


# role -> (the part of hmi.program.order its blocks are called at, their builder)
BUILT_IN: dict[str, tuple[str, StageBlocks]] = {
    MEMORY.role: (order.MEMORY, _memory),
    DIAGNOSERS.role: (order.DIAGNOSERS, _diagnosers),
    LAW.role: (order.LAW, _law),
    FILTER.role: (order.FILTER, _filter),
    MONITORS.role: (order.MONITORS, _monitors),
}

# added stage class (an hmi.engine.program_stages.AddedStage) -> the builder of its block:
# (the stage, the layout, the name of its POU, the scope of POU names, the durations)
BLOCKS: dict[type, BlockBuilder] = {}


def stage_calls(declaration: Declaration[Any], stage: Any, c: ExportContext
                ) -> tuple[str, list[StageCall]] | None:
    """The part of the scan `stage`'s blocks are called at, and the blocks (None: the stage
    is not exported)."""
    if declaration.place is None:
        built_in = BUILT_IN.get(declaration.role)
        if built_in is None:
            return None
        part, builder = built_in
        return part, builder(stage, c)
    part = declaration.place[0]
    added = BLOCKS.get(type(stage))
    if added is None:
        raise NotPrintable(f"{type(stage).__name__} has no PLC block "
                           "(hmi.export.stage_blocks.BLOCKS)")
    block = added(stage, c.layout, c.pous.take(f"FB_{c.prefix}_{type(stage).__name__}"),
                  c.pous, c.durations)
    # its ports Now (the scan's time) and Reset (FALSE at a scan, TRUE at a fault reset),
    # if it has them
    reset = "Reset" in block.ports
    return part, [StageCall(f"Stage_{part}", f"The added stage {part} ({block.pou.name})",
                            block, now="Now" in block.ports,
                            consts=(("Reset", m.FALSE),) if reset else (), resets=reset)]
