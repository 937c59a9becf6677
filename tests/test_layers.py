"""The import graph keeps the layering of docs/architecture.md, and has no import cycle.

    base (errors, timefmt, paths, limits, textfile, codecache, crash) <- logic <- project
        <- plant, engine, farm <- studies, export <- explain <- session, history <- wire
        <- runtime <- link
        <- apps (ui, cli, bench, opcua, soak, web)

A module imports from its own layer or from a lower one, never from a higher one; within
its layer, plant/ does not import engine/ (the engine drives a plant through the contract of
plant/base.py), and explain/ reads what a scan left behind (the snapshot and the data types
in it), never the engine that runs the scan. engine/ holds what runs a scan: the offline
studies that run it (explorations, campaigns, sweeps) and their reports are in studies/, a
floor above it. Read from the source with `ast` (the standard library only); every import
counts, also those inside functions and under TYPE_CHECKING, for the layers and for cycles
alike.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "hmi"

LAYERS: tuple[tuple[str, ...], ...] = (
    ("hmi", "hmi.errors", "hmi.timefmt", "hmi.paths", "hmi.limits", "hmi.codecache",
     "hmi.textfile", "hmi.crash", "hmi.outpaths"),
    ("hmi.logic",),
    ("hmi.project",),
    ("hmi.program",),
    ("hmi.plant", "hmi.engine", "hmi.farm"),
    ("hmi.studies", "hmi.export"),
    ("hmi.explain",),
    ("hmi.session", "hmi.history", "hmi.access"),
    ("hmi.wire",),
    ("hmi.runtime",),
    ("hmi.link",),
    ("hmi.ui", "hmi.cli", "hmi.bench", "hmi.opcua", "hmi.soak", "hmi.web"),
)
# What explain/ may read of engine/: the snapshot and the types it carries.
SNAPSHOT_TYPES = {"hmi.engine.snapshot", "hmi.engine.commands", "hmi.engine.stopwatch",
                  "hmi.engine.monitors", "hmi.engine.diagnoser", "hmi.engine.filter",
                  "hmi.engine.layout", "hmi.engine.criteria"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in PACKAGE.rglob("*.py")}


def _resolve(name: str) -> str | None:
    """The hmi module an imported name lives in (`hmi.plant.base.Plant` -> hmi.plant.base)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _import_statements(body: list[ast.stmt], typing: bool, text: str
                       ) -> Iterator[tuple[ast.Import | ast.ImportFrom, bool]]:
    """Every import statement in `body` and the statements nested in it (a function's lazy
    imports too), with whether it sits under ``if TYPE_CHECKING``. Only statements are
    walked: an import is never inside an expression (ast.walk over every expression node
    made the graph cost 1 CPU s)."""
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, typing
            continue
        inner = typing or (isinstance(node, ast.If) and "TYPE_CHECKING" in text
                           and "TYPE_CHECKING" in ast.unparse(node.test))
        for field in ("body", "orelse", "finalbody"):
            yield from _import_statements(getattr(node, field, []), inner, text)
        for part in (*getattr(node, "handlers", ()), *getattr(node, "cases", ())):
            yield from _import_statements(part.body, inner, text)


def imports(name: str) -> list[tuple[str, bool]]:
    """(imported hmi module, whether it runs: not under TYPE_CHECKING) for one module."""
    path = MODULES[name]
    text = path.read_text(encoding="utf-8")
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node, typing in _import_statements(ast.parse(text).body, False, text):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[:len(parts) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            # `from hmi.engine import commands` imports hmi.engine.commands; `from
            # hmi.engine.scan import Engine` imports hmi.engine.scan.
            names = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base
                     for alias in node.names]
        for imported in names:
            target = _resolve(imported) if imported.startswith("hmi") else None
            if target and target != name:
                found.append((target, not typing))
    return found


@cache
def graph() -> dict[str, list[tuple[str, bool]]]:
    """Every module's imports, read once, when a test first asks: not at collection, which
    each pytest-xdist worker does for the whole suite (it cost each worker ~1 CPU s)."""
    return {name: imports(name) for name in MODULES}


def layer(name: str) -> int:
    for k, prefixes in enumerate(LAYERS):
        if any(name == p or name.startswith(p + ".") for p in prefixes if p != "hmi"):
            return k
    assert name == "hmi", f"{name} belongs to no layer: add it to LAYERS"
    return 0


def test_every_module_has_a_layer():
    for name in MODULES:
        layer(name)


