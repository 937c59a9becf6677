"""The operator journal: every alarm transition and every operator action, durably.

One JSON object per line, appended, flushed and fsynced per entry, so a process killed with
SIGKILL loses at most the entry being written; a truncated last line is tolerated on read
(and reported), a damaged line elsewhere is an error naming its line number. Entries carry
the scan number, the virtual time and the wall time.

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
    """Append-only writer; each `append` is on disk when it returns."""

    def __init__(self, path: Path):
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        self.seq = 0

    def append(self, entry: dict[str, Any]) -> None:
        self.seq += 1
        record = {"wall": wall_now(), **entry}
        line = json.dumps(record, ensure_ascii=False, separators=(",", ":")) + "\n"
        data = line.encode("utf-8")
        written = 0
        while written < len(data):
            written += os.write(self._fd, data[written:])
        os.fsync(self._fd)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


@dataclass(frozen=True)
class JournalRead:
    entries: list[dict[str, Any]]
    truncated: bool  # the last line was cut short (a crash while writing it)


class JournalError(Exception):
    pass


def read(path: Path) -> JournalRead:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise JournalError(f"{path}: no journal yet") from None
    lines = raw.split(b"\n")
    complete, tail = lines[:-1], lines[-1]
    entries = []
    for number, line in enumerate(complete, start=1):
        if not line.strip():
            continue
        try:
            entries.append(json.loads(line))
        except (json.JSONDecodeError, UnicodeDecodeError):
            if number == len(complete) and not tail:
                return JournalRead(entries, True)
            raise JournalError(f"{path}:{number}: damaged journal entry") from None
    truncated = bool(tail.strip())
    if truncated:
        try:
            entries.append(json.loads(tail))
            truncated = False  # complete object, only the newline was lost
        except (json.JSONDecodeError, UnicodeDecodeError):
            pass
    return JournalRead(entries, truncated)


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
