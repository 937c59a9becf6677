"""The stages added to the mode's program, declared once: the one list a new stage joins.

A stage of the mode's program is its lowering (``hmi/program/<stage>.py``: its rules as the
scan program's statements, its rare events as calls of its handler) and its handler (the
object holding its state and those methods, ``hmi/engine/<stage>.py``). Beyond those, an
added stage declares, on its own class (:class:`AddedStage`), where it runs (``PLACE``: its
part of the scan and the part it runs after) and how the engine builds it from the project
(``build``); its class named in :data:`ADDED` is then all that places it:

* the engine builds it (``Engine.__init__``, :func:`added_stages`) and lists it among the
  stages of the mode's program: the compiled scan puts its part where ``PLACE`` says
  (:func:`hmi.program.order.placed`), in every mode's function, printed and evaluated, and
  allows its names (``PRINTED``); the history is as deep as its ``depth``;
* the PLC export builds its function block (hmi.export.stage_blocks, its ST handler) and
  the PLC program calls it at the same place (hmi.export.program_pou).

The built-in stages (the memory, the diagnosers, the control law, the recovery procedures)
are built by ``Engine.__init__`` itself: the engine addresses each by its role (the
diagnosers' mask for the filter, a recovery procedure in place of the law), and their parts
are hmi.program.order's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar, Protocol

from hmi.engine.layout import Layout
from hmi.engine.stages import ProgramStage
from hmi.program import order
from hmi.project.model import Project


class AddedStage(ProgramStage, Protocol):
    """A stage added to the mode's program (see the module docstring)."""

    # (its part of the scan, the part of hmi.program.order it runs right after)
    PLACE: ClassVar[tuple[str, str]]
    depth: int  # how many past images its statements read

    @classmethod
    def build(cls, project: Project, layout: Layout) -> AddedStage | None:
        """The stage for `project` (None: the project has nothing for it to do)."""
        ...


# The added stages, in the order they are placed (several after one part: in this order).
ADDED: tuple[type[AddedStage], ...] = ()


def added_stages(project: Project, layout: Layout) -> tuple[AddedStage, ...]:
    """The added stages `project` has, built (ADDED, read at each call)."""
    built = (kind.build(project, layout) for kind in ADDED)
    return tuple(stage for stage in built if stage is not None)


def program_order(added: Sequence[AddedStage]) -> tuple[str, ...]:
    """The parts of the mode's program with the added stages' (hmi.program.order.PROGRAM,
    each added part right after the part it declares)."""
    return order.placed(order.PROGRAM, [stage.PLACE for stage in added])


def scan_order(added: Sequence[AddedStage]) -> tuple[str, ...]:
    """The parts of a scan with the added stages' (hmi.program.order.SCAN)."""
    return order.placed(order.SCAN, [stage.PLACE for stage in added])
