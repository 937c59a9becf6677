"""The PLC model as IEC 61131-3 Structured Text: one file, the POUs then the configuration.

The file is a complete IEC 61131-3 program (OpenPLC's runtime takes it as it is). The POU
text is also what the PLCopen XML writer embeds, through :func:`body_text` and
:func:`expr_text`, so both targets carry the very same code.
"""

from __future__ import annotations

import unicodedata

from hmi.export import model as m

INDENT = "    "
WIDTH = 100

# Binding strength (higher binds tighter), IEC 61131-3 table 55.
STRENGTH = {"OR": 1, "XOR": 2, "AND": 3, "=": 4, "<>": 4, "<": 5, "<=": 5, ">": 5, ">=": 5,
            "+": 6, "-": 6, "*": 7}
UNARY = 8
ATOM = 10
KEYWORDS = {"input": "VAR_INPUT", "output": "VAR_OUTPUT", "inout": "VAR_IN_OUT",
            "external": "VAR_EXTERNAL", "local": "VAR", "global": "VAR_GLOBAL"}
POU_WORDS = {"functionBlock": "FUNCTION_BLOCK", "program": "PROGRAM"}


ASCII = {"§": "s.", "°": " deg", "×": "x", "–": "-", "—": "-", "≈": "~", "≥": ">=",
         "≤": "<=", "→": "->", "’": "'", "“": '"', "”": '"', "…": "...", "α": "alpha", "β": "beta",
         "γ": "gamma", "δ": "delta", "Π": "Pi", "✗": "x", "✓": "v"}


def ascii_text(text: str) -> str:
    """Comments in plain ASCII: not every PLC editor reads UTF-8 source."""
    for char, repl in ASCII.items():
        text = text.replace(char, repl)
    text = unicodedata.normalize("NFKD", text)
    return text.encode("ascii", "ignore").decode("ascii")


def comment(text: str) -> str:
    """`(* text *)`, with anything that would end or open a comment defused."""
    text = ascii_text(text).replace("(*", "( *").replace("*)", "* )")
    return f"(* {text} *)"


def time_text(ms: int) -> str:
    if ms == 0:
        return "T#0ms"
    parts = []
    for unit, size in (("d", 86_400_000), ("h", 3_600_000), ("m", 60_000), ("s", 1000),
                       ("ms", 1)):
        if ms >= size:
            parts.append(f"{ms // size}{unit}")
            ms %= size
    return "T#" + "".join(parts)


def type_text(t: m.PlcType) -> str:
    if isinstance(t, m.Array):
        return f"ARRAY[{t.lower}..{t.upper}] OF {t.element.name}"
    return t.name


def expr_text(e: m.Expr) -> str:
    return _expr(e)


def _strength(e: m.Expr) -> int:
    if isinstance(e, m.Binary):
        return STRENGTH[e.op]
    if isinstance(e, m.Unary):
        return UNARY
    return ATOM


def _expr(e: m.Expr) -> str:
    match e:
        case m.Name(id=ident):
            return ident
        case m.Member(base=base, member=member):
            return f"{_expr(base)}.{member}"
        case m.Index(base=base, index=index):
            return f"{_expr(base)}[{_expr(index)}]"
        case m.BoolLit(value=value):
            return "TRUE" if value else "FALSE"
        case m.IntLit(value=value):
            return str(value)
        case m.TimeLit(ms=ms):
            return time_text(ms)
        case m.BitsLit(value=value, type=type_):
            return f"{type_}#16#{value:X}"
        case m.Unary(op=op, operand=operand):
            inner = _expr(operand)
            if _strength(operand) < ATOM:
                inner = f"({inner})"
            return f"NOT {inner}" if op == "NOT" else f"-{inner}"
        case m.Binary(op=op, left=left, right=right):
            return f"{_side(op, left, False)} {op} {_side(op, right, True)}"
        case m.Call(func=func, args=args):
            return f"{func}({', '.join(_expr(a) for a in args)})"
    raise TypeError(e)


def _side(op: str, child: m.Expr, right: bool) -> str:
    """A Binary's operand, in parentheses unless it obviously needs none.

    Precedence alone would allow `a AND b OR c` and `x AND y = z`; the writer brackets every
    operand that is itself a different operation, so a reader never has to know table 55.
    """
    text = _expr(child)
    if not isinstance(child, m.Binary):
        return text
    same_chain = child.op == op and op in ("AND", "OR", "XOR", "+", "*") and not right
    if same_chain or (child.op == op and op in ("AND", "OR", "XOR")):
        return text
    return f"({text})"


def body_text(stmts: tuple[m.Stmt, ...], depth: int = 0) -> list[str]:
    lines: list[str] = []
    for s in stmts:
        lines += _stmt(s, depth)
    return lines


