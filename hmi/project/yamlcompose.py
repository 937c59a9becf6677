"""YAML text composed into positioned nodes (:class:`~hmi.project.yamlnodes.YNode`), within
the limits of hmi.limits.

The one module of the project layer that imports PyYAML: the loader and the component
files call it when they read a file; nothing on the HMI's start path imports it when the
project is read back as an earlier start loaded it (hmi/project/kept.py).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from hmi.errors import ProjectError, SourcePos
from hmi.limits import MAX_FILE_BYTES, MAX_NUMBER_DIGITS, MAX_YAML_DEPTH, MAX_YAML_NODES
from hmi.project.yamlnodes import _BOOL, _FLOAT, _INT, _NULL, _STR, NodeError, YNode
from hmi.textfile import FileProblem, char_name, line_col, read_text


def _pos(mark: yaml.Mark | None, file: str) -> SourcePos:
    if mark is None:
        return SourcePos(file)
    return SourcePos(file, mark.line + 1, mark.column + 1)


def _describe_tag(tag: str) -> str:
    return {_BOOL: "a Boolean (yes/no/on/off/true/false)", _INT: "an integer",
            _FLOAT: "a number", _NULL: "null"}.get(tag, tag)


_MAP = "tag:yaml.org,2002:map"
_SEQ = "tag:yaml.org,2002:seq"
_SCALAR_TAGS = (_STR, _INT, _FLOAT, _BOOL, _NULL)
# In a value: control characters but tab and newline, lone surrogates ("\ud800" is a valid
# YAML escape, and no file, terminal or journal can hold it), and the bidirectional overrides
# and isolates that make a text shown to the operator read otherwise than it is stored.
_NOT_IN_VALUE = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x84\x86-\x9f\ud800-\udfff"
                           "\u202a-\u202e\u2066-\u2069]")
_RESOLVER = yaml.resolver.Resolver()
_CONSTRUCTOR = yaml.constructor.SafeConstructor()


@dataclass
class _Open:
    """A mapping or list being composed."""

    node: YNode
    anchor: str | None
    first: int  # the composer's node count once this node was counted
    key: str | None = None  # a mapping's key waiting for its value
    depth: int = 0  # levels of nesting below it so far


class _Composer:
    """YAML events to YNodes, without recursion and within the limits of hmi.limits.

    PyYAML's own composer recurses once per nesting level (a thousand `[` exhaust Python's
    stack) and shares the node of an anchor between its aliases, so that converting the
    tree copies it once per path: nine aliases of nine aliases, eight levels deep, are 43
    million nodes from 452 bytes. Here each alias is counted as the copy it stands for
    *before* it is copied, so an alias bomb is refused at the first alias past the limit
    (about 0.15 s and 30 MB, whatever its depth), and an alias to an enclosing node (a loop)
    is refused as such.
    """

    def __init__(self, file: str, text: str = ""):
        self.file = file
        self.text_lines = text.split("\n")  # (a scalar over several lines: _written)
        self.nodes = 0
        # anchor -> (node, nodes in it, its depth); complete nodes only
        self.anchors: dict[str, tuple[YNode, int, int]] = {}
        self.open_anchors: set[str] = set()

    def pos(self, mark: yaml.Mark | None) -> SourcePos:
        return _pos(mark, self.file)

    def count(self, mark: yaml.Mark | None, added: int) -> None:
        self.nodes += added
        if self.nodes > MAX_YAML_NODES:
            raise NodeError(self.pos(mark), f"the file holds more than {MAX_YAML_NODES:,} YAML "
                            "values (aliases count as copies of what they name)",
                            f"at most {MAX_YAML_NODES:,} values in one file (a limit of "
                            "plchmi, see docs/project-format.md)")

    def compose(self, events: Iterable[Any]) -> YNode | None:
        stack: list[_Open] = []  # the mappings and lists not closed yet, outermost first
        root: YNode | None = None
        documents = 0
        for event in events:
            if isinstance(event, yaml.DocumentStartEvent):
                documents += 1
                if documents > 1:
                    raise NodeError(self.pos(event.start_mark), "the file holds more than one "
                                    "YAML document ('---' starts a second one)",
                                    "one document per file")
                continue
            if isinstance(event, (yaml.StreamStartEvent, yaml.StreamEndEvent,
                                  yaml.DocumentEndEvent)):
                continue
            if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                stack.append(self._open(event, len(stack)))
                continue
            # A node is complete: a closed collection, an alias or a scalar.
            if isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                done = stack.pop()
                node, depth = done.node, done.depth
                if done.anchor is not None:
                    self.anchors[done.anchor] = (node, self.nodes - done.first + 1, depth)
                    self.open_anchors.discard(done.anchor)
            elif isinstance(event, yaml.AliasEvent):
                node, depth = self._alias(event, len(stack))
            else:
                node, depth = self._scalar(event), 0
                if event.anchor is not None:
                    self.anchors[event.anchor] = (node, 1, 0)
            if not stack:
                root = node
                continue
            parent = stack[-1]
            parent.depth = max(parent.depth, depth + 1)
            self._add(parent, node, event)
        return root

    def _open(self, event: yaml.CollectionStartEvent, depth: int) -> _Open:
        if depth >= MAX_YAML_DEPTH:
            raise NodeError(self.pos(event.start_mark), f"lists and mappings nested more "
                            f"than {MAX_YAML_DEPTH} deep",
                            f"at most {MAX_YAML_DEPTH} levels (a limit of plchmi)")
        is_map = isinstance(event, yaml.MappingStartEvent)
        tag = event.tag
        if tag in (None, "!"):
            tag = _MAP if is_map else _SEQ
        if tag != (_MAP if is_map else _SEQ):
            raise NodeError(self.pos(event.start_mark), f"unsupported YAML tag {tag!r}",
                            "plain YAML values")
        self.count(event.start_mark, 1)
        node = YNode("map" if is_map else "seq", {} if is_map else [],
                     self.pos(event.start_mark), tag, {} if is_map else None)
        if event.anchor is not None:
            self.open_anchors.add(event.anchor)
            self.anchors.pop(event.anchor, None)  # a redefined anchor names the new node
        return _Open(node, event.anchor, self.nodes)

    def _alias(self, event: yaml.AliasEvent, depth: int) -> tuple[YNode, int]:
        pos = self.pos(event.start_mark)
        if event.anchor in self.open_anchors:
            raise NodeError(pos, f"the alias *{event.anchor} names a list or mapping that "
                            "contains it (a loop)", "an alias to a value defined before it")
        if event.anchor not in self.anchors:
            raise NodeError(pos, f"the alias *{event.anchor} names no anchor defined before it",
                            f"&{event.anchor} on a value above")
        node, size, node_depth = self.anchors[event.anchor]
        if depth + node_depth > MAX_YAML_DEPTH:
            raise NodeError(pos, f"the alias *{event.anchor} nests lists and mappings more than "
                            f"{MAX_YAML_DEPTH} deep", f"at most {MAX_YAML_DEPTH} levels")
        self.count(event.start_mark, size)  # refused here, before any copy is made
        return _copy(node), node_depth

    def _add(self, parent: _Open, node: YNode, event: yaml.Event) -> None:
        """Put `node` in the open collection `parent`: a list item, a key or a value."""
        collection = parent.node
        if collection.kind == "seq":
            collection.value.append(node)
            return
        key = parent.key
        if key is None:  # this node is a key
            if node.kind != "scalar" or isinstance(event, yaml.AliasEvent):
                raise NodeError(node.pos, "a key must be a plain name", "a name such as fsc")
            if node.tag not in (_STR, _INT):
                raise NodeError(node.pos, f"the key {node.raw!r} is read by YAML as "
                                f"{_describe_tag(node.tag)}", "a name; quote it, e.g. \"on\"")
            name = node.raw
            if name in collection.value:
                raise NodeError(node.pos, f"duplicate key {name!r} (first defined at line "
                                f"{collection.key_pos[name].line})", "each key once per mapping")
            collection.key_pos[name] = node.pos
            parent.key = name
            return
        collection.value[key] = node
        parent.key = None

    def _scalar(self, event: yaml.ScalarEvent) -> YNode:
        pos = self.pos(event.start_mark)
        self.count(event.start_mark, 1)
        tag = event.tag
        if tag in (None, "!"):
            tag = _RESOLVER.resolve(yaml.ScalarNode, event.value, event.implicit)
        if tag not in _SCALAR_TAGS:
            raise NodeError(pos, f"unsupported YAML tag {tag!r}", "plain YAML values")
        text = event.value
        bad = _NOT_IN_VALUE.search(text)
        if bad is not None:
            raise NodeError(pos, f"the value holds the character {char_name(bad.group())}",
                            "text without control characters")
        if tag in (_INT, _FLOAT):
            digits = sum(c.isdigit() for c in text)
            if digits > MAX_NUMBER_DIGITS:
                raise NodeError(pos, f"the number has {digits} digits",
                                f"at most {MAX_NUMBER_DIGITS} digits (a limit of plchmi)")
        value = _CONSTRUCTOR.yaml_constructors[tag](_CONSTRUCTOR, yaml.ScalarNode(tag, text))
        node = YNode("scalar", value, pos, tag)
        node._raw = text
        node.style = event.style or None  # libyaml says "" for plain, PyYAML None
        if event.end_mark is not None and event.start_mark.line != event.end_mark.line:
            node.lines = self._written(event.start_mark, event.end_mark, node.style)
        return node

    def _written(self, start: yaml.Mark, end: yaml.Mark, style: str | None
                 ) -> tuple[tuple[str, int, int], ...]:
        """A scalar over several lines: each line's part as written (without the
        indentation, a quote, a block's header line, the blanks at its end), with its line
        and column from 1 (hmi.project.yamlnodes.text_start finds them in the value)."""
        parts = []
        lines = self.text_lines
        for number in range(start.line, min(end.line, len(lines) - 1) + 1):
            raw = lines[number].rstrip("\r")
            first = number == start.line
            if first and style in ("|", ">"):
                continue  # the header: | or > and its indicators
            if number == end.line:
                raw = raw[:end.column]
                if style in ('"', "'") and raw.endswith(style):
                    raw = raw[:-1]
            begin = start.column + (1 if style in ('"', "'") else 0) if first else 0
            written = raw[begin:].rstrip(" \t")
            stripped = written.lstrip(" \t")
            if stripped:
                parts.append((stripped, number + 1, begin + len(written) - len(stripped) + 1))
        return tuple(parts)


def _copy(node: YNode) -> YNode:
    """A fresh copy of a node and everything under it (what an alias stands for)."""
    if node.kind == "scalar":
        copy = YNode("scalar", node.value, node.pos, node.tag)
        copy._raw, copy.style, copy.lines = node._raw, node.style, node.lines
        return copy
    if node.kind == "map":
        return YNode("map", {k: _copy(v) for k, v in node.value.items()}, node.pos, node.tag,
                     dict(node.key_pos))
    return YNode("seq", [_copy(v) for v in node.value], node.pos, node.tag)


def load_yaml(path: Path, display: str) -> YNode:
    """Compose a YAML file into positioned nodes; any problem is a ProjectError.

    The file is read by hmi.textfile (a regular file, at most MAX_FILE_BYTES, UTF-8 without
    control characters) and composed within the limits of hmi.limits."""
    try:
        text = read_text(path, MAX_FILE_BYTES)
    except FileProblem as exc:
        raise ProjectError.single(SourcePos(display, exc.line, exc.col), exc.message,
                                  exc.expected) from None
    return compose_text(text, display)


# libyaml's parser (PyYAML's C extension, in its wheels) gives the same events and marks as
# PyYAML's pure-Python one, twenty times faster (a file of 5,000 constraints: 0.1 s instead of
# 1.7 s). A document it refuses is parsed again by the pure-Python parser, whose messages
# (and acceptance) are the documented ones.
_FAST_LOADER = getattr(yaml, "CSafeLoader", None) if yaml.__with_libyaml__ else None


# Line breaks YAML reads as such but editors and hmi.textfile.line_col do not count (NEL,
# the Unicode line and paragraph separators, a carriage return alone): with them in a file,
# the parser's line numbers and the editor's would differ, and every position told after
# them would be wrong.
_ODD_BREAK = re.compile("\x85|\u2028|\u2029|\r(?!\n)")


def compose_text(text: str, display: str) -> YNode:
    """Positioned nodes of YAML `text` (read from `display`); any problem is a ProjectError."""
    odd = _ODD_BREAK.search(text)
    if odd is not None:
        line, col = line_col(text, odd.start())
        char = odd.group()
        what = ("a carriage return without a line feed (old Mac line ends)" if char == "\r"
                else char_name(char))
        raise ProjectError.single(SourcePos(display, line, col), f"the file holds {what}, a "
                                  "line break for YAML that editors do not all show as one",
                                  "line ends of LF or CR LF only")
    try:
        node = _compose(text, display)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or "invalid YAML"
        raise ProjectError.single(_pos(mark, display), f"YAML syntax error: {problem}",
                                  "valid YAML") from None
    except yaml.YAMLError as exc:
        raise ProjectError.single(SourcePos(display), f"YAML error: {exc}") from None
    except NodeError as exc:
        raise ProjectError([exc.diagnostic]) from None
    if node is None:
        raise ProjectError.single(SourcePos(display, 1, 1), "the file is empty",
                                  "a mapping of project sections")
    return node


def _compose(text: str, display: str) -> YNode | None:
    if _FAST_LOADER is not None:
        try:
            return _Composer(display, text).compose(yaml.parse(text, Loader=_FAST_LOADER))
        except yaml.YAMLError:
            pass  # said by the pure-Python parser below, in its words
    return _Composer(display, text).compose(yaml.parse(text, Loader=yaml.SafeLoader))
