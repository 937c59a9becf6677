"""The corrector is the one part of the filter written twice (docs/architecture.md, "The scan
program"): the engine searches with hmi.engine.solver (branch and bound and SAT, bounded in
steps), the PLC's filter block enumerates every k-subset of the free outputs up to
MAX_DISTANCE (hmi.export.filter_pou). Both must give the exact strategy's unique vector.
Here the exported block runs (tests/stsubset.py) beside the engine's SafetyFilter on seeded
random candidates and contexts of every example project, under `correct`, masks off: the
same vector whenever the engine's repair is within MAX_DISTANCE, the safe state (Fallback)
when it is not or there is none."""

from __future__ import annotations

import random

import pytest

from hmi.engine.filter import SafetyFilter, Solver
from hmi.engine.layout import Layout
from hmi.engine.program_stages import FILTER, StageContext, build_stages
from hmi.export import source
from hmi.export.filter_pou import build_filter, max_distance
from hmi.export.names import Scope
from hmi.export.st import pou_text
from hmi.project.diagnosers import layout_names
from hmi.project.loader import load_project
from tests.conftest import PROJECTS
from tests.stsubset import Program

NAMES = ("cispi_valve", "conveyor_robot", "sorting", "palletizer", "cispi_subsystem")


@pytest.mark.parametrize("name", NAMES)
def test_the_plc_search_and_the_engine_search_give_the_same_vector(name):
    project = load_project(PROJECTS / name)
    bound = source.filter_bound(project)
    limit = max_distance(bound)
    # the exported filter block (as hmi.export.build builds it: from the filter stage the
    # engine builds), alone
    layout = Layout.build(project, project.control(None), extra=layout_names(project))
    stages = build_stages(StageContext(project, layout, project.control(None),
                                       tuple(v.safe for v in project.outputs),
                                       Solver(project.solver, project.solver_budget)))
    block = build_filter(stages.need(FILTER), project, "FB_Filter", Scope(), bound)
    program = Program("\n".join(pou_text(block.pou)) + "\n")
    fb = next(iter(program.pous))
    run = program.fbs[fb]
    engine = SafetyFilter(project, layout.slots, layout.step_times)
    engine.remember = False
    rows = engine.table.rows
    outputs = engine.outputs
    depth = max((d for _, d in block.inputs), default=0)
    rng = random.Random(name)
    compared = repaired = 0
    for _ in range(150):
        instance = program.instantiate(fb)
        v = instance.vars
        image = [False] * len(layout.names)
        history = [[False] * len(layout.names) for _ in range(max(depth, 1))]
        for (var, d), ident in block.inputs.items():
            value = rng.random() < 0.5
            v[ident.upper()] = value
            if var in layout.slots:
                (image if d == 0 else history[d - 1])[layout.slots[var]] = value
        # a candidate that makes some combined constraint's output literals true, mostly
        row = rng.choice(rows)
        fov = tuple(bool(row.pos >> k & 1) if (row.pos | row.neg) >> k & 1
                    else rng.random() < 0.5 for k in range(len(outputs)))
        for k, out in enumerate(outputs):
            v[block.ports[f"FOV_{out}"].upper()] = fov[k]
        v[block.ports["Policy"].upper()] = 2
        v[block.ports["Ftc"].upper()] = False  # (the masks are the filter stage's)
        run(v, {})
        written = tuple(v[block.outputs[out].upper()] for out in outputs)
        decision = engine.apply(image, [tuple(h) for h in history], fov, "correct", False)
        report = decision.report
        if not report.violations:
            assert written == fov and not v[block.ports["Fallback"].upper()]
            continue
        compared += 1
        if report.safe_state or report.distance > limit:
            # no safe vector, forced both ways, or farther than the block searches
            assert v[block.ports["Fallback"].upper()], (fov, report)
            assert written == tuple(bool(engine.safe >> k & 1) for k in range(len(outputs)))
        else:
            repaired += 1
            assert written == decision.outputs, (fov, report)
    assert compared > 20 and repaired > 5  # corrections were compared, not only clean scans
