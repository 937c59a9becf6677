"""Renaming the variables of an expression: a component's names become an instance's
(`fsc` -> `fsc1`), in the tree the engine compiles and in the source text reports show."""

from __future__ import annotations

import ast
from dataclasses import replace

from hmi.logic.expr import And, Compare, Node, Not, Or, Var


def rename_node(node: Node, renames: dict[str, str]) -> Node:
    """A copy of the tree with every variable renamed (names not in `renames` kept)."""
    if isinstance(node, Var):
        return replace(node, name=renames.get(node.name, node.name))
    if isinstance(node, Not):
        return replace(node, operand=rename_node(node.operand, renames))
    if isinstance(node, (And, Or)):
        return replace(node, operands=tuple(rename_node(op, renames) for op in node.operands))
    if isinstance(node, Compare):
        return replace(node, left=rename_node(node.left, renames),
                       right=rename_node(node.right, renames))
    return node


def renamed_source(source: str, renames: dict[str, str]) -> str | None:
    """`source` with each identifier in `renames` replaced, located by Python's parser.

    Only whole identifiers (ast.Name nodes) are replaced, never parts of a word. None if the
    text does not parse as Python (it then holds durations: the caller renders the tree).
    """
    try:
        tree = ast.parse(source, mode="eval")
    except SyntaxError:
        return None
    data = source.encode("utf-8")  # ast offsets count UTF-8 bytes
    spans = sorted(((n.col_offset, n.end_col_offset or n.col_offset, renames[n.id])
                    for n in ast.walk(tree) if isinstance(n, ast.Name) and n.id in renames),
                   reverse=True)
    for start, end, name in spans:
        data = data[:start] + name.encode("utf-8") + data[end:]
    return data.decode("utf-8")
