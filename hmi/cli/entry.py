"""``plchmi``'s entry point: the argument parser made of each command module's part, the
dispatch to the command, and the exit status of every way a command can end (module
docstring of hmi/cli/__init__.py)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from hmi.cli import bench, check, export, journal, run, serve, soak, studies, ui
from hmi.cli.common import RunFailure, print_project_error
from hmi.errors import OutputError, ProjectError, UsageError

SUBCOMMANDS = ("check", "run", "sweep", "ui", "serve-plant", "bench", "journal",
               "diagnose", "campaign", "export", "opcua-passwd", "soak")


COMMANDS = {
    "check": check.cmd_check, "run": run.cmd_run, "sweep": studies.cmd_sweep,
    "ui": ui.cmd_ui, "serve-plant": serve.cmd_serve_plant, "bench": bench.cmd_bench,
    "journal": journal.cmd_journal, "diagnose": studies.cmd_diagnose,
    "campaign": studies.cmd_campaign, "export": export.cmd_export,
    "opcua-passwd": serve.cmd_opcua_passwd, "soak": soak.cmd_soak,
}


def build_parser() -> argparse.ArgumentParser:
    """Every command's options, the commands listed in the order of ``plchmi --help``."""
    top = argparse.ArgumentParser(
        prog="plchmi",
        description="Operator HMI and soft-PLC runtime with a safety control filter. "
        "'plchmi PROJECT' opens the HMI.")
    sub = top.add_subparsers(dest="command", metavar="COMMAND")
    check.add_parser(sub)
    run.add_parser(sub)
    studies.add_parsers(sub)
    export.add_parser(sub)
    journal.add_parser(sub)
    studies.add_sweep_parser(sub)
    soak.add_parser(sub)
    bench.add_parser(sub)
    ui.add_parser(sub)
    serve.add_parsers(sub)
    return top


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] not in SUBCOMMANDS and not args_list[0].startswith("-"):
        args_list.insert(0, "ui")
    parser = build_parser()
    if not args_list:
        parser.print_help()
        return 2
    args = parser.parse_args(args_list)
    try:
        handler = COMMANDS.get(args.command)
        if handler is not None:
            return handler(args)
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
