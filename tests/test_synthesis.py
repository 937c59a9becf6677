"""The diagnoser built from the plant model, the fault models and the control law
(hmi/studies/synthesis.py), and the diagnosers file that loads it (`--diagnoser FILE.yaml`).

Fast: the diagnosers file replaces the project's diagnoser of the same name, bad files are
reported at their line; the NBM of the valve is what the physics says. Slow: the whole
construction is deterministic (it rebuilds projects/cispi_valve/diagnoser.built.yaml byte for
byte), the file loads with `plchmi check`, and on the closed loop, at every scan instant, it
isolates at least what the hand-written diagnoser does in each configuration (at some instant,
and whatever the instant), with no misdiagnosis."""

from __future__ import annotations

import subprocess
import sys

import pytest

from hmi.errors import ProjectError
from hmi.project.loader import load_project
from hmi.studies.explore import Explorer
from hmi.studies.synth_build import synthesise
from hmi.studies.synthesis import OBSERVING, View, build_nbm, find_target
from tests.conftest import PROJECTS

VALVE = PROJECTS / "cispi_valve"
BUILT = VALVE / "diagnoser.built.yaml"


def test_a_diagnosers_file_replaces_the_projects_diagnoser_of_that_name():
    own = load_project(VALVE)
    built = load_project(VALVE, str(BUILT))
    assert [s.name for s in built.diagnosers] == ["V1"]
    assert built.diagnosers[0].description != own.diagnosers[0].description
    assert built.diagnosers_file == str(BUILT)
    assert any(f.endswith("diagnoser.built.yaml") for f in built.files)
    # The partitions are the project's (its observers read def_fso, def_fsc).
    assert [(p.name, p.labels, p.sensor, p.estimate, p.actuators)
            for p in built.diagnosers[0].partitions] == \
        [(p.name, p.labels, p.sensor, p.estimate, p.actuators)
         for p in own.diagnosers[0].partitions]


@pytest.mark.parametrize("text,message", [
    ("diagnosers:\n  V1: {}\nname: x\n", "holds only the 'diagnosers:' section"),
    ("name: x\n", "holds only the 'diagnosers:' section"),
    ("diagnosers: [1]\n", "'diagnosers:' must be a mapping"),
])
def test_a_bad_diagnosers_file_is_reported_at_its_line(tmp_path, text, message):
    bad = tmp_path / "d.yaml"
    bad.write_text(text)
    with pytest.raises(ProjectError) as err:
        load_project(VALVE, str(bad))
    assert message in str(err.value) and "d.yaml:" in str(err.value)


def test_a_missing_diagnosers_file_is_an_error_not_a_default(tmp_path):
    with pytest.raises(ProjectError, match="no such diagnosers file"):
        load_project(VALVE, str(tmp_path / "none.yaml"))


def test_the_comparison_grid_goes_with_build_only(capsys):
    from hmi.cli import main
    assert main(["diagnose", str(VALVE), "--every", "10ms"]) == 2
    assert "--every needs --build" in capsys.readouterr().err


def test_the_valves_normal_behaviour_model_is_its_physics():
    project = load_project(VALVE)
    target = find_target(project, "V1")
    assert (target.device, target.sensors, target.actuators) == ("valve", ("fsc", "fso"),
                                                                  ("C", "O"))
    assert find_target(project, "valve").name == "V1"
    ex = Explorer(project, OBSERVING, "cycles", settle=False)
    nbm = build_nbm(ex.graph, View(ex.graph, target), target)
    texts = [target.vector_text(v) for v in nbm.vectors[1:]]
    assert texts[0] == "fsc=1 fso=0 C=0 O=0"  # closed at rest, first
    travel = nbm.expected[nbm.state_of(0b1000)][0b1010]  # opening: fso made with O on
    # fso is made 1.91 s after fsc broke in the fault-free loop (travel 2 s, switch band
    # 40 ms), widened by two scans; the order's own events have no window.
    assert (travel.dwell, travel.tmin, travel.tmax) == ((1_910_000,), 1_890_000, 1_930_000)
    assert all(e.tmax is None for e in nbm.expected[nbm.state_of(0b0001)].values())


def test_the_normal_behaviour_is_measured_over_the_band_and_lets_switches_settle():
    """The windows hold the fault-free runs of every corner of the valve's declared
    tolerances (travel 1.6-2.4 s, bounce 0-20 ms, delay 0-5 ms), widened by two scans and
    the scan jitter (10 ms) each side; a switch that changed may read its old value for its
    bounce and a scan (30 ms) without leaving the normal behaviour."""
    from hmi.studies.synthesis import band_plants, deviation_of, settle_of
    project = load_project(VALVE)
    target = find_target(project, "V1")
    ex = Explorer(project, OBSERVING, "cycles", settle=False)
    plants = band_plants(project, target, "cycles")
    assert [label for label, _, _ in plants][::7] == ["travel=1.6s,bounce=0s,delay=0s",
                                                      "travel=2.4s,bounce=20ms,delay=5ms"]
    nbm = build_nbm(ex.graph, View(ex.graph, target), target, plants,
                    project.plant.scan_jitter_us, settle_of(project, target))
    opening, open_ = nbm.state_of(0b1000), nbm.state_of(0b1010)
    travel = nbm.expected[opening][0b1010]
    # fso made 1.51 s after fsc broke at the fast corner, 2.33 s at the slow one.
    assert (travel.dwell[0], travel.dwell[-1]) == (1_510_000, 2_330_000)
    assert (travel.tmin, travel.tmax) == (1_480_000, 2_360_000)
    assert nbm.settle == 30_000 and nbm.margin == 30_000
    # Opening, fsc reads 1 again within 30 ms: its bounce, no event; after: a deviation.
    assert deviation_of(nbm, target, opening, 20_000, 0b1001) is None
    assert deviation_of(nbm, target, opening, 30_000, 0b1001) is not None
    # Just arrived open, O dropped as fso bounced to 0: the control law's event all the same.
    assert deviation_of(nbm, target, open_, 10_000, 0b0000) == nbm.state_of(0b0010)
    # Without a band (no tolerance declared), the windows are the nominal run's alone.
    bare = build_nbm(ex.graph, View(ex.graph, target), target)
    assert bare.settle == 0 and bare.expected[opening][0b1010].tmax == 1_930_000


