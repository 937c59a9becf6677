"""The last scan's results, and what the next scan's news is judged against (Engine.run).

Both are read and written by the engine (hmi.engine.scan) and by its printed frame
(hmi.engine.compiled.auto_frame), which writes the record's fields and reads the news':
they live here, below both.
"""

from __future__ import annotations

from dataclasses import make_dataclass
from typing import Any, NamedTuple, cast

from hmi.engine.diagnoser import NO_DIAGNOSIS, Diagnosis


class Raised(NamedTuple):
    """A read the printed frame made for the scan's conclusion raised (Engine._conclude,
    which latches it as its own would have): which, in plain words (EVENTS, STATUS or a
    publication's `reading`: hmi.engine.program_stages, in snapshot.INTERNAL_PARTS), and
    what."""

    part: str
    exc: Exception


EVENTS = "reading the plant's events"
STATUS = "reading the plant's status"


class QuietRun(NamedTuple):
    """What Engine.run_while_quiet ran: how many scans, and whether the last had news."""

    scans: int
    news: bool


class ScanRecord:
    """The last scan's results, from stages 1 to 8 (Engine._cycle) and what Engine.run read
    after them, until Engine.snapshot builds them into a Snapshot. One per engine, filled in
    place by every scan: a record built per scan (a NamedTuple, by its constructor or by
    tuple.__new__) cost 1,400 to 3,500 instructions a scan more than the positional tuples
    it replaced (python -m hmi.bench.instructions), slot stores about as much as a tuple."""

    __slots__ = (
        "diagnosis",
        "error",
        "events",
        "filter_us",
        "fov",
        "monitored",
        "outputs",
        "published",
        "scan_us",
        "settled",
        "values",
    )

    def __init__(self) -> None:
        self.fov: tuple[bool, ...] = ()  # the functional output vector (stage 5)
        self.outputs: tuple[bool, ...] = ()  # what was written (stage 7)
        self.diagnosis: Diagnosis = NO_DIAGNOSIS  # routes, mask and records (stage 3)
        # whether the part after the output scan (hmi.program.order.MONITORS: the stages'
        # statements there) ran to its end: False when it raised, or no stage has any
        self.monitored = False
        self.error: str | None = None  # an internal error of the scan, latched
        self.filter_us = 0.0  # the filter's wall time (0.0 unless Engine.wall_times)
        self.values: tuple[Any, ...] = ()  # the image as the scan left it (history[0])
        # what each publishing stage gave (Engine.stages.publishing, in its order): the
        # filter's report, the diagnosers' states, the monitors' marks, ...
        self.published: tuple[Any, ...] = ()
        self.events: tuple[Any, ...] = ()  # the plant's events
        self.scan_us = 0.0  # the scan's wall time
        # Every field but fov, outputs and values is a quiet scan's (the printed frame, at a
        # quiet scan after a quiet one, writes only those three: hmi.engine.compiled)
        self.settled = False


class ScanNews:
    """What a scan is compared with to say whether the next one has news (Engine.run): the
    very objects the last scan with news gave: the plant's status, then what each publishing
    stage gave (Engine.stages.publishing, in its order: the filter's report, the monitors'
    marks, ...), as one tuple (`given`: Engine._conclude compares it) and each in a slot
    named after its snapshot field, which the printed frame reads at every quiet scan
    (hmi.engine.compiled): on CPython 3.11 a slot's field is one specialized instruction, an
    item of a tuple by a constant index two (an item of a tuple subclass a generic subscript,
    some 100 instructions). The class with those slots is one engine's (:func:`news_kind`:
    its stages' publications, a slotted dataclass whose generated __init__ stores each
    field); one is built at the scans with news only, ``kind(given, *given)``."""

    given: tuple[Any, ...]
    status: Any


def news_kind(fields: tuple[str, ...]) -> type[ScanNews]:
    """The class of ScanNews whose slots are `fields` besides the status (the snapshot
    fields of an engine's publications, in their order)."""
    kind = make_dataclass("ScanNews", ("given", "status", *fields), bases=(ScanNews,),
                          slots=True)
    return cast("type[ScanNews]", kind)
