"""Declared tolerances (hmi/project/tolerances.py) and the band of plants they make
(hmi/studies/band.py): loading them, their errors at file:line:column, the band's corners and
seeded points, fault-free runs across it, and what `plchmi check` and `plchmi band` say — a
diagnoser too tight for the band is reported with the run that shows it."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from hmi.cli import main
from hmi.errors import ProjectError
from hmi.project.loader import load_project
from hmi.studies.band import band_of, run_point
from hmi.studies.band_report import check_band, fault_free_band, run_length
from tests.conftest import PROJECTS
from tests.examples import example

MS = 1_000
S = 1_000_000
VALVE = PROJECTS / "cispi_valve"
BUILT = VALVE / "diagnoser.built.yaml"
EXAMPLES = ("cispi_valve", "cispi_subsystem", "conveyor_robot", "sorting", "palletizer")


def farm_for_a_test():
    """Where a test's study runs: its own processes (tests/conftest.py says how many), its
    shards not kept."""
    from hmi.farm.executors import InProcess, LocalPool
    from hmi.farm.run import Farm
    from tests.conftest import processes_for_a_test
    jobs = processes_for_a_test()
    return Farm(LocalPool(jobs) if jobs > 1 else InProcess(), keep=False)


def copy_valve(tmp_path: Path) -> Path:
    folder = tmp_path / "cispi_valve"
    shutil.copytree(VALVE, folder)
    return folder


def with_plant(folder: Path, old: str, new: str) -> Path:
    path = folder / "project.yaml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    return path


# -- the format ----------------------------------------------------------------------------


def test_the_valve_declares_the_band_it_is_built_for():
    project = example("cispi_valve")
    (device,) = project.plant.devices
    spans = {t.param: (t.low, t.high, t.nominal) for t in device.tolerances}
    assert spans == {"travel": (1_600_000, 2_400_000, 2_000_000), "bounce": (0, 20 * MS, 0),
                     "delay": (0, 5 * MS, 0), "block_at": (0.05, 0.95, 0.5)}
    assert project.plant.scan_jitter_us == 10 * MS  # up to one period


@pytest.mark.parametrize("name", EXAMPLES)
def test_every_example_project_declares_its_own(name):
    project = example(name)
    assert project.plant.tolerances and project.plant.scan_jitter_us > 0
    assert not band_of(project).empty


# (the tolerance's line, what the error says, where: the text it points at)
BAD = [
    ("    travel: ±120%\n", "a percentage above 0 and below 100", "±"),
    ("    trvel: ±10%\n", "the valve model has no parameter 'trvel'", "trvel"),
    ("    initial: ±10%\n", "parameter 'initial' of the valve model takes no tolerance",
     "initial"),
    ("    travel: [2.1s, 2.4s]\n", "leaves out the parameter's value 2s", "["),
    ("    bounce: ±20%\n", "±20% of 0s is no range", "±"),
    ("    travel: [0s, 2.4s]\n", "reaches 0s", "["),
    ("    block_at: [0.01, 0.9]\n", "out of the parameter's range", "["),
    ("    travel: [2.4s, 1.6s]\n", "an empty range", "["),
    ("    travel: [1s]\n", "has 1 values", "["),
    ("    travel: fast\n", "is 'fast'", "fast"),
    ("    travel: [1.6, 2.4s]\n", "low end 1.6 has no unit", "1.6"),
]


@pytest.mark.parametrize("line,fragment,where", BAD, ids=[b[1][:30] for b in BAD])
def test_a_bad_tolerance_is_an_error_at_its_line_and_column(tmp_path, line, fragment, where):
    folder = copy_valve(tmp_path)
    path = with_plant(folder, "  tolerances:\n    travel: ±20%\n    bounce: [0ms, 20ms]\n"
                      "    delay: [0ms, 5ms]\n    block_at: [0.05, 0.95]\n",
                      "  tolerances:\n" + line)
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    (error,) = info.value.errors
    lines = path.read_text().splitlines()
    row = next(k for k, text in enumerate(lines, start=1) if text == line.rstrip("\n"))
    assert fragment in str(error), str(error)
    assert (Path(error.pos.file).name, error.pos.line) == ("project.yaml", row)
    assert error.pos.col == line.index(where) + 1, str(error)


def test_scan_jitter_longer_than_a_period_is_an_error(tmp_path):
    folder = copy_valve(tmp_path)
    with_plant(folder, "  scan_jitter: 10ms", "  scan_jitter: 15ms")
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    assert "longer than the scan period (10ms)" in str(info.value.errors[0])


def test_tolerances_of_several_devices_go_inside_each_device(tmp_path):
    folder = tmp_path / "cispi_subsystem"
    shutil.copytree(PROJECTS / "cispi_subsystem", folder)
    path = folder / "project.yaml"
    text = path.read_text()
    path.write_text(text.replace("  scan_jitter: 10ms", "  scan_jitter: 10ms\n  tolerances: "
                                 "{travel: ±10%}"))
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    (error,) = [e for e in info.value.errors if "tolerances" in e.message]
    assert "the plant's 'tolerances' belong to one device" in str(error)


# -- the band ------------------------------------------------------------------------------


def test_the_band_its_corners_and_seeded_points():
    band = band_of(example("cispi_valve"))
    assert [d.name(False) for d in band.dimensions] == ["travel", "bounce", "delay",
                                                        "block_at", "jitter"]
    corners = band.corners()
    assert len(corners) == 32 and len({c.values for c in corners}) == 32
    assert all(v in (d.low, d.high) for c in corners for d, v in zip(band.dimensions,
                                                                      c.values, strict=True))
    sample = band.sample(50, seed=3)
    assert sample == band.sample(50, seed=3) and sample != band.sample(50, seed=4)
    assert all(d.low <= v <= d.high for p in sample
               for d, v in zip(band.dimensions, p.values, strict=True))
    for point in [*corners[:3], *sample[:5]]:  # a point's text gives the point back
        again = band.parse_point(point.text(band))
        assert (again.values, again.seed) == (point.values, point.seed)


def test_a_point_applies_its_values_and_a_travel_scales_the_switch_band():
    project = example("cispi_valve")
    band = band_of(project)
    point = band.parse_point("travel=2.4s,bounce=20ms,delay=5ms,block_at=0.9,seed=7")
    (device,) = band.apply(project, point, "same").plant.devices
    assert device.params["travel"] == 2_400_000 and device.params["switch_band"] == 48 * MS
    assert (device.params["bounce"], device.params["delay"], device.params["block_at"]) == (
        20 * MS, 5 * MS, 0.9)
    assert (device.params["bounce_seed"], device.params["bounce_pattern"]) == (7, "same")
    assert point.jitter_us(band) == 0


@pytest.mark.parametrize("text,fragment", [
    ("travel=3s", "outside the declared band"), ("speed=1", "not a tolerance of"),
    ("travel", "is not NAME=VALUE"), ("seed=x", "is not a whole number"),
    ("travel=fast", "travel=fast")])
def test_a_bad_point_says_what_is_wrong(text, fragment):
    from hmi.errors import UsageError
    band = band_of(example("cispi_valve"))
    with pytest.raises(UsageError, match=fragment):
        band.parse_point(text)


def test_a_fault_free_run_at_a_point_is_deterministic():
    project = example("cispi_valve")
    band = fault_free_band(project)
    point = band.parse_point("travel=2.2s,bounce=15ms,delay=3ms,jitter=7ms,seed=11")
    first = run_point(project, band, point, 20 * S)
    again = run_point(project, band, point, 20 * S)
    assert first.windows == again.windows and first.progress == again.progress >= 2
    assert first.clean


@pytest.mark.parametrize("variant", [None, "paper", str(BUILT)])
def test_the_valve_at_every_corner_of_its_band_raises_no_fault_diagnosis(variant):
    """Every corner (travel 1.6 or 2.4 s, switches bouncing 0 or 20 ms and 0 or 5 ms late,
    scans on time or up to 10 ms late), 40 s each: no faulty diagnoser state, no damage,
    and the valve keeps cycling — with either hand-written variant and with the diagnoser
    built from the models (diagnoser.built.yaml: its windows measured over the band)."""
    project = load_project(VALVE, variant)
    band = fault_free_band(project)
    for corner in band.corners():
        run = run_point(project, band, corner, run_length(project))
        assert run.clean, (corner.text(band), run.diagnosis, run.damage, run.late_progress)


@pytest.mark.slow
@pytest.mark.parametrize("name", EXAMPLES[1:])
def test_every_example_at_every_corner_raises_no_fault_diagnosis(name):
    """The other examples' bands, every corner (cispi_subsystem: 256), a run each: no
    diagnoser nor stopwatch monitor says a healthy cell is faulty, nothing is damaged, and
    the cell keeps working."""
    from hmi.studies.band import run_band
    project = example(name)
    band = fault_free_band(project)
    runs = run_band(project, band, band.corners(), run_length(project), farm_for_a_test())
    bad = [(r.point.text(band), r.diagnosis, r.monitor, r.damage) for r in runs.runs
           if not r.clean]
    assert not bad and len(runs.runs) == len(band.corners())


# -- check and band --------------------------------------------------------------------------


def test_check_says_the_valve_holds_across_its_band():
    lines, warnings = check_band(example("cispi_valve"))
    text = "\n".join(lines)
    assert "travel 1.6s to 2.4s (±20%)" in text and "scan jitter up to 10ms" in text
    assert "33 runs of 40s (the nominal plant, its 16 corners, 16 seeded points): no fault " \
        "diagnosed" in text
    assert not warnings


TIGHT = ("{from: N3, to: N4, when: fso and not fsc, within: [1.4s, 2.45s]}",
         "{from: N3, to: N4, when: fso and not fsc, within: [1.5s, 1.93s]}")


def test_check_warns_at_the_transition_of_a_diagnoser_too_tight_for_the_band(tmp_path,
                                                                           capsys):
    """The window of the exact simulator (N3 -> N4 within [1.5 s, 1.93 s), as it was): the
    slow valves of the band arrive after it. check says so at the timeout that fires, with
    the run that shows it, and the run replays."""
    folder = copy_valve(tmp_path)
    path = folder / "diagnoser.yaml"
    text = path.read_text()
    assert TIGHT[0] in text
    path.write_text(text.replace(TIGHT[0], TIGHT[1]).replace(
        "{from: N3, to: A3, after: 2.45s", "{from: N3, to: A3, after: 1.93s"))
    assert main(["check", str(folder)]) == 0
    out = capsys.readouterr().out
    warning = next(line for line in out.splitlines()
                   if "a fault-free run in the declared tolerances is diagnosed faulty" in line)
    line_no = next(k for k, line in enumerate(path.read_text().splitlines(), start=1)
                   if "{from: N3, to: A3, after: 1.93s" in line)
    assert warning.strip().startswith(f"{path}:{line_no}:")
    assert "V1 -> A3 {F3, F13}" in warning and "(N3 -> A3 after 1.93s)" in warning
    assert "travel=2.4s" in warning and "Replay: plchmi band" in warning
    point = warning.split("--point '")[1].split("'")[0]
    assert main(["band", str(folder), "--point", point]) == 0
    replay = capsys.readouterr().out
    assert "V1 -> A3 {F3, F13} (N3 -> A3 after 1.93s)" in replay
    assert "diagnosed faulty: V1 -> A3 {F3, F13}" in replay


def test_check_says_the_built_diagnoser_holds_across_the_band():
    """The diagnoser built from the models takes its windows from the band's corners and
    lets a switch's bounce settle: the fault-free runs of `check` stay normal."""
    lines, warnings = check_band(load_project(VALVE, str(BUILT)))
    assert "33 runs of 40s (the nominal plant, its 16 corners, 16 seeded points): no fault " \
        "diagnosed" in "\n".join(lines)
    assert not warnings