def against_layers(name: str, target: str) -> bool:
    if layer(target) > layer(name):
        return True
    if name.startswith("hmi.plant"):
        return target.startswith("hmi.engine")
    if name.startswith("hmi.explain"):
        return target.startswith("hmi.engine") and target not in SNAPSHOT_TYPES
    return False


def test_no_import_runs_up_the_layers():
    upward = {(name, target) for name, targets in graph().items() for target, _ in targets
              if against_layers(name, target)}
    assert upward == set(), "imports against the layering"


# The command line (hmi/cli/): one module per command, assembled by entry.py; what several
# commands share lives in these modules, never in another command's.
CLI_SHARED = {"hmi.cli.common", "hmi.cli.options", "hmi.cli.session", "hmi.cli.summary",
              "hmi.cli.farm", "hmi.cli.screens"}
CLI_ASSEMBLY = {"hmi.cli", "hmi.cli.__main__", "hmi.cli.entry"}


def against_cli_layout(name: str, target: str) -> bool:
    """An import the command line's layout forbids: hmi/cli/ from outside it (the command
    line is the top: nothing is built on it), or one command's module from another's."""
    if not target.startswith("hmi.cli"):
        return False
    if not name.startswith("hmi.cli"):
        return True
    if name in CLI_ASSEMBLY:
        return False
    return target not in CLI_SHARED


def test_the_command_line_is_one_module_per_command():
    wrong = {(name, target) for name, targets in graph().items() for target, _ in targets
             if against_cli_layout(name, target)}
    assert wrong == set(), "imports against hmi/cli/'s layout"
    assert {"hmi.cli.run", "hmi.cli.ui", "hmi.cli.journal"} <= set(MODULES)
    assert against_cli_layout("hmi.bench.engine", "hmi.cli.summary")
    assert against_cli_layout("hmi.cli.run", "hmi.cli.ui")
    assert not against_cli_layout("hmi.cli.run", "hmi.cli.options")
    assert not against_cli_layout("hmi.cli.entry", "hmi.cli.run")


def _cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(component)
    return found


def test_no_import_cycle():
    """No cycle, counting the imports under TYPE_CHECKING too: a module that only names
    another's types still depends on it (mypy reads them together, and a reader must know
    both to know either)."""
    every = {name: {t for t, _ in targets} for name, targets in graph().items()}
    assert _cycles(every) == []


def test_the_checker_sees_a_cycle_and_an_upward_import():
    """The checks themselves can fail: a made-up graph with a loop, and the real layers."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
    assert layer("hmi.engine.scan") > layer("hmi.project.model")
    assert layer("hmi.studies.campaign") > layer("hmi.engine.scan")
    assert against_layers("hmi.engine.scan", "hmi.studies.explore")
    assert layer("hmi.session.session") > layer("hmi.explain.builder") > layer("hmi.engine.scan")
    assert against_layers("hmi.explain.builder", "hmi.engine.scan")
    assert against_layers("hmi.plant.sim.plant", "hmi.engine.scan")
    assert against_layers("hmi.engine.scan", "hmi.session.session")
    assert not against_layers("hmi.explain.builder", "hmi.engine.snapshot")
    assert ("hmi.engine.scan", True) in graph()["hmi.session.session"]
    # An import under TYPE_CHECKING is in the graph, marked as not run.
    assert ("hmi.engine.snapshot", False) in graph()["hmi.explain.diagnoses"]


TEST_ONLY = {"pytest", "hypothesis", "syrupy", "pytest_textual_snapshot", "tests",
             "ui_harness", "ui_scenarios", "ui_faults", "screenshots", "conftest"}


def test_the_package_ships_no_test_harness():
    """What only the tests use lives in tests/ (the wheel installs hmi/ alone): no module of
    hmi/ imports a test tool or a module of tests/, and none reads a PLCHMI_TEST_ variable
    (a fault injector the production app would arm)."""
    wrong = []
    for name, path in MODULES.items():
        text = path.read_text(encoding="utf-8")
        if "PLCHMI_TEST_" in text:
            wrong.append((name, "PLCHMI_TEST_"))
        for node, _ in _import_statements(ast.parse(text).body, False, text):
            modules = ([a.name for a in node.names] if isinstance(node, ast.Import)
                       else [node.module or ""] if not node.level else [])
            wrong += [(name, m) for m in modules if m.split(".")[0] in TEST_ONLY]
    assert wrong == []
