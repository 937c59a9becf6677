"""Shared helpers: projects written to temporary folders, engines on the simulated plant."""

from __future__ import annotations

import os
import sys
import textwrap
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from hmi.engine.scan import Engine
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import parse_injection
from hmi.project.loader import load_project
from hmi.session.session import Session

ROOT = Path(__file__).resolve().parent.parent
PROJECTS = ROOT / "projects"

# Hypothesis's defaults time each example on the wall clock (a 200 ms deadline, a health
# check of slow generation): on the shared 2-core machine a loaded moment failed a Modbus
# fuzzer that passes at once when run again. Tests here never wait on the wall clock, so no
# deadline and no timing health check; each test's own settings still choose its examples.
settings.register_profile("plchmi", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("plchmi")


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config):
    """Compile each module once in a run and reuse it: this process, the xdist workers (started
    after this) and the commands tests start (`python -m hmi.cli ...`) write and read bytecode
    even where PYTHONDONTWRITEBYTECODE is set (this machine sets it). Without it each worker
    and each command compiled hmi (and each worker the tests) again: measured, 0.45 CPU s
    more for each `python -m hmi.cli check`, 5 s more for each worker's collection."""
    sys.dont_write_bytecode = False
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    # xdist's default distribution (`load`, what `-n` gives) as `loadgroup`: the same, and
    # the tests marked `xdist_group` on one worker: the tests that share a computed run
    # (tests/cellruns.py) then compute it once. The workers name a marked test with its
    # group (`nodeid@group`), which the scheduler reads; the name changes nothing else.
    if hasattr(config, "workerinput"):
        config.option.loadgroup = True
    elif config.getoption("dist", None) == "load":
        config.option.dist = "loadgroup"


def _studies_left_out(config) -> bool:
    """The default run (no file or test named, no -m) is the everyday suite: it leaves out
    the tests marked `slow`, the long studies (agreement over every trace, an independent
    parser over every export, the fuzzing budgets, the soak's random runs, the closed loop's
    sweeps). The everyday suite is to stay under 3 minutes and CI runs everything: `.ci/run`
    runs the studies as a second step (`-m slow`). Naming a file or a test runs what it
    names, slow or not, so working on a study never silently skips it."""
    return config.args_source is pytest.Config.ArgsSource.TESTPATHS and not config.option.markexpr


def pytest_collection_modifyitems(config, items):
    if not _studies_left_out(config):
        return
    studies = [item for item in items if item.get_closest_marker("slow")]
    if studies:
        config.hook.pytest_deselected(items=studies)
        items[:] = [item for item in items if not item.get_closest_marker("slow")]


def pytest_terminal_summary(terminalreporter, config):
    """Say what the run left out (under xdist the workers deselect, and pytest's own count
    of deselected tests is not shown): a reader of the summary must not take the everyday
    suite for everything."""
    if _studies_left_out(config) and not hasattr(config, "workerinput"):
        terminalreporter.write_line(
            "The long studies (tests marked slow) were left out: "
            "`python -m pytest -n auto -m slow` runs them; .ci/run runs both.")


@pytest.fixture
def loads(monkeypatch):
    """How many times hmi.project.kept ran the real loader (the rest were read back):
    the start-cache tests (test_start_caches, test_fastpath_caches) count with it."""
    from hmi.project import kept
    count = [0]
    real = kept.load_project

    def counted(*args, **kwargs):
        count[0] += 1
        return real(*args, **kwargs)
    monkeypatch.setattr(kept, "load_project", counted)
    return count


@pytest.fixture
def fresh_scan_code():
    """codegen's table of compiled scan code emptied for the test (as in a new process),
    restored after: the start-cache tests (test_start_caches, test_fastpath_caches) fill
    it from a kept file and check what was taken."""
    from hmi.engine import codegen
    table = codegen.code_table()
    saved = dict(table)
    table.clear()
    yield table
    table.clear()
    table.update(saved)


