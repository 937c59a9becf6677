"""`plchmi run` without a trace builds no snapshot for a quiet scan (hmi.session.Session.run_for:
no news from the engine, nothing explained, no alarm): what it prints and journals must be
exactly what the same run building every scan's snapshot prints and journals."""

from __future__ import annotations

import json

import pytest

from hmi.cli import main
from hmi.engine import commands as cmd
from hmi.session.run_report import RunCollector
from hmi.session.session import Session
from tests.conftest import PROJECTS, make_session

S = 1_000_000

RUNS = [
    ("cispi_valve", ["--for", "60s"]),
    ("cispi_valve", ["--for", "40s", "--inject", "F5@5s", "--inject", "F9@12s+2s"]),
    ("cispi_subsystem", ["--for", "60s", "--inject", "P.welded@30s"]),
    ("sorting", ["--for", "60s", "--scenario", "table_jam"]),
    ("sorting", ["--for", "40s", "--policy", "monitor", "--inject", "left_blocked@10s"]),
    ("palletizer", ["--for", "60s"]),
    ("conveyor_robot", ["--scenario", "paper"]),
    ("conveyor_robot", ["--for", "30s", "--explain"]),
]


def run(capsys, tmp_path, name: str, project: str, args: list[str]) -> tuple[list[str], list]:
    journal = tmp_path / f"{name}.jsonl"
    assert main(["run", str(PROJECTS / project), *args, "--journal", str(journal)]) == 0
    out = capsys.readouterr().out.splitlines()
    # the wall time and the journal's path are all that may differ
    out = [line.split(" scans in ")[0] if line.startswith("Ran ") else line for line in out
           if not line.startswith("Journal: ")]
    entries = [json.loads(line) for line in journal.read_text().splitlines()]
    for entry in entries:
        entry.pop("wall")
        entry.pop("session")
        entry.pop("prev")
    return out, entries


@pytest.mark.parametrize(("project", "args"), RUNS)
def test_a_run_prints_and_journals_what_building_every_snapshot_does(
        capsys, tmp_path, monkeypatch, project, args):
    scans = {"quiet": 0}
    real = RunCollector.quiet

    def counted(self, count=1):
        scans["quiet"] += count
        real(self, count)

    monkeypatch.setattr(RunCollector, "quiet", counted)
    quiet = run(capsys, tmp_path, "quiet", project, args)
    assert scans["quiet"] > 100  # the run did skip building snapshots
    # the reference: every scan built, explained and added
    monkeypatch.setattr(Session, "_ready_for_quiet", lambda self: False)
    monkeypatch.setattr(Session, "_scan_unless_quiet", lambda self, now: self.scan_once())
    assert run(capsys, tmp_path, "full", project, args) == quiet


@pytest.mark.parametrize(("project", "faults"), [
    ("sorting", ()), ("sorting", ("table_jam@5s",)), ("cispi_valve", ("F5@3s", "F13@9s")),
    ("conveyor_robot", ("C1.stop@2s+2s",)), ("palletizer", ()),
    ("palletizer", ("layer_eye_stuck0@9s",))])
def test_last_builds_a_quiet_scans_snapshot_as_a_scan_would_have(project, faults):
    """Session.last after quiet scans: the snapshot scan_once gives (measured times apart),
    alarms and explanations included; a command between scans sees it too."""
    def comparable(cell):
        snap = cell.snapshot._replace(scan_wall_us=0.0, filter_wall_us=0.0)
        return cell._replace(snapshot=snap, explain_wall_us=0.0)

    lazy, full = (make_session(PROJECTS / project, inject=faults) for _ in range(2))
    quiet = []
    for until in (4, 7, 13, 21, 30):
        lazy.run_for(until * S - lazy.next_time, None, quiet.append)
        full.run_for(until * S - full.next_time)
        assert comparable(lazy.last) == comparable(full.last)
        for session in (lazy, full):
            assert session.command(cmd.SetPolicy("monitor" if until % 2 else "correct")).accepted
        assert comparable(lazy.last) == comparable(full.last)
    assert sum(quiet) > 300


@pytest.mark.parametrize("project", ["palletizer", "sorting", "cispi_valve"])
def test_the_collector_counts_quiet_scans_as_the_scans_they_repeat(project):
    """RunCollector.quiet(n) against the same run adding every scan's snapshot."""
    lazy, full = RunCollector(), RunCollector()
    quiet = []
    last = make_session(PROJECTS / project).run_for(
        30 * S, lazy.add, lambda n: (quiet.append(n), lazy.quiet(n)))
    lazy.finish(last)
    full.finish(make_session(PROJECTS / project).run_for(30 * S, full.add))
    assert lazy.scans == full.scans and sum(quiet) > full.scans // 2
    for field in ("violations", "corrections", "safe_scans", "unsafe_written", "fallbacks",
                  "max_distance", "first_latch", "events", "alarm_events", "step_changes",
                  "explanations"):
        assert getattr(lazy, field) == getattr(full, field), field
    assert lazy.monitors.last == full.monitors.last
    assert lazy.monitors.detections == full.monitors.detections
