"""The engine reproduces the recorded golden traces byte for byte (tests/golden_traces.py).

A failure names the first line that differs. If the change was meant to change behaviour,
re-record (see tests/golden_traces.py) and say why in the commit; if it was a refactoring, it
was not behaviour-preserving.
"""

from __future__ import annotations

import json

import pytest
from golden_traces import CASES, CLI_CASES, CLI_DIGESTS, GOLDEN, golden_path, run_case, run_cli_case


def _first_difference(expected: str, actual: str) -> str:
    old, new = expected.splitlines(), actual.splitlines()
    for k, (a, b) in enumerate(zip(old, new, strict=False), start=1):
        if a != b:
            return f"line {k}:\n  recorded {a[:600]}\n  now      {b[:600]}"
    return f"recorded {len(old)} lines, now {len(new)}"


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_golden_trace(case):
    expected = golden_path(case.name).read_text(encoding="utf-8")
    actual = run_case(case)
    if actual != expected:
        pytest.fail(f"{case.name} no longer matches its golden trace; "
                    + _first_difference(expected, actual), pytrace=False)


@pytest.mark.parametrize("name,args", CLI_CASES, ids=[n for n, _ in CLI_CASES])
def test_golden_cli_trace(name, args):
    recorded = json.loads(CLI_DIGESTS.read_text(encoding="utf-8"))
    assert run_cli_case(args) == recorded[name], f"plchmi run {' '.join(args)}: trace changed"


def test_every_golden_file_has_its_case():
    names = {c.name for c in CASES}
    files = {p.stem for p in GOLDEN.glob("*.jsonl")}
    assert files == names
    assert set(json.loads(CLI_DIGESTS.read_text(encoding="utf-8"))) == {n for n, _ in CLI_CASES}
