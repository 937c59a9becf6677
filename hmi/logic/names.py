"""The one rule for names in project files: ASCII letters, digits and `_`.

Python reads identifiers after NFKC normalisation, so in an expression `Ｙ` (fullwidth),
`𝐘` (mathematical bold) and `Y` are one name to `ast`: a constraint written with a look-alike
would silently read another variable. plchmi therefore accepts only ASCII in names and in
expressions, and says which character it refused and what Python would have made of it. Step
numbers and addresses are ASCII digits for the same reason (`"²".isdigit()` is true).
"""

from __future__ import annotations

import keyword
import re
import unicodedata

from hmi.limits import MAX_NAME_CHARS
from hmi.textfile import char_name

# `match` with `\Z` is a full match: `$` would also accept a name followed by a newline.
NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
STEP_RE = re.compile(r"X[0-9]+\Z")
STEP_NUMBER_RE = re.compile(r"[0-9]+\Z")
RESERVED = {"and", "or", "not", "True", "False", "prev", "rise", "fall", "None"} | set(
    keyword.kwlist)
NAME_HINT = "ASCII letters, digits and _, not starting with a digit"


def is_name(name: str) -> bool:
    return NAME_RE.match(name) is not None and len(name) <= MAX_NAME_CHARS


def name_problem(name: str) -> str | None:
    """Why `name` is not a valid name (None if it is), for the message after the name."""
    if len(name) > MAX_NAME_CHARS:
        return f"is {len(name)} characters long, more than {MAX_NAME_CHARS}"
    if NAME_RE.match(name):
        return None
    odd = first_non_ascii(name)
    if odd is not None:
        return f"holds {describe_non_ascii(name[odd])}"
    return "is not a valid name"


def first_non_ascii(text: str) -> int | None:
    """Index of the first character of `text` that is not ASCII, or None."""
    if text.isascii():
        return None
    return next(i for i, c in enumerate(text) if not c.isascii())


def describe_non_ascii(char: str) -> str:
    """U+FF39 (FULLWIDTH LATIN CAPITAL LETTER Y), which Python would read as 'Y'."""
    text = char_name(char)
    folded = unicodedata.normalize("NFKC", char)
    if folded != char and folded.isascii() and folded.isprintable():
        text += f", which Python would read as {folded!r}"
    return text


def is_step_number(key: object) -> bool:
    """A GRAFCET step number as YAML gives it: an int >= 0, or a text of ASCII digits."""
    if isinstance(key, bool):
        return False
    if isinstance(key, int):
        return key >= 0
    return isinstance(key, str) and STEP_NUMBER_RE.match(key) is not None
