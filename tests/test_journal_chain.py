"""The journal's hash chain and anchor: a real journal, tampered with at 1,000 random places.

The journal is written by real runs (plchmi run, five sessions into one file), closed as a
session closes it (its anchor written). Each of the 1,000 cases edits a byte, deletes a
line, swaps two lines, inserts a line (a copy, garbage, or a forged entry that links
correctly to the line before it) or truncates the file at a random byte; every one must be
found by ``verify``, and the untouched journal verifies intact.
"""

from __future__ import annotations

import hashlib
import json
import random
import threading
from pathlib import Path

import pytest

from hmi.cli import main
from hmi.explain import journal as journal_module
from hmi.explain.chain import verify
from hmi.explain.journal import GENESIS, Journal, anchor_path


@pytest.fixture(scope="module")
def real_journal(tmp_path_factory) -> tuple[bytes, bytes]:
    """(journal bytes, anchor bytes) of five real runs."""
    folder = tmp_path_factory.mktemp("chain")
    path = folder / "journal.jsonl"
    for fault in ("F5@5s", "F1@3s", "F13@4s", "F9@2s", "F3@3s"):
        assert main(["run", "projects/cispi_valve", "--for", "15s", "--inject", fault,
                     "--journal", str(path)]) == 0
    return path.read_bytes(), anchor_path(path).read_bytes()


def lay(folder: Path, data: bytes, anchor: bytes) -> Path:
    path = folder / "journal.jsonl"
    path.write_bytes(data)
    anchor_path(path).write_bytes(anchor)
    return path


def test_an_untouched_journal_verifies(tmp_path, real_journal, capsys):
    data, anchor = real_journal
    path = lay(tmp_path, data, anchor)
    verdict = verify(path)
    lines = data.count(b"\n")
    assert lines >= 20, lines
    assert verdict.intact and verdict.lines == lines and not verdict.unchained
    assert verdict.anchor.endswith(f"matches line {lines}")
    assert main(["journal", "verify", "projects/cispi_valve", "--path", str(path)]) == 0
    assert "the chain intact" in capsys.readouterr().out


def _forged(prev_line: bytes | None) -> bytes:
    """An entry as a forger would write it, linked correctly to the line before it."""
    link = hashlib.sha256(prev_line).hexdigest() if prev_line is not None else GENESIS
    return json.dumps({"wall": "2026-11-29T05:00:00.000+00:00", "type": "action",
                       "event": "acknowledge all alarms", "accepted": True,
                       "message": "nothing happened here", "prev": link},
                      separators=(",", ":")).encode()