def processes_for_a_test() -> int:
    """Worker processes a test may start for itself: both cores when the suite runs in one
    process, one when pytest-xdist already runs a test on each core (.ci/run, README)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return 1
    return min(2, os.cpu_count() or 1)


def write_project(folder: Path, files: dict[str, str]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (folder / name).write_text(textwrap.dedent(text).lstrip("\n"), encoding="utf-8")
    return folder


def make_session(project_path, control=None, policy=None, inject=()):
    project = load_project(project_path)
    plant = SimPlant(project)
    for text in inject:
        plant.inject(parse_injection(text))
    engine = Engine(project, plant, control=control, policy=policy)
    return Session(engine)


@pytest.fixture(autouse=True)
def data_folder(tmp_path, monkeypatch):
    """Journals written by tests go to a temporary folder, never the user's data folder;
    a cell's runtime a test started (plchmi PROJECT starts one, detached) does not outlive
    it, whatever the test did."""
    monkeypatch.setenv("PLCHMI_DATA", str(tmp_path / "data"))
    yield
    stop_runtimes(tmp_path)


def stop_runtimes(folder: Path) -> None:
    import signal
    import time

    from hmi.runtime.place import Place, running
    for lock in folder.rglob("runtime.lock"):
        pid = running(Place(lock.parent))
        if pid is None or pid <= 0:
            continue
        try:
            os.kill(pid, signal.SIGTERM)
        except ProcessLookupError:
            continue
        deadline = time.monotonic() + 30
        while running(Place(lock.parent)) is not None and time.monotonic() < deadline:
            time.sleep(0.02)
        if running(Place(lock.parent)) is not None:
            os.kill(pid, signal.SIGKILL)


@pytest.fixture(scope="session")
def postgres():
    """A throwaway PostgreSQL cluster (tests/pgcluster.py), one per worker that needs it; a
    machine without PostgreSQL's binaries skips the test and says why (pytest -rs)."""
    from pgcluster import Cluster, Unavailable
    try:
        cluster = Cluster().start()
    except Unavailable as exc:
        pytest.skip(f"no PostgreSQL here: {exc}")
    try:
        import psycopg  # noqa: F401
    except ImportError:
        cluster.stop()
        pytest.skip("psycopg is not installed (the [test] extra installs it)")
    yield cluster
    cluster.stop()


@pytest.fixture
def valve_project():
    return load_project(PROJECTS / "cispi_valve")


@pytest.fixture(autouse=True, scope="session")
def closed_loop_cache(tmp_path_factory):
    """One cache of closed-loop explorations for the whole session (hmi/studies/loop_sweep.py):
    `check` of an unchanged copy of a project does not explore it again, and nothing is read
    from or written to the user's own cache."""
    previous = os.environ.get("PLCHMI_CACHE")
    os.environ["PLCHMI_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    yield
    if previous is None:
        os.environ.pop("PLCHMI_CACHE", None)
    else:
        os.environ["PLCHMI_CACHE"] = previous


@pytest.fixture(autouse=True, scope="module")
def kept_textual_css(request, tmp_path_factory):
    """Textual's parsed stylesheets kept across the app starts of a worker, as the HMI keeps
    them across its own starts (hmi/ui/csscache.py): each pilot test starts an app, and
    Textual parsed all the CSS again at each (~15 ms CPU of each start). The rules are read
    back as new objects for each app; nothing else is shared. Not around the tests of the
    cache itself, which enter it on their own."""
    if request.module.__name__.endswith("test_start_caches"):
        yield
        return
    from hmi.ui.csscache import kept_css
    folder = tmp_path_factory.getbasetemp() / "kept-css"
    folder.mkdir(exist_ok=True)
    with kept_css(folder / "textual-css.pickle", write=True):
        yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With PLCHMI_TEST_CPU=FILE, each test's CPU seconds (its process and the children it
    reaped: servers, pools), wall seconds and the seconds its process waited for a core
    (runnable, not running: the machine's load), set-up and teardown included, are appended
    to FILE.<worker> as `nodeid<TAB>cpu<TAB>wall<TAB>waited`: on a shared machine the wall
    time of a test says more about the load than about the test (docs/performance.md).
    wall - cpu - waited is the time the test slept (a real process, a deadline): a core
    another worker may use."""
    path = os.environ.get("PLCHMI_TEST_CPU")
    if not path:
        yield
        return
    import resource
    import time

    def cpu() -> float:
        own = resource.getrusage(resource.RUSAGE_SELF)
        children = resource.getrusage(resource.RUSAGE_CHILDREN)
        return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime
    def waited() -> float:  # run-queue time of this process (Linux; 0 elsewhere)
        try:
            with open("/proc/self/schedstat", encoding="ascii") as stat:
                return int(stat.read().split()[1]) / 1e9
        except (OSError, IndexError, ValueError):
            return 0.0
    cpu0, wall0, waited0 = cpu(), time.perf_counter(), waited()
    yield
    line = (f"{item.nodeid}\t{cpu() - cpu0:.3f}\t{time.perf_counter() - wall0:.3f}"
            f"\t{waited() - waited0:.3f}\n")
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(f"{path}.{worker}", "a", encoding="utf-8") as out:
        out.write(line)
