"""The PLC's function block of each added stage (hmi.engine.program_stages.ADDED): its ST
handler, declared once.

A builder takes the stage (as the engine builds it for the project), the layout, the name of
its POU, the scope of POU names and the export's durations, and returns its block
(hmi.export.views.Block): the stage's lowering printed by hmi.export.program_st (where its
cells live, the ST version of each handler it calls), its inputs by (name, depth), its
outputs by name and, if it reads the scan's time, its port ``Now``. The export builds every
added stage's block (hmi.export.build) and the PLC program calls it where the stage's
``PLACE`` says (hmi.export.program_pou): the builder named here is all the PLC side needs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hmi.engine.layout import Layout
from hmi.export.names import Scope
from hmi.export.program_st import NotPrintable
from hmi.export.views import Block, Durations

BlockBuilder = Callable[[Any, Layout, str, Scope, Durations], Block]

# stage class (an hmi.engine.program_stages.AddedStage) -> the builder of its block
BLOCKS: dict[type, BlockBuilder] = {}


def block_of(stage: Any, layout: Layout, name: str, scope: Scope, durations: Durations
             ) -> Block:
    builder = BLOCKS.get(type(stage))
    if builder is None:
        raise NotPrintable(f"{type(stage).__name__} has no PLC block "
                           "(hmi.export.stage_blocks.BLOCKS)")
    return builder(stage, layout, name, scope, durations)
