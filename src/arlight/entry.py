"""The ``arlight`` console script: a SIGINT handler first, then the command line.

Importing the command line (typer, rich, NumPy, Mitsuba) takes a while on a loaded machine;
a Ctrl-C in that time would otherwise end in a ``KeyboardInterrupt`` traceback from some
import. Until :func:`arlight.cli.main` installs its own handlers, an interrupt prints one
line and exits 130, like an interrupt later on (see ``docs/cli.md``).
"""

from __future__ import annotations

import os
import signal
import sys


def _interrupted_while_starting(signum: int, _frame: object) -> None:
    sys.stderr.write("arlight: interrupted while starting; nothing was written\n")
    os._exit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the installed ``arlight`` command."""
    signal.signal(signal.SIGINT, _interrupted_while_starting)
    from arlight.cli import main as cli_main

    return cli_main(argv)


if __name__ == "__main__":
    sys.exit(main())
