"""The start caches from the outside (hmi/project/kept.py, hmi/codecache.py,
hmi/ui/csscache.py): a damaged or truncated cache file never crashes a start and is never
taken; a kept project says what a fresh load says (its warnings included, from wherever it is
started); a change the key might miss is seen at the next load."""

from __future__ import annotations

import dataclasses
import os
import random
import shutil
from pathlib import Path

import pytest
from textual.css.stylesheet import Stylesheet

from hmi.cli.check import check_report
from hmi.codecache import dataclass_code, kept_codes, source_fingerprint
from hmi.engine import codegen
from hmi.engine.scan import Engine
from hmi.paths import PROJECTS
from hmi.plant.sim.plant import SimPlant
from hmi.project import kept
from hmi.project.loader import load_project
from hmi.ui import csscache

DAMAGES = 24


def damaged(data: bytes, rng: random.Random) -> bytes:
    """`data` cut short, with bits flipped (header, digest or body), or with bytes added."""
    how = rng.randrange(4)
    if how == 0:
        return data[:rng.randrange(len(data))]
    if how == 3:
        return data + bytes(rng.randrange(256) for _ in range(rng.randint(1, 9)))
    out = bytearray(data)
    # (how 1: anywhere; how 2: past the first line, where a damaged header cannot help)
    first = 0 if how == 1 else data.index(b"\n") + 1
    for _ in range(rng.randint(1, 3)):
        k = rng.randrange(first, len(out))
        out[k] ^= 1 << rng.randrange(8)
    return bytes(out)


def test_damaged_scan_code_is_never_taken_nor_crashes(tmp_path, fresh_scan_code):
    """A flipped bit in the kept compiled scan must not reach the scan: that code never went
    through codegen's checker in this process (it is trusted for having passed it when it
    was written)."""
    path = tmp_path / "scan.marshal"
    fingerprint = source_fingerprint(codegen)
    project = load_project(PROJECTS / "sorting")
    with kept_codes(fresh_scan_code, path, fingerprint, write=True):
        Engine(project, SimPlant(project))
    good = path.read_bytes()
    fresh_scan_code.clear()
    with kept_codes(fresh_scan_code, path, fingerprint, write=False) as taken:
        assert taken > 0  # the file as written is taken
    rng = random.Random(5)
    for _ in range(DAMAGES):
        path.write_bytes(damaged(good, rng))
        fresh_scan_code.clear()
        with kept_codes(fresh_scan_code, path, fingerprint, write=False) as taken:
            assert taken == 0


def make_point():
    return dataclasses.make_dataclass("Point", [("x", int), ("y", int, 0)], frozen=True)


def test_damaged_generated_code_is_never_taken_nor_crashes(tmp_path):
    path = tmp_path / "generated.marshal"
    with dataclass_code(path, write=True) as cache:
        if cache is None:
            pytest.skip("another generated-code cache is active in this process")
        make_point()
    good = path.read_bytes()
    with dataclass_code(path, write=False) as cache:
        assert cache is not None
        make_point()
        assert cache.hits > 0
    rng = random.Random(6)
    for _ in range(DAMAGES):
        path.write_bytes(damaged(good, rng))
        with dataclass_code(path, write=False) as cache:
            assert cache is not None
            point = make_point()(1)
            assert cache.hits == 0
        assert (point.x, point.y) == (1, 0) and point == type(point)(1, 0)


def test_a_damaged_kept_project_is_never_taken_nor_crashes(tmp_path, loads):
    folder = PROJECTS / "palletizer"
    cache = tmp_path / "kept"
    fresh = kept.load(folder, folder=cache, write=True)
    (file,) = cache.iterdir()
    good = file.read_bytes()
    assert kept.load(folder, folder=cache, write=False) == fresh and loads[0] == 1
    rng = random.Random(7)
    for n in range(DAMAGES):
        file.write_bytes(damaged(good, rng))
        assert kept.load(folder, folder=cache, write=False) == fresh
        assert loads[0] == n + 2, "a damaged kept project was read back"


