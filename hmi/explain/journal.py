"""The operator journal: every alarm transition and every operator action, durably.

One JSON object per line, appended, flushed and fsynced per entry, so a process killed with
SIGKILL loses at most the entry being written. Entries carry the scan number, the virtual
time and the wall time.

A killed process can leave a partial last line. The next writer must not glue its first entry
onto it (that would damage both), so opening a journal whose last byte is not a newline ends
the partial line and journals a ``session``/``abnormal-end`` entry with the size of the cut
entry: the operator learns that entries may be missing. The reader never gives up on the
readable entries because of a damaged line: each damaged line is reported (line number and
what is wrong) and skipped.

The default place is the user's data folder: $PLCHMI_DATA, else $XDG_DATA_HOME/plchmi, else
~/.local/share/plchmi, then <project name>/journal.jsonl.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from hmi.timefmt import seconds


def data_folder() -> Path:
    if os.environ.get("PLCHMI_DATA"):
        return Path(os.environ["PLCHMI_DATA"])
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "plchmi"


def default_path(project_name: str) -> Path:
    return data_folder() / project_name / "journal.jsonl"


def wall_now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


class Journal:
    """Append-only writer; each `append` is on disk when it returns.

    `cut_bytes` is the size of the partial last line found on opening (None if the file
    ended cleanly): the previous writer was killed while writing that entry.
    """

    def __init__(self, path: Path):
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o644)
        self.seq = 0
        self.cut_bytes = self._partial_tail()
        if self.cut_bytes is not None:
            self._write(b"\n")
            self.append({"type": "session", "event": "abnormal-end", "cut_bytes": self.cut_bytes,
                         "message": f"the previous session ended abnormally while writing an "
                         f"entry ({self.cut_bytes} bytes cut short); entries may be missing"})

    def _partial_tail(self) -> int | None:
        """Length of the last line if it has no newline (a writer killed mid-entry)."""
        size = os.fstat(self._fd).st_size
        if size == 0:
            return None
        cut = 0
        block = 65536
        end = size
        while end > 0:
            start = max(0, end - block)
            chunk = os.pread(self._fd, end - start, start)
            if end == size and chunk.endswith(b"\n"):
                return None
            newline = chunk.rfind(b"\n")
            if newline >= 0:
                return cut + len(chunk) - newline - 1
            cut += len(chunk)
            end = start
        return cut

    def _write(self, data: bytes) -> None:
        written = 0
        while written < len(data):
            written += os.write(self._fd, data[written:])
        os.fsync(self._fd)

    def append(self, entry: dict[str, Any]) -> None:
        self.seq += 1
        record = {"wall": wall_now(), **entry}
        line = json.dumps(record, ensure_ascii=False, separators=(",", ":")) + "\n"
        self._write(line.encode("utf-8"))

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


@dataclass(frozen=True)
class Damaged:
    """A line that could not be read: its number (from 1) and what was wrong with it."""

    line: int
    reason: str


@dataclass(frozen=True)
class JournalRead:
    entries: list[dict[str, Any]]
    truncated: bool  # the last line was cut short (a crash while writing it)
    damaged: tuple[Damaged, ...] = ()  # every unreadable line, the cut last one included


class JournalError(Exception):
    pass


def read(path: Path) -> JournalRead:
    """Every readable entry; damaged lines are listed in `damaged`, never fatal."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise JournalError(f"{path}: no journal yet") from None
    lines = raw.split(b"\n")
    if lines[-1] == b"":
        lines.pop()  # the file ends with a newline
        ends_clean = True
    else:
        ends_clean = False
    entries: list[dict[str, Any]] = []
    damaged: list[Damaged] = []
    truncated = False
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        last_cut = number == len(lines) and not ends_clean
        entry, reason = _parse(line)
        if entry is not None:
            entries.append(entry)  # a last line missing only its newline is still whole
            continue
        if last_cut:
            truncated = True
        damaged.append(Damaged(number, reason))
    return JournalRead(entries, truncated, tuple(damaged))


def _parse(line: bytes) -> tuple[dict[str, Any] | None, str]:
    """The entry on one line, or None and why it is not one (in the operator's words)."""
    text = line.decode("utf-8", errors="replace")
    try:
        entry = json.loads(text)
    except json.JSONDecodeError as exc:
        # The text ends before the JSON does: what a kill inside os.write leaves.
        if exc.pos >= len(text.rstrip()) or exc.msg.startswith("Unterminated string"):
            return None, (f"entry cut short after {len(line)} bytes (the process writing "
                          "it was killed)")
        return None, f"not valid JSON ({exc.msg}, column {exc.colno})"
    if "\ufffd" in text and "\ufffd" not in line.decode("utf-8", errors="ignore"):
        return None, "not UTF-8 text"
    if not isinstance(entry, dict):
        return None, f"not a journal entry (a JSON {type(entry).__name__})"
    return entry, ""


def since_filter(entries: list[dict], since: datetime | None) -> Iterator[dict]:
    for entry in entries:
        if since is None:
            yield entry
            continue
        try:
            when = datetime.fromisoformat(entry["wall"])
        except (KeyError, ValueError):
            continue
        if when >= since:
            yield entry


def virtual(time_us: int) -> str:
    return seconds(time_us)
