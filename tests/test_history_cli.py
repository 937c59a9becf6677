"""`plchmi run --historian` and `plchmi history`: the history written by a headless run and
read back, as a table, CSV, the signal list and the events; bad input said, exit status 2;
no history, exit status 1."""

from __future__ import annotations

import csv
import io
from datetime import datetime

from hmi.cli import main
from tests.conftest import PROJECTS

VALVE = str(PROJECTS / "cispi_valve")


def test_a_virtual_run_records_only_when_asked(tmp_path, capsys):
    assert main(["run", VALVE, "--for", "5s"]) == 0
    assert "History" not in capsys.readouterr().out
    assert not list(tmp_path.rglob("history.sqlite"))


def test_run_then_export(tmp_path, capsys):
    path = tmp_path / "h.sqlite"
    assert main(["run", VALVE, "--for", "60s", "--inject", "F13@30s", "--historian",
                 str(path)]) == 0
    out = capsys.readouterr().out
    assert f"History: {path}" in out and "samples and events" in out
    # the run is placed to end as it finished: --since 2h holds all of it
    assert main(["history", VALVE, "--historian", str(path), "--signals", "fso,C,V1.state",
                 "--since", "2h", "--csv"]) == 0
    rows = list(csv.reader(io.StringIO(capsys.readouterr().out)))
    assert rows[0] == ["time", "fso", "C", "V1.state"]
    times = [datetime.fromisoformat(r[0].replace("Z", "+00:00")) for r in rows[1:]]
    assert times == sorted(times) and len(rows) > 10
    assert (times[-1] - times[0]).total_seconds() > 50
    assert {r[3] for r in rows[1:]} >= {"N1", "N2"}  # the diagnoser's states by name
    assert all(r[1] in ("0", "1") for r in rows[1:-1])
    assert rows[-1][1:] == ["", "", ""]  # where the history stops: unknown from there
    assert main(["history", VALVE, "--historian", str(path), "--signals", "fso,O.travel",
                 "--since", "2h"]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].split() == ["time", "fso", "O.travel"] and " s" in table[3]
    assert main(["history", VALVE, "--historian", str(path), "--list"]) == 0
    listed = capsys.readouterr().out
    assert "O.travel" in listed and "V1.state" in listed and "enum" in listed
    assert main(["history", VALVE, "--historian", str(path), "--events", "--since", "2h"]) == 0
    events = capsys.readouterr().out
    assert "raised" in events and "session" in events


def test_bad_input_is_said(tmp_path, capsys):
    path = tmp_path / "h.sqlite"
    assert main(["run", VALVE, "--for", "2s", "--historian", str(path)]) == 0
    capsys.readouterr()
    for args, words in (
            (["--signals", "fsoo"], "did you mean fso"),
            (["--since", "yesterday"], "not an instant"),
            (["--since", "1h", "--until", "2h"], "is not after"),
            (["--historian", "ftp://x"], "not a history target")):
        assert main(["history", VALVE, "--historian", str(path), *args]) == 2, args
        assert words in capsys.readouterr().err, args
    assert main(["run", VALVE, "--for", "2s", "--historian", "ftp://x/y"]) == 2
    assert "not a history target" in capsys.readouterr().err
    try:
        main(["run", VALVE, "--for", "2s", "--history-retention", "0d"])
    except SystemExit as exc:
        assert exc.code == 2
    assert "more than zero" in capsys.readouterr().err


def test_no_history_is_exit_status_1(tmp_path, capsys):
    assert main(["history", VALVE]) == 1
    assert "no history here yet" in capsys.readouterr().err
    (tmp_path / "other.sqlite").write_bytes(b"not a database at all" * 100)
    assert main(["history", VALVE, "--historian", str(tmp_path / "other.sqlite")]) == 1
    assert "not" in capsys.readouterr().err


def test_off_records_nothing(tmp_path, capsys):
    assert main(["run", VALVE, "--for", "2s", "--historian", "off"]) == 0
    assert "History" not in capsys.readouterr().out
