"""The exported Structured Text parses with an independent IEC 61131-3 parser (blark).

blark (the TwinCAT-flavoured grammar on PyPI) parses POUs and global variable lists but has
no rule for an IEC CONFIGURATION, which TwinCAT does not use: each file is given to it as its
POUs plus its global variables as a TwinCAT-style VAR_GLOBAL list; the CONFIGURATION's
resource, task and program lines are checked by the tests' own parser (tests/stsubset.py,
which every agreement test loads). blark is slow (an Earley parser, about 45 ms a line on
this machine), so each file is cut into its POUs and global variable list, each parsed once
as a test of its own (a POU two projects export identically is parsed once), which lets
pytest-xdist spread them over the cores.
"""

from __future__ import annotations

import re
from functools import cache
from typing import Any

import pytest

from hmi.export.build import build
from hmi.export.st import write_st
from hmi.project.loader import load_project
from tests.conftest import PROJECTS

pytestmark = pytest.mark.slow  # a long study: tests/conftest.py, _studies_left_out

REQUIRED = ("cispi_valve", "conveyor_robot", "sorting")


def blark_view(text: str) -> str:
    """The POUs, then the configuration's globals as a global variable list."""
    pous, _, config = text.partition("\nCONFIGURATION ")
    match = re.search(r"\n    VAR_GLOBAL\n(.*?)\n    END_VAR\n", config, re.DOTALL)
    assert match is not None, "the configuration declares no globals"
    gvl = "\n".join(line[4:] for line in match.group(0).strip("\n").splitlines())
    return pous + "\n" + gvl + "\n"


@cache
def blark_parser() -> Any:
    """blark's parser (its grammar and Earley settings, blark.parse.new_parser), built once
    per process, with two lark options that change what a parse costs, not what it accepts:
    plain sets for Earley's item sets (ordered ones only make the choice among ambiguous
    trees repeatable) and the shared packed parse forest as the result instead of one tree
    picked from it (a syntax check needs no tree). Measured on the units below: 16 % less
    CPU than blark's default parser."""
    from blark.parse import new_parser
    return new_parser(ordered_sets=False, ambiguity="forest")


def parse_errors(text: str) -> list[str]:
    """Every syntax error blark finds in `text` (empty: it parsed)."""
    from blark.parse import parse_source_code
    result = parse_source_code(text, parser=blark_parser())
    return [] if result.exception is None else [str(result.exception)]


END = re.compile(r"^(END_FUNCTION_BLOCK|END_PROGRAM|END_FUNCTION)[ \t]*$", re.MULTILINE)


def units(text: str) -> list[str]:
    """A blark view cut into its POUs and its global variable list, each parsable alone."""
    pieces, start = [], 0
    for match in END.finditer(text):
        pieces.append(text[start:match.end()].strip("\n") + "\n")
        start = match.end()
    rest = text[start:].strip("\n")
    return [*pieces, rest + "\n"] if rest else pieces


def _distinct_units() -> dict[str, str]:
    """Every distinct unit of the required projects' exports, named by project and POU: a
    POU exported identically by two projects is parsed once."""
    found: dict[str, str] = {}
    for name in REQUIRED:
        for unit in units(blark_view(write_st(build(load_project(PROJECTS / name))))):
            if unit not in found.values():
                head = re.search(r"^(?:FUNCTION_BLOCK|PROGRAM|FUNCTION) (\w+)", unit, re.M)
                found[f"{name}:{head.group(1) if head else 'globals'}"] = unit
    return found


UNITS = _distinct_units()


def test_the_exports_hold_what_blark_is_given():
    texts = {name: blark_view(write_st(build(load_project(PROJECTS / name))))
             for name in REQUIRED}
    for text in texts.values():
        assert "FUNCTION_BLOCK" in text and "VAR_GLOBAL" in text and "AT %IX0.0" in text
        # cut into units without losing a line (each unit is parsed on its own below)
        assert "".join(units(text)).split() == text.split()
    assert all(any(key.startswith(f"{name}:") for key in UNITS) for name in REQUIRED)
    assert sum("globals" in key for key in UNITS) == len(REQUIRED)


@pytest.mark.parametrize("key", list(UNITS))
def test_the_exports_parse_with_blark(key):
    """Each POU (and each global variable list) apart: blark parses about 20 lines a second,
    so the units are separate tests that pytest-xdist spreads over the cores."""
    assert parse_errors(UNITS[key]) == []


def test_blark_does_catch_a_syntax_error():
    """The check can fail: a missing semicolon in an exported POU is an error to blark."""
    text = write_st(build(load_project(PROJECTS / "conveyor_robot")))
    start = text.index("FUNCTION_BLOCK FB_conveyor_robot_Filter")
    pou = text[start:text.index("END_FUNCTION_BLOCK", start) + len("END_FUNCTION_BLOCK")]
    broken = pou.replace("Tested := 0;", "Tested := 0", 1)
    assert broken != pou
    assert parse_errors(broken)
