"""What the HMI's start keeps across processes (docs/performance.md): the
compiled scan's code (hmi.codecache.kept_codes), the loaded project (hmi.project.kept).
Each is used only when what it stands for would come out the same, and then runs the same:
checked here against the uncached path, scan by scan. How much faster the start is, is
measured by `plchmi bench startup`, never here. Also Textual's parsed stylesheets
(hmi.ui.csscache): the same rules, the same screens."""

from __future__ import annotations

import contextlib
import marshal
import os
import re
import shutil
from pathlib import Path

import pytest
from textual.css.stylesheet import Stylesheet, StylesheetParseError
from ui_scenarios import make_app

from hmi.codecache import kept_codes, source_fingerprint
from hmi.engine import codegen
from hmi.engine.scan import Engine
from hmi.errors import ProjectError
from hmi.paths import PROJECTS
from hmi.plant.sim.plant import SimPlant
from hmi.project import kept
from hmi.project.loader import load_project
from hmi.project.recovery import recoveries_of
from hmi.session.session import Session
from hmi.session.trace import _row
from hmi.ui import csscache
from hmi.ui.csscache import kept_css
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.headless import press, settle, wait_for_screen

EXAMPLES = sorted(p.name for p in PROJECTS.iterdir() if (p / "project.yaml").is_file())
SCANS = 1500


def trace(project, scans: int = SCANS) -> list:
    """The trace rows (`plchmi run --trace`) and alarms of `scans` scans on the simulated
    plant."""
    session = Session(Engine(project, SimPlant(project)))
    rows = []
    for _ in range(scans):
        cell = session.scan_once()
        rows.append((_row(cell.snapshot), [(a.key, a.state) for a in cell.alarms]))
    return rows


# -- the compiled scan's code ----------------------------------------------------------------

def test_an_engine_built_from_kept_scan_code_runs_as_a_compiled_one(tmp_path, fresh_scan_code):
    project = load_project(PROJECTS / "cispi_valve")
    path = tmp_path / "scan.marshal"
    fingerprint = source_fingerprint(codegen)
    reference = trace(project)  # compiled here, as without the cache
    compiled = {key: code.co_code for key, code in fresh_scan_code.items()}
    assert compiled
    fresh_scan_code.clear()
    with kept_codes(fresh_scan_code, path, fingerprint, write=True) as taken:
        Engine(project, SimPlant(project))
    assert taken == 0 and path.exists()
    fresh_scan_code.clear()  # a new process
    with kept_codes(fresh_scan_code, path, fingerprint, write=True) as taken:
        assert taken == len(compiled)
        assert {key: code.co_code for key, code in fresh_scan_code.items()} == compiled
        assert trace(project) == reference


def test_scan_code_kept_under_another_checker_or_damaged_is_not_taken(tmp_path,
                                                                    fresh_scan_code):
    project = load_project(PROJECTS / "sorting")
    path = tmp_path / "scan.marshal"
    with kept_codes(fresh_scan_code, path, b"an older codegen", write=True):
        Engine(project, SimPlant(project))
    fresh_scan_code.clear()
    with kept_codes(fresh_scan_code, path, source_fingerprint(codegen), write=False) as taken:
        assert taken == 0
    for damage in (b"", b"garbage", path.read_bytes()[:-40]):
        path.write_bytes(damage)
        fresh_scan_code.clear()
        with kept_codes(fresh_scan_code, path, b"an older codegen", write=False) as taken:
            assert taken == 0


FORGED = {
    "a call of a name": "def core(v, h, now, scan):\n    return open('x')\n",
    "an attribute outside the vocabulary": "def core(v, h, now, scan):\n    return v.__class__\n",
    "a string constant": "def core(v, h, now, scan):\n    return 'text'\n",
    "a nested function": "def core(v, h, now, scan):\n    return (lambda: v)()\n",
    "another function's name": "def held(v, h, now, scan):\n    return ()\n",
    "a second definition": ("def core(v, h, now, scan):\n    return ()\n"
                            "def other():\n    pass\n"),
}


