"""``plchmi bench SECTION``: measurements of the runtime, one section per concern.

Each section is a module with ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``;
add a line to :data:`SECTIONS` to add one (``plchmi bench ui`` is the HMI's).
"""

from __future__ import annotations

import argparse
from importlib import import_module

SECTIONS: dict[str, str] = {
    "ui": "hmi.bench.ui",
}


def add_parser(sub) -> argparse.ArgumentParser:
    """Add ``bench`` and its sections to the CLI's subparsers."""
    parser = sub.add_parser("bench", help="measure the runtime (scan jitter, UI refresh...)")
    sections = parser.add_subparsers(dest="section", metavar="SECTION", required=True)
    for name, module_name in SECTIONS.items():
        module = import_module(module_name)
        section = sections.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(section)
        section.set_defaults(bench_run=module.run)
    return parser


def run(args: argparse.Namespace) -> int:
    return args.bench_run(args)
