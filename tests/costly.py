"""Projects under every limit that cost as much as a project may: the generators behind the
bounds of docs/project-format.md ("What a project may cost") and their tests.

    python -m tests.costly KIND FOLDER [COUNT]

writes one (kinds: `monomials`, `aliased`, `short`, `combined`, `flood`) for measuring by
hand, e.g. `/usr/bin/time -v plchmi check FOLDER`.
"""

from __future__ import annotations

import random
import sys
from pathlib import Path

from hmi.limits import MAX_CONSTRAINTS, MAX_EXPR_CHARS, MAX_TOTAL_EXPR_CHARS


def head(inputs: int, outputs: int, name: str = "costly", policy: str = "correct") -> str:
    text = f"name: {name}\nscan_period: 10ms\npolicy: {policy}\ninputs:\n"
    text += "".join(f"  i{k}: input {k}\n" for k in range(inputs))
    text += "outputs:\n" + "".join(f"  Y{k}: output {k}\n" for k in range(outputs))
    text += "control:\n  equations:\n    Y0: i0\n"
    text += "plant:\n  kind: sim\n  model: valve\n  ports: {fsc: i0, fso: i1, C: Y0, O: Y1}\n"
    return text


def monomial(inputs: int, outputs: int, seed: int, chars: int = MAX_EXPR_CHARS) -> str:
    """One output and as many literals on inputs (then their previous values) as fit."""
    parts = [f"Y{seed % outputs}"]
    k = 0
    while True:
        name = f"i{k % inputs}" if k < inputs else f"prev(i{k % inputs}, {1 + k // inputs})"
        literal = ("not " if (k + seed) % 3 == 0 else "") + name
        if len(" and ".join([*parts, literal])) > chars:
            return " and ".join(parts)
        parts.append(literal)
        k += 1


def monomials(count: int = MAX_TOTAL_EXPR_CHARS // MAX_EXPR_CHARS, inputs: int = 200,
              outputs: int = 24) -> str:
    """`count` constraints of MAX_EXPR_CHARS characters each (the most literals)."""
    return head(inputs, outputs) + "constraints:\n" + "".join(
        f"  K{i}: '{monomial(inputs, outputs, i)}'\n" for i in range(count))


def aliased(count: int = MAX_CONSTRAINTS, inputs: int = 200, outputs: int = 24) -> str:
    """`count` constraints, each a YAML alias of one longest monomial: a small file."""
    return (head(inputs, outputs) + f"constraints:\n  K0: &m '{monomial(inputs, outputs, 0)}'\n"
            + "".join(f"  K{i}: *m\n" for i in range(1, count)))


def short(count: int = MAX_CONSTRAINTS, inputs: int = 16, outputs: int = 24) -> str:
    """The most constraints, each as short a combined one as reads three outputs."""
    rng = random.Random(count)
    lines = []
    for i in range(count):
        ys = rng.sample(range(outputs), 3)
        lits = [("not " if rng.random() < 0.5 else "") + f"Y{y}" for y in ys]
        lits.append(("not " if rng.random() < 0.5 else "") + f"i{rng.randrange(inputs)}")
        lines.append(f"  K{i}: {' and '.join(lits)}\n")
    return head(inputs, outputs) + "constraints:\n" + "".join(lines)


def combined(count: int = 2000, inputs: int = 16, outputs: int = 24) -> str:
    """Combined constraints of two outputs, each in a context of two inputs: many active at
    once, each situation a different problem for the corrector."""
    rng = random.Random(count)
    lines = []
    for i in range(count):
        a, b = rng.sample(range(outputs), 2)
        ctx = rng.sample(range(inputs), 2)
        lits = [f"Y{a}", f"not Y{b}"] + [("not " if rng.random() < 0.5 else "") + f"i{c}"
                                        for c in ctx]
        lines.append(f"  K{i}: {' and '.join(lits)}\n")
    return head(inputs, outputs) + "constraints:\n" + "".join(lines)




def opposed(count: int = MAX_CONSTRAINTS, inputs: int = 16, outputs: int = 24) -> str:
    """Simple constraints, half forcing Y0 to 0 and half to 1 in contexts of one input:
    every pair of them is a conflict to compare (count² / 4 pairs)."""
    lines = [f"  K{i}: {'' if i % 2 else 'not '}Y0 and {'not ' if i // 2 % 2 else ''}"
             f"i{i // 4 % inputs}\n" for i in range(count)]
    return head(inputs, outputs) + "constraints:\n" + "".join(lines)


def flood(count: int = 3000, bits: int = 13, outputs: int = 24) -> str:
    """Combined constraints whose contexts follow a `bits`-bit counter made of observers:
    the program asks for every output on, so hundreds are violated at each scan and the
    set of active constraints is a new one at each scan for 2**bits scans (an alarm flood,
    and as many active sets for the filter to prepare)."""
    text = head(2, outputs).replace("    Y0: i0\n", "".join(f"    Y{k}: True\n"
                                                          for k in range(outputs)))
    text += "observers:\n  b0: not prev(b0)\n"
    for k in range(1, bits):
        carry = " and ".join(f"prev(b{j})" for j in range(k))
        text += (f"  b{k}: (prev(b{k}) and not ({carry})) or (not prev(b{k}) and {carry})\n")
    rng = random.Random(count)
    lines = []
    for i in range(count):
        a, b, c = rng.sample(range(outputs), 3)
        ctx = [("not " if rng.random() < 0.5 else "") + f"b{j}"
               for j in rng.sample(range(bits), 3)]
        lines.append(f"  K{i}: Y{a} and Y{b} and Y{c} and {' and '.join(ctx)}\n")
    return text + "constraints:\n" + "".join(lines)


KINDS = {"monomials": monomials, "aliased": aliased, "short": short, "combined": combined,
         "opposed": opposed, "flood": flood}


def write(kind: str, folder: Path, count: int | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    make = KINDS[kind]
    (folder / "project.yaml").write_text(make(count) if count else make(), encoding="utf-8")
    return folder


if __name__ == "__main__":
    where = write(sys.argv[1], Path(sys.argv[2]), int(sys.argv[3]) if len(sys.argv) > 3 else None)
    print(where / "project.yaml", (where / "project.yaml").stat().st_size, "bytes")

