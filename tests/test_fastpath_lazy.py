"""Things built later than they used to be: `plchmi run` without a trace on its
quiet path, for every control variant with random options (policy, solver, diagnosis mode,
scan period, scenario or faults), prints and journals what it does building every scan; and
a snapshot whose monitors are read long after its scan (Snapshot.monitors is lazy) shows
that scan's monitors, not later ones."""

from __future__ import annotations

import json
import random

import pytest

from hmi.cli import main
from hmi.engine import commands as cmd
from hmi.engine.scan import Engine
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.loader import load_project
from hmi.session.session import Session
from tests.conftest import PROJECTS

NAMES = ("cispi_valve", "sorting", "palletizer", "conveyor_robot", "cispi_subsystem")


def random_arguments(name: str, seed: int) -> list[str]:
    project = load_project(PROJECTS / name)
    rng = random.Random(f"{name}:{seed}")
    controls = sorted(project.controls)  # each variant in turn
    args = ["--for", f"{rng.randint(8, 30)}s", "--control", controls[seed % len(controls)],
            "--policy", rng.choice(("monitor", "block", "correct", "correct")),
            "--solver", rng.choice(("exact", "paper")),
            "--diagnosis", rng.choice(("ftc", "observe", "off"))]
    if rng.random() < 0.3:
        args += ["--period", f"{project.scan_period_us // 1000 * rng.choice((2, 3))}ms"]
    scenarios = [s.name for s in getattr(project, "scenarios", ())]
    if scenarios and rng.random() < 0.5:
        args += ["--scenario", rng.choice(scenarios)]
    else:
        faults = SimPlant(project).faults()
        for _ in range(rng.randint(0, 2)):
            device, code, _ = rng.choice(faults)
            at = rng.randint(1, 8)
            length = f"+{rng.randint(1, 4)}s" if rng.random() < 0.4 else ""
            args += ["--inject", f"{device}.{code}@{at}s{length}"]
    if rng.random() < 0.3:
        args.append("--explain")
    return args


def run(capsys, tmp_path, label: str, name: str, args: list[str]) -> tuple[list[str], list]:
    journal = tmp_path / f"{label}.jsonl"
    status = main(["run", str(PROJECTS / name), *args, "--journal", str(journal)])
    captured = capsys.readouterr()
    out = [line.split(" scans in ")[0] if line.startswith("Ran ") else line
           for line in captured.out.splitlines() if not line.startswith("Journal: ")]
    entries = [json.loads(line) for line in journal.read_text().splitlines()] \
        if journal.exists() else []
    for entry in entries:
        entry.pop("wall", None)
        entry.pop("session", None)
        entry.pop("prev", None)  # the chain link: follows the wall time
    return [str(status), *out, *captured.err.splitlines()], entries


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("seed", (0, 1, 2))
def test_plchmi_run_prints_and_journals_the_same_on_its_quiet_path(capsys, tmp_path,
                                                                   monkeypatch, name, seed):
    args = random_arguments(name, seed)
    quiet_scans = [0]
    real = Session.run_for

    def counted(self, duration, on_scan=None, on_quiet=None):
        def told(count):
            quiet_scans[0] += count
            on_quiet(count)
        return real(self, duration, on_scan, told if on_quiet is not None else None)

    monkeypatch.setattr(Session, "run_for", counted)
    quiet = run(capsys, tmp_path, "quiet", name, args)

    def every_scan_built(self, duration, on_scan=None, on_quiet=None):
        return real(self, duration, on_scan, None)  # (what a run with --trace does)

    monkeypatch.setattr(Session, "run_for", every_scan_built)
    full = run(capsys, tmp_path, "full", name, args)
    assert quiet[0] == full[0], args
    assert quiet[1] == full[1], args
    assert quiet[0][0] == "0" and quiet_scans[0] > 0, (args, quiet[0][:3])


@pytest.mark.parametrize("name", ("sorting", "palletizer", "conveyor_robot"))
def test_monitors_read_late_are_the_monitors_of_their_scan(name):
    """Snapshots kept unread (as a UI or a trace writer might hold them) and read after many
    more scans, commands and faults against the same run reading them at once."""
    project = load_project(PROJECTS / name)
    rng = random.Random(name)
    engines = [Engine(project, SimPlant(project)) for _ in range(2)]
    kept, read_at_once = [], []
    faults = engines[0].plant.faults()
    for k in range(3000):
        now = k * project.scan_period_us
        if k and k % 400 == 0:
            device, code, _ = rng.choice(faults)
            command = rng.choice((cmd.FaultReset(), cmd.RepairFaults(),
                                  cmd.InjectFault(Injection(code, now + 100_000, device))))
            for engine in engines:
                engine.apply(command)
        late, early = (engine.step(now) for engine in engines)
        read_at_once.append(early.monitors)
        if rng.random() < 0.3:
            kept.append((k, late))
    assert any(m.running for _, snap in kept for m in snap.monitors), "no task ever ran"
    for k, snap in kept:
        assert snap.monitors == read_at_once[k], f"scan {k}"
