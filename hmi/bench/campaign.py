"""``plchmi bench campaign``: the fault campaign of the CISPI valve, as times real time.

``plchmi campaign projects/cispi_valve`` runs every scenario under the three configurations
of 000 Table 1 (48 runs of 40 s of virtual time); this section times it on one worker
process and on as many as the machine has cores (at most 2, the development machine's),
and prints the virtual time simulated per second of wall time. The results are checked to be
the same whatever the number of workers (each run is deterministic and independent).

The goal: the campaign at >= 1000x real time on both cores.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from hmi.bench import goal_line, load_line

SECTION = "campaign"
HELP = "the cispi_valve fault campaign on 1 and 2 cores, x real time (goal >= 1000x)"

GOAL = 1000
PROJECT = Path(__file__).resolve().parents[2] / "projects" / "cispi_valve"


def run(args: argparse.Namespace) -> None:
    from hmi.farm.executors import executor_for
    from hmi.farm.run import Farm
    from hmi.project.campaign import campaign_of
    from hmi.project.loader import load_project
    from hmi.studies.campaign import CONFIGS, run_campaign

    project = load_project(PROJECT)
    spec = campaign_of(project)
    assert spec is not None, "the valve project has a campaign"
    runs = len(spec.scenarios) * len(CONFIGS)
    virtual_s = runs * spec.length_us / 1e6
    cores = min(2, os.cpu_count() or 1)
    print(f"  {project.name}: {runs} runs x {spec.length_us / 1e6:g} s of virtual time "
          f"({virtual_s:,.0f} s); {load_line()}", flush=True)
    print("  (CPU: this process's and its workers' CPU time; on a quiet machine with a core "
          "per worker the wall time is the CPU time over the workers)", flush=True)
    outcomes = []
    for jobs in sorted({1, cores}):
        started, cpu = time.perf_counter(), _cpu()
        farm = Farm(executor_for(None, jobs), keep=False)
        result = run_campaign(project, spec, farm=farm)
        wall, cpu = time.perf_counter() - started, _cpu() - cpu
        outcomes.append([(r.scenario.name, r.config.key, r.outcome, r.reason)
                         for r in result.runs])
        speed = virtual_s / wall
        idle = virtual_s / (cpu / jobs)  # each worker on a core of its own
        print(f"  {jobs} worker{'s' if jobs > 1 else ' '}  {wall:6.2f} s wall  "
              f"{speed:8,.0f}x real time; CPU {cpu:6.2f} s: {idle:8,.0f}x with a core per "
              "worker", flush=True)
        if jobs == cores:
            print(f"             {goal_line(speed, GOAL, 'x real time')}; with a core per "
                  f"worker: {'met' if idle >= GOAL else 'NOT met'} ({idle / GOAL:.2f}x)",
                  flush=True)
    same = all(o == outcomes[0] for o in outcomes)
    print(f"  results identical on 1 and {cores} workers: {'yes' if same else 'NO'}")


def _cpu() -> float:
    """CPU seconds of this process and of its reaped children (the campaign's workers)."""
    import resource

    own, children = (resource.getrusage(who) for who in (resource.RUSAGE_SELF,
                                                          resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime
