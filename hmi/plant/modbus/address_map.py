"""The project's Modbus address map, and the requests one scan needs.

Shared by the client plant (which reads inputs and writes outputs) and by `serve-plant`
(which serves the simulated plant at the same addresses), so both sides always agree.

A scan reads each table in as few requests as possible: the addresses it needs are sorted and
grouped into ranges, bridging gaps of up to `read_gap` unused addresses (one request for
`di:0` and `di:5` rather than two), and never longer than the protocol allows in one request.
Outputs are written as runs of consecutive coils (one Write Multiple Coils each; a gap is
never bridged, because the coils in it belong to someone else) and, for holding-register
bits, one Mask Write Register per register, which changes only our bits of it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from hmi.errors import Diagnostic
from hmi.plant.modbus.frame import MAX_READ_BITS, MAX_READ_REGISTERS, MAX_WRITE_COILS
from hmi.project.model import PlantAddress, Project, Variable

BIT_TABLES = ("coil", "di")
REGISTER_TABLES = ("hr", "ir")
# Modbus application protocol v1.1b3: the most one request may read.
MAX_READ = {"coil": MAX_READ_BITS, "di": MAX_READ_BITS, "hr": MAX_READ_REGISTERS,
            "ir": MAX_READ_REGISTERS}
TABLE_WORDS = {"coil": "coils", "di": "discrete inputs", "hr": "holding registers",
               "ir": "input registers"}


@dataclass(frozen=True)
class Point:
    """One project variable at one Modbus address."""

    name: str
    kind: str  # "input" or "output"
    address: PlantAddress


@dataclass(frozen=True)
class ReadRange:
    """One read request: `count` consecutive addresses of a table from `start`."""

    table: str
    start: int
    count: int
    points: tuple[Point, ...]

    def __str__(self) -> str:
        last = self.start + self.count - 1
        where = f"{self.start}" if last == self.start else f"{self.start}-{last}"
        return f"{TABLE_WORDS[self.table]} {where}"


@dataclass(frozen=True)
class CoilRun:
    """One Write Multiple Coils request: outputs on consecutive coils from `start`."""

    start: int
    names: tuple[str, ...]

    def __str__(self) -> str:
        last = self.start + len(self.names) - 1
        return f"coils {self.start}" + (f"-{last}" if last != self.start else "")


@dataclass(frozen=True)
class RegisterBits:
    """One Mask Write Register request: output bits of one holding register."""

    index: int
    bits: tuple[tuple[str, int], ...]  # (output name, bit number)

    def masks(self, values: Mapping[str, bool]) -> tuple[int, int]:
        """(and_mask, or_mask) of FC 22: keep the register's other bits, set ours."""
        ours = 0
        on = 0
        for name, bit in self.bits:
            ours |= 1 << bit
            if values[name]:
                on |= 1 << bit
        return 0xFFFF & ~ours, on

    def __str__(self) -> str:
        return f"holding register {self.index} bits " + ",".join(str(b) for _, b in self.bits)


