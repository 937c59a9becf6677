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

import contextlib
import itertools
import json
import os
import re
import stat
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from hmi.errors import OutputError
from hmi.limits import MAX_JOURNAL_LINE_BYTES, describe_bytes
from hmi.paths import data_folder
from hmi.textfile import FileProblem, open_regular
from hmi.timefmt import seconds


def default_path(project_name: str) -> Path:
    return data_folder() / safe_file_name(project_name) / "journal.jsonl"


_UNSAFE_IN_FILE_NAME = re.compile(r"[^A-Za-z0-9._-]")


def safe_file_name(name: str) -> str:
    """A folder name for a project's journal, whatever its `name:` says.

    The name is text for the operator (`name: ../../x` or `name: Cell 3/Line 2` is not a
    path), so anything but ASCII letters, digits, `.`, `_` and `-` becomes `_`, leading dots
    go (no `..`, no hidden folder) and the length is bounded. A name changed that way gets a
    short digest of the original, so that two names cleaned alike keep separate journals.
    """
    cleaned = _UNSAFE_IN_FILE_NAME.sub("_", name).lstrip(".")[:80]
    if cleaned == name:
        return name
    import hashlib  # rarely wanted: not imported at every start (docs/performance.md)

    digest = hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:8]
    return f"{cleaned or 'project'}-{digest}"


def wall_now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


_SESSIONS = itertools.count(1)


def new_session_id() -> str:
    """An id for one session's entries (its start, UTC, and the process; `.2`, `.3` for a
    process's further sessions): what tells apart the entries of two sessions, also of two
    processes writing one journal at once."""
    n = next(_SESSIONS)
    return f"{datetime.now(UTC).strftime('%Y%m%dT%H%M%SZ')}-{os.getpid()}" + (
        f".{n}" if n > 1 else "")


