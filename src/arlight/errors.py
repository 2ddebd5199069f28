"""Errors that name the file and the field at fault, for clear CLI messages."""

from __future__ import annotations

import os
from pathlib import Path


class ArlightError(Exception):
    """Base class for errors that the CLI reports without a traceback."""


class InputError(ArlightError, ValueError):
    """Bad input data: names the file (or object) and the field that is wrong.

    ``str(err)`` reads ``"<file>: <field>: <message>"`` so that a user can find the mistake.
    """

    def __init__(self, message: str, *, file: str | None = None, field: str | None = None):
        self.file = file
        self.field = field
        self.message = message
        parts = [p for p in (file, field) if p]
        super().__init__(": ".join([*parts, message]))


def read_text(path: str | os.PathLike, what: str) -> str:
    """The UTF-8 text of ``path``, or an :class:`InputError` naming the file: ``"<what> not
    found"`` or ``"cannot read the <what> (<reason>)"`` (``what``: e.g. ``"light file"``)."""
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise InputError(f"{what} not found", file=str(p)) from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the {what} ({exc})", file=str(p)) from exc
