"""Writing every scan to a file: CSV or JSON Lines, chosen by the file's extension.

Only deterministic fields are written (virtual time, values, decisions), never wall-clock
measurements, so two runs of the same project with the same inputs give identical files.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import IO, Any

from hmi.engine.snapshot import Snapshot
from hmi.errors import OutputError
from hmi.timefmt import seconds


def _row(snap: Snapshot) -> dict[str, Any]:
    lay = snap.layout
    row: dict[str, Any] = {"scan": snap.scan, "time_s": seconds(snap.time_us)}
    for name in lay.inputs:
        row[name] = int(snap.value(name))
    for name, value in zip(lay.outputs, snap.fov, strict=True):
        row[f"fov.{name}"] = int(value)
    for name, value in zip(lay.outputs, snap.outputs, strict=True):
        row[name] = int(value)
    for group in (lay.memories, lay.timers, lay.observers):
        for name in group:
            row[name] = int(snap.value(name))
    for kind in sorted(lay.extra):
        for name in lay.extra[kind]:
            value = snap.value(name)
            row[name] = int(value) if isinstance(value, bool) else value
    row["steps"] = "+".join(snap.active_steps)
    row["mode"] = snap.mode
    row["latched"] = int(bool(snap.latched))
    report = snap.filter_report
    row["violated"] = "+".join(report.violated_names) if report else ""
    row["changed"] = "+".join(report.changed_names) if report else ""
    for diag in snap.diagnosers:
        row[f"diag.{diag.name}"] = diag.state
    for mon in snap.monitors:
        row[f"monitor.{mon.name}"] = mon.location
    for key, value in snap.plant_state:
        row[f"plant.{key}"] = int(value) if isinstance(value, bool) else value
    row["events"] = "; ".join(f"{e.kind}" for e in snap.plant_events)
    return row


class TraceWriteError(OutputError):
    """The trace file could not be opened or written."""


class TraceWriter:
    """Every scan to `path`. A failure to open or write it is a TraceWriteError (say what and
    where); after one, close() only releases the file."""

    def __init__(self, path: Path):
        self.path = path
        self.format = "jsonl" if path.suffix.lower() in (".jsonl", ".json", ".ndjson") else "csv"
        try:
            # Without blocking: a FIFO nobody reads is refused (ENXIO) instead of hanging.
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NONBLOCK
                         | os.O_NOCTTY | os.O_CLOEXEC, 0o644)
            os.set_blocking(fd, True)
            self.file: IO[str] = os.fdopen(fd, "w", encoding="utf-8", newline="")
        except OSError as exc:
            raise TraceWriteError("the trace", path, exc) from None
        except ValueError as exc:  # a NUL in the name
            raise TraceWriteError("the trace", path, str(exc), bad_path=True) from None
        self.writer: csv.DictWriter[str] | None = None
        self.count = 0
        self.failed = False

    def write(self, snap: Snapshot) -> None:
        row = _row(snap)
        try:
            if self.format == "jsonl":
                self.file.write(json.dumps(row, separators=(",", ":")) + "\n")
            else:
                if self.writer is None:
                    self.writer = csv.DictWriter(self.file, fieldnames=list(row),
                                                 lineterminator="\n")
                    self.writer.writeheader()
                self.writer.writerow(row)
        except OSError as exc:
            self.failed = True
            raise TraceWriteError("the trace", self.path, exc) from None
        self.count += 1

    def close(self) -> None:
        """Flush and close; a failure to flush is a TraceWriteError (unless one was already
        reported: then the file is only released)."""
        try:
            self.file.close()  # releases the descriptor even when the final flush fails
        except OSError as exc:
            if not self.failed:
                self.failed = True
                raise TraceWriteError("the trace", self.path, exc) from None

    def __enter__(self) -> TraceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