class Journal:
    """Append-only writer; each `append` is on disk when it returns.

    `cut_bytes` is the size of the partial last line found on opening (None if the file
    ended cleanly): the previous writer was killed while writing that entry.

    `background` (the runtime's): `append` only queues the entry and a thread of the
    journal's own writes and syncs what is queued, one sync for all (a sync takes 7-20 ms on
    the machine this was built on: a scan that waited for one would be late). Entries keep
    their order and are on disk within one sync of their event; :meth:`flush` waits until
    everything appended before it is (a command's answer waits for it). A write that fails
    is raised by the next `append` or `flush`.
    """

    MAX_QUEUED = 100_000  # entries waiting for the disk: beyond, it does not keep up

    def __init__(self, path: Path, background: bool = False):
        self.path = path
        self._fd = -1
        self._queue: list[bytes] = []
        self._queued = 0  # writes handed to the writer so far (each one or more entries)
        self._written = 0  # of them, on disk so far
        self._failure: JournalWriteError | None = None
        self._cond = threading.Condition()
        self._closing = False
        self._writer: threading.Thread | None = None
        self.session: str | None = None  # written into every entry once set (new_session_id)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # Not a FIFO or a device: only a regular file (or a new one) is a journal.
            self._fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT | os.O_NONBLOCK
                               | os.O_NOCTTY | os.O_CLOEXEC, 0o644)
            if not stat.S_ISREG(os.fstat(self._fd).st_mode):
                self.close()
                raise JournalWriteError("the journal", path, "not a regular file (a journal "
                                        "must be a file on disk)", bad_path=True)
            os.set_blocking(self._fd, True)
            self.cut_bytes = self._partial_tail()
        except OSError as exc:
            self.close()
            raise JournalWriteError("the journal", path, exc) from None
        except ValueError as exc:  # a NUL in the name
            raise JournalWriteError("the journal", path, str(exc), bad_path=True) from None
        self.seq = 0
        if self.cut_bytes is not None:
            self._write(b"\n")
            self.append({"type": "session", "event": "abnormal-end", "cut_bytes": self.cut_bytes,
                         "message": f"the previous session ended abnormally while writing an "
                         f"entry ({self.cut_bytes} bytes cut short); entries may be missing"})
        if background:
            self._writer = threading.Thread(target=self._write_queued, name="plchmi-journal",
                                            daemon=True)
            self._writer.start()

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
        try:
            written = 0
            while written < len(data):
                written += os.write(self._fd, data[written:])
            os.fsync(self._fd)
        except OSError as exc:
            raise JournalWriteError("the journal", self.path, exc) from None

    def append(self, entry: dict[str, Any]) -> None:
        self.append_all([entry])

    def append_all(self, entries: list[dict[str, Any]]) -> None:
        """Several entries in one write and one fsync (a scan's alarm transitions: hundreds of
        fsyncs a scan held a run to a scan a second); in the background (the class) queued
        for the journal's own thread, in order."""
        if not entries:
            return
        wall = wall_now()
        session = {} if self.session is None else {"session": self.session}
        data = "".join(json.dumps({"wall": wall, **entry, **session}, ensure_ascii=False,
                                  separators=(",", ":")) + "\n" for entry in entries
                       ).encode("utf-8")
        if self._writer is None:
            self.seq += len(entries)
            self._write(data)
            return
        with self._cond:
            if self._failure is not None:
                raise self._failure
            if len(self._queue) >= self.MAX_QUEUED:
                raise JournalWriteError("the journal", self.path, "the disk does not keep up "
                                        f"({self.MAX_QUEUED} writes waiting)")
            self.seq += len(entries)
            self._queue.append(data)
            self._queued += 1
            self._cond.notify_all()
    def flush(self) -> None:
        """Until every entry appended so far is on disk (background: see the class)."""
        if self._writer is None:
            return
        with self._cond:
            target = self._queued
            while self._written < target and self._failure is None and \
                    self._writer.is_alive():
                self._cond.wait(1.0)
            if self._failure is not None:
                raise self._failure

    def _write_queued(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closing:
                    self._cond.wait()
                if not self._queue:
                    return  # closing, and everything written
                lines, self._queue = self._queue, []
            try:
                self._write(b"".join(lines))
            except JournalWriteError as exc:
                with self._cond:
                    self._failure = exc
                    self._cond.notify_all()
                return
            with self._cond:
                self._written += len(lines)
                self._cond.notify_all()

    def close(self) -> None:
        writer = self._writer
        if writer is not None and writer is not threading.current_thread():
            with contextlib.suppress(JournalWriteError):
                self.flush()
            with self._cond:
                self._closing = True
                self._cond.notify_all()
            writer.join(5.0)
            self._writer = None
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


@dataclass(frozen=True)
class Damaged:
    """A line that could not be read: its number (from 1) and what was wrong with it;
    `cut`: it was the last line and had no newline (a writer killed while writing it)."""

    line: int
    reason: str
    cut: bool = False


@dataclass(frozen=True)
class JournalRead:
    entries: list[dict[str, Any]]
    truncated: bool  # the last line was cut short (a crash while writing it)
    damaged: tuple[Damaged, ...] = ()  # every unreadable line, the cut last one included


class JournalError(Exception):
    """There is no journal to read (exit status 1)."""


class JournalWriteError(OutputError):
    """The journal could not be opened or written."""


class JournalPathError(Exception):
    """The path given is not a journal file (a folder, a device, a FIFO): a usage error."""


def read(path: Path) -> JournalRead:
    """Every readable entry, kept in memory; damaged lines are listed in `damaged`, never
    fatal. For a journal of any size, :func:`stream` holds one line at a time."""
    entries: list[dict[str, Any]] = []
    damaged: list[Damaged] = []
    for item in stream(path):
        if isinstance(item, Damaged):
            damaged.append(item)
        else:
            entries.append(item)
    return JournalRead(entries, any(d.cut for d in damaged), tuple(damaged))


def stream(path: Path) -> Iterator[dict[str, Any] | Damaged]:
    """Each readable entry, or the Damaged line in its place, in file order.

    The file is opened here (JournalError: there is none; JournalPathError: not a regular
    file, hmi.textfile.open_regular) and read one line at a time as the result is iterated,
    each line at most MAX_JOURNAL_LINE_BYTES, so neither a device, a huge line of garbage
    nor millions of lines can make the reader hang or hold more than a line."""
    try:
        fd = open_regular(path)
    except FileProblem as exc:
        if exc.message == "file not found":
            raise JournalError(f"{path}: no journal yet") from None
        raise JournalPathError(f"{path}: {exc.message}") from None
    return _stream(os.fdopen(fd, "rb"))


def _stream(file) -> Iterator[dict[str, Any] | Damaged]:
    with file:
        for number, line, complete in _lines(file):
            if not line.strip():
                continue
            if len(line) > MAX_JOURNAL_LINE_BYTES:
                entry, reason = None, (f"line longer than {describe_bytes(MAX_JOURNAL_LINE_BYTES)}"
                                       " (not a journal entry)")
            else:
                entry, reason = _parse(line)
            if entry is not None:
                yield entry  # a last line missing only its newline is still whole
            else:
                yield Damaged(number, reason, not complete)


def _lines(file) -> Iterator[tuple[int, bytes, bool]]:
    """(number, line without its newline, whether a newline ended it); a line longer than the
    limit is returned as its first MAX_JOURNAL_LINE_BYTES + 1 bytes, the rest skipped."""
    number = 0
    while True:
        line = file.readline(MAX_JOURNAL_LINE_BYTES + 1)
        if not line:
            return
        number += 1
        if len(line) > MAX_JOURNAL_LINE_BYTES and not line.endswith(b"\n"):
            rest = line
            while rest and not rest.endswith(b"\n"):  # skip to the end of this line
                rest = file.readline(1 << 20)
            yield number, line, rest.endswith(b"\n")
            continue
        complete = line.endswith(b"\n")
        yield number, line.rstrip(b"\n"), complete


# Fields an entry may carry, and what they must be for the reader to show them.
_FIELD_TYPES: dict[str, tuple[type, ...]] = {
    "wall": (str,), "type": (str,), "event": (str,), "scan": (int,), "t": (str, int, float),
    "message": (str,), "text": (str,), "key": (str,), "severity": (str,), "state": (str,),
    "project": (str,), "session": (str,), "control": (str,), "policy": (str,),
    "plant": (str,)}
_JSON_TYPE = {dict: "an object", list: "a list", str: "a string", bool: "a Boolean",
              int: "a number", float: "a number", type(None): "null"}


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
    except RecursionError:
        return None, "not a journal entry (JSON nested too deep)"
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        return None, f"not a journal entry ({exc})"
    if "\ufffd" in text and "\ufffd" not in line.decode("utf-8", errors="ignore"):
        return None, "not UTF-8 text"
    if not isinstance(entry, dict):
        return None, f"not a journal entry (a JSON {type(entry).__name__})"
    for name, types in _FIELD_TYPES.items():
        value = entry.get(name)
        if value is not None and (not isinstance(value, types) or isinstance(value, bool)):
            return None, (f"not a journal entry (its {name!r} is "
                          f"{_JSON_TYPE.get(type(value), 'a value')} where "
                          f"{_JSON_TYPE[types[0]]} belongs)")
    if _SURROGATE.search(text) and _has_surrogate(entry):
        return None, "not a journal entry (a lone surrogate in a text)"
    return entry, ""


_SURROGATE = re.compile(r"\\u[dD][89a-fA-F]")


def _has_surrogate(value: Any) -> bool:
    if isinstance(value, str):
        return any("\ud800" <= c <= "\udfff" for c in value)
    if isinstance(value, dict):
        return any(_has_surrogate(k) or _has_surrogate(v) for k, v in value.items())
    if isinstance(value, list):
        return any(_has_surrogate(v) for v in value)
    return False


def since_filter(entries: list[dict], since: datetime | None) -> Iterator[dict]:
    for entry in entries:
        if since is None:
            yield entry
            continue
        try:
            when = datetime.fromisoformat(entry["wall"])
        except (KeyError, TypeError, ValueError):
            continue
        if when.tzinfo is None:
            when = when.replace(tzinfo=UTC)  # the journal writes UTC
        if when >= since:
            yield entry


def virtual(time_us: int) -> str:
    return seconds(time_us)
