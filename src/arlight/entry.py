"""The ``arlight`` console script: a SIGINT handler first, then the command line.

Importing the command line (typer, rich, NumPy, Mitsuba) takes a while on a loaded machine;
a Ctrl-C in that time would otherwise end in a ``KeyboardInterrupt`` traceback from some
import. Until :func:`arlight.cli.main` installs its own handlers, an interrupt prints one
line and exits 130, like an interrupt later on (see ``docs/cli.md``). Once the command has
returned, SIGINT is ignored until the process exits: the run is complete.
"""

from __future__ import annotations

import os
import signal
import sys


def _interrupted_while_starting(signum: int, _frame: object) -> None:
    sys.stderr.write("error: interrupted while starting; the output was not written\n")
    os._exit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the installed ``arlight`` command."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _interrupted_while_starting)
    # The imports start native threads (OpenBLAS, ...): started with the signals blocked,
    # they keep them blocked (see arlight.interrupts); a Ctrl-C meanwhile is delivered
    # when the block ends, to the start-up handler.
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        from arlight import interrupts

        interrupts.test_point("startup")
        from arlight.cli import main as cli_main
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)

    status = cli_main(argv)
    # The command has finished (its outputs are committed or it failed cleanly). Python's
    # shutdown (Dr.Jit's thread pools, imported libraries) can take a while and resets Python
    # signal handlers to the default, so a Ctrl-C now would kill the finished process by the
    # signal (exit -2). SIG_IGN survives the shutdown (and, unlike a mask, covers every
    # thread): a Ctrl-C after a complete run is ignored.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return status


if __name__ == "__main__":
    sys.exit(main())