def test_damaged_kept_stylesheets_are_never_taken_nor_crash(tmp_path):
    path = tmp_path / "css.pickle"
    text = "Label { color: red; padding: 1 2; } Button:hover { background: blue; }"
    header = csscache.header()
    parse = Stylesheet._parse_rules  # Textual's (or the suite's own kept one)

    def rules(write: bool) -> tuple[list[str], csscache.KeptCss]:
        keeper = csscache.KeptCss(path, header, write)
        sheet = Stylesheet()
        found = keeper.rules(parse, sheet, text, ("t.tcss", ""), False, 0, "")
        keeper.save()
        return [repr(r.styles._rules) for r in found], keeper

    reference, first = rules(True)
    assert first.parsed == 1 and path.exists()
    good = path.read_bytes()
    assert rules(False)[1].hits == 1
    rng = random.Random(8)
    for _ in range(DAMAGES):
        path.write_bytes(damaged(good, rng))
        found, keeper = rules(False)
        assert keeper.hits == 0 and found == reference


# -- a kept project says what a fresh load says -------------------------------------------------

def project_with_warnings(tmp_path: Path) -> Path:
    folder = tmp_path / "projects" / "warned"
    shutil.copytree(PROJECTS / "cispi_valve", folder)
    project = folder / "project.yaml"
    text = project.read_text(encoding="utf-8")
    # an input no device drives: the loader warns about it (plchmi check lists it)
    assert "\ninputs:" in text
    project.write_text(text.replace("\ninputs:", "\ninputs:\n  spare_button: a spare push "
                                    "button\n", 1), encoding="utf-8")
    return folder


def test_a_kept_project_warns_as_a_fresh_load_from_wherever_it_is_started(tmp_path, loads,
                                                                          monkeypatch):
    folder = project_with_warnings(tmp_path)
    cache = tmp_path / "kept"
    for cwd, given in ((tmp_path, "projects/warned"), (folder, "."),
                       (tmp_path / "projects", str(folder))):
        monkeypatch.chdir(cwd)
        fresh = load_project(given)
        assert fresh.warnings, "the project was meant to warn"
        before = loads[0]
        kept.load(given, folder=cache, write=True)
        again = kept.load(given, folder=cache, write=True)
        assert loads[0] == before + 1  # the second one read back
        assert [str(w) for w in again.warnings] == [str(w) for w in fresh.warnings], cwd
        assert check_report(again) == check_report(fresh)


# -- changes a key might miss -------------------------------------------------------------------

def test_a_project_folder_behind_a_retargeted_symlink_is_loaded_again(tmp_path, loads):
    one, two = tmp_path / "one", tmp_path / "two"
    shutil.copytree(PROJECTS / "cispi_valve", one)
    shutil.copytree(PROJECTS / "cispi_valve", two)
    text = (two / "project.yaml").read_text(encoding="utf-8")
    (two / "project.yaml").write_text(text.replace("name: ", "name: other ", 1),
                                      encoding="utf-8")
    link = tmp_path / "current"
    link.symlink_to(one)
    cache = tmp_path / "kept"
    first = kept.load(link, folder=cache, write=True)
    link.unlink()
    link.symlink_to(two)
    second = kept.load(link, folder=cache, write=True)
    assert loads[0] == 2 and second.name.startswith("other ") and second != first
    assert second == load_project(link)


def test_an_included_file_changed_in_place_same_size_and_time_is_seen(tmp_path, loads):
    folder = tmp_path / "valve"
    shutil.copytree(PROJECTS / "cispi_valve", folder)
    cache = tmp_path / "kept"
    before = kept.load(folder, folder=cache, write=True)
    target = folder / "explanations.yaml"
    data = target.read_bytes()
    stat = target.stat()
    changed = data.replace(b"Both orders", b"both orders", 1)
    assert len(changed) == len(data) and changed != data
    with open(target, "r+b") as file:  # the same inode, rewritten in place
        file.write(changed)
    os.utime(target, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    after = kept.load(folder, folder=cache, write=True)
    assert loads[0] == 2 and after == load_project(folder) and after != before
