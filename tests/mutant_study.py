"""The mutation study of one project's export: every single-operator mutant of the exported
Structured Text (tests/st_mutants.py) replayed on the recorded traces, and every survivor
judged.

A survivor is handed to the block proof of the function block it changes (z3, for every
input and every state the proof's invariant admits): the filter FB to tests/st_prove.py's
`prove_filter`, a monitor, the memory, a diagnoser, the control law to tests/ir_prove.py's
`prove_monitor`, `prove_memory`, `prove_diagnoser`, `prove_control`. Proved equal to the
engine's (or the scan program's lowering): an *equivalent* mutant. Refuted with a
counterexample: *refuted*, i.e. caught (it differs from the engine on some input and state
the invariant admits, or leaves the invariant, or indexes out of bounds). Neither (z3 cannot
say, or the proof does not cover the mutated text): *unexplained*, unless listed below. A
survivor in the program (PRG_..._Safety: the blocks' wiring) is handed to
tests/program_prove.py's `prove_program`, every block taken as any function: proved, an
equivalent mutant; refuted, it hands some block another value, which the block may never
read (not caught): listed with its reason, or unexplained. A study with an unexplained
survivor fails.

The lists (by Mutant.key()): EQUIVALENT, equivalent mutants z3 cannot judge, each with why;
CAUGHT_BY_TESTS, survivors a test of their own catches (the test named); GAPS, what no trace
reaches and no proof judges (listed so that they stay in sight).

`python -m tests.mutant_study PROJECT... [--sample N | --per-block N] [--only TEXT]
[--jobs N] [--log FILE]` prints each project's figures (every mutant; `--sample N`: N
seeded mutants of each diagnoser FB, every other mutant; `--per-block N`: N seeded mutants
of each POU; `--only TEXT`: those of the POUs whose name holds TEXT) and the CPU time they
took, by block (`--log FILE`: each verdict appended as it is reached, and those already
there for the same export and traces taken, so that a stopped study goes on where it
ended; `--jobs N`: judged by N processes, each every N-th mutant, the figures the same).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import multiprocessing
import random
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hmi.export import source
from hmi.export.filter_pou import max_distance
from hmi.project.loader import load_project
from hmi.project.model import Project
from tests.conftest import PROJECTS
from tests.ir_prove import prove_control, prove_diagnoser, prove_memory, prove_monitor
from tests.program_prove import _section, prove_program
from tests.st_mutants import Mutant, Recording, Run, Trace, judge, mutants, record, study_runs
from tests.st_prove import (
    Proof,
    Unsupported,
    builds_kept,
    indices_at_start,
    indices_not_negative,
    pou_text,
    prove_filter,
)

_FTC = "Ftc := (DiagnosisMode <> 1) AND (DiagnosisMode <> 2),"


def _no_diagnoser(project: str) -> dict[str, str]:
    return {f"PRG_{project}_Safety: {_FTC} [{old} -> {new}]": (
        "Ftc gates the masks of the diagnosers' actuator partitions; the cell has no "
        "diagnoser, so the filter never reads it")
        for old, new in (("<>", "="), ("1", "0"), ("AND", "OR"), ("2", "1"))}


def _off_mode(project: str) -> dict[str, str]:
    return {f"PRG_{project}_Safety: {_FTC} [2 -> 1]": (
        "Ftc := DiagnosisMode <> 1: TRUE in off mode too, where it gates masks that are "
        "all 0 (a diagnoser off writes its flags 0, at the scan the mode changes too: "
        "its Dirty is set then), and the filter is its only reader")}


def _first_rise(project: str, names: tuple[str, ...], rising: str) -> dict[str, str]:
    return {f"PRG_{project}_Safety: prev_{n} := FALSE; [FALSE -> TRUE]": (
        f"the first cycle's history of {n}: read only in a conjunction with rise({rising}) "
        f"(`{rising} AND NOT prev_{rising}`), FALSE at the first cycle, where prev_{rising} "
        f"is {rising}") for n in names}


def _observe_masks(project: str) -> dict[str, str]:
    return {f"PRG_{project}_Safety: {_FTC} [AND -> OR]": (
        "tests/test_export_mutants.py::test_observe_mode_masks_no_order_on_the_plc: Ftc "
        "always TRUE, the filter masks the orders of a flagged actuator in observe mode "
        "too (the study's runs are in FTC mode)")}


EQUIVALENT: dict[str, dict[str, str]] = {
    "conveyor_robot": _no_diagnoser("conveyor_robot"),
    "sorting": _no_diagnoser("sorting"),
    "palletizer": {**_no_diagnoser("palletizer"),
                   **_first_rise("palletizer", ("n1", "n2"), "pusher_out")},
    "cispi_valve": _off_mode("cispi_valve"),
    "cispi_subsystem": {**_off_mode("cispi_subsystem"),
                        **_first_rise("cispi_subsystem", ("T2_timed", "T2_fill"), "LH2")},
}

GAPS: dict[str, dict[str, str]] = {}


def _clock(project: str) -> dict[str, str]:
    return {f"PRG_{project}_Safety: Clock(IN := TRUE, PT := T#24d); [T#24d -> T#2073600001ms]": (
        "tests/test_export.py::test_the_programs_clock_saturates_at_24_days: the clock read "
        "at 24 days and 1 ms (no recorded trace runs 24 days)")}


FIRST_SCAN_TEST = "tests/test_export_mutants.py::test_the_first_scans_history_is_caught"


def _first_scan(project: str, changes: tuple[tuple[str, str, str], ...]) -> dict[str, str]:
    return {f"PRG_{project}_Safety: {line} [{old} -> {new}]": (
        f"{FIRST_SCAN_TEST}: 40 runs of 4 scans in manual mode, the inputs and requests "
        "random from the first scan, where a rise of an order (or of an input, the history "
        "not initialised) is seen by a monitor or an observer (the study's runs have a "
        "random first scan in 4 runs only)") for line, old, new in changes}


CAUGHT_BY_TESTS: dict[str, dict[str, str]] = {
    "conveyor_robot": _clock("conveyor_robot"),
    "palletizer": {**_clock("palletizer"), **_first_scan("palletizer", (
        ("IF NOT Started THEN", "NOT", "(dropped)"),
        ("prev_RETRACT := FALSE;", "FALSE", "TRUE"),
        ("prev_ELEV_DOWN := FALSE;", "FALSE", "TRUE")))},
    "sorting": {**_clock("sorting"), **_first_scan("sorting", tuple(
        (f"prev_{o} := FALSE;", "FALSE", "TRUE") for o in ("ROLL_P", "ROT0", "ROLL_M")))},
    **{name: {**_clock(name), **_observe_masks(name)}
       for name in ("cispi_valve", "cispi_subsystem")},
}

# (outcomes that depend on the lists, which may have changed since: judged again)
LISTED = ("tested", "gap", "listed", "unexplained")
OUTCOMES = ("caught", "stillborn", "equivalent", "refuted", "tested", "listed", "gap",
            "unexplained")


@dataclass(frozen=True)
class Judged:
    """A mutant's outcome (one of OUTCOMES), and how it was reached: the trace and scan that
    caught it, the proof that judged it, the reason it is listed."""

    mutant: Mutant
    outcome: str
    how: str = ""
    cpu_s: float = 0.0


@dataclass
class Study:
    """One project's study: every mutant found, those judged (all, or a sample), the CPU
    seconds it took."""

    name: str
    found: int
    judged: list[Judged] = field(default_factory=list)
    cpu_s: float = 0.0
    traces: int = 0
    scans: int = 0

    def counts(self) -> Counter[str]:
        return Counter(j.outcome for j in self.judged)

    def by_proof(self) -> Counter[str]:
        """The equivalent and refuted survivors, by the proof that judged them."""
        return Counter(f"{j.outcome} by {j.how.split(':')[0]}" for j in self.judged
                       if j.outcome in ("equivalent", "refuted"))

    def unexplained(self) -> list[Judged]:
        return [j for j in self.judged if j.outcome == "unexplained"]

    def report(self) -> str:
        c = self.counts()
        lines = [f"{self.name}: {self.found} mutants, {len(self.judged)} judged "
                 f"({self.traces} traces, {self.scans} scans, {self.cpu_s:.0f} s CPU): "
                 + ", ".join(f"{c[o]} {o}" for o in OUTCOMES)]
        lines += [f"  {n} {what}" for what, n in sorted(self.by_proof().items())]
        cpu: dict[str, float] = {}
        for j in self.judged:
            cpu[j.mutant.pou] = cpu.get(j.mutant.pou, 0.0) + j.cpu_s
        count = Counter(j.mutant.pou for j in self.judged)
        lines.append("  CPU by block: " + ", ".join(
            f"{pou} {count[pou]} in {s:.0f} s"
            for pou, s in sorted(cpu.items(), key=lambda kv: -kv[1])))
        lines += [f"  {j.outcome}: {j.mutant.describe()} ({j.how})" for j in self.judged
                  if j.outcome in ("tested", "listed", "gap", "unexplained")]
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# The block proofs, as judges of a mutated text
# --------------------------------------------------------------------------------------------

Judge = Callable[[Project, str, Mutant], list[Proof]]


def _tamper(mutated: str, pou: str) -> Callable[[str], str]:
    """The block's text replaced by the mutant's (the proof parses only the changed line
    again: tests/st_prove.py, parse_changed)."""
    return lambda _original: pou_text(mutated, pou)


def _filter(project: Project, text: str, m: Mutant) -> list[Proof]:
    """prove_filter on the mutant, first for every input and state; when a loop of the
    mutant then runs more than 100 times (the block's own run at most 4 times: e.g. a
    next-subset step that counts up a Comb element left from an earlier call, which "every
    state" lets hold any negative number), first from the index lists a PLC starts with
    (every element 0, the rest of the state any: a counterexample there refutes it; none
    proves nothing), then for every state whose kept index lists hold no negative value,
    an invariant the proof shows the mutant keeps (they start at 0 on a PLC): every state
    the PLC reaches. In both, a pass of a WHILE that branches on an element left from an
    earlier call runs once per world to the loop's end (st_prove's `stale`)."""
    limit = max_distance(source.filter_bound(project))
    tamper = _tamper(m.apply(text), m.pou)
    try:
        proofs = prove_filter(project, text, limit, tamper, loop_limit=100, at_once=True)
        if all(p.proved for p in proofs):
            return proofs
    except Unsupported:
        try:  # a counterexample from the index lists a PLC starts with, if there is one
            proofs = prove_filter(project, text, limit, tamper, loop_limit=100,
                                  start=indices_at_start, unchecked=2, at_once=True,
                                  stale=True)
            if any("counterexample" in p.detail for p in proofs):
                return proofs
        except Unsupported:
            pass
    return prove_filter(project, text, limit, tamper, loop_limit=100,
                        invariant=indices_not_negative, unchecked=2, at_once=True,
                        stale=True)


def _block(kind: str) -> Judge:
    def judge_block(project: Project, text: str, m: Mutant) -> list[Proof]:
        tamper = _tamper(m.apply(text), m.pou)
        if kind == "monitor":
            return prove_monitor(project, text, m.pou.split("_Mon_", 1)[1], tamper, True)
        if kind == "diagnoser":
            return prove_diagnoser(project, text, m.pou.split("_Diag_", 1)[1], tamper, True)
        if kind == "control":
            return prove_control(project, text, tamper, True)
        return prove_memory(project, text, tamper, True)
    return judge_block


def _program(project: Project, text: str, m: Mutant) -> list[Proof]:
    """prove_program on the mutant (tests/program_prove.py: the program against one engine
    scan, every block any function): proved, the mutant is equivalent; refuted, it hands
    some block another value, which that block may never read: not caught."""
    mutated = m.apply(text)
    return prove_program(project, text, lambda _original: _section(mutated, "PROGRAM", m.pou))


def block_of(pou: str) -> tuple[str, Judge]:
    """The proof that judges a mutant of `pou` (its name says what the exporter built it
    for; the program's: prove_program)."""
    if pou.startswith("PRG_"):
        return "prove_program", _program
    if pou.endswith("_Filter"):
        return "prove_filter", _filter
    for marker, kind in (("_Mon_", "monitor"), ("_Diag_", "diagnoser")):
        if marker in pou:
            return f"prove_{kind}", _block(kind)
    for suffix, kind in (("_Control", "control"), ("_Memory", "memory")):
        if pou.endswith(suffix):
            return f"prove_{kind}", _block(kind)
    raise KeyError(f"no block proof for {pou}")


def judge_survivor(name: str, project: Project, text: str, m: Mutant) -> Judged:
    """A mutant no trace caught: by its block's proof (a program's mutant only when proved
    equivalent), else by the lists."""
    proof_name, judge_block = block_of(m.pou)
    try:
        proofs = judge_block(project, text, m)
        unproved = next((p for p in proofs if not p.proved), None)
        said = "" if unproved is None else f"{proof_name}: {unproved.name}, {unproved.detail}"
    except (Unsupported, SyntaxError, RecursionError) as error:
        unproved, said = None, f"{proof_name}: cannot judge ({error})"
        proofs = []
    if proofs and unproved is None:
        return Judged(m, "equivalent", f"{proof_name}: proved")
    if (unproved is not None and "counterexample" in unproved.detail
            and proof_name != "prove_program"):
        return Judged(m, "refuted", said[:300])
    for outcome, listed in (("tested", CAUGHT_BY_TESTS), ("gap", GAPS),
                            ("listed", EQUIVALENT)):
        why = listed.get(name, {}).get(m.key())
        if why is not None:
            return Judged(m, outcome, why)
    return Judged(m, "unexplained", said[:300])


# --------------------------------------------------------------------------------------------
# The study
# --------------------------------------------------------------------------------------------


def chosen(found: Sequence[Mutant], per_diagnoser: int | None, seed: int,
           per_block: int | None = None) -> list[Mutant]:
    """Every mutant, or (`per_diagnoser`) a seeded sample of that many of each diagnoser
    FB's and every other one, or (`per_block`) of each POU's, in file order."""
    if per_diagnoser is None and per_block is None:
        return list(found)
    by_pou: dict[str, list[Mutant]] = {}
    for m in found:
        by_pou.setdefault(m.pou, []).append(m)
    out: list[Mutant] = []
    for pou, items in by_pou.items():
        k = per_block if per_block is not None else per_diagnoser if "_Diag_" in pou else None
        if k is not None and len(items) > k:
            items = random.Random(f"{seed} {pou}").sample(items, k)
        out += items
    return sorted(out, key=lambda m: m.start)


@dataclass(frozen=True)
class Choice:
    """Which mutants a run judges: all, or a seeded sample (`chosen`); only those of POUs
    whose name holds `only`; of those every n-th from the k-th (`shard`)."""

    per_diagnoser: int | None = None
    per_block: int | None = None
    seed: int = 0
    only: str | None = None
    shard: tuple[int, int] = (0, 1)

    def of(self, found: Sequence[Mutant]) -> list[Mutant]:
        picked = [m for m in chosen(found, self.per_diagnoser, self.seed, self.per_block)
                  if self.only is None or self.only in m.pou]
        k, n = self.shard
        return picked[k::n]


def study_digest(rec: Recording, traces: Sequence[Trace]) -> str:
    """What a logged verdict holds for: the exported text and the recorded traces (a
    verdict of another export, or on other traces, is not taken)."""
    h = hashlib.sha256(rec.text.encode())
    for t in traces:
        h.update(repr((t.name, t.scans, t.values, sorted(t.skip.items()), t.manual,
                       t.fov)).encode())
    return h.hexdigest()[:16]


def _logged(log: Path | None, digest: str) -> dict[tuple[int, str], dict[str, Any]]:
    """The verdicts `log` already holds for this study, by (start, key)."""
    if log is None or not log.exists():
        return {}
    out: dict[tuple[int, str], dict[str, Any]] = {}
    for line in log.read_text().splitlines():
        try:
            v = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line cut short when a run was stopped
        if v.get("study") == digest:
            out[(v["start"], v["key"])] = v
    return out


def _log(log: Path | None, digest: str, j: Judged) -> None:
    if log is None:
        return
    line = json.dumps({"study": digest, "start": j.mutant.start, "key": j.mutant.key(),
                       "outcome": j.outcome, "how": j.how, "cpu_s": round(j.cpu_s, 3)})
    with log.open("a") as f:  # one short line per write: appends from several processes
        f.write(line + "\n")


def run_study(name: str, runs: Sequence[Run] | None = None,
              progress: Callable[[Judged], Any] | None = None,
              choice: Choice = Choice(), log: Path | None = None) -> Study:
    """Record `name`'s traces (its study runs by default), judge its mutants (all, or those
    `choice` picks), each survivor by its block's proof or the lists. With a `log`, each
    verdict is appended to it as it is reached, and those it already holds for the same
    export and traces are taken from it (but for a survivor listed or unexplained, judged
    again: the lists may have changed): a long study goes on where a stopped one ended.
    The CPU time is the recording's and each verdict's (a logged one's as logged)."""
    start = time.process_time()
    project = load_project(PROJECTS / name)
    rec, traces = record(name, study_runs(name) if runs is None else runs)
    found = mutants(rec.text)
    digest = study_digest(rec, traces)
    done = _logged(log, digest)
    study = Study(name, len(found), traces=len(traces),
                  scans=sum(len(t.scans) for t in traces))
    recording = time.process_time() - start
    with builds_kept():
        for m in choice.of(found):
            v = done.get((m.start, m.key()))
            if v is not None and v["outcome"] not in LISTED:
                study.judged.append(Judged(m, v["outcome"], v["how"], v["cpu_s"]))
                continue
            began = time.process_time()
            judged = judge_mutant(name, project, rec, traces, m)
            study.judged.append(replace(judged, cpu_s=time.process_time() - began))
            _log(log, digest, study.judged[-1])
            if progress is not None:
                progress(study.judged[-1])
    study.cpu_s = recording + sum(j.cpu_s for j in study.judged)
    return study


def _shard(name: str, choice: Choice, log: Path | None) -> Study:
    k, n = choice.shard
    return run_study(name, progress=_progress(f"{name} {k + 1}/{n}"), choice=choice, log=log)


def run_parallel(name: str, jobs: int, choice: Choice = Choice(),
                 log: Path | None = None) -> Study:
    """`run_study` split over `jobs` processes (each records the traces itself and judges
    every `jobs`-th mutant): the same mutants judged the same way, in file order, on a
    machine with more than one core; the CPU time is the processes' sum."""
    spawn = multiprocessing.get_context("spawn")
    shards = [replace(choice, shard=(k, jobs)) for k in range(jobs)]
    with ProcessPoolExecutor(jobs, mp_context=spawn) as pool:
        parts = list(pool.map(_shard, [name] * jobs, shards, [log] * jobs))
    study = Study(name, parts[0].found, traces=parts[0].traces, scans=parts[0].scans,
                  cpu_s=sum(p.cpu_s for p in parts))
    study.judged = sorted((j for p in parts for j in p.judged), key=lambda j: j.mutant.start)
    return study


def judge_mutant(name: str, project: Project, rec: Recording, traces: Sequence[Trace],
                 m: Mutant) -> Judged:
    verdict = judge(rec, traces, m)
    if verdict.outcome != "survived":
        return Judged(m, verdict.outcome, verdict.why)
    return judge_survivor(name, project, rec.text, m)


def _progress(name: str) -> Callable[[Judged], None]:
    """A line on stderr every 100 mutants judged, and at each unexplained survivor."""
    done = [0]

    def progress(j: Judged) -> None:
        done[0] += 1
        if j.outcome == "unexplained" or done[0] % 100 == 0:
            print(f"{name}: {done[0]} judged, {time.process_time():.0f} s CPU"
                  + (f"; unexplained: {j.mutant.describe()} ({j.how})"
                     if j.outcome == "unexplained" else ""), file=sys.stderr, flush=True)
    return progress


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.mutant_study")
    parser.add_argument("projects", nargs="*", metavar="PROJECT")
    parser.add_argument("--sample", type=int, metavar="N")
    parser.add_argument("--per-block", type=int, metavar="N")
    parser.add_argument("--only", metavar="TEXT")
    parser.add_argument("--jobs", type=int, default=1, metavar="N")
    parser.add_argument("--log", type=Path, metavar="FILE")
    args = parser.parse_args(argv)
    choice = Choice(args.sample, args.per_block, only=args.only)
    for name in args.projects or [p.name for p in sorted(PROJECTS.iterdir()) if p.is_dir()]:
        study = (run_study(name, progress=_progress(name), choice=choice, log=args.log)
                 if args.jobs == 1 else run_parallel(name, args.jobs, choice, args.log))
        print(study.report(), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
