"""``plchmi``'s entry point: the argument parser made of each command module's part, the
dispatch to the command, and the exit status of every way a command can end (module
docstring of hmi/cli/__init__.py)."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from typing import Any

from hmi.cli.common import RunFailure, print_project_error
from hmi.errors import OutputError, ProjectError, UsageError

# Each command's module in hmi/cli/ and its function adding the command's options (a module
# adding several commands lists them all), in the order of ``plchmi --help``.
PARTS: tuple[tuple[tuple[str, ...], str, str], ...] = (
    (("check",), "check", "add_parser"),
    (("run",), "run", "add_parser"),
    (("diagnose", "campaign"), "studies", "add_parsers"),
    (("band",), "band", "add_parser"),
    (("export",), "export", "add_parser"),
    (("journal",), "journal", "add_parser"),
    (("journal-verify",), "journal", "add_verify_parser"),
    (("history",), "history", "add_parser"),
    (("sweep",), "studies", "add_sweep_parser"),
    (("soak",), "soak", "add_parser"),
    (("bench",), "bench", "add_parser"),
    (("ui",), "ui", "add_parser"),
    (("serve", "attach"), "cell", "add_parsers"),
    (("gateway",), "gateway", "add_parser"),
    (("web",), "web", "add_parser"),
    (("opcua", "serve-plant"), "serve", "add_parsers"),
    (("users",), "users", "add_parser"),
)
SUBCOMMANDS = ("check", "run", "sweep", "ui", "serve", "attach", "gateway", "web",
               "serve-plant", "bench", "journal", "diagnose", "campaign", "band", "export",
               "opcua", "soak", "history", "users", "journal-verify")

# command -> (its module, its function)
COMMANDS = {
    "check": ("check", "cmd_check"), "run": ("run", "cmd_run"),
    "sweep": ("studies", "cmd_sweep"), "ui": ("ui", "cmd_ui"),
    "serve": ("cell", "cmd_serve"), "attach": ("cell", "cmd_attach"),
    "gateway": ("gateway", "cmd_gateway"),
    "web": ("web", "cmd_web"),
    "serve-plant": ("serve", "cmd_serve_plant"), "bench": ("bench", "cmd_bench"),
    "journal": ("journal", "cmd_journal"),
    "journal-verify": ("journal", "cmd_verify"), "history": ("history", "cmd_history"),
    "diagnose": ("studies", "cmd_diagnose"), "band": ("band", "cmd_band"),
    "campaign": ("studies", "cmd_campaign"), "export": ("export", "cmd_export"),
    "opcua": ("serve", "cmd_opcua"), "soak": ("soak", "cmd_soak"),
    "users": ("users", "cmd_users"),
}


def _part(module: str, function: str) -> Callable[..., Any]:
    """A function of a command's module, imported when wanted (a command imports its own
    module only)."""
    part: Callable[..., Any] = getattr(importlib.import_module(f"hmi.cli.{module}"), function)
    return part


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Every command's options, the commands listed in the order of ``plchmi --help``; or
    `command`'s alone, for running it: its usage, help and errors are the same, and the
    other commands' modules are not imported (the HMI's start, docs/performance.md)."""
    top = argparse.ArgumentParser(
        prog="plchmi",
        description="Operator HMI and soft-PLC runtime with a safety control filter. "
        "'plchmi PROJECT' opens the HMI.")
    sub = top.add_subparsers(dest="command", metavar="COMMAND")
    for names, module, function in PARTS:
        if command is None or command in names:
            _part(module, function)(sub)
    return top


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] not in SUBCOMMANDS and not args_list[0].startswith("-"):
        args_list.insert(0, "ui")
    if args_list[:2] == ["journal", "verify"] and len(args_list) > 2:
        args_list[:2] = ["journal-verify"]  # plchmi journal verify PROJECT
    if not args_list:
        build_parser().print_help()
        return 2
    # a command named: only its options (each command's own usage and errors); anything
    # else (--help, a bad option) is said by the whole parser
    parser = build_parser(args_list[0] if args_list[0] in SUBCOMMANDS else None)
    args = parser.parse_args(args_list)
    try:
        if args.command in COMMANDS:
            status: int = _part(*COMMANDS[args.command])(args)
            return status
    except ProjectError as exc:
        print_project_error(exc)
        return 2
    except UsageError as exc:
        print(f"plchmi: error: {exc}", file=sys.stderr)
        return 2
    except RunFailure as exc:
        print(f"plchmi: error: {exc}", file=sys.stderr)
        return 1
    except OutputError as exc:  # a trace or journal that cannot be opened
        print(f"plchmi: error: {exc}", file=sys.stderr)
        return 2 if exc.bad_path else 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader went away (plchmi ... | head): not an error; silence the final flush.
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except Exception as exc:  # a bug: say so plainly, keep the details for the developers
        from hmi.crash import write_crash_report
        report = write_crash_report(exc)
        print(f"plchmi: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        print(f"plchmi: the details are in {report}; please report it", file=sys.stderr)
        return 1
    parser.print_help()
    return 2
