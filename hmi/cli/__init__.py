"""The `plchmi` command.

    plchmi PROJECT                 open the operator HMI (Textual)
    plchmi check PROJECT           load, validate and summarise a project
    plchmi run PROJECT --for 60s   headless run in virtual time (real time on a real plant)
    plchmi sweep PROJECT           stopwatch monitor vs watchdog over interruptions
    plchmi serve-plant PROJECT     the simulated plant as a Modbus TCP server
    plchmi diagnose PROJECT        the diagnosers' automata and their diagnosability
    plchmi campaign PROJECT        the fault campaign (000 Table 1)
    plchmi export PROJECT --format st|plcopen -o DIR
                                   the safety layer as IEC 61131-3 code for a PLC

Exit status: 0 success, 2 bad input (a project error, a bad argument), 1 a failure at run
time. Errors about a project name the file, line and column; there is never a traceback for
bad input.

One module per command (group), each with its options (``add_parser``) and its command
(``cmd_*``); entry.py assembles the parser and dispatches; options.py, common.py and
session.py hold what several commands share. Nothing outside this package imports it
(tests/test_layers.py).
"""

from hmi.cli.entry import main

__all__ = ["main"]
