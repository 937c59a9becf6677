"""IEC 61131-3 identifiers for the project's names.

Project names are Python-like and case-sensitive; ST identifiers are case-insensitive, may not
hold two underscores in a row or end with one, and must not be a keyword or the name of a
standard type, function or function block. :class:`Scope` hands out identifiers that are
valid and unique within one scope (a POU's variables, or the global names), keeping the
project's name whenever it is already a valid identifier, and records every rename so the
exported file can say which variable is which.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

# Keywords, elementary types and the standard functions / FBs a name could be confused with
# (IEC 61131-3 ed. 2 and 3, plus the words CODESYS and TwinCAT reserve in ST).
RESERVED = frozenset((
    "ABS", "ACOS", "ACTION", "ADD", "AND", "AND_THEN", "ANY", "ANY_BIT", "ANY_DATE",
    "ANY_DERIVED", "ANY_ELEMENTARY", "ANY_INT", "ANY_MAGNITUDE", "ANY_NUM", "ANY_REAL",
    "ANY_STRING", "ARRAY", "ASIN", "AT", "ATAN", "BOOL", "BY", "BYTE", "CASE", "CHAR", "CLASS",
    "CONCAT", "CONFIGURATION", "CONSTANT", "COS", "CTD", "CTU", "CTUD", "DATE",
    "DATE_AND_TIME", "DELETE", "DINT", "DIV", "DO", "DT", "DWORD", "ELSE", "ELSIF",
    "END_ACTION", "END_CASE", "END_CLASS", "END_CONFIGURATION", "END_FOR", "END_FUNCTION",
    "END_FUNCTION_BLOCK", "END_IF", "END_INTERFACE", "END_METHOD", "END_PROGRAM", "END_REPEAT",
    "END_RESOURCE", "END_STEP", "END_STRUCT", "END_TRANSITION", "END_TYPE", "END_VAR",
    "END_WHILE", "EN", "ENO", "EQ", "EXIT", "EXP", "EXPT", "EXTENDS", "F_EDGE", "F_TRIG",
    "FALSE", "FIND", "FINAL", "FOR", "FROM", "FUNCTION", "FUNCTION_BLOCK", "GE", "GT", "IF",
    "IMPLEMENTS", "IN", "INITIAL_STEP", "INSERT", "INT", "INTERFACE", "INTERNAL", "INTERVAL",
    "LDATE", "LDT", "LE", "LEFT", "LEN", "LIMIT", "LINT", "LN", "LOG", "LREAL", "LT", "LTIME",
    "LTOD", "LWORD", "MAX", "METHOD", "MID", "MIN", "MOD", "MOVE", "MUL", "MUX", "NE",
    "NON_RETAIN", "NOT", "NULL", "OF", "ON", "OR", "OR_ELSE", "OVERLAP", "OVERRIDE", "POINTER",
    "PRIORITY", "PRIVATE", "PROGRAM", "PROTECTED", "PT", "PUBLIC", "Q", "R_EDGE", "R_TRIG",
    "READ_ONLY", "READ_WRITE", "REAL", "REF", "REFERENCE", "REF_TO", "REPEAT", "REPLACE",
    "RESOURCE", "RETAIN", "RETURN", "RIGHT", "ROL", "ROR", "RS", "RTC", "SEL", "SEMA", "SHL",
    "SHR", "SIN", "SINGLE", "SINT", "SQRT", "SR", "STEP", "STRING", "STRUCT", "SUB", "SUPER",
    "TAN", "TASK", "THEN", "THIS", "TIME", "TIME_OF_DAY", "TO", "TOD", "TOF", "TON", "TP",
    "TRANSITION", "TRUE", "TRUNC", "TYPE", "UDINT", "UINT", "ULINT", "UNTIL", "USINT", "VAR",
    "VAR_ACCESS", "VAR_CONFIG", "VAR_EXTERNAL", "VAR_GLOBAL", "VAR_IN_OUT", "VAR_INPUT",
    "VAR_INST", "VAR_OUTPUT", "VAR_STAT", "VAR_TEMP", "WCHAR", "WHILE", "WITH", "WORD",
    "WSTRING", "XOR",
))

_VALID = re.compile(r"^[A-Za-z](?:_?[A-Za-z0-9])*$|^_[A-Za-z0-9](?:_?[A-Za-z0-9])*$")


def is_valid(ident: str) -> bool:
    """An IEC identifier: no double or trailing underscore, not reserved."""
    return bool(_VALID.match(ident)) and ident.upper() not in RESERVED


def _sanitise(name: str) -> str:
    text = re.sub(r"[^A-Za-z0-9_]", "_", name)
    text = re.sub(r"_+", "_", text).rstrip("_") or "v"
    if text[0].isdigit():
        text = "v" + text
    if text == "_":
        text = "v"
    return text


@dataclass
class Scope:
    """Identifiers of one scope; `parent` names (globals, POU names) are taken too."""

    parent: Scope | None = None
    taken: dict[str, str] = field(default_factory=dict)  # upper-case key -> identifier
    renamed: dict[str, str] = field(default_factory=dict)  # project name -> identifier

    def _clash(self, ident: str) -> bool:
        key = ident.upper()
        scope: Scope | None = self
        while scope is not None:
            if key in scope.taken:
                return True
            scope = scope.parent
        return key in RESERVED

    def take(self, name: str) -> str:
        """A unique valid identifier for `name` in this scope (the name itself if it can)."""
        base = _sanitise(name)
        ident = base
        k = 2
        while not _VALID.match(ident) or self._clash(ident):
            ident = f"{base}_{k}"
            k += 1
        self.taken[ident.upper()] = ident
        if ident != name:
            self.renamed[name] = ident
        return ident

    def child(self) -> Scope:
        return Scope(parent=self)
