"""The HMI's start path (docs/performance.md): what it imports, the dataclass code cache, the
garbage collector's pause, and an equivalent faster regular expression. How fast it starts
is measured by `plchmi bench startup`, never here."""

from __future__ import annotations

import collections
import dataclasses
import json
import subprocess
import sys
import textwrap
import types
import typing
from pathlib import Path

import pytest

from hmi import codecache
from hmi.codecache import CodeCache, dataclass_code

ROOT = Path(__file__).resolve().parent.parent

# A module with dataclasses of every kind the code base uses: plain, frozen, ordered, with
# defaults, factories, ClassVar, InitVar, __post_init__, a field left out of compare/repr.
CLASSES = textwrap.dedent('''
    from __future__ import annotations
    import dataclasses
    from dataclasses import InitVar, dataclass, field
    from typing import ClassVar

    @dataclass
    class Plain:
        a: int
        b: list[int] = field(default_factory=list)
        c: str = "c"

    @dataclass(frozen=True, order=True)
    class Point:
        """A point."""
        x: int
        y: int = 0
        label: str = field(default="", compare=False, repr=False)
        KIND: ClassVar[str] = "point"

    @dataclass(frozen=True)
    class Derived:
        scale: InitVar[int]
        value: int = 1
        scaled: int = field(init=False, default=0)

        def __post_init__(self, scale: int) -> None:
            object.__setattr__(self, "scaled", self.value * scale)

    # named tuples: __new__ is eval'ed text, a string annotation compiled by typing
    import collections
    from typing import NamedTuple

    class Pair(NamedTuple):
        left: int
        right: list[str] = []

    Legacy = collections.namedtuple("Legacy", "a b", defaults=[2])
''')


def build(cache_path: Path | None, write: bool = True, source: str = CLASSES
          ) -> tuple[dict, CodeCache | None]:
    """The classes of `source`, built with the cache at `cache_path` (None: without), as a
    module of their own (dataclasses reads the module of a string annotation)."""
    module = types.ModuleType("startup_classes")
    sys.modules[module.__name__] = module
    try:
        code = compile(source, "startup_classes.py", "exec")
        if cache_path is None:
            exec(code, module.__dict__)
            return module.__dict__, None
        with dataclass_code(cache_path, write=write) as cache:
            exec(code, module.__dict__)
        return module.__dict__, cache
    finally:
        del sys.modules[module.__name__]


def behaviour(ns: dict) -> list:
    """What the generated methods do, as data: built, compared, hashed, printed, refused."""
    plain, point, derived = ns["Plain"], ns["Point"], ns["Derived"]
    p1, p2 = point(1, 2, "a"), point(1, 2, "b")
    seen = [repr(plain(1)), plain(1) == plain(1), plain(1) == plain(2), repr(p1), p1 == p2,
            hash(p1) == hash(p2), p1 < point(2), sorted([point(3), point(1, 5), point(1)]),
            repr(derived(3, value=2)), derived(3, 2).scaled, point.KIND,
            [f.name for f in dataclasses.fields(point)], ns["Plain"].__doc__, point.__doc__,
            ns["Pair"](1), ns["Pair"](1, ["x"]).right, ns["Pair"].__annotations__,
            ns["Legacy"](1), ns["Legacy"](1, 3)._asdict()]
    with pytest.raises(dataclasses.FrozenInstanceError):
        p1.x = 5
    with pytest.raises(TypeError):
        plain()
    return [str(item) for item in seen]


def test_cached_classes_behave_as_compiled_ones(tmp_path):
    path = tmp_path / "methods.marshal"
    reference = behaviour(build(None)[0])
    first, cache = build(path)
    assert cache is not None and cache.compiled > 0 and cache.hits == 0
    assert path.exists()
    again, cache = build(path)  # a new process would read the same file
    assert cache is not None and cache.compiled == 0 and cache.hits > 0
    assert behaviour(first) == behaviour(again) == reference
    # the very same code: compiled from the same text
    fresh = build(None)[0]
    assert (again["Pair"].__new__.__code__.co_code == fresh["Pair"].__new__.__code__.co_code)
    assert (again["Pair"].__annotations__["right"].__forward_code__.co_code
            == fresh["Pair"].__annotations__["right"].__forward_code__.co_code)
    for name in ("__init__", "__repr__", "__eq__", "__lt__", "__setattr__", "__hash__"):
        assert (getattr(again["Point"], name).__code__.co_code
                == getattr(fresh["Point"], name).__code__.co_code), name


