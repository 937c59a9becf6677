"""The exported Structured Text parses with an independent IEC 61131-3 parser (blark).

blark (the TwinCAT-flavoured grammar on PyPI) parses POUs and global variable lists but has
no rule for an IEC CONFIGURATION, which TwinCAT does not use: each file is given to it as its
POUs plus its global variables as a TwinCAT-style VAR_GLOBAL list; the CONFIGURATION's
resource, task and program lines are checked by the tests' own parser (tests/stsubset.py,
which every agreement test loads). blark is slow (an Earley parser, about 10 ms a line), so
each file is parsed once, the three in two worker processes.
"""

from __future__ import annotations

import re
from concurrent.futures import ProcessPoolExecutor

from hmi.export.build import build
from hmi.export.st import write_st
from hmi.project.loader import load_project
from tests.conftest import PROJECTS, processes_for_a_test

REQUIRED = ("cispi_valve", "conveyor_robot", "sorting")


def blark_view(text: str) -> str:
    """The POUs, then the configuration's globals as a global variable list."""
    pous, _, config = text.partition("\nCONFIGURATION ")
    match = re.search(r"\n    VAR_GLOBAL\n(.*?)\n    END_VAR\n", config, re.DOTALL)
    assert match is not None, "the configuration declares no globals"
    gvl = "\n".join(line[4:] for line in match.group(0).strip("\n").splitlines())
    return pous + "\n" + gvl + "\n"


def parse_errors(text: str) -> list[str]:
    """Every syntax error blark finds in `text` (empty: it parsed)."""
    from blark.parse import parse_source_code
    result = parse_source_code(text)
    return [] if result.exception is None else [str(result.exception)]


def test_the_exports_parse_with_blark():
    texts = {name: blark_view(write_st(build(load_project(PROJECTS / name))))
             for name in REQUIRED}
    for text in texts.values():
        assert "FUNCTION_BLOCK" in text and "VAR_GLOBAL" in text and "AT %IX0.0" in text
    with ProcessPoolExecutor(max_workers=processes_for_a_test()) as pool:
        errors = dict(zip(texts, pool.map(parse_errors, texts.values()), strict=True))
    assert errors == {name: [] for name in REQUIRED}


def test_blark_does_catch_a_syntax_error():
    """The check can fail: a missing semicolon in an exported POU is an error to blark."""
    text = write_st(build(load_project(PROJECTS / "conveyor_robot")))
    start = text.index("FUNCTION_BLOCK FB_conveyor_robot_Filter")
    pou = text[start:text.index("END_FUNCTION_BLOCK", start) + len("END_FUNCTION_BLOCK")]
    broken = pou.replace("Tested := 0;", "Tested := 0", 1)
    assert broken != pou
    assert parse_errors(broken)
