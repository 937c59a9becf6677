"""matiec (iec2c, the IEC 61131-3 compiler behind OpenPLC and Beremiz) as an independent PLC
for the export: the exported Structured Text compiled to C by iec2c, then by gcc with a small
driver, and run on the inputs of a recorded trace.

A peer, not a part of the product: the source of matiec is not in this repository. It is
looked for in ``$PLCHMI_MATIEC`` (a folder holding ``build.sh`` and the source tarball), else
in ``shared/tools/matiec`` beside the checkout or beside one of its parent folders (CI clones
the repository next to ``shared/``). It is built once, into the user's cache
(``$XDG_CACHE_HOME/plchmi``, else ``~/.cache/plchmi``), under a name that changes with the
source and the build script, and reused. :func:`compiler` says why when it cannot be had; the
tests then skip with that reason (pytest -rs shows it), never pass silently.

The driver reads one line per scan on standard input (the scan's time in microseconds, then
one integer per value written before the cycle: the inputs, the program's outputs FOV_x when
the control is the engine's, FaultReset, FilterPolicy, DiagnosisMode), sets them, runs the
configuration's task once, and prints one line of integers: every value probed after the
cycle (TIME in microseconds).
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BUILD_TIMEOUT_S = 600
SIGNED = {"BOOL", "SINT", "INT", "DINT", "LINT"}
UNSIGNED = {"BYTE", "WORD", "DWORD", "LWORD", "USINT", "UINT", "UDINT", "ULINT"}


class MatiecUnavailable(Exception):
    """matiec cannot be had here: the message says why (the tests' skip reason)."""


def source_folder() -> Path:
    """The folder with matiec's ``build.sh`` and source tarball, or MatiecUnavailable."""
    named = os.environ.get("PLCHMI_MATIEC")
    if named:
        folder = Path(named)
        if not (folder / "build.sh").is_file():
            raise MatiecUnavailable(f"PLCHMI_MATIEC={named} holds no build.sh")
        return folder
    for parent in (ROOT, *ROOT.parents):
        folder = parent / "shared" / "tools" / "matiec"
        if (folder / "build.sh").is_file():
            return folder
    raise MatiecUnavailable("matiec's source (shared/tools/matiec/build.sh) is neither beside "
                            f"{ROOT} nor beside a parent folder, and PLCHMI_MATIEC is not set")


def _cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "plchmi"


@dataclass(frozen=True)
class Compiler:
    """A built matiec: ``iec2c`` and its runtime library (``lib/C`` holds the headers)."""

    iec2c: Path
    lib: Path


def compiler() -> Compiler:
    """matiec, built once into the cache (under a lock: pytest's workers share it)."""
    folder = source_folder()
    digest = hashlib.sha256()
    for path in sorted(folder.iterdir()):
        if path.is_file():
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
    digest.update(ROUNDING.encode())  # (the correction below is part of the build)
    dest = _cache_root() / f"matiec-{digest.hexdigest()[:16]}"
    iec2c = dest / "iec2c"
    if not iec2c.exists():
        dest.parent.mkdir(parents=True, exist_ok=True)
        with open(dest.parent / f"{dest.name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not iec2c.exists():
                _build(folder, dest)
    return Compiler(iec2c, dest / "lib")


def _build(folder: Path, dest: Path) -> None:
    partial = dest.with_name(dest.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    try:
        done = subprocess.run(["bash", str(folder / "build.sh"), str(partial)],
                              capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise MatiecUnavailable(f"building matiec took over {BUILD_TIMEOUT_S} s") from None
    if done.returncode != 0 or not (partial / "iec2c").exists():
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        raise MatiecUnavailable(f"building matiec failed ({folder / 'build.sh'}): "
                                + " / ".join(tail))
    _round_time_literals(partial / "lib" / "C" / "iec_std_lib.h")
    partial.rename(dest)


ROUNDING = "+ (((sign>=0)?1:-1)*0.5)"


def _round_time_literals(header: Path) -> None:
    """matiec's TIME literals lose a nanosecond: ``__time_to_timespec`` (the macro iec2c
    writes for ``T#1s300ms``) truncates the fraction of a long double, so T#1s300ms is
    1.299999999 s and T#2s100ms 2.099999999 s. A sum that should reach a bound exactly then
    falls 1 ns short: the stopwatch's ``X + (Alpha - Y) >= Gamma`` judged a task one scan
    late (the sorting cell's faulty program, block policy, t = 8.5 s: x 2.7 s, alpha 1.3 s,
    y 1.0 s, gamma 3 s). The nanoseconds are rounded to the nearest instead (a literal of
    whole milliseconds is then exact): the runtime library's header is corrected in the
    cached build, as shared/tools/matiec/timespec.patch corrects its comparisons."""
    text = header.read_text()
    start = text.index("#define __time_to_timespec(")
    at = text.index(")*1e9))", start)
    header.write_text(text[:at] + f")*1e9 {ROUNDING}))" + text[at + len(")*1e9))"):])


@dataclass(frozen=True)
class Probe:
    """A value of the compiled program: ``CONFIG0.X`` (a global) or ``CONFIG0.RES0.P.A.B``
    (a variable inside program instance P), as iec2c's VARIABLES.csv names it."""

    path: str
    type: str


class CompileError(Exception):
    """iec2c or gcc refused the exported program (a bug of the export, or of matiec)."""


class CompiledPlc:
    """One exported program, compiled by iec2c and gcc, with a driver that writes `writes`
    before each cycle and prints `reads` after it."""

    def __init__(self, st_text: str, writes: Sequence[str], reads: Sequence[str],
                 program: str = "SAFETY"):
        self.writes = tuple(writes)
        self.reads = tuple(reads)
        tools = compiler()
        key = hashlib.sha256("\0".join((st_text, *self.writes, "|", *self.reads, program,
                                        str(tools.iec2c))).encode()).hexdigest()[:20]
        folder = _cache_root() / "matiec-programs" / key
        self.binary = folder / "plc"
        if self.binary.exists():
            return
        folder.parent.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=key, dir=folder.parent))
        try:
            (work / "program.st").write_text(st_text)
            _run([str(tools.iec2c), "-I", str(tools.lib), "-T", str(work),
                  str(work / "program.st")], "iec2c")
            types = _variables(work / "VARIABLES.csv")
            pou = _program_type(work / "VARIABLES.csv", program)
            (work / "driver.c").write_text(_driver(self.writes, self.reads, types, program,
                                                   pou))
            _run(["gcc", "-O1", "-w", "-I", str(tools.lib / "C"), "-I", str(work), "-o",
                  str(work / "plc"), str(work / "driver.c"), str(work / "Config0.c"),
                  str(work / "Res0.c")], "gcc")
            try:
                work.rename(folder)
            except OSError:  # another worker compiled the same program meanwhile
                if not self.binary.exists():
                    raise
        finally:
            shutil.rmtree(work, ignore_errors=True)

    def run(self, rows: Sequence[Sequence[int]]) -> list[tuple[int, ...]]:
        """The values read after each cycle, one tuple per row of values written."""
        text = "".join(" ".join(str(int(v)) for v in row) + "\n" for row in rows)
        done = subprocess.run([str(self.binary)], input=text, capture_output=True, text=True,
                              timeout=600)
        if done.returncode != 0:
            raise RuntimeError(f"the compiled program exited {done.returncode}: "
                               f"{done.stderr[-500:]}")
        out = [tuple(map(int, line.split())) for line in done.stdout.splitlines()]
        if len(out) != len(rows):
            raise RuntimeError(f"{len(rows)} scans given, {len(out)} answered")
        return out


def _run(argv: list[str], what: str) -> None:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise CompileError(f"{what} refused the program:\n{done.stdout}{done.stderr}"[-4000:])


def _variables(csv: Path) -> dict[str, str]:
    """Each variable's path and elementary type (VARIABLES.csv: num;kind;path;path;type;...)."""
    types = {}
    for line in csv.read_text().splitlines():
        parts = line.split(";")
        if len(parts) >= 5 and parts[0].isdigit():
            types[parts[2].upper()] = parts[4].upper()
    return types


def _program_type(csv: Path, program: str) -> str:
    for line in csv.read_text().splitlines():
        parts = line.split(";")
        if len(parts) >= 3 and parts[1].upper() == f"CONFIG0.RES0.{program}":
            return parts[2].upper()
    raise CompileError(f"no program instance {program} in the configuration")


_PATH = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*\Z")


def _c_access(path: str, program: str) -> str:
    """`path` (``X`` a global, ``P.A.B`` inside program instance P) as a C lvalue."""
    if not _PATH.match(path):
        raise ValueError(f"not a variable path: {path!r}")
    parts = path.upper().split(".")
    if len(parts) == 1:
        return f"(*__GET_GLOBAL_{parts[0]}())"
    if parts[0] != program:
        raise ValueError(f"{path!r} is not inside program instance {program}")
    return f"RES0__{program}." + ".".join(parts[1:]) + ".value"


def _full(path: str, program: str) -> str:
    parts = path.upper().split(".")
    return "CONFIG0." + (parts[0] if len(parts) == 1 else "RES0." + ".".join(parts))


def _driver(writes: Sequence[str], reads: Sequence[str], types: dict[str, str], program: str,
            pou: str) -> str:
    def type_of(path: str) -> str:
        found = types.get(_full(path, program))
        if found is None:
            raise CompileError(f"{path} is not a variable of the compiled program")
        return found

    lines = [
        "#include <stdio.h>",
        '#include "iec_std_lib.h"',
        '#include "accessor.h"',
        '#include "POUS.h"',
        '#include "Config0.h"',
        "#define __LOCATED_VAR(type, name, ...) type __##name; type *name = &__##name;",
        '#include "LOCATED_VARIABLES.h"',
        "#undef __LOCATED_VAR",
        "TIME __CURRENT_TIME;",
        "BOOL __DEBUG;",
        f"extern {pou} RES0__{program};",
        "void config_init__(void);",
        "void config_run__(unsigned long tick);",
        "static long long us(TIME t) {",
        "    return (long long)t.tv_sec * 1000000LL + (long long)t.tv_nsec / 1000LL; }",
        "int main(void) {",
        "    unsigned long tick = 0;",
        f"    long long in[{len(writes) + 1}];",
        "    config_init__();",
        "    for (;;) {",
        f"        for (int k = 0; k < {len(writes) + 1}; k++)",
        '            if (scanf("%lld", &in[k]) != 1) return 0;',
        "        __CURRENT_TIME.tv_sec = in[0] / 1000000LL;",
        "        __CURRENT_TIME.tv_nsec = (in[0] % 1000000LL) * 1000LL;",
    ]
    for k, path in enumerate(writes, start=1):
        kind = type_of(path)
        if kind not in SIGNED | UNSIGNED:
            raise CompileError(f"{path} is a {kind}: the driver writes integers and BOOLs")
        lines.append(f"        {_c_access(path, program)} = ({kind})in[{k}];")
    lines.append("        config_run__(tick++);")
    formats, values = [], []
    for path in reads:
        kind = type_of(path)
        access = _c_access(path, program)
        if kind == "TIME":
            formats.append("%lld")
            values.append(f"us({access})")
        elif kind in SIGNED:
            formats.append("%lld")
            values.append(f"(long long)({access})")
        elif kind in UNSIGNED:
            formats.append("%llu")
            values.append(f"(unsigned long long)({access})")
        else:
            raise CompileError(f"{path} is a {kind}: the driver prints elementary values")
    lines.append(f'        printf("{" ".join(formats)}\\n"' + "".join(f", {v}" for v in values)
                 + ");")
    lines += ["    }", "}"]
    return "\n".join(lines) + "\n"
