"""YAML loaded into nodes that remember where they came from.

PyYAML's composer gives every node a start mark; we keep it on a small :class:`YNode` tree so
that every later check (an unknown name inside an expression, a duplicate output, a wrong
type) can name the file, line and column. Typed accessors raise :class:`NodeError` with the
node's position, which the loader turns into diagnostics. Reading YAML into these nodes is
hmi.project.yamlcompose's job: the nodes' users (every section's parser, on the HMI's start
path through the engine's imports) do not import PyYAML, which a start whose project is
read back (hmi/project/kept.py) never needs.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import replace
from typing import Any, cast

from hmi.errors import Diagnostic, SourcePos, excerpt
from hmi.logic.expr import expression_text
from hmi.timefmt import DURATION_HINT, DurationError, parse_duration

# YAML's tags of the values a project file may hold (hmi.project.yamlcompose resolves them)
_BOOL = "tag:yaml.org,2002:bool"
_INT = "tag:yaml.org,2002:int"
_FLOAT = "tag:yaml.org,2002:float"
_NULL = "tag:yaml.org,2002:null"
_STR = "tag:yaml.org,2002:str"


class NodeError(Exception):
    """A typed access failed; carries the diagnostic to report."""

    def __init__(self, pos: SourcePos, message: str, expected: str | None = None):
        super().__init__(message)
        self.diagnostic = Diagnostic(pos, message, expected)


class YNode:
    """One YAML node: a mapping, a sequence or a scalar, with its position."""

    __slots__ = ("_raw", "key_pos", "kind", "lines", "pos", "style", "tag", "value")

    def __init__(self, kind: str, value: Any, pos: SourcePos, tag: str,
                 key_pos: dict[str, SourcePos] | None = None):
        self.kind = kind  # "map", "seq" or "scalar"
        self.value = value
        self.pos = pos
        self.tag = tag
        self.key_pos = key_pos or {}
        self.style: str | None = None
        self._raw: str | None = None
        # A scalar written over several lines: each line's part as written, with its line
        # and column ((text, line, column), hmi.project.yamlcompose); None on one line.
        self.lines: tuple[tuple[str, int, int], ...] | None = None

    def __repr__(self) -> str:
        return f"YNode({self.kind}, {self.value!r}, {self.pos})"

    # -- structure -----------------------------------------------------------------------
    def describe(self) -> str:
        if self.kind == "map":
            return "a mapping"
        if self.kind == "seq":
            return "a list"
        return {_BOOL: "a Boolean", _INT: "an integer", _FLOAT: "a number",
                _NULL: "nothing (null)"}.get(self.tag, f"the text {excerpt(str(self.value))}")

    def as_map(self, what: str) -> dict[str, YNode]:
        if self.kind != "map":
            raise NodeError(self.pos, f"{what} must be a mapping, found {self.describe()}",
                            "key: value pairs")
        return cast("dict[str, YNode]", self.value)

    def as_seq(self, what: str) -> list[YNode]:
        if self.kind != "seq":
            raise NodeError(self.pos, f"{what} must be a list, found {self.describe()}",
                            "a YAML list (- item)")
        return cast("list[YNode]", self.value)

    def check_keys(self, what: str, allowed: Collection[str],
                   required: Collection[str] = ()) -> dict[str, YNode]:
        """The mapping, after checking it has no unknown and no missing keys."""
        mapping = self.as_map(what)
        for key in mapping:
            if key not in allowed:
                raise NodeError(self.key_pos.get(key, self.pos),
                                f"unknown key {excerpt(key)} in {what}",
                                "one of " + ", ".join(sorted(allowed)))
        for key in required:
            if key not in mapping:
                raise NodeError(self.pos, f"{what} has no {key!r}", f"a {key!r} key")
        return mapping

    # -- scalars ---------------------------------------------------------------------------
    def _scalar(self, what: str) -> Any:
        if self.kind != "scalar":
            raise NodeError(self.pos, f"{what} must be a single value, found {self.describe()}")
        return self.value

    def as_str(self, what: str) -> str:
        value = self._scalar(what)
        if self.tag != _STR:
            raise NodeError(self.pos, f"{what} must be text, found {self.describe()}",
                            "text (quote it if YAML reads it as another type)")
        return cast(str, value)

    def as_text(self, what: str) -> str:
        """Text, accepting numbers and Booleans written bare (an expression `1`, `True`)."""
        value = self._scalar(what)
        if self.tag == _NULL:
            raise NodeError(self.pos, f"{what} is empty", "a value")
        if self.tag == _STR:
            return cast(str, value)
        return str(self.raw)

    @property
    def raw(self) -> str:
        """The scalar exactly as written in the file (before YAML typing)."""
        return self._raw if self._raw is not None else str(self.value)

    def as_bool(self, what: str) -> bool:
        value = self._scalar(what)
        if self.tag == _BOOL:
            return bool(value)
        if self.tag == _INT and value in (0, 1):
            return bool(value)
        raise NodeError(self.pos, f"{what} must be a Boolean, found {self.describe()}",
                        "true/false or 1/0")

    def as_int(self, what: str, minimum: int | None = None, maximum: int | None = None) -> int:
        value = self._scalar(what)
        if self.tag != _INT:
            raise NodeError(self.pos, f"{what} must be an integer, found {self.describe()}",
                            "an integer")
        if minimum is not None and value < minimum:
            raise NodeError(self.pos, f"{what} is {value}, below the minimum {minimum}",
                            f"an integer >= {minimum}")
        if maximum is not None and value > maximum:
            raise NodeError(self.pos, f"{what} is {value}, above the maximum {maximum}",
                            f"an integer <= {maximum}")
        return cast(int, value)

    def as_number(self, what: str) -> float:
        value = self._scalar(what)
        if self.tag not in (_INT, _FLOAT):
            raise NodeError(self.pos, f"{what} must be a number, found {self.describe()}",
                            "a number")
        if not math.isfinite(value):
            raise NodeError(self.pos, f"{what} is {self.raw}, not a finite number",
                            "a number such as 2 or 0.5")
        return float(value)

    def as_duration(self, what: str, allow_zero: bool = False) -> int:
        """A duration in microseconds; a bare number is refused (which unit would it be?)."""
        value = self._scalar(what)
        if self.tag == _FLOAT and not math.isfinite(value):
            raise NodeError(self.pos, f"{what} is {self.raw}, not a duration", DURATION_HINT)
        if self.tag in (_INT, _FLOAT):
            raise NodeError(self.pos, f"{what} {value} has no unit", DURATION_HINT)
        if self.tag != _STR:
            raise NodeError(self.pos, f"{what} must be a duration, found {self.describe()}",
                            DURATION_HINT)
        try:
            us = parse_duration(value)
        except DurationError as exc:
            raise NodeError(self.pos, f"{what} {value!r} {exc.reason}",
                            DURATION_HINT) from None
        if us == 0 and not allow_zero:
            raise NodeError(self.pos, f"{what} must be longer than zero", DURATION_HINT)
        return us


def text_start(node: YNode, text: str) -> SourcePos:
    """Where `text`, the scalar's value as read (or a form of it with its blanks folded),
    starts in the file: after a quote, if quoted; for a value written over several lines, a
    position whose :meth:`~hmi.errors.SourcePos.shifted` finds the line of each character.
    A line's part that cannot be found again in `text` (an escape sequence, a component's
    renamed text) leaves every character at the scalar's first one: never a column past the
    end of a line."""
    start = node.pos.shifted(1) if node.style in ('"', "'") else node.pos
    if node.lines is None:
        return start
    parts: list[tuple[int, int, int, int]] = []
    cursor = 0
    for written, line, col in node.lines:
        found = text.find(written, cursor)
        length = len(written)
        if found < 0:  # blanks folded inside the line: found by its words
            folded = " ".join(written.split())
            found, length = text.find(folded, cursor), len(folded)
        if found < 0:
            return replace(start, lines=((0, start.line, start.col, 1),))
        parts.append((found, line, col, length))
        cursor = found + length
    if not parts:
        return start
    return replace(start, line=parts[0][1], col=parts[0][2], lines=tuple(parts))


def expr_start(node: YNode, text: str) -> SourcePos:
    """Where the expression `text` read from `node` starts in the file (hmi.logic.expr
    counts its columns in :func:`~hmi.logic.expr.expression_text`)."""
    return text_start(node, expression_text(text))
