"""Typer option types shared by the commands (one declaration, one help text)."""

from __future__ import annotations

from typing import Annotated

import typer

Force = Annotated[bool, typer.Option("--force", help="run even when the estimated memory or "
                                     "time is beyond the limits (see docs/cli.md)")]
"""``--force``: run a request whose cost estimate is beyond the bounds (:mod:`arlight.bounds`)."""

__all__ = ["Force"]