@pytest.mark.parametrize("why", sorted(FORGED))
def test_kept_scan_code_is_checked_before_it_runs(tmp_path, fresh_scan_code, why):
    """The kept table is read from a file: a code object filed under a generated text but
    not what codegen compiles from it (here, code outside its vocabulary) is never run; the
    text it is filed under is compiled again, checked, and the engine runs as compiled."""
    project = load_project(PROJECTS / "cispi_valve")
    reference = trace(project, 300)
    (key,) = [k for k in fresh_scan_code if k[0].startswith("def core(")]
    path = tmp_path / "scan.marshal"
    forged = compile(FORGED[why], key[1], "exec")
    assert codegen.check_code(forged, "core") is not None
    fresh_scan_code.clear()
    with kept_codes(fresh_scan_code, path, b"x", write=True):
        fresh_scan_code[key] = forged  # as read back from a forged file
        assert trace(project, 300) == reference
        assert fresh_scan_code[key] is not forged


def test_codegen_passes_its_own_code():
    """Every function the example projects generate, in every mode, passes the check of
    kept code."""
    codegen.code_table().clear()
    built = 0
    for name in EXAMPLES:
        project = load_project(PROJECTS / name)
        compiled = Engine(project, SimPlant(project)).compiled
        assert compiled.held is not None and compiled.observed is not None
        for procedure in recoveries_of(project):
            assert compiled.recovery(procedure.name) is not None
        built += len(compiled.sources)
    table = codegen.code_table()
    assert len(table) == built > 20
    for (text, _), code in table.items():
        assert codegen.check_code(code, text[4:text.index("(")]) is None, text[:80]


def test_kept_scan_code_is_not_written_when_bytecode_writing_is_off(tmp_path, monkeypatch,
                                                                   fresh_scan_code):
    monkeypatch.setattr("sys.dont_write_bytecode", True)
    project = load_project(PROJECTS / "cispi_valve")
    with kept_codes(fresh_scan_code, tmp_path / "scan.marshal", b"x"):
        Engine(project, SimPlant(project))
    assert fresh_scan_code and not (tmp_path / "scan.marshal").exists()


def test_the_fingerprint_follows_the_checkers_source():
    digest = source_fingerprint(codegen)
    assert digest == source_fingerprint(codegen) and len(digest) == 32
    assert digest != source_fingerprint(kept)
    # the file holds a header naming it, and the table marshalled
    assert marshal.loads(marshal.dumps({("t", "f"): compile("1", "f", "exec")}))


# -- the loaded project ----------------------------------------------------------------------

def copy_project(tmp_path: Path, name: str = "cispi_valve") -> Path:
    folder = tmp_path / "projects" / name
    shutil.copytree(PROJECTS / name, folder)
    return folder


@pytest.mark.parametrize("name", EXAMPLES)
def test_a_kept_project_is_the_loaded_one_and_runs_the_same(tmp_path, loads, name):
    cache = tmp_path / "kept"
    folder = PROJECTS / name
    first = kept.load(folder, folder=cache, write=True)
    again = kept.load(folder, folder=cache, write=True)
    assert loads[0] == 1  # the second one read back
    fresh = load_project(folder)
    assert again == fresh and first == fresh and again is not first
    assert trace(again, 600) == trace(fresh, 600)


def test_a_diagnoser_variant_is_kept_apart(tmp_path, loads):
    cache = tmp_path / "kept"
    folder = PROJECTS / "cispi_valve"
    plain = kept.load(folder, folder=cache, write=True)
    variants = [d.variants for d in plain.diagnosers if getattr(d, "variants", None)]
    variant = variants[0][-1] if variants else None
    if variant is None:
        pytest.skip("cispi_valve declares no diagnoser variants")
    other = kept.load(folder, variant, folder=cache, write=True)
    assert loads[0] == 2 and other == load_project(folder, variant)


