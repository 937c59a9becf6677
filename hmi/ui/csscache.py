"""Textual's parsed stylesheets, kept across starts (docs/performance.md).

At every start Textual parses the HMI's ``.tcss`` files and the default CSS of every widget
class it mounts, with the theme's variables substituted: about 17 ms of the CPU time to the
first frame. The rules a parse gives (``RuleSet`` objects: selectors and declared styles)
are plain data; read back with pickle they cost about 1.5 ms. Inside :func:`kept_css`,
``Stylesheet._parse_rules`` (the one place Textual turns CSS text into rules; it keeps an
in-process cache of its own there) first looks in what earlier starts kept under a digest
of everything the parse reads: the CSS text, where it was read from, its default/scope/
tie-breaker flags and every variable's value. A text that parses with errors is never kept
(Textual reports it as usual).

``_parse_rules`` is Textual's, not a public interface (hmi/ui/textual_adapter.py, which
tests/test_textual_adapter.py checks): the cache works with the Textual versions it was
checked with (CHECKED, pyproject.toml's range; the installed version is read from its
distribution's folder name: ``textual.__version__`` imports importlib.metadata, some 8 ms)
and stays out of the way with any other. The parsed rules are Textual's objects: the file's
header names the version and the size and time of each file of Textual's CSS package, so
rules parsed by other code are never read back. The file sits beside hmi's bytecode,
written under the bytecode's rule (hmi/codecache.py) and trusted as it is.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import textual.css
from textual.css.stylesheet import Stylesheet

from hmi.codecache import blake2b, read_file, write_file, writing
from hmi.ui.textual_adapter import css_variables, parse_cache, parse_rules, set_parse_rules

# The Textual versions (major, minor; both ends included) whose Stylesheet._parse_rules this
# was checked with: pyproject.toml's range.
CHECKED = ((8, 0), (8, 2))
DEFAULT_PATH = (Path(__file__).resolve().parents[1] / "__pycache__"
                / f"textual-css.{sys.implementation.cache_tag}.pickle")
FORMAT = b"plchmi kept css 2"
MAX_ENTRIES = 256  # past this (stylesheets of older versions of the HMI), start afresh


class KeptCss:
    """Parsed rules by the digest of what their parse read, pickled: each stylesheet reads
    them back as new objects, as its own parse would give (Textual keeps parsed rules per
    stylesheet, and builds a new stylesheet to parse again when the variables change)."""

    def __init__(self, path: Path, header: bytes, write: bool | None = None) -> None:
        self.path = path
        self.header = header
        self.write = write  # None: the bytecode's rule
        self.entries: dict[str, bytes] = _read(path, header)
        self.hits = 0
        self.parsed = 0
        self._unsaved = False

    def rules(self, parse: Any, stylesheet: Stylesheet, css: str, read_from: Any,
              is_default_rules: bool, tie_breaker: int, scope: str) -> list[Any]:
        """What ``parse`` (Textual's ``_parse_rules``) would return."""
        in_process = parse_cache(stylesheet)
        cache_key = (css, read_from, is_default_rules, tie_breaker, scope)
        rules: list[Any] | None = in_process.get(cache_key)
        if rules is not None:  # as Textual's own method answers it
            return rules
        key = blake2b(repr((*cache_key, sorted(css_variables(stylesheet).items())))
                              .encode("utf-8", "surrogatepass"), digest_size=20).hexdigest()
        kept = self.entries.get(key)
        if kept is not None:
            with contextlib.suppress(Exception):  # anything unreadable: parsed again
                rules = pickle.loads(kept)
        if isinstance(rules, list):
            self.hits += 1
            in_process[cache_key] = rules
            return rules
        parsed: list[Any] = parse(stylesheet, css, read_from, is_default_rules, tie_breaker,
                                  scope)
        self.parsed += 1
        if not any(rule.errors for rule in parsed):
            # pickled now, before anything else holds (and might change) them
            self.entries[key] = pickle.dumps(parsed, pickle.HIGHEST_PROTOCOL)
            self._unsaved = True
        return parsed

    def save(self) -> None:
        """Write the file if something was parsed since the last save."""
        if not self._unsaved or not writing(self.write):
            return
        self._unsaved = False
        entries = self.entries if len(self.entries) <= MAX_ENTRIES else {}
        write_file(self.path, self.header, pickle.dumps(entries, pickle.HIGHEST_PROTOCOL))


def textual_version() -> str | None:
    """The installed Textual's version, from its distribution's folder beside it (None if
    there is not exactly one)."""
    package = Path(textual.css.__file__).resolve().parents[1]
    try:
        found = [name for name in os.listdir(package.parent)
                 if name.startswith("textual-") and name.endswith(".dist-info")]
    except OSError:
        return None
    return found[0][len("textual-"):-len(".dist-info")] if len(found) == 1 else None


def checked(version: str | None) -> bool:
    """Whether this Textual version is one the cache was checked with (CHECKED)."""
    try:
        major, minor = (int(part) for part in (version or "").split(".")[:2])
    except ValueError:
        return False
    return CHECKED[0] <= (major, minor) <= CHECKED[1]


def header() -> bytes:
    """The file's first line: the format, and each file of Textual's CSS package by name,
    size and modification time (what parsed the rules, and what their classes are)."""
    css = Path(textual.css.__file__).resolve().parent
    digest = blake2b(digest_size=16)
    with os.scandir(css) as listing:
        for entry in sorted(listing, key=lambda e: e.name):
            if entry.name.endswith(".py"):
                stat = entry.stat()
                digest.update(f"{entry.name} {stat.st_size} {stat.st_mtime_ns}\0".encode())
    version = (textual_version() or "?").encode()
    return b"%s textual %s %s\n" % (FORMAT, version, digest.hexdigest().encode())


def _read(path: Path, header: bytes) -> dict[str, bytes]:
    body = read_file(path, header)
    if body is None:
        return {}
    try:
        entries = pickle.loads(body)
    except Exception:  # damaged: rebuilt
        return {}
    if not isinstance(entries, dict):
        return {}
    return {k: v for k, v in entries.items() if isinstance(k, str) and isinstance(v, bytes)}


@contextlib.contextmanager
def kept_css(path: Path = DEFAULT_PATH, write: bool | None = None) -> Iterator[KeptCss | None]:
    """Stylesheets parsed inside read their rules from what earlier starts kept at `path`;
    what was parsed is kept at the end, or before with :meth:`KeptCss.save` (the HMI saves
    once its first frame is shown: an operator's HMI is rarely quit cleanly). `write`:
    default, the bytecode's rule. Yields None and changes nothing with another Textual
    version, or when already inside."""
    original = parse_rules()
    if not checked(textual_version()) or getattr(original, "kept_css", False):
        yield None
        return
    kept = KeptCss(path, header(), write)

    def kept_parse_rules(self: Stylesheet, css: str, read_from: Any,
                         is_default_rules: bool = False, tie_breaker: int = 0,
                         scope: str = "") -> list[Any]:
        return kept.rules(original, self, css, read_from, is_default_rules, tie_breaker,
                          scope)

    kept_parse_rules.kept_css = True  # type: ignore[attr-defined]
    set_parse_rules(kept_parse_rules)
    try:
        yield kept
    finally:
        set_parse_rules(original)
        kept.save()