@pytest.mark.slow
def test_the_built_diagnoser_is_deterministic_and_meets_its_goal(tmp_path):
    from hmi.studies.synth_report import loop_figures
    project = load_project(VALVE)
    built, text, loaded = synthesise(project, "V1")
    assert built.converged
    assert text == BUILT.read_text()  # same project, same YAML, byte for byte
    out = tmp_path / "again.yaml"
    out.write_text(text)
    check = subprocess.run([sys.executable, "-m", "hmi.cli", "check", str(VALVE),
                            "--diagnoser", str(out)], capture_output=True, text=True)
    assert check.returncode == 0, check.stderr
    # The goal on every scan instant of the cycle (and 1 us around each transition of the
    # diagnoser in the loop), not only on the 200 ms grid `plchmi diagnose` prints.
    every = project.scan_period_us
    mine, new = loop_figures(project, every_us=every), loop_figures(loaded, every_us=every)
    for a, b in zip(mine, new, strict=True):
        assert set(a.isolable) <= set(b.isolable), a.config.title
        assert set(a.guaranteed) <= set(b.guaranteed), a.config.title
        assert b.misdiagnoses == 0, b.config.title
    # Observing: F1 too, the most observation allows (F13 is told apart from F3 or F1 only
    # by where the valve stopped); the hand-written diagnoser reaches it by its dwell at
    # closed rest, the built one by construction.
    assert "F1" in new[0].isolable and len(new[0].isolable) == 12


# -- the High Level Diagnoser (hmi/project/high_level.py, DiagnosisStage.refine) ----------------


def _subsystem_run(name: str, key: str):
    from hmi.studies.campaign import configs_of, run_one
    project = load_project(PROJECTS / "cispi_subsystem")
    spec = project.campaign
    scenario = next(s for s in spec.scenarios if s.name == name)
    config = next(c for c in configs_of(project) if c.key == key)
    return run_one(project, spec, scenario, config)


@pytest.mark.parametrize("scenario,label,at,outcomes", [
    # F1 alone is a sensor fault: V2 unmasked, its switch reconstructed, the cycle goes on
    ("V2.F1@25s", "F1", 32_140_000, ("Blocked", "Tolerant")),
    # V2 masked where it jammed (22 % open): the cycle cannot go on, refined or not
    ("V2.F13@28.8s", "F13", 32_340_000, ("Blocked", "Blocked"))])
def test_the_high_level_diagnoser_resolves_f1_f13_on_the_subsystem(scenario, label, at,
                                                                   outcomes):
    before = _subsystem_run(scenario, "ftc_no_hld")
    after = _subsystem_run(scenario, "ftc")
    assert before.decision == ("F1", "F13") and before.refined is None
    assert after.decision == (label,)
    assert after.refined == (("F1", "F13"), label, 29_750_000, at)
    assert (before.outcome, after.outcome) == outcomes  # and no damage from refining


def test_the_refined_decision_is_explained_in_plain_words():
    from hmi.engine.scan import Engine
    from hmi.explain.builder import ExplanationBuilder
    from hmi.plant.sim.plant import SimPlant
    from hmi.project.injection import Injection
    project = load_project(PROJECTS / "cispi_subsystem")
    plant = SimPlant(project)
    plant.inject(Injection("F1", 25_000_000, "V2"))
    engine = Engine(project, plant)
    snap = None
    for now in range(0, 32_200_001, 10_000):
        snap = engine.step(now)
    record = next(d for d in snap.diagnosers if d.name == "V2")
    assert record.labels == ("F1",) and "closed end switch is stuck" in record.refined_by
    assert "by the high level diagnoser" in record.what()
    texts = ExplanationBuilder(project).build(snap)
    why = next(e.why for e in texts if e.key == "diagnosis:V2")
    assert "the cell as a whole did: T2 filled" in why


def test_a_high_level_rule_must_decide_a_label_of_its_decision(tmp_path):
    import shutil
    copy = tmp_path / "valve"
    shutil.copytree(VALVE, copy)
    (copy / "hl.yaml").write_text(
        "high_level:\n  x:\n    diagnoser: V1\n    decision: [F1, F13]\n    rules:\n"
        "      - {when: fsc, decide: F5, because: no}\n")
    text = (copy / "project.yaml").read_text()
    (copy / "project.yaml").write_text(text.replace("  - recovery.yaml\n",
                                                    "  - recovery.yaml\n  - hl.yaml\n"))
    with pytest.raises(ProjectError, match=r"hl.yaml:6:.*decides 'F5', not one of the "
                       "decision it refines"):
        load_project(copy)
