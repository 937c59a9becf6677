"""The construction of hmi/studies/synthesis.py iterated to its fixpoint under FTC, each
round's diagnoser written (hmi/studies/synth_yaml.py) and loaded back into the loop."""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

from hmi.project.model import Project
from hmi.studies.explore import Explorer, LoopConfig
from hmi.studies.synth_yaml import to_yaml
from hmi.studies.synthesis import (
    DEBUG_DIR,
    GRID_US,
    MAX_ITERATIONS,
    OBSERVING,
    Diagnoser,
    Runs,
    SynthesisError,
    View,
    band_plants,
    build_faulty,
    build_nbm,
    explore_runs,
    find_target,
    minimise,
    settle_of,
)


def synthesise(project: Project, name: str, grid_us: int = GRID_US,
               progress: Callable[[int], None] | None = None
               ) -> tuple[Diagnoser, str, Project]:
    """Build the diagnoser of device `name`: (what was built, its YAML, the project loaded
    with it). Deterministic: the same project gives the same YAML."""
    target = find_target(project, name)
    campaign = project.campaign
    counter = campaign.counter if campaign is not None else first_counter(project)
    period = project.scan_period_us
    every = max(1, round(grid_us / period))  # GRID_US (0): every scan
    # Steps 1-2: the fault-free loop (the same in every configuration: no fault, no flag).
    probe = Explorer(project, OBSERVING, counter, settle=False)
    # ... at the nominal plant (its states and changes) and at each corner of the device's
    # declared tolerances (the windows), settling each switch's bounce.
    nbm = build_nbm(probe.graph, View(probe.graph, target), target,
                    band_plants(project, target, counter), project.plant.scan_jitter_us,
                    settle_of(project, target))
    observing = explore_runs(project, [OBSERVING], target, every, counter)
    ftc_config = LoopConfig("ftc", "FTC", None, "off")  # round 0: the diagnoser acts on nothing
    loop_project = project
    text = ""
    built: Diagnoser | None = None
    seen: list[str] = []
    with tempfile.TemporaryDirectory(prefix="plchmi-synth-") as tmp:
        for iteration in range(1, MAX_ITERATIONS + 1):
            if progress is not None:
                progress(iteration)
            ftc = explore_runs(loop_project, [ftc_config], target, every, counter)
            runs = Runs(observing.graphs + ftc.graphs, observing.views + ftc.views,
                        observing.starts + ftc.starts, observing.ftc + ftc.ftc)
            deviations, faulty = build_faulty(target, nbm, runs)
            deviations, faulty = minimise(deviations, faulty)
            built = Diagnoser(target, nbm, deviations, faulty, 0, True,
                              runs_used=sum(len(s) for s in runs.starts), grid_us=every * period)
            new_text = to_yaml(project, built)  # without the rounds: what is compared
            built.iterations, built.converged = iteration, False
            if new_text == text:
                built.converged = True
                break
            if DEBUG_DIR:
                Path(DEBUG_DIR, f"round{iteration}.yaml").write_text(new_text)
            if new_text in seen:  # an oscillation: stop with the last one, not converged
                text = new_text
                break
            seen.append(new_text)
            text = new_text
            loop_project = load_with(project, text, Path(tmp) / f"round{iteration}.yaml")
            ftc_config = LoopConfig("ftc", "FTC", None, "ftc")
    assert built is not None
    text = to_yaml(project, built)
    if built.converged:  # the file says how it was built; its diagnoser is the last round's
        loop_project = load_with(project, text, Path(tempfile.mkdtemp(prefix="plchmi-synth-"))
                                 / "built.yaml")
    return built, text, loop_project


def load_with(project: Project, text: str, file: Path) -> Project:
    """The project loaded with the diagnosers of `text` (a diagnosers file) in place of its
    own of the same names."""
    from hmi.project.loader import load_project
    file.write_text(text)
    return load_project(project.path, str(file))


def first_counter(project: Project) -> str:
    """The plant's first cycle counter: the closed loop is explored cycle by cycle."""
    from hmi.plant.sim.plant import SimPlant
    counters = [name for name, _ in SimPlant(project).counters()]
    if not counters:
        raise SynthesisError("the plant counts nothing: the closed loop needs a cycle counter")
    return counters[0]
