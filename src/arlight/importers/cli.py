"""The ``arlight import-mitsuba`` command (registered in :mod:`arlight.cli`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def import_mitsuba_command(
    xml: Annotated[Path, typer.Argument(help="Mitsuba 3 scene (XML)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="arlight world file to write "
                                      "(.toml; meshes and maps are written next to it)")],
    virtual: Annotated[list[str] | None, typer.Option("--virtual", help="shape id (or glob "
                       "on ids) that becomes a virtual shape (repeatable; default: every "
                       "shape is real)")] = None,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace existing files at the output paths that arlight did not "
        "write (never the XML or a file it references)")] = False,
    force: Annotated[bool, typer.Option(
        "--force", help="import even when the memory estimate is beyond the bounds")] = False,
) -> None:
    """Import a Mitsuba 3 XML scene as an arlight world (see docs/scene-format.md,
    "From Mitsuba")."""
    from arlight.importers.mitsuba import import_mitsuba

    path = import_mitsuba(xml, out, virtual or [], overwrite=overwrite, force=force)
    typer.echo(f"{path}: written (from {xml})")
