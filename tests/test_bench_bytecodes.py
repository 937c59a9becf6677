"""The bytecode split of a scan (hmi.bench.bytecodes): counted over the scans of the window
only, by function, the scan program's printed functions among them."""

from __future__ import annotations

from hmi.bench.bytecodes import bytecodes, main


def test_the_valve_scans_are_split_by_function_over_the_window_only():
    scans, counts = bytecodes("cispi_valve", 1, 2)
    assert scans == 101  # 10 ms a scan: 1.01 s to 2.01 s (a run_for includes its end)
    core = [name for name in counts if name.endswith(":core") and "compiled" in name]
    assert len(core) == 1 and counts[core[0]] > 100 * scans // 2  # the program, every scan
    assert any(name.startswith("plant/sim/") for name in counts)  # the plant's read
    assert sum(counts.values()) < 5_000 * scans  # quiet scans: not the start's thousands


def test_the_command_prints_each_project_and_its_functions(capsys):
    assert main(["cispi_valve", "--from", "1", "--to", "2", "--top", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("  cispi_valve: ") and "bytecodes/scan over 101 scans" in lines[0]
    assert len(lines) == 4