def test_a_changed_class_is_compiled_again_not_taken_from_the_cache(tmp_path):
    path = tmp_path / "methods.marshal"
    build(path)
    source = CLASSES.replace('    c: str = "c"\n', '    c: str = "c"\n    d: int = 4\n')
    assert source != CLASSES
    changed, cache = build(path, source=source)
    assert cache is not None and cache.compiled >= 2  # Plain's __init__, __repr__, __eq__
    assert repr(changed["Plain"](1)) == "Plain(a=1, b=[], c='c', d=4)"


@pytest.mark.parametrize("content", [b"", b"garbage", b"\x00" * 40, None])
def test_an_unreadable_cache_is_ignored_and_rewritten(tmp_path, content):
    path = tmp_path / "methods.marshal"
    if content is None:  # written by another interpreter version
        build(path)
        path.write_bytes(b"\xff\xff\r\n" + path.read_bytes()[4:])
    else:
        path.write_bytes(content)
    ns, cache = build(path)
    assert cache is not None and cache.hits == 0 and cache.compiled > 0
    assert behaviour(ns) == behaviour(build(None)[0])
    assert build(path)[1].hits > 0  # rewritten, readable again


def test_nothing_is_written_when_bytecode_writing_is_off(tmp_path, monkeypatch):
    path = tmp_path / "methods.marshal"
    build(path, write=False)
    assert not path.exists()
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    with dataclass_code(path) as cache:
        @dataclasses.dataclass
        class Built:
            a: int
    assert cache is not None and cache.compiled > 0 and Built(1).a == 1
    assert not path.exists()


def test_the_cache_is_removed_after_use_and_never_nested(tmp_path):
    with dataclass_code(tmp_path / "a") as outer:
        assert dataclasses.exec == outer.run
        with dataclass_code(tmp_path / "b") as inner:
            assert inner is None  # the outer one stays in place
        assert dataclasses.exec == outer.run
    assert "exec" not in vars(dataclasses)  # the builtin again
    assert "eval" not in vars(collections) and "compile" not in vars(typing)
    with pytest.raises(KeyError), dataclass_code(tmp_path / "c"):
        {}["missing"]
    assert "exec" not in vars(dataclasses)
    assert "eval" not in vars(collections) and "compile" not in vars(typing)


def test_the_default_cache_sits_with_hmis_bytecode():
    assert codecache.DEFAULT_PATH.parent == ROOT / "hmi" / "__pycache__"
    assert sys.implementation.cache_tag in codecache.DEFAULT_PATH.name


def run_python(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, cwd=ROOT).stdout


def test_the_command_line_parser_imports_neither_the_hmi_nor_the_soak():
    """Every command builds the whole parser: the soak's options once imported the soak,
    and with it Textual and the whole HMI, before any command ran."""
    out = run_python("import json, sys\nfrom hmi.cli.entry import build_parser\n"
                     "build_parser()\nprint(json.dumps(sorted(m for m in sys.modules if "
                     "m.split('.')[0] in ('textual', 'hmi'))))")
    loaded = json.loads(out)
    assert not [m for m in loaded if m.startswith(("textual", "hmi.soak.", "hmi.ui",
                                                   "hmi.engine", "hmi.project"))]
    assert "hmi.cli.soak" in loaded


def test_the_scans_start_with_the_garbage_collector_on():
    """The HMI's start runs without automatic collection (hmi.cli.ui); the live driver turns
    it back on when the scans start."""
    out = run_python(textwrap.dedent("""
        import gc
        from hmi.paths import PROJECTS
        from hmi.engine.scan import Engine
        from hmi.plant.sim.plant import SimPlant
        from hmi.project.loader import load_project
        from hmi.session.session import Session
        from hmi.link.local import SessionLink
        from hmi.ui.driver import LiveDriver
        project = load_project(PROJECTS / "cispi_valve")
        driver = LiveDriver(SessionLink(Session(Engine(project, SimPlant(project))), live=True))
        gc.disable()
        driver.start()
        print(gc.isenabled())
        driver.stop()
    """))
    assert out.strip() == "True"


def test_the_faster_not_text_pattern_is_the_same_set():
    """textfile's refused characters: YAML 1.1's non-printable set, as written before."""
    from hmi.textfile import _NOT_TEXT

    def printable(c: int) -> bool:
        return (c in (0x09, 0x0A, 0x0D, 0x85) or 0x20 <= c <= 0x7E or 0xA0 <= c <= 0xD7FF
                or 0xE000 <= c <= 0xFFFD or 0x10000 <= c <= 0x10FFFF)

    everything = "".join(map(chr, range(sys.maxunicode + 1)))
    refused = {ord(c) for c in _NOT_TEXT.findall(everything)}
    assert refused == {c for c in range(sys.maxunicode + 1) if not printable(c)}