def _block(stmts: tuple[m.Stmt, ...], depth: int) -> list[str]:
    lines = body_text(stmts, depth)
    if not any(not isinstance(s, m.Comment) for s in stmts):
        lines.append(INDENT * depth + ";")  # an empty statement keeps the branch legal
    return lines


def _else(orelse: tuple[m.Stmt, ...], depth: int) -> list[str]:
    return [INDENT * depth + "ELSE", *_block(orelse, depth + 1)] if orelse else []


def _stmt(s: m.Stmt, depth: int) -> list[str]:
    pad = INDENT * depth
    match s:
        case m.Comment(text=text):
            return [pad + comment(text)]
        case m.Assign(target=target, value=value):
            return [f"{pad}{_expr(target)} := {_expr(value)};"]
        case m.Exit():
            return [f"{pad}EXIT;"]
        case m.FbCall(instance=inst, inputs=inputs):
            args = [f"{name} := {_expr(value)}" for name, value in inputs]
            one = f"{pad}{inst}({', '.join(args)});"
            if len(one) <= WIDTH or len(args) < 2:
                return [one]
            head = f"{pad}{inst}("
            lines = [head + args[0] + ","]
            lines += [" " * len(head) + a + "," for a in args[1:-1]]
            lines.append(" " * len(head) + args[-1] + ");")
            return lines
        case m.If(branches=branches, orelse=orelse):
            lines = []
            for k, (cond, then) in enumerate(branches):
                lines.append(f"{pad}{'IF' if k == 0 else 'ELSIF'} {_expr(cond)} THEN")
                lines += _block(then, depth + 1)
            return lines + _else(orelse, depth) + [f"{pad}END_IF;"]
        case m.Case(selector=sel, cases=cases, orelse=orelse):
            lines = [f"{pad}CASE {_expr(sel)} OF"]
            for labels, then in cases:
                lines.append(f"{pad}{INDENT}{', '.join(str(v) for v in labels)}:")
                lines += _block(then, depth + 2)
            return lines + _else(orelse, depth) + [f"{pad}END_CASE;"]
        case m.For(var=var, start=start, end=end, body=body, step=step):
            by = f" BY {step}" if step != 1 else ""
            head = f"{pad}FOR {var} := {_expr(start)} TO {_expr(end)}{by} DO"
            return [head, *_block(body, depth + 1), f"{pad}END_FOR;"]
        case m.While(cond=cond, body=body):
            return [f"{pad}WHILE {_expr(cond)} DO", *_block(body, depth + 1),
                    f"{pad}END_WHILE;"]
    raise TypeError(s)


def var_line(v: m.Var) -> str:
    at = f" AT {v.address}" if v.address else ""
    init = ""
    if isinstance(v.initial, m.ArrayInit):
        init = " := [" + ", ".join(_expr(x) for x in v.initial.values) + "]"
    elif v.initial is not None:
        init = f" := {_expr(v.initial)}"
    note = f" {comment(v.comment)}" if v.comment else ""
    return f"{v.name}{at} : {type_text(v.type)}{init};{note}"


def blocks_text(blocks: tuple[m.VarBlock, ...], depth: int = 0) -> list[str]:
    pad = INDENT * depth
    lines = []
    for b in blocks:
        if not b.vars:
            continue
        lines.append(pad + KEYWORDS[b.section] + (" CONSTANT" if b.constant else ""))
        lines += [pad + INDENT + var_line(v) for v in b.vars]
        lines.append(pad + "END_VAR")
    return lines


def pou_text(p: m.Pou) -> list[str]:
    word = POU_WORDS[p.kind]
    lines = [f"{word} {p.name}"]
    lines += [comment(line) for line in p.comment.splitlines()]
    lines += blocks_text(p.blocks)
    lines += body_text(p.body)
    lines.append(f"END_{word}")
    return lines


def configuration_text(c: m.Configuration) -> list[str]:
    lines = [f"CONFIGURATION {c.name}"]
    lines += blocks_text(c.globals, 1)
    lines.append(f"{INDENT}RESOURCE {c.resource} ON PLC")
    for t in c.tasks:
        lines.append(f"{INDENT * 2}TASK {t.name}(INTERVAL := {time_text(t.interval_ms)}, "
                     f"PRIORITY := {t.priority});")
    for i in c.instances:
        lines.append(f"{INDENT * 2}PROGRAM {i.name} WITH {i.task} : {i.program};")
    lines.append(f"{INDENT}END_RESOURCE")
    lines.append("END_CONFIGURATION")
    return lines


def write_st(project: m.PlcProject) -> str:
    lines = [comment(line) for line in project.comment.splitlines()]
    for p in project.pous:
        lines.append("")
        lines += pou_text(p)
    lines.append("")
    lines += configuration_text(project.configuration)
    return "\n".join(lines) + "\n"
