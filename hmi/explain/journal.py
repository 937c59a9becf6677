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

Each entry carries ``prev``, the SHA-256 of the line before it as it is in the file (64 zeros
for the first): a hash chain, so a line changed, removed, inserted or moved breaks the link
of the line after it (:mod:`hmi.explain.chain` verifies it, ``plchmi journal verify``).
The end of the chain — the file's size and its last line's hash — is written to an anchor
file beside the journal (``journal.jsonl.anchor``) when the writer closes and at most a
minute after any entry (:meth:`Journal.tick`), so entries removed from the end are found
too. Writers take an exclusive lock on the file for each write (several processes may
journal at once and each links to the other's last line).

The default place is the user's data folder: $PLCHMI_DATA, else $XDG_DATA_HOME/plchmi, else
~/.local/share/plchmi, then <project name>/journal.jsonl.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import itertools
import json
import os
import re
import stat
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, BinaryIO

from hmi.errors import OutputError
from hmi.limits import MAX_JOURNAL_LINE_BYTES, describe_bytes
from hmi.paths import data_folder
from hmi.textfile import FileProblem, open_regular
from hmi.timefmt import seconds

# One journal line: a JSON object whose values are what its "type" says (text, numbers,
# flags, lists), read back from a file as data.
Entry = dict[str, Any]


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


GENESIS = "0" * 64  # the link of a journal's first line
ANCHOR_EVERY_S = 60.0  # the anchor follows the journal's end at most this late


def anchor_path(journal: Path) -> Path:
    return journal.with_name(journal.name + ".anchor")


def line_hash(line: bytes) -> str:
    """The link to a line: the SHA-256 of its bytes as in the file, without its newline."""
    return hashlib.sha256(line).hexdigest()


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
        self._queue: list[list[bytes]] = []  # each append's lines, not linked yet
        self._queued = 0  # writes handed to the writer so far (each one or more entries)
        self._written = 0  # of them, on disk so far
        self._failure: JournalWriteError | None = None
        self._cond = threading.Condition()
        self._closing = False
        self._writer: threading.Thread | None = None
        self.session: str | None = None  # written into every entry once set (new_session_id)
        self._end = -1  # the file's size after our last write (-1: unknown, read it again)
        self._prev = GENESIS  # the link the next line carries
        self._anchored_at = time.monotonic()
        self._unanchored = False  # entries written since the anchor was
        # the chain's writes and the anchor, one thread at a time (flock orders processes,
        # not the threads that share one descriptor: the writer's and the scan's)
        self._chain = threading.Lock()
        self._anchor_due = False  # the journal's thread is to write the anchor
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
            self._write(b"\n")  # the cut line ends; the next entry links to it as it is
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
        fsyncs a scan held a run to a scan a second), each linked to the one before it; in
        the background (the class) queued for the journal's own thread, in order."""
        if not entries:
            return
        wall = wall_now()
        session = {} if self.session is None else {"session": self.session}
        lines = []
        for entry in entries:
            record = {"wall": wall, **entry, **session}
            record.pop("prev", None)  # the link is the writer's alone
            lines.append(json.dumps(record, ensure_ascii=False,
                                    separators=(",", ":")).encode("utf-8"))
        if self._writer is None:
            self.seq += len(entries)
            self._write_entries(lines)
            return
        with self._cond:
            if self._failure is not None:
                raise self._failure
            if len(self._queue) >= self.MAX_QUEUED:
                raise JournalWriteError("the journal", self.path, "the disk does not keep up "
                                        f"({self.MAX_QUEUED} writes waiting)")
            self.seq += len(entries)
            self._queue.append(lines)
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
                while not self._queue and not self._closing and not self._anchor_due:
                    self._cond.wait()
                if not self._queue and not self._anchor_due:
                    return  # closing, and everything written
                batches, self._queue = self._queue, []
                anchor, self._anchor_due = self._anchor_due, False
            if anchor:
                self.write_anchor()
            if not batches:
                continue
            try:
                self._write_entries([line for batch in batches for line in batch])
            except JournalWriteError as exc:
                with self._cond:
                    self._failure = exc
                    self._cond.notify_all()
                return
            with self._cond:
                self._written += len(batches)
                self._cond.notify_all()

    def _write_entries(self, lines: list[bytes]) -> None:
        """Entries (JSON objects, no newline) written in order, each given its link, under
        the file's lock: whoever wrote last, in this process or another, the chain goes on
        from the file's real last line."""
        try:
            with self._chain:
                self._write_linked(lines)
        except OSError as exc:
            raise JournalWriteError("the journal", self.path, exc) from None

    def _write_linked(self, lines: list[bytes]) -> None:
        fcntl.flock(self._fd, fcntl.LOCK_EX)
        try:
            size = os.fstat(self._fd).st_size
            out = []
            if size != self._end:  # another writer (or our own failed write) moved it
                self._prev, ended = self._last_line(size)
                if not ended:
                    out.append(b"\n")  # never glue an entry onto a cut line
            prev = self._prev
            for line in lines:
                chained = line[:-1] + b',"prev":"' + prev.encode("ascii") + b'"}'
                prev = line_hash(chained)
                out.append(chained + b"\n")
            data = b"".join(out)
            self._end = -1
            self._write(data)
            self._prev, self._end = prev, size + len(data)
            self._unanchored = True
        finally:
            fcntl.flock(self._fd, fcntl.LOCK_UN)

    def _last_line(self, size: int) -> tuple[str, bool]:
        """The link to the file's last line (GENESIS for an empty file) and whether a
        newline ends it; read backwards to its start, then hashed forwards in blocks."""
        if size == 0:
            return GENESIS, True
        ended = os.pread(self._fd, 1, size - 1) == b"\n"
        end = size - 1 if ended else size
        start = end
        block = 65536
        while start > 0:
            chunk = os.pread(self._fd, min(block, start), max(0, start - block))
            newline = chunk.rfind(b"\n")
            if newline >= 0:
                start = start - len(chunk) + newline + 1
                break
            start -= len(chunk)
        digest = hashlib.sha256()
        at = start
        while at < end:
            chunk = os.pread(self._fd, min(1 << 20, end - at), at)
            if not chunk:
                break
            digest.update(chunk)
            at += len(chunk)
        return digest.hexdigest(), ended

    def size(self) -> int:
        """The file's size now (0 once closed)."""
        try:
            return os.fstat(self._fd).st_size if self._fd >= 0 else 0
        except OSError:
            return 0

    def tick_due(self, now: float) -> bool:
        return self._unanchored and now - self._anchored_at >= ANCHOR_EVERY_S

    def tick(self) -> None:
        """The anchor written again if entries came since it was and a minute has passed
        (the session calls this often: it costs a clock read)."""
        if self.tick_due(time.monotonic()):
            if self._writer is None:
                self.write_anchor()
                return
            with self._cond:  # the journal's thread writes it (a scan never waits for a sync)
                self._anchored_at = time.monotonic()
                self._anchor_due = True
                self._cond.notify_all()

    def write_anchor(self) -> None:
        """The chain's end (size and last line's link) into the anchor file, atomically. A
        failure is not the journal's (the entries are on disk): it is tried again later."""
        if self._fd < 0:
            return
        self._anchored_at = time.monotonic()
        with self._chain:
            self._anchor()

    def _anchor(self) -> None:
        try:
            fcntl.flock(self._fd, fcntl.LOCK_SH)
            try:
                size = os.fstat(self._fd).st_size
                head = self._prev if size == self._end else self._last_line(size)[0]
                text = json.dumps({"size": size, "head": head, "wall": wall_now()})
                target = anchor_path(self.path)
                temporary = target.with_name(f".{target.name}.{os.getpid()}.tmp")
                fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC
                             | os.O_NOFOLLOW, 0o644)
                try:
                    os.write(fd, text.encode("ascii") + b"\n")
                    os.fsync(fd)
                finally:
                    os.close(fd)
                os.replace(temporary, target)
                self._unanchored = False
            finally:
                fcntl.flock(self._fd, fcntl.LOCK_UN)
        except OSError:
            self._unanchored = True

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
        if self._fd >= 0 and self._unanchored:
            self.write_anchor()
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


def _stream(file: BinaryIO) -> Iterator[Entry | Damaged]:
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


def _lines(file: BinaryIO) -> Iterator[tuple[int, bytes, bool]]:
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


def since_filter(entries: Iterable[Entry], since: datetime | None) -> Iterator[Entry]:
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