FINGERPRINT = textwrap.dedent("""
    import dataclasses, json, re, sys
    from pathlib import Path
    from hmi.codecache import dataclass_code

    def start():
        import hmi.cli, hmi.ui.app, hmi.project.loader, hmi.plant.select  # noqa: F401

    if sys.argv[1] == "-":
        start()
    else:
        with dataclass_code(Path(sys.argv[1]), write=True) as cache:
            start()
    seen = {}
    for name, module in list(sys.modules.items()):
        for cls in list(vars(module).values()):
            if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)
                    and cls.__module__ == name):
                continue
            for attr, fn in sorted(vars(cls).items()):
                code = getattr(fn, "__code__", None)
                if code is not None and code.co_filename == "<string>":
                    seen[f"{name}.{cls.__qualname__}.{attr}"] = [
                        code.co_code.hex(), repr(code.co_consts), code.co_names,
                        code.co_varnames, repr(fn.__annotations__), repr(fn.__defaults__),
                        repr(fn.__kwdefaults__), fn.__qualname__]
            seen[f"{name}.{cls.__qualname__}.__doc__"] = cls.__doc__
        for cls in list(vars(module).values()):  # named tuples: __new__, string annotations
            if not (isinstance(cls, type) and issubclass(cls, tuple) and hasattr(cls, "_fields")
                    and cls.__module__ == name):
                continue
            new = cls.__new__
            seen[f"{name}.{cls.__qualname__}.__new__"] = [
                new.__code__.co_code.hex(), repr(new.__code__.co_consts),
                new.__code__.co_varnames, repr(new.__defaults__)]
            for field, annotation in getattr(cls, "__annotations__", {}).items():
                code = getattr(annotation, "__forward_code__", None)
                if code is not None:
                    seen[f"{name}.{cls.__qualname__}.{field}:annotation"] = [
                        code.co_code.hex(), repr(code.co_consts), code.co_names]
    # addresses differ from one process to the next (a default's repr)
    print(re.sub(r" at 0x[0-9a-f]+", " at 0x", json.dumps(seen)))
""")


def test_every_class_on_the_start_path_gets_the_same_methods_from_the_cache(tmp_path):
    """The HMI's own start path, in three processes: without the cache, compiling into it,
    and reading from it. Every generated method of every dataclass (ours, Textual's, the
    standard library's) is the same code with the same annotations and defaults."""
    script = tmp_path / "fingerprint.py"
    script.write_text(FINGERPRINT, encoding="utf-8")
    cache = tmp_path / "methods.marshal"

    def fingerprint(arg: str) -> dict:
        return json.loads(subprocess.run([sys.executable, str(script), arg], cwd=ROOT,
                                         capture_output=True, text=True, check=True).stdout)

    reference = fingerprint("-")
    assert len([k for k in reference if k.endswith(".__init__")]) > 100
    assert len([k for k in reference if k.endswith(".__new__")]) > 30  # named tuples
    assert len([k for k in reference if k.endswith(":annotation")]) > 100
    assert fingerprint(str(cache)) == reference
    assert cache.stat().st_size > 0
    assert fingerprint(str(cache)) == reference


def _subparsers(parser) -> dict:
    return next(a for a in parser._actions if a.dest == "command").choices


def test_a_command_builds_only_its_own_options_the_same_as_the_whole_parser():
    """`plchmi COMMAND ...` builds COMMAND's options alone (hmi/cli/entry.py): its help,
    usage and defaults are those of the whole parser's."""
    from hmi.cli import entry

    whole = _subparsers(entry.build_parser())
    assert set(whole) == set(entry.SUBCOMMANDS) == set(entry.COMMANDS)
    assert {n for names, _, _ in entry.PARTS for n in names} == set(entry.SUBCOMMANDS)
    for command in entry.SUBCOMMANDS:
        alone = _subparsers(entry.build_parser(command))
        assert command in alone and set(alone) <= set(whole)
        assert alone[command].format_help() == whole[command].format_help(), command
        assert _options(alone[command]) == _options(whole[command]), command


def _options(parser) -> list[str]:
    return [repr((a.dest, a.default, a.option_strings, a.nargs, a.choices, a.type,
                  a.required)) for a in parser._actions]


def test_the_hmis_start_imports_no_other_commands_module():
    """(hmi.cli.screens is the HMI's own: it starts the cell's runtime and attaches to it.)"""
    out = run_python("import json, sys\nfrom hmi.cli.entry import build_parser\n"
                     "build_parser('ui').parse_args(['ui', 'projects/cispi_valve'])\n"
                     "print(json.dumps(sorted(m for m in sys.modules if "
                     "m.startswith('hmi.cli.'))))")
    assert set(json.loads(out)) == {"hmi.cli.entry", "hmi.cli.common", "hmi.cli.ui",
                                    "hmi.cli.options", "hmi.cli.screens"}