BUILT_ARRIVAL = 'to: N4, when: "not fsc and fso and not C and O", within: [1.48s, 2.36s]}'


def test_check_takes_a_diagnosers_file_from_outside_the_project(tmp_path, capsys):
    """`check --diagnoser FILE.yaml` with the file anywhere (here the built diagnoser, copied
    out of the project, its arrival window narrowed to the nominal valve's): the band's runs
    load that file, and the warning points into it."""
    outside = tmp_path / "elsewhere" / "built.yaml"
    outside.parent.mkdir()
    text = BUILT.read_text()
    assert BUILT_ARRIVAL in text
    outside.write_text(text.replace(BUILT_ARRIVAL, BUILT_ARRIVAL.replace("1.48s", "1.89s")))
    assert main(["check", str(VALVE), "--diagnoser", str(outside)]) == 0
    out = capsys.readouterr().out
    warning = next(line for line in out.splitlines()
                   if "a fault-free run in the declared tolerances is diagnosed faulty" in line)
    assert warning.strip().startswith(f"{outside}:") and "Replay: plchmi band" in warning


def test_band_runs_the_corners_and_a_seeded_sample_and_shows_the_windows_used(capsys):
    assert main(["band", str(VALVE), "--runs", "8", "--for", "20s", "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert "25 runs of 20s: the nominal plant, 16 corners, 8 points drawn with seed 1" in out
    assert "diagnosed faulty: none" in out and "damage: none" in out
    arrival = next(line for line in out.splitlines() if "N3 -> N4 on fso and not fsc" in line)
    assert "[1.4s, 2.45s)" in arrival  # the window, and the margins the band leaves


@pytest.mark.parametrize("args,fragment", [
    (["--runs", "-1"], "--runs -1"), (["--point", "travel=9s"], "outside the declared band"),
    (["--jobs", "0"], "--jobs 0")])
def test_band_refuses_bad_arguments(args, fragment, capsys):
    assert main(["band", str(VALVE), *args]) == 2
    assert fragment in capsys.readouterr().err


def test_band_needs_declared_tolerances(tmp_path, capsys):
    folder = copy_valve(tmp_path)
    path = folder / "project.yaml"
    text = path.read_text()
    start = text.index("  # What a real valve varies in")
    path.write_text(text[:start])
    assert main(["band", str(folder)]) == 2
    assert "declares no tolerance" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("variant", [None, "paper", str(BUILT)])
def test_the_valve_is_never_diagnosed_faulty_across_its_band(variant):
    """The corners and 400 seeded points of the band, 40 s each (scans late, switches bouncing
    their own way at every change): no faulty diagnoser state, no damage, cycling on.
    `plchmi band projects/cispi_valve --runs 10000` is the long form (docs/cispi_valve.md)."""
    from hmi.studies.band import fault_free_points, run_band
    project = load_project(VALVE, variant)
    band = fault_free_band(project)
    runs = run_band(project, band, fault_free_points(band, 400, seed=2), run_length(project),
                    farm_for_a_test())
    assert len(runs.runs) == 417
    assert not runs.diagnosed and not runs.damaged and not runs.stopped


# -- the closed loop over the band -----------------------------------------------------------


def test_the_closed_loop_over_the_band_gives_each_figure_as_its_range():
    """Three plants (nominal, the all-low corner, it with F13's block point high), one cheap
    fault: the sweep of F5 is made once for the two corners (F5 does not depend on where
    F13 jams), and the report gives each figure worst .. best."""
    from hmi.studies.band import exploration_band
    from hmi.studies.band_sweep import band_sweep
    from hmi.studies.diag_report import band_lines
    from hmi.studies.loop_sweep import DIAG_NO_FILTER, FTC
    project = example("cispi_valve")
    band = exploration_band(project)
    assert [d.name(False) for d in band.dimensions] == ["travel", "bounce", "delay",
                                                        "block_at"]
    corners = band.corners()
    points = [band.nominal(), corners[0], corners[1]]
    from hmi.farm.executors import InProcess
    from hmi.farm.run import Farm
    over = band_sweep(project, band, (DIAG_NO_FILTER, FTC), "cycles", points,
                      faults=("F5", "F8"), farm=Farm(InProcess(), keep=False), cache=False)
    assert over is not None and len(over.results) == 3
    low, low_block = over.results[1], over.results[2]
    assert low.runs == low_block.runs  # one sweep for both: F5, F8 ignore the block point
    assert points[1].text(band) != points[2].text(band)
    assert over.points[1].seed == over.points[2].seed  # one plant, one bounce pattern
    text = "\n".join(band_lines(project, over, 0, 1))
    assert "Over the declared tolerances: 3 plants" in text
    assert "isolated with certainty at some instant:" in text
    assert "wrong certain diagnoses (pieces of instants): 0" in text
    row = next(line for line in text.splitlines() if line.strip().startswith("F8"))
    assert ".." in row and "%" in row


@pytest.mark.slow
def test_an_exact_figure_moves_when_the_plant_model_changes(tmp_path):
    """F13's share of Defect instants under FTC, every instant of the cycle (about a minute):
    a jam at rest jams the next travel at `block_at`, and the motor stalls 1 s later. At
    half the travel (1 s in) that comes before the 2.45 s arrival deadline; at 90 % (1.8 s
    in) the deadline masks the valve first more often (measured: 88.5 % of the instants
    Defect at 0.5, 75.8 % at 0.9; the jams during a travel, 37.5 %, stall first either way).
    The figure follows the plant, not a table."""
    from hmi.studies.loop_sweep import FTC, sweep
    shares = {}
    for block_at in ("0.5", "0.9"):
        folder = tmp_path / f"valve_{block_at}"
        shutil.copytree(VALVE, folder)
        with_plant(folder, "travel: 2s\n", f"travel: 2s\n    block_at: {block_at}\n")
        project = load_project(folder)
        result = sweep(project, (FTC,), "cycles", exact=True, faults=("F13",),
                       farm=farm_for_a_test(), cache=False)
        assert result is not None and result.exact
        runs = result.of(FTC.key)
        total = sum(r.weight for r in runs)
        assert total == result.cycle_us  # the pieces cover the cycle, every instant once
        shares[block_at] = sum(r.weight for r in runs if r.outcome == "Defect") / total
    assert shares["0.5"] > 0.8
    assert shares["0.9"] < shares["0.5"] - 0.1