@pytest.mark.parametrize("change", ["edit", "same size", "add", "remove", "relink",
                                    "component", "cwd", "code"])
def test_any_change_the_load_depends_on_loads_again(tmp_path, loads, monkeypatch, change):
    folder = copy_project(tmp_path, "cispi_subsystem")  # it uses the component library
    cache = tmp_path / "kept"
    components = tmp_path / "components"
    shutil.copytree(kept.COMPONENTS, components)
    monkeypatch.setattr(kept, "COMPONENTS", components)
    monkeypatch.setattr("hmi.project.confine.COMPONENTS", components)
    code = tmp_path / "code"
    (code / "sub").mkdir(parents=True)
    (code / "sub" / "module.py").write_text("A = 1\n")
    monkeypatch.setattr(kept, "PACKAGE", code)
    before = kept.load(folder, folder=cache, write=True)
    assert kept.load(folder, folder=cache, write=True) == before and loads[0] == 1
    project_file = folder / "project.yaml"
    text = project_file.read_text(encoding="utf-8")
    if change == "edit":
        project_file.write_text(text.replace("name: ", "name: edited ", 1), encoding="utf-8")
    elif change == "same size":  # same size, same second: the content decides
        stat = project_file.stat()
        changed = re.sub(r"^name: .", "name: Q", text, count=1, flags=re.MULTILINE)
        assert changed != text and len(changed) == len(text)
        project_file.write_text(changed, encoding="utf-8")
        os.utime(project_file, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    elif change == "add":
        (folder / "notes.txt").write_text("a file the project does not include\n")
    elif change == "remove":
        (folder / "campaign.yaml").rename(tmp_path / "campaign.yaml")
    elif change == "relink":
        (folder / "other.yaml").write_text((folder / "control.yaml").read_text())
        (folder / "control.yaml").unlink()
        (folder / "control.yaml").symlink_to("other.yaml")
    elif change == "component":
        valve = next(components.glob("*.yaml"))
        valve.write_text(valve.read_text() + "\n# edited\n")
    elif change == "cwd":
        monkeypatch.chdir(tmp_path)
    elif change == "code":
        (code / "sub" / "module.py").write_text("A = 22\n")
    if change == "remove":  # an included file gone: said, not a project read back
        with pytest.raises(ProjectError, match=r"campaign\.yaml' not found"):
            kept.load(folder, folder=cache, write=True)
        assert loads[0] == 2
        return
    after = kept.load(folder, folder=cache, write=True)
    assert loads[0] == 2, f"{change}: read back instead of loaded"
    if change == "edit":
        assert after.name.startswith("edited ") and after != before


@pytest.mark.parametrize("change", ["edit", "component", "cwd", "variant"])
def test_a_project_loaded_once_per_process_is_loaded_again_on_any_change(
        tmp_path, loads, monkeypatch, change):
    """kept.load_once (the pilot tests' make_app): the same project object while nothing it
    reads changes; a change of a file, of the component library, of the working directory
    or of the variant asked loads it again."""
    folder = copy_project(tmp_path, "cispi_subsystem")  # it uses the component library
    components = tmp_path / "components"
    shutil.copytree(kept.COMPONENTS, components)
    monkeypatch.setattr(kept, "COMPONENTS", components)
    monkeypatch.setattr("hmi.project.confine.COMPONENTS", components)
    before = kept.load_once(folder)
    assert kept.load_once(folder) is before and loads[0] == 1
    variant = None
    if change == "edit":
        project_file = folder / "project.yaml"
        project_file.write_text(project_file.read_text(encoding="utf-8").replace(
            "name: ", "name: edited ", 1), encoding="utf-8")
    elif change == "component":
        valve = next(components.glob("*.yaml"))
        valve.write_text(valve.read_text() + "\n# edited\n")
    elif change == "cwd":
        monkeypatch.chdir(tmp_path)
    else:
        variant = "another"
    if variant is None:
        after = kept.load_once(folder)
        assert loads[0] == 2 and after is not before, change
        assert after == load_project(folder) and kept.load_once(folder) is after
    else:
        with pytest.raises(ProjectError):  # cispi_subsystem has no such variant: said
            kept.load_once(folder, variant)
        assert loads[0] == 2
    if change == "edit":
        assert after.name.startswith("edited ")


def test_a_project_with_errors_says_them_as_without_the_cache_and_is_not_kept(tmp_path):
    folder = copy_project(tmp_path)
    (folder / "project.yaml").write_text("name: broken\nscan_period: 10ms\ninputs: [\n")
    cache = tmp_path / "kept"
    with pytest.raises(ProjectError) as without:
        load_project(folder)
    with pytest.raises(ProjectError) as kept_error:
        kept.load(folder, folder=cache, write=True)
    assert [str(d) for d in kept_error.value.errors] == [str(d) for d in without.value.errors]
    assert not cache.exists() or not list(cache.iterdir())
    for missing in (tmp_path / "nowhere", tmp_path):  # no such folder, no project.yaml
        with pytest.raises(ProjectError) as without:
            load_project(missing)
        with pytest.raises(ProjectError) as kept_error:
            kept.load(missing, folder=cache, write=True)
        assert str(kept_error.value.errors[0]) == str(without.value.errors[0])


def test_a_damaged_kept_project_is_loaded_again(tmp_path, loads):
    cache = tmp_path / "kept"
    folder = PROJECTS / "conveyor_robot"
    kept.load(folder, folder=cache, write=True)
    (file,) = cache.iterdir()
    for damage in (b"", b"plchmi kept project 1\ngarbage", file.read_bytes()[:-50]):
        file.write_bytes(damage)
        assert kept.load(folder, folder=cache, write=False) == load_project(folder)
    assert loads[0] == 4


def test_a_folder_too_big_to_walk_is_loaded_every_time(tmp_path, loads, monkeypatch):
    folder = copy_project(tmp_path)
    monkeypatch.setattr(kept, "MAX_ENTRIES", 3)
    cache = tmp_path / "kept"
    kept.load(folder, folder=cache, write=True)
    kept.load(folder, folder=cache, write=True)
    assert loads[0] == 2 and not cache.exists()


def test_only_the_latest_projects_are_kept(tmp_path, monkeypatch):
    monkeypatch.setattr(kept, "MAX_KEPT", 2)
    cache = tmp_path / "kept"
    for name in EXAMPLES[:3]:
        kept.load(PROJECTS / name, folder=cache, write=True)
    assert len(list(cache.iterdir())) == 2


def test_nothing_is_kept_when_bytecode_writing_is_off(tmp_path, monkeypatch):
    monkeypatch.setattr("sys.dont_write_bytecode", True)
    cache = tmp_path / "kept"
    kept.load(PROJECTS / "cispi_valve", folder=cache)
    assert not cache.exists()


# -- Textual's parsed stylesheets ------------------------------------------------------------

def rules_seen(app) -> list[tuple]:
    """Every rule of the app's stylesheet as data: selectors, declared styles (a layout by
    its repr: Textual makes a new one per parse), flags."""
    return [(repr(rule.selector_set), sorted((k, repr(v)) for k, v in rule.styles._rules.items()),
             rule.is_default_rules, rule.tie_breaker, sorted(rule.selector_names),
             sorted(rule.pseudo_classes)) for rule in app.stylesheet.rules]


async def screens(css: Path | None, size: tuple[int, int]) -> tuple[list, list[str], object]:
    """The app's rules, its screen and its quit dialog (whose CSS is parsed when it opens),
    with the kept stylesheets at `css` (None: without)."""
    with (kept_css(css, write=True) if css else contextlib.nullcontext()) as kept:
        app = make_app()
        async with app.run_test(size=size) as pilot:
            await settle(pilot)
            shots = [app.export_screenshot()]
            await press(pilot, "ctrl+q")
            await wait_for_screen(pilot, ConfirmDialog)
            shots.append(app.export_screenshot())
            rules = rules_seen(app)
            await press(pilot, "escape")
    return rules, shots, kept


async def test_kept_stylesheets_give_the_same_rules_and_the_same_screens(tmp_path):
    """At 80x24, the operator's terminal (the rules are the same whatever the size: every
    stylesheet is parsed, whichever rules a size then applies)."""
    css = tmp_path / "css.pickle"
    size = (80, 24)
    reference = await screens(None, size)
    first = await screens(css, size)
    assert first[2].parsed > 0 and css.exists()
    again = await screens(css, size)
    assert again[2].hits > 0 and again[2].parsed == 0  # every stylesheet read back
    assert again[0] == first[0] == reference[0]
    assert again[1] == first[1] == reference[1]


def test_other_variables_another_textual_or_errors_are_not_taken_from_the_cache(tmp_path,
                                                                              monkeypatch):
    css = tmp_path / "css.pickle"
    text = "Label { color: $accent; padding: 1 2; }"

    def parse(variables: dict[str, str]) -> tuple[list, object]:
        with kept_css(css, write=True) as kept:
            sheet = Stylesheet(variables=variables)
            sheet.add_source(text, ("test.tcss", ""))
            sheet.parse()
        return [repr(r.styles._rules) for r in sheet.rules], kept

    red, kept = parse({"accent": "red"})
    assert kept.parsed == 1
    assert parse({"accent": "red"})[1].hits == 1
    blue, kept = parse({"accent": "blue"})
    assert kept.parsed == 1 and blue != red and "Color(0, 0, 255)" in blue[0]
    with kept_css(css, write=True) as kept:  # a CSS error: said as usual, never kept
        sheet = Stylesheet()
        sheet.add_source("Label { colour: red; }", ("bad.tcss", ""))
        with pytest.raises(StylesheetParseError):
            sheet.parse()
        assert kept.parsed == 1
    assert len(csscache._read(css, csscache.header())) == 2
    css.write_bytes(csscache.header() + b"damaged")
    assert parse({"accent": "red"})[1].parsed == 1
    # Textual's CSS code changed (another build of it): its rules are not read back
    monkeypatch.setattr(csscache, "FORMAT", b"another textual.css")
    assert parse({"accent": "red"})[1].parsed == 1
    monkeypatch.setattr(csscache, "CHECKED", ((0, 0), (0, 1)))
    with kept_css(css) as kept:
        assert kept is None
        assert Stylesheet._parse_rules is vars(Stylesheet)["_parse_rules"]
        assert not getattr(Stylesheet._parse_rules, "kept_css", False)


def test_the_stylesheet_cache_is_checked_against_the_installed_textual():
    """The cache wraps a private method of Textual: it was checked with the versions of
    CHECKED (pyproject.toml's range); another one turns it off (above), and this test says to
    check it again."""
    import textual
    assert csscache.textual_version() == textual.__version__
    assert csscache.checked(textual.__version__)
    assert not csscache.checked("7.5.0") and not csscache.checked("9.0.0")
    assert not csscache.checked(None) and not csscache.checked("dev")


async def test_the_first_frame_listeners_are_told_once_the_first_frame_is_shown():
    """Where the HMI saves the kept stylesheets (an operator's HMI is rarely quit cleanly)."""
    app = make_app()
    told: list[bool] = []
    app.first_frame_listeners.append(lambda: told.append(app.screen.is_mounted))
    async with app.run_test(size=(80, 24)) as pilot:
        await settle(pilot)
        assert told == [True]
        await press(pilot, "space")
        await settle(pilot)
    assert told == [True]
