"""The journal survives crashes: a new session after a kill, and damaged lines anywhere."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from hmi.cli import main
from hmi.explain.journal import Journal, read
from tests.conftest import PROJECTS, ROOT

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000
HALF_ENTRY = b'{"wall":"2026-11-22T10:00:00.000+00:00","type":"alarm","event":"rai'


def kill_a_run_mid_journal(path) -> None:
    """Start a long faulty run writing `path`, SIGKILL it once it has journalled 20 entries."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", "100h",
         "--control", "faulty", "--journal", str(path)],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if path.exists() and path.read_bytes().count(b"\n") >= 20:
                break
            time.sleep(0.05)
        else:
            raise AssertionError("the run did not journal 20 entries in 60 s")
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()


def test_a_session_after_a_kill_mid_entry_leaves_everything_readable(tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    kill_a_run_mid_journal(path)
    if path.read_bytes().endswith(b"\n"):
        # The kill fell between two entries; make it the worst case, a kill inside os.write.
        with path.open("ab") as f:
            f.write(HALF_ENTRY)
    killed = read(path)
    assert killed.truncated and len(killed.entries) >= 20
    cut = len(path.read_bytes().rsplit(b"\n", 1)[1])

    assert main(["run", str(VALVE), "--for", "5s", "--journal", str(path)]) == 0
    capsys.readouterr()
    result = read(path)
    assert result.entries[:len(killed.entries)] == killed.entries  # nothing lost
    after = result.entries[len(killed.entries):]
    assert after[0]["event"] == "abnormal-end" and after[0]["cut_bytes"] == cut
    assert "entries may be missing" in after[0]["message"]
    assert [e["event"] for e in after if e["type"] == "session"][1:] == ["start", "stop"]
    assert len(result.damaged) == 1 and "cut short" in result.damaged[0].reason
    assert not result.truncated  # the cut line is in the middle now, ended by a newline

    assert main(["journal", str(VALVE), "--path", str(path)]) == 0
    out, err = capsys.readouterr()
    assert out.count("\n") == len(result.entries)
    line = result.damaged[0].line
    assert f"warning: {path}:{line}: damaged journal entry skipped: entry cut short" in err


def test_opening_a_cleanly_ended_journal_adds_no_abnormal_end(tmp_path):
    path = tmp_path / "j.jsonl"
    journal = Journal(path)
    journal.append({"type": "action", "event": "one"})
    journal.close()
    journal = Journal(path)
    assert journal.cut_bytes is None
    journal.append({"type": "action", "event": "two"})
    journal.close()
    assert [e["event"] for e in read(path).entries] == ["one", "two"]


def test_a_partial_line_is_ended_before_the_next_entry(tmp_path):
    path = tmp_path / "j.jsonl"
    path.write_bytes(b'{"type":"action","event":"one"}\n' + HALF_ENTRY)
    journal = Journal(path)
    assert journal.cut_bytes == len(HALF_ENTRY)
    journal.append({"type": "action", "event": "two"})
    journal.close()
    lines = path.read_bytes().split(b"\n")
    assert lines[1] == HALF_ENTRY and lines[-1] == b""
    assert [e["event"] for e in read(path).entries] == ["one", "abnormal-end", "two"]


def test_damaged_lines_anywhere_are_reported_and_skipped(tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    path.write_bytes(b'{"type":"action","event":"one","scan":1}\n'
                     b'garbage here\n'
                     b'{"type":"action","event":"two","scan":2}\n'
                     b'[1, 2]\n'
                     b'{"type":"action","event":"bad \xff\xfe utf8"}\n'
                     + HALF_ENTRY + b'\n'
                     b'{"type":"action","event":"three","scan":3}\n')
    result = read(path)
    assert [e["event"] for e in result.entries] == ["one", "two", "three"]
    assert [d.line for d in result.damaged] == [2, 4, 5, 6]
    reasons = [d.reason for d in result.damaged]
    assert reasons[0].startswith("not valid JSON") and "JSON list" in reasons[1]
    assert reasons[2] == "not UTF-8 text" and "cut short" in reasons[3]
    assert main(["journal", str(VALVE), "--path", str(path)]) == 0
    out, err = capsys.readouterr()
    assert "one" in out and "two" in out and "three" in out
    assert err.count("damaged journal entry skipped") == 4
    assert f"{path}:2: damaged journal entry skipped: not valid JSON" in err


# -- chattering alarms -----------------------------------------------------------------------

def test_a_collapsed_alarm_still_journals_every_change_of_its_condition():
    from hmi.explain.alarms import AlarmManager
    from tests.test_explain import chatter
    m = AlarmManager()
    events, t = chatter(m)
    kinds = [x.event for x in events]
    # Every return and clear the operator could have seen: 10 of each, in order.
    changes = [k for k in kinds if k in ("raised", "returned", "condition-returned",
                                         "cleared", "condition-cleared")]
    assert changes == ["raised", "cleared"] + ["returned", "cleared"] * 3 + \
        ["returned", "condition-cleared"] + ["condition-returned", "condition-cleared"] * 5
    returns = [x.returns for x in events if x.event in ("returned", "condition-returned")]
    assert returns == list(range(1, 10))  # the running count
    held = [x for x in events if x.event == "condition-cleared"]
    assert all(x.state == "active-unacknowledged" and x.note for x in held)
    assert [x.time_us for x in held] == [(2 * i + 1) * S for i in range(4, 10)]
    later = m.update((), 0, t + 61 * S)
    assert [x.event for x in later] == ["cleared"]
    assert later[0].note == "condition clear since 19.000 s (held while chattering)"


def test_a_faulty_run_journals_every_return_of_a_chattering_constraint(tmp_path):
    path = tmp_path / "j.jsonl"
    assert main(["run", str(VALVE), "--control", "faulty", "--for", "120s",
                 "--journal", str(path)]) == 0
    alarms = [e for e in read(path).entries if e["type"] == "alarm"]
    chattering = {e["key"] for e in alarms if e["event"] == "chattering"}
    assert chattering
    for key in chattering:
        mine = [e for e in alarms if e["key"] == key]
        came = [e for e in mine if e["event"] in ("raised", "returned", "condition-returned")]
        went = [e for e in mine if e["event"] in ("cleared", "condition-cleared")]
        assert len(came) > 5 and abs(len(came) - len(went)) <= 1
        assert [e["returns"] for e in came] == list(range(len(came)))


def test_a_sigkilled_run_leaves_a_readable_journal(tmp_path):
    path = tmp_path / "j.jsonl"
    kill_a_run_mid_journal(path)
    result = read(path)
    assert len(result.entries) >= 20
    assert result.entries[0]["event"] == "start"
    assert all("wall" in e and "scan" in e for e in result.entries)
    assert json.loads(path.read_bytes().split(b"\n")[1])  # complete lines are valid JSON
    assert main(["journal", str(VALVE), "--path", str(path)]) == 0
