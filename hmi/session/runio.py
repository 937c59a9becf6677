"""The files a headless run writes (its trace and the journal), and what a failure does.

A full disk, an I/O error or a journal that can no longer be written is a failure at run
time, not a bug: the run stops at that scan, the plant's outputs are written safe (as a
stopping PLC leaves them), the other file is closed cleanly, and the command says what
failed, where and when, with exit status 1. Nothing here reads a clock or changes what the
engine computes: a run that does not fail writes exactly what it wrote before.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from hmi.engine.snapshot import Snapshot
from hmi.errors import OutputError
from hmi.limits import MAX_RUN_SCANS, NOTICE_RUN_SCANS
from hmi.outpaths import check_outputs
from hmi.plant.base import PlantError
from hmi.session.session import Session
from hmi.session.trace import TraceWriter
from hmi.timefmt import format_duration, seconds


class RunLengthError(Exception):
    """A run longer than plchmi runs (a usage error)."""


def check_run_length(duration_us: int, period_us: int) -> str | None:
    """None, or a notice to print before a run that will take a while; RunLengthError if
    the run would be longer than MAX_RUN_SCANS scans."""
    scans = duration_us // period_us + 1
    if scans > MAX_RUN_SCANS:
        raise RunLengthError(
            f"a run of {format_duration(duration_us)} at a {format_duration(period_us)} scan "
            f"period is {scans:,} scans, more than the {MAX_RUN_SCANS:,} plchmi runs at once "
            "(a shorter --for, or a longer --period)")
    if scans > NOTICE_RUN_SCANS:
        return (f"{scans:,} scans to run ({format_duration(duration_us)} at a "
                f"{format_duration(period_us)} scan period); this takes a while (about a "
                "minute per million scans on a small machine)")
    return None


class RunOutputs:
    """The trace and the journal of one run. `on_scan` writes the trace; a failure of either
    file is kept in `failure` and ends the run (see `stop_on_failure`)."""

    def __init__(self, session: Session, trace: Path | None, journal: Path | None,
                 source: str, background: bool = False):
        self.session = session
        self.failure: OutputError | None = None
        self.stopped_early = False
        journal = journal or default_journal(session)
        check_outputs([("--journal", "the journal of this run", journal),
                       ("--trace", "the trace", trace)], project_files(session))
        self.writer = TraceWriter(trace) if trace else None
        try:
            self.recorder = open_journal(session, journal, source, background)
        except BaseException:
            if self.writer is not None:
                self.writer.close()
            raise

    @property
    def trace(self) -> tuple[Path, int] | None:
        return (self.writer.path, self.writer.count) if self.writer else None

    def write(self, snap: Snapshot) -> bool:
        """Write one scan; True if an output failed (the run must stop now)."""
        if self.failure is None and self.recorder.failure is not None:
            self.failure = self.recorder.failure
        if self.writer is not None and self.failure is None:
            try:
                self.writer.write(snap)
            except OutputError as exc:
                self.failure = exc
        return self.failure is not None

    def leave_safe(self) -> None:
        """After a failure: latch the engine safe and write the safe vector to the plant now
        (a real plant is also stopped safe by the caller)."""
        self.stopped_early = True
        engine = self.session.engine
        engine.latch_safe("output", f"run stopped: {self.failure}")
        if engine.started:
            safe = dict(zip(engine.layout.outputs, engine.safe_vector, strict=True))
            with contextlib.suppress(PlantError):  # a real plant is stopped safe after
                engine.plant.write(engine.now, safe)

    def close(self, abnormal: str | None = None) -> None:
        """Close both files; a failure to close the trace (its last flush) is a failure.
        `abnormal`: why the run is ending on an error (the journal's abnormal-end), if it
        is; an output failure that stopped the run is one too."""
        if self.writer is not None:
            try:
                self.writer.close()
            except OutputError as exc:
                self.failure = self.failure or exc
        if abnormal is None and self.stopped_early:
            abnormal = f"output failure: {self.failure}"
        self.recorder.close(abnormal)
        if self.failure is None and self.recorder.failure is not None:
            self.failure = self.recorder.failure

    def failure_message(self) -> str:
        engine = self.session.engine
        if self.stopped_early:
            return (f"{self.failure}; the run stopped at scan {engine.scan} "
                    f"(t = {seconds(engine.now)} s) with the outputs written safe")
        return (f"{self.failure}; the run ended at scan {engine.scan} "
                f"(t = {seconds(engine.now)} s) but what it wrote there is incomplete")


def open_journal(session: Session, path: Path | None, source: str,
                 background: bool = False):
    """The journal recorder of a session: `path`, else the project's default journal. A
    journal that cannot be opened is an OutputError (hmi.errors). `background`: written by
    a thread of its own (the runtime's: a scan never waits for the disk; hmi.explain.journal)."""
    from hmi.explain.journal import Journal
    from hmi.session.journal_recorder import JournalRecorder
    target = path or default_journal(session)
    check_outputs([("--journal", "the journal", target)], project_files(session))
    journal = Journal(target, background)
    try:
        return JournalRecorder(session, journal, source)
    except BaseException:
        journal.close()
        raise


def default_journal(session: Session) -> Path:
    from hmi.explain.journal import default_path
    return default_path(session.engine.project.name)


def project_files(session: Session) -> list[tuple[str, Path]]:
    """Every file the project was read from (its own, its includes, its components')."""
    return [("a file of the project", Path(name))
            for name in session.engine.project.files]
