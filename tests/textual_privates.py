"""Where code touches a private member of Textual (an underscore name it does not document):

- an import of an underscore name, or from an underscore module, of textual;
- an attribute ``x._name`` that Textual's source defines and plchmi's does not (its own
  ``self._name`` are its own), a name-mangled ``x._Class__name``, or a string naming one
  (``getattr(node, "__watchers")``);
- a method or class attribute of plchmi's (a Textual subclass, or a mixin of one) that has
  the name of one of Textual's private ones in that class's bases: an override.

    python tests/textual_privates.py [PATH ...]     (default: hmi) prints each, with where

tests/test_textual_adapter.py uses it to check that only hmi/ui/textual_adapter.py does.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import re
import sys
import textwrap
from functools import cache
from pathlib import Path

import textual

TEXTUAL = Path(textual.__file__).resolve().parent
MANGLED = re.compile(r"^_[A-Z][A-Za-z0-9]*__[A-Za-z0-9_]+$")
MODULES_NOT_TEXTUAL = {"os", "sys", "asyncio"}  # os._exit is not Textual's _exit


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


@cache
def textual_names() -> frozenset[str]:
    """Every private name Textual's source defines, assigns or spells as a string."""
    names: set[str] = set()
    for path in TEXTUAL.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and node.value.isidentifier():
                names.add(node.value)
    return frozenset(n for n in names if _private(n))


def own_names(trees: list[ast.AST]) -> set[str]:
    """The names the code defines itself: on self or cls, in a class body, a function, a
    module (a store on another object is not one: that is patching someone else's)."""
    names: set[str] = set()
    for tree in trees:
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) \
                    and isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                names.add(node.attr)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
    return names


@cache
def class_names(cls: type) -> frozenset[str]:
    """The private names a class of Textual defines: in its body, or on self in a method."""
    names = {name for name in vars(cls) if _private(name)}
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))  # a nested class too
    except (OSError, TypeError, SyntaxError):
        return frozenset(names)
    names |= {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)
              and isinstance(node.ctx, ast.Store) and isinstance(node.value, ast.Name)
              and node.value.id == "self" and _private(node.attr)}
    return frozenset(names)


def self_names(cls: type) -> set[str]:
    """The private names a class of ours reads or writes on self."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError, SyntaxError):
        return set()
    return {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name) and node.value.id == "self"
            and _private(node.attr) and not MANGLED.match(node.attr)}


def module_name(path: Path, root: Path) -> str | None:
    try:
        parts = list(path.resolve().relative_to(root.resolve()).with_suffix("").parts)
    except ValueError:
        return None
    if parts[-1] == "__init__":
        parts = parts[:-1]
    if not parts or parts[0] != "hmi" or parts[-1] == "__main__":
        return None
    return ".".join(parts)


def private_uses(files: list[Path], root: Path) -> dict[str, list[str]]:
    """{member: [file:line, ...]} for every touch of a private member of Textual in
    `files` (modules of hmi/ under `root` are imported to find overrides)."""
    theirs = textual_names()
    trees = [ast.parse(f.read_text(encoding="utf-8")) for f in files]
    ours = own_names(trees)
    found: dict[str, list[str]] = {}

    def add(member: str, where: str) -> None:
        found.setdefault(member, []).append(where)

    for path, tree in zip(files, trees, strict=True):
        for node in ast.walk(tree):
            where = f"{path}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] \
                    == "textual":
                if any(_private(part) for part in (node.module or "").split(".")):
                    add(node.module or "", where)
                for alias in node.names:
                    if _private(alias.name):
                        add(alias.name, where)
            elif isinstance(node, ast.Attribute) and _private(node.attr):
                if isinstance(node.value, ast.Name) and node.value.id in MODULES_NOT_TEXTUAL:
                    continue
                if MANGLED.match(node.attr) or (node.attr in theirs and node.attr not in ours):
                    add(node.attr, where)
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and node.value.isidentifier() and node.value.startswith("_") and (
                        MANGLED.match(node.value)
                        or (node.value in theirs and node.value not in ours)):
                add(node.value, where)
        name = module_name(path, root)
        if name is None:
            continue
        module = importlib.import_module(name)
        for cls in vars(module).values():
            if not inspect.isclass(cls) or cls.__module__ != module.__name__:
                continue
            textual_bases = [b for b in cls.__mro__ if b.__module__.split(".")[0] == "textual"]
            if not textual_bases:
                continue
            inherited = set().union(*(class_names(base) for base in textual_bases))
            for own in (k for k in cls.__mro__ if k.__module__.split(".")[0] == "hmi"):
                for attr in vars(own):
                    if _private(attr) and attr in ours and any(
                            attr in vars(base) for base in textual_bases):
                        member = f"{own.__name__}.{attr} (overrides Textual's)"
                        if member not in found:
                            add(member, str(inspect.getsourcefile(own)))
                for attr in self_names(own) & inherited:  # self._x of a Textual base
                    member = f"{own.__name__}: self.{attr} (Textual's)"
                    if member not in found:
                        add(member, str(inspect.getsourcefile(own)))
    return found


def main(argv: list[str]) -> int:
    root = Path(__file__).resolve().parent.parent
    paths = [Path(a) for a in argv] or [root / "hmi"]
    files = [f for p in paths for f in (sorted(p.rglob("*.py")) if p.is_dir() else [p])]
    found = private_uses(files, root)
    for member in sorted(found):
        sites = found[member]
        print(f"{member:55} {len(sites):3}  {' '.join(sites[:3])}")
    print(f"{len(found)} private members of Textual, {sum(map(len, found.values()))} uses")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
