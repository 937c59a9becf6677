"""Verifying a journal's hash chain and its anchor (``plchmi journal verify``).

Each line's ``prev`` must be the SHA-256 of the line before it (hmi.explain.journal): a line
changed, removed, inserted or moved breaks the link of the line that follows it, which is
where it is reported — the first broken link names the line. The anchor file beside the
journal holds the chain's end when it was last written (at every session's stop, at most a
minute after any entry): a journal shorter than its anchor lost entries from its end; a line
at the anchor's point that is not the one anchored was changed.

What is not a break: lines written before the journal carried a chain (before its first
linked line: counted and said), and a line cut short by a writer killed while writing it,
which the next session ended and declared (its ``abnormal-end`` with the cut's size) or which
is the file's last line (the writer was killed and nobody wrote since; the anchor still says
whether anything before it went missing). What it cannot see: a forger who rewrites the
whole chain from the changed line on and the anchor with it — keep a copy of the anchor
elsewhere (the OPC UA server publishes it) — or entries appended after the last anchor by
someone who links them correctly, which is what a writer does.

Read in blocks, one line at a time (its hash computed as it streams, at most
MAX_JOURNAL_LINE_BYTES of it kept to read the link), so a journal of any size verifies in
bounded memory.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hmi.explain.journal import GENESIS, JournalError, JournalPathError, anchor_path
from hmi.limits import MAX_JOURNAL_LINE_BYTES
from hmi.textfile import FileProblem, open_regular

MAX_BREAKS_KEPT = 10


@dataclass(frozen=True)
class Break:
    line: int
    what: str


@dataclass
class Verdict:
    lines: int = 0
    unchained: int = 0  # lines before the first linked one (written before the chain)
    breaks: list[Break] = field(default_factory=list)  # the first MAX_BREAKS_KEPT
    break_count: int = 0
    crash_cuts: list[int] = field(default_factory=list)  # lines cut by a killed writer
    anchor: str = ""  # what the anchor says about the end (plain words)
    notes: list[str] = field(default_factory=list)

    @property
    def intact(self) -> bool:
        return self.break_count == 0

    def broke(self, line: int, what: str) -> None:
        self.break_count += 1
        if len(self.breaks) < MAX_BREAKS_KEPT:
            self.breaks.append(Break(line, what))


@dataclass(frozen=True)
class _Line:
    number: int
    head: bytes  # its first MAX_JOURNAL_LINE_BYTES + 1 bytes
    size: int
    digest: str
    end: int  # the file offset after it (and its newline)
    complete: bool


def _lines(fd: int) -> Iterator[_Line]:
    number = 0
    offset = 0
    head = bytearray()
    size = 0
    digest = hashlib.sha256()
    with os.fdopen(fd, "rb", buffering=0) as file:
        while True:
            block = file.read(1 << 20)
            if not block:
                break
            start = 0
            while start < len(block):
                newline = block.find(b"\n", start)
                piece = block[start:] if newline < 0 else block[start:newline]
                digest.update(piece)
                if len(head) <= MAX_JOURNAL_LINE_BYTES:
                    head += piece[:MAX_JOURNAL_LINE_BYTES + 1 - len(head)]
                size += len(piece)
                if newline < 0:
                    break
                offset += size + 1
                number += 1
                yield _Line(number, bytes(head), size, digest.hexdigest(), offset, True)
                head, size, digest = bytearray(), 0, hashlib.sha256()
                start = newline + 1
        if size:
            number += 1
            yield _Line(number, bytes(head), size, digest.hexdigest(), offset + size, False)


def _entry(line: _Line) -> dict[str, Any] | None:
    if line.size > MAX_JOURNAL_LINE_BYTES:
        return None
    try:
        entry = json.loads(line.head.decode("utf-8"))
    except (ValueError, RecursionError):
        return None
    return entry if isinstance(entry, dict) else None


def verify(path: Path) -> Verdict:
    """The journal's chain and anchor checked (JournalError: no journal; JournalPathError:
    not a regular file)."""
    try:
        fd = open_regular(path)
    except FileProblem as exc:
        if exc.message == "file not found":
            raise JournalError(f"{path}: no journal yet") from None
        raise JournalPathError(f"{path}: {exc.message}") from None
    verdict = Verdict()
    anchor = _read_anchor(path, verdict)
    previous = GENESIS
    chained = False
    cut: _Line | None = None  # a damaged line that may be a writer's cut, pending
    anchored: _Line | None = None  # the line that ends at the anchor's point
    end = 0
    last: _Line | None = None
    for line in _lines(fd):
        verdict.lines = line.number
        last = line
        end = line.end
        if anchor is not None and anchored is None and line.end >= anchor[0]:
            anchored = line  # the line that ends at the anchor's point, or holds it
        entry = _entry(line)
        if cut is not None:
            if (entry is not None and entry.get("event") == "abnormal-end"
                    and entry.get("cut_bytes") == cut.size):
                verdict.crash_cuts.append(cut.number)
            else:
                verdict.broke(cut.number, "not a journal entry (changed, or garbage)")
            cut = None
        link = entry.get("prev") if entry is not None else None
        if isinstance(link, str):
            if not chained and line.number > 1:
                verdict.unchained = line.number - 1
            chained = True
            if link != previous:
                verdict.broke(line.number, (
                    f"its link does not match line {line.number - 1}: that line was changed, "
                    "or lines were removed, inserted or moved here" if line.number > 1 else
                    "its link is not the start of a journal: the first lines were removed "
                    "or replaced"))
        elif entry is not None and chained:
            verdict.broke(line.number, "an entry without a link inside the chain (inserted "
                          "by hand?)")
        elif entry is None and not line.size:
            verdict.broke(line.number, "a blank line (a writer never writes one)")
        elif entry is None:
            cut = line  # decided by the next line (or the end of the file)
        previous = line.digest
    if cut is not None:
        if cut.complete:
            verdict.broke(cut.number, "not a journal entry (changed, or garbage)")
        else:
            verdict.crash_cuts.append(cut.number)
            verdict.notes.append(f"line {cut.number} is cut short: the last writer was "
                                 "killed while writing it, or the file was cut there")
    if not chained and verdict.lines:
        verdict.unchained = verdict.lines
    _check_anchor(verdict, anchor, anchored, end, last)
    return verdict


def _read_anchor(path: Path, verdict: Verdict) -> tuple[int, str, str] | None:
    target = anchor_path(path)
    try:
        data = json.loads(target.read_text(encoding="ascii"))
        size, head, wall = int(data["size"]), str(data["head"]), str(data.get("wall", "?"))
    except FileNotFoundError:
        verdict.anchor = (f"no anchor file ({target.name}): whether entries were removed "
                          "from the end cannot be told")
        return None
    except (OSError, ValueError, TypeError, KeyError) as exc:
        verdict.broke(0, f"the anchor file {target.name} is damaged ({exc})")
        return None
    return size, head, wall


def _check_anchor(verdict: Verdict, anchor: tuple[int, str, str] | None,
                  anchored: _Line | None, end: int, last: _Line | None) -> None:
    if anchor is None:
        return
    size, head, wall = anchor
    after = verdict.lines
    if size == 0:
        verdict.anchor = f"the anchor of {wall} was written on an empty journal"
        return
    if end < size:
        verdict.broke(after, f"the journal ends after line {after} at byte {end:,}, but its "
                      f"anchor of {wall} says {size:,}: {size - end:,} bytes are missing "
                      "(entries removed from its end, or lines before shortened)")
        return
    if anchored is None or anchored.end != size:
        verdict.broke(anchored.number if anchored else after,
                      f"the anchor of {wall} points inside this line (byte {size:,}): the "
                      "journal was changed before it")
        return
    if anchored.digest != head:
        verdict.broke(anchored.number, f"this line is not the one the anchor of {wall} "
                      "holds: it was changed")
        return
    verdict.anchor = (f"the anchor of {wall} matches line {anchored.number}"
                      + (f"; {verdict.lines - anchored.number} lines written after it"
                         if last is not None and last.number > anchored.number else ""))
