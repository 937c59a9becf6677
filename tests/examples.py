"""Sessions on the example projects, each project loaded once per test process.

Why: tests that drive an example project build a new session per case, and loading
cispi_valve costs ~25 CPU ms: test_filter, test_engine and test_explain loaded it 49 times.
A Project is a frozen dataclass nothing changes after loading (tests/test_compiled_scan.py
and tests/test_fastpath_errors.py share theirs the same way); the folders under projects/
are never written by a test (tests that edit a project copy it to tmp_path first)."""

from __future__ import annotations

from functools import cache
from pathlib import Path

from hmi.project.model import Project
from hmi.session.session import Session
from tests import conftest
from tests.conftest import PROJECTS


@cache
def example(name: str) -> Project:
    from hmi.project.loader import load_project
    return load_project(PROJECTS / name)


def make_session(path: Path, control: str | None = None, policy: str | None = None,
                 inject=()) -> Session:
    """conftest.make_session, with an example project's load shared (any other folder
    is loaded afresh)."""
    if Path(path).parent != PROJECTS:
        return conftest.make_session(path, control, policy, inject)
    from hmi.engine.scan import Engine
    from hmi.plant.sim.plant import SimPlant
    from hmi.project.injection import parse_injection
    project = example(Path(path).name)
    plant = SimPlant(project)
    for text in inject:
        plant.inject(parse_injection(text))
    return Session(Engine(project, plant, control=control, policy=policy))