class AddressMap:
    """Where every input and output of a project lives, and the requests of one scan.

    With `read_back`, the scan also reads the outputs' own addresses (read-only mode: the
    device's actual outputs are observed instead of written).
    """

    def __init__(self, points: Sequence[Point], read_gap: int = 8, read_back: bool = False):
        self.points = tuple(points)
        self.inputs = tuple(p for p in self.points if p.kind == "input")
        self.outputs = tuple(p for p in self.points if p.kind == "output")
        wanted = self.points if read_back else self.inputs
        self.reads = plan_reads(wanted, read_gap)
        coil_outputs = [p for p in self.outputs if p.address.table == "coil"]
        self.coil_runs = plan_coil_runs(coil_outputs)
        self.register_bits = plan_register_bits(
            [p for p in self.outputs if p.address.table == "hr"])

    @classmethod
    def for_project(cls, project: Project, read_gap: int = 8,
                    read_back: bool = False) -> AddressMap:
        missing = missing_addresses(project)
        if missing:
            raise ValueError(f"{len(missing)} variables have no plant address")
        points = [Point(v.name, v.kind, v.address) for v in (*project.inputs, *project.outputs)
                  if v.address is not None]
        return cls(points, read_gap, read_back)

    def decode(self, rng: ReadRange, values: Sequence[int] | Sequence[bool],
               into: dict[str, bool]) -> None:
        """Put the variables of one read's answer into `into` (bits, or register words)."""
        start = rng.start
        if rng.table in BIT_TABLES:
            for p in rng.points:
                into[p.name] = bool(values[p.address.index - start])
        else:
            for p in rng.points:
                word = int(values[p.address.index - start])
                into[p.name] = bool((word >> (p.address.bit or 0)) & 1)

    def table_sizes(self) -> dict[str, int]:
        """Addresses a server must hold per table: up to the highest one used."""
        sizes = dict.fromkeys(BIT_TABLES + REGISTER_TABLES, 0)
        for p in self.points:
            sizes[p.address.table] = max(sizes[p.address.table], p.address.index + 1)
        return sizes

    def describe(self) -> list[str]:
        """The requests of one scan, for `plchmi check` and the docs."""
        lines = [f"read {r} ({', '.join(p.name for p in r.points)})" for r in self.reads]
        lines += [f"write {c} ({', '.join(c.names)})" for c in self.coil_runs]
        lines += [f"write {r} ({', '.join(n for n, _ in r.bits)})" for r in self.register_bits]
        return lines


def plan_reads(points: Iterable[Point], read_gap: int) -> tuple[ReadRange, ...]:
    """Group addresses into read requests per table (see the module docstring)."""
    by_table: dict[str, dict[int, list[Point]]] = {}
    for p in points:
        by_table.setdefault(p.address.table, {}).setdefault(p.address.index, []).append(p)
    ranges: list[ReadRange] = []
    for table in (*BIT_TABLES, *REGISTER_TABLES):
        at = by_table.get(table)
        if not at:
            continue
        limit = MAX_READ[table]
        group: list[int] = []
        for index in sorted(at):
            if group and (index - group[-1] - 1 > read_gap or index - group[0] + 1 > limit):
                ranges.append(_range(table, group, at))
                group = []
            group.append(index)
        ranges.append(_range(table, group, at))
    return tuple(ranges)


def _range(table: str, indices: list[int], at: dict[int, list[Point]]) -> ReadRange:
    points = tuple(p for i in indices for p in at[i])
    return ReadRange(table, indices[0], indices[-1] - indices[0] + 1, points)


def plan_coil_runs(points: Iterable[Point]) -> tuple[CoilRun, ...]:
    runs: list[CoilRun] = []
    ordered = sorted(points, key=lambda p: p.address.index)
    start = -1
    names: list[str] = []
    for p in ordered:
        index = p.address.index
        if names and (index != start + len(names) or len(names) >= MAX_WRITE_COILS):
            runs.append(CoilRun(start, tuple(names)))
            names = []
        if not names:
            start = index
        names.append(p.name)
    if names:
        runs.append(CoilRun(start, tuple(names)))
    return tuple(runs)


def plan_register_bits(points: Iterable[Point]) -> tuple[RegisterBits, ...]:
    by_register: dict[int, list[tuple[str, int]]] = {}
    for p in points:
        by_register.setdefault(p.address.index, []).append((p.name, p.address.bit or 0))
    return tuple(RegisterBits(index, tuple(sorted(bits, key=lambda b: b[1])))
                 for index, bits in sorted(by_register.items()))


def missing_addresses(project: Project) -> list[Variable]:
    return [v for v in (*project.inputs, *project.outputs) if v.address is None]


def address_diagnostics(project: Project, why: str) -> list[Diagnostic]:
    """An error at each input or output that has no address, saying why one is needed."""
    return [Diagnostic(v.pos, f"{v.kind} {v.name!r} has no plant address; {why}",
                       "address: di:N or coil:N (or ir:N.B, hr:N.B)" if v.kind == "input"
                       else "address: coil:N or hr:N.B")
            for v in missing_addresses(project)]