def tamper(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    lines = data.split(b"\n")[:-1]
    kind = rng.choice(("edit", "delete", "reorder", "insert", "truncate"))
    n = len(lines)
    if kind == "edit":
        i = rng.randrange(n)
        j = rng.randrange(len(lines[i]))
        old = lines[i][j]
        new = rng.choice([c for c in range(32, 127) if c != old])
        lines[i] = lines[i][:j] + bytes([new]) + lines[i][j + 1:]
        where = f"edit line {i + 1} byte {j}"
    elif kind == "delete":
        i = rng.randrange(n)
        del lines[i]
        where = f"delete line {i + 1}"
    elif kind == "reorder":
        i, k = rng.sample(range(n), 2)
        lines[i], lines[k] = lines[k], lines[i]
        where = f"swap lines {i + 1} and {k + 1}"
    elif kind == "insert":
        i = rng.randrange(n)  # before line i + 1: between entries, or before the first
        how = rng.choice(("copy", "garbage", "forged"))
        line = (lines[rng.randrange(n)] if how == "copy" else b'{"type":"action"}'
                if how == "garbage" else _forged(lines[i - 1] if i else None))
        lines.insert(i, line)
        where = f"insert a {how} line before line {i + 1}"
    else:
        cut = rng.randrange(len(data))
        return f"truncate at byte {cut}", data[:cut]
    return where, b"\n".join(lines) + b"\n"


def test_tampering_at_1000_random_places_is_always_found(tmp_path, real_journal):
    data, anchor = real_journal
    rng = random.Random(20261129)
    kinds: dict[str, int] = {}
    for case in range(1000):
        where, changed = tamper(data, rng)
        assert changed != data, where
        path = lay(tmp_path, changed, anchor)
        verdict = verify(path)
        assert not verdict.intact, f"case {case}: {where} was not found"
        kinds[where.split()[0]] = kinds.get(where.split()[0], 0) + 1
    assert set(kinds) == {"edit", "delete", "swap", "insert", "truncate"}
    assert min(kinds.values()) > 150


def test_the_first_broken_link_is_named_with_its_line(tmp_path, real_journal, capsys):
    data, anchor = real_journal
    lines = data.split(b"\n")
    lines[6] = lines[6].replace(b'"scan":', b'"scan":1', 1)
    path = lay(tmp_path, b"\n".join(lines), anchor)
    assert main(["journal", "verify", "projects/cispi_valve", "--path", str(path)]) == 1
    out = capsys.readouterr().out
    assert f"{path}:8: broken: its link does not match line 7" in out
    assert "NOT INTACT" in out and "the first at line 8" in out


def test_a_truncated_tail_is_found_by_the_anchor(tmp_path, real_journal):
    data, anchor = real_journal
    cut = data[:data.rstrip(b"\n").rfind(b"\n") + 1]  # the last entry removed cleanly
    verdict = verify(lay(tmp_path, cut, anchor))
    assert not verdict.intact and "bytes are missing" in verdict.breaks[0].what
    path = lay(tmp_path, cut, anchor)
    anchor_path(path).unlink()
    verdict = verify(path)
    assert verdict.intact and "no anchor file" in verdict.anchor  # said, not hidden


def test_a_killed_writer_is_a_note_not_a_break(tmp_path, real_journal):
    data, anchor = real_journal
    lines = data.count(b"\n")
    fragment = b'{"wall":"2026-11-29T06:00:00.000+00:00","type":"al'
    path = lay(tmp_path, data + fragment, anchor)
    verdict = verify(path)
    assert verdict.intact and verdict.crash_cuts == [lines + 1]
    journal = Journal(path)  # the next session ends the cut line and says so
    assert journal.cut_bytes == len(fragment)
    journal.append({"type": "session", "event": "start"})
    journal.close()
    verdict = verify(path)
    assert verdict.intact and verdict.crash_cuts == [lines + 1], verdict.breaks
    assert verdict.anchor.endswith(f"matches line {lines + 3}")


def test_writers_in_two_threads_keep_one_chain(tmp_path):
    path = tmp_path / "journal.jsonl"
    writers = [Journal(path), Journal(path)]

    def write(journal: Journal, n: int) -> None:
        for i in range(150):
            journal.append({"type": "action", "event": f"writer {n} entry {i}"})

    threads = [threading.Thread(target=write, args=(j, n)) for n, j in enumerate(writers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for journal in writers:
        journal.close()
    verdict = verify(path)
    assert verdict.intact and verdict.lines == 300, verdict.breaks


def test_the_anchor_follows_within_a_minute(tmp_path, monkeypatch):
    path = tmp_path / "journal.jsonl"
    journal = Journal(path)
    journal.append({"type": "session", "event": "start"})
    journal.tick()
    assert not anchor_path(path).exists()  # not yet: less than a minute
    monkeypatch.setattr(journal, "_anchored_at", journal._anchored_at
                        - journal_module.ANCHOR_EVERY_S)
    journal.tick()
    anchored = json.loads(anchor_path(path).read_text())
    assert anchored["size"] == path.stat().st_size
    journal.append({"type": "session", "event": "stop"})
    path.write_bytes(path.read_bytes())  # nothing changed; the anchor is a line behind
    assert verify(path).intact
    journal.close()
    assert json.loads(anchor_path(path).read_text())["size"] == path.stat().st_size
