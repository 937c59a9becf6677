"""``python -m hmi.cli``: the ``plchmi`` command (tests and the Modbus server process use it)."""

from hmi.cli.entry import main

raise SystemExit(main())
