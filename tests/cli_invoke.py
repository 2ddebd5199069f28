"""Run ``arlight`` commands in this process through :func:`arlight.cli.main`, the one error
path (bad input: one ``error:`` line, exit 2), with Typer's ``CliRunner`` interface.

Typer's own runner calls a command group directly and would see an
:class:`~arlight.errors.InputError` as an uncaught exception (exit 1): the commands raise and
leave printing to ``main``, as the installed ``arlight`` does.
"""

from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass


@dataclass
class Result:
    exit_code: int
    stdout: str
    stderr: str

    @property
    def output(self) -> str:
        return self.stdout + self.stderr


class MainRunner:
    """``MainRunner().invoke(app, args)``: ``app`` is :data:`arlight.cli.app` or a command
    group mounted on it (``arlight.light.cli.app``: the args are prefixed with ``light``)."""

    def invoke(self, app, args: list[str]) -> Result:
        from arlight import cli
        from arlight.light import cli as light_cli

        prefix = {id(cli.app): [], id(light_cli.app): ["light"]}[id(app)]
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = cli.main([*prefix, *map(str, args)])
        return Result(rc, out.getvalue(), err.getvalue())
