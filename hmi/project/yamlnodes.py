"""YAML loaded into nodes that remember where they came from.

PyYAML's composer gives every node a start mark; we keep it on a small :class:`YNode` tree so
that every later check (an unknown name inside an expression, a duplicate output, a wrong
type) can name the file, line and column. Typed accessors raise :class:`NodeError` with the
node's position, which the loader turns into diagnostics.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from hmi.errors import Diagnostic, ProjectError, SourcePos
from hmi.timefmt import DURATION_HINT, parse_duration

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

    __slots__ = ("_raw", "key_pos", "kind", "pos", "style", "tag", "value")

    def __init__(self, kind: str, value: Any, pos: SourcePos, tag: str,
                 key_pos: dict[str, SourcePos] | None = None):
        self.kind = kind  # "map", "seq" or "scalar"
        self.value = value
        self.pos = pos
        self.tag = tag
        self.key_pos = key_pos or {}
        self.style: str | None = None
        self._raw: str | None = None

    def __repr__(self) -> str:
        return f"YNode({self.kind}, {self.value!r}, {self.pos})"

    # -- structure -----------------------------------------------------------------------
    def describe(self) -> str:
        if self.kind == "map":
            return "a mapping"
        if self.kind == "seq":
            return "a list"
        return {_BOOL: "a Boolean", _INT: "an integer", _FLOAT: "a number",
                _NULL: "nothing (null)"}.get(self.tag, f"the text {self.value!r}")

    def as_map(self, what: str) -> dict[str, YNode]:
        if self.kind != "map":
            raise NodeError(self.pos, f"{what} must be a mapping, found {self.describe()}",
                            "key: value pairs")
        return self.value

    def as_seq(self, what: str) -> list[YNode]:
        if self.kind != "seq":
            raise NodeError(self.pos, f"{what} must be a list, found {self.describe()}",
                            "a YAML list (- item)")
        return self.value

    def check_keys(self, what: str, allowed: set[str] | list[str],
                   required: set[str] | list[str] = ()) -> dict[str, YNode]:
        """The mapping, after checking it has no unknown and no missing keys."""
        mapping = self.as_map(what)
        for key in mapping:
            if key not in allowed:
                raise NodeError(self.key_pos.get(key, self.pos),
                                f"unknown key {key!r} in {what}",
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
        return value

    def as_text(self, what: str) -> str:
        """Text, accepting numbers and Booleans written bare (an expression `1`, `True`)."""
        value = self._scalar(what)
        if self.tag == _NULL:
            raise NodeError(self.pos, f"{what} is empty", "a value")
        if self.tag == _STR:
            return value
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
        return value

    def as_number(self, what: str) -> float:
        value = self._scalar(what)
        if self.tag not in (_INT, _FLOAT):
            raise NodeError(self.pos, f"{what} must be a number, found {self.describe()}",
                            "a number")
        return float(value)

    def as_duration(self, what: str, allow_zero: bool = False) -> int:
        """A duration in microseconds; a bare number is refused (which unit would it be?)."""
        value = self._scalar(what)
        if self.tag in (_INT, _FLOAT):
            raise NodeError(self.pos, f"{what} {value} has no unit", DURATION_HINT)
        if self.tag != _STR:
            raise NodeError(self.pos, f"{what} must be a duration, found {self.describe()}",
                            DURATION_HINT)
        try:
            us = parse_duration(value)
        except ValueError:
            raise NodeError(self.pos, f"{what} {value!r} is not a duration",
                            DURATION_HINT) from None
        if us == 0 and not allow_zero:
            raise NodeError(self.pos, f"{what} must be longer than zero", DURATION_HINT)
        return us


def _pos(mark: yaml.Mark | None, file: str) -> SourcePos:
    if mark is None:
        return SourcePos(file)
    return SourcePos(file, mark.line + 1, mark.column + 1)


def _convert(node: yaml.Node, file: str) -> YNode:
    pos = _pos(node.start_mark, file)
    if isinstance(node, yaml.MappingNode):
        value: dict[str, YNode] = {}
        key_pos: dict[str, SourcePos] = {}
        for key_node, value_node in node.value:
            kpos = _pos(key_node.start_mark, file)
            if not isinstance(key_node, yaml.ScalarNode):
                raise NodeError(kpos, "a key must be a plain name", "a name such as fsc")
            key = key_node.value
            if key_node.tag not in (_STR, _INT):
                raise NodeError(kpos, f"the key {key!r} is read by YAML as "
                                f"{_describe_tag(key_node.tag)}",
                                "a name; quote it, e.g. \"on\"")
            if key in value:
                raise NodeError(kpos, f"duplicate key {key!r} (first defined at line "
                                f"{key_pos[key].line})", "each key once per mapping")
            key_pos[key] = kpos
            value[key] = _convert(value_node, file)
        return YNode("map", value, pos, node.tag, key_pos)
    if isinstance(node, yaml.SequenceNode):
        return YNode("seq", [_convert(n, file) for n in node.value], pos, node.tag)
    assert isinstance(node, yaml.ScalarNode)
    if node.tag not in (_STR, _INT, _FLOAT, _BOOL, _NULL):
        raise NodeError(pos, f"unsupported YAML tag {node.tag!r}", "plain YAML values")
    constructor = yaml.SafeLoader(b"")
    try:
        value = constructor.construct_object(node, deep=True)
    finally:
        constructor.dispose()
    result = YNode("scalar", value, pos, node.tag)
    result._raw = node.value
    result.style = node.style
    return result


def _describe_tag(tag: str) -> str:
    return {_BOOL: "a Boolean (yes/no/on/off/true/false)", _INT: "an integer",
            _FLOAT: "a number", _NULL: "null"}.get(tag, tag)


def load_yaml(path: Path, display: str) -> YNode:
    """Compose a YAML file into positioned nodes; any problem is a ProjectError."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ProjectError.single(SourcePos(display), "file not found") from None
    except UnicodeDecodeError as exc:
        raise ProjectError.single(SourcePos(display), f"not UTF-8 text ({exc.reason})",
                                  "a UTF-8 YAML file") from None
    except OSError as exc:
        raise ProjectError.single(SourcePos(display), f"cannot read: {exc.strerror}") from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or "invalid YAML"
        raise ProjectError.single(_pos(mark, display), f"YAML syntax error: {problem}",
                                  "valid YAML") from None
    except yaml.YAMLError as exc:
        raise ProjectError.single(SourcePos(display), f"YAML error: {exc}") from None
    if node is None:
        raise ProjectError.single(SourcePos(display, 1, 1), "the file is empty",
                                  "a mapping of project sections")
    try:
        return _convert(node, display)
    except NodeError as exc:
        raise ProjectError([exc.diagnostic]) from None
