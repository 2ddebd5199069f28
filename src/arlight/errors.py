"""Errors that name the file and the field at fault, for clear CLI messages."""

from __future__ import annotations


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
