"""Inputs are never destroyed: the checks a command makes on every file it will write, before
any work, and the record that lets a later run replace what arlight itself wrote.

A command lists its inputs (the files it reads, including the files those reference: meshes
and images of a scene, the frames of an RGB-D folder) and every file it will write (the main
output and each side file, e.g. the PLY meshes next to an imported scene). Before any work
:func:`check_outputs` refuses, with an :class:`~arlight.errors.InputError` naming both
paths (exit 2 in the CLI):

* an output that resolves (symlinks followed) to an input or to another output;
* an output that exists and is not a file arlight wrote (a user's file, or an arlight
  output edited since), unless the command was told to overwrite;
* an output that is a folder, a dangling symlink, or under a path that is not a folder or
  not writable (a read-only mount).

Files arlight writes as single files are recorded by :func:`record_written` in a ledger
``.arlight-written.json`` in their folder: the file name and the SHA-256 of its bytes. A
later run may replace a file whose current bytes still match the ledger — re-running a
command onto its own earlier output works; replacing a file a person made or changed does not.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from arlight.errors import InputError

LEDGER = ".arlight-written.json"
"""The per-folder record of the single files arlight wrote there (name → SHA-256)."""

PathLike = str | os.PathLike


def _real(path: PathLike) -> Path:
    return Path(os.path.realpath(os.fspath(path)))


def file_digest(path: PathLike) -> str:
    """SHA-256 (hex) of the bytes of ``path``."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _read_ledger(folder: Path) -> dict[str, str]:
    try:
        data = json.loads((folder / LEDGER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {k: v for k, v in data.items() if isinstance(k, str) and isinstance(v, str)}


def written_by_arlight(path: PathLike) -> bool:
    """True when ``path`` is a file arlight recorded and its bytes are unchanged since."""
    real = _real(path)
    if not real.is_file():
        return False
    digest = _read_ledger(real.parent).get(real.name)
    try:
        return digest is not None and digest == file_digest(real)
    except OSError:
        return False


def record_written(paths: Iterable[PathLike]) -> None:
    """Record ``paths`` (files just written) in their folders' ledgers.

    Best effort: a ledger that cannot be written only means a later run will refuse to
    replace those files without being told to.
    """
    by_folder: dict[Path, dict[str, str]] = {}
    for p in paths:
        real = _real(p)
        try:
            by_folder.setdefault(real.parent, {})[real.name] = file_digest(real)
        except OSError:
            continue
    for folder, entries in by_folder.items():
        ledger = {**_read_ledger(folder), **entries}
        with contextlib.suppress(OSError):
            fd, tmp = tempfile.mkstemp(prefix=f"{LEDGER}.", dir=folder)
            try:
                with os.fdopen(fd, "w", encoding="utf-8") as f:
                    json.dump(ledger, f, indent=1, sort_keys=True)
                os.replace(tmp, folder / LEDGER)
            finally:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(tmp)


def _existing_ancestor(path: Path) -> Path:
    p = path
    while not os.path.lexists(p) and p != p.parent:
        p = p.parent
    return p


def check_writable_file(path: PathLike, field: str) -> Path:
    """Refuse a file output path that can never be written: a folder, a dangling symlink, a
    path under a file, a folder that is not writable or on a read-only mount."""
    p = Path(path)
    where = str(p)
    if os.path.islink(p) and not os.path.exists(p):
        raise InputError(f"is a dangling symlink (to {os.readlink(p)})", file=where,
                         field=field)
    if p.is_dir():
        raise InputError("is a folder; give the path of a file", file=where, field=field)
    anc = _existing_ancestor(p.parent if p.parent != Path("") else Path("."))
    if os.path.islink(anc) and not os.path.exists(anc):
        raise InputError(f"is under the dangling symlink {anc}", file=where, field=field)
    if not anc.is_dir():
        raise InputError(f"cannot create it: {anc} is not a folder", file=where, field=field)
    if not os.access(anc, os.W_OK | os.X_OK):
        raise InputError(f"cannot write: folder {anc} is not writable (or is on a read-only "
                         "mount)", file=where, field=field)
    return p


def check_outputs(outputs: Mapping[str, PathLike | Sequence[PathLike]],
                  inputs: Iterable[PathLike], *, overwrite: bool = False,
                  overwrite_flag: str = "--overwrite") -> None:
    """Refuse, before any work, every planned output that would destroy a file.

    ``outputs``: field (e.g. ``"-o"``, ``"--mesh"``, ``"mesh file"``) → the path or paths
    written under it; ``inputs``: every file read, including files referenced by inputs.
    ``overwrite``: replace existing files arlight did not write (never an input). Raises
    :class:`InputError` naming the output (file), the field and the other path.
    """
    reads = {_real(p): Path(p) for p in inputs}
    planned: dict[Path, str] = {}
    for field, value in outputs.items():
        paths = [value] if isinstance(value, str | os.PathLike) else list(value)
        for p in paths:
            p = Path(p)
            check_writable_file(p, field)
            real = _real(p)
            if real.name in (LEDGER, ".arlight-output.json"):
                raise InputError("is arlight's own record of the files it wrote; choose "
                                 "another name", file=str(p), field=field)
            if real in reads:
                raise InputError(f"is the input {reads[real]}; the output would replace it "
                                 "(choose another output path)", file=str(p), field=field)
            if real in planned:
                raise InputError(f"is written twice (also as {planned[real]})", file=str(p),
                                 field=field)
            planned[real] = field
            if real.exists() and not overwrite and not written_by_arlight(real):
                raise InputError("exists and is not a file arlight wrote (or it was changed "
                                 f"since); remove it, choose another path or pass "
                                 f"{overwrite_flag}", file=str(p), field=field)


def referenced_files(path: PathLike) -> list[Path]:
    """``path`` and every existing file a TOML/JSON file at ``path`` names (string values,
    relative to its folder or absolute) — the files a scene or rig file makes a command read.

    Over-inclusive on purpose (any string that happens to name a file counts): the list only
    protects files from being written over. An unreadable or malformed file yields just
    ``[path]`` (the command's own reader reports it).
    """
    import tomllib

    p = Path(path)
    found = [p]
    try:
        text = p.read_text(encoding="utf-8")
        data = json.loads(text) if p.suffix.lower() == ".json" else tomllib.loads(text)
    except (OSError, ValueError, UnicodeDecodeError):
        return found
    stack: list = [data]
    while stack:
        node = stack.pop()
        if isinstance(node, dict):
            stack.extend(node.values())
        elif isinstance(node, list):
            stack.extend(node)
        elif isinstance(node, str) and node and len(node) < 4096 and "\0" not in node:
            q = Path(node)
            q = q if q.is_absolute() else p.parent / q
            try:
                if q.is_file():
                    found.append(q)
            except OSError:
                continue
    return found


def folder_files(folder: PathLike) -> list[Path]:
    """Every file under ``folder`` (inputs read from a folder, e.g. an RGB-D sequence)."""
    f = Path(folder)
    if not f.is_dir():
        return []
    return [p for p in f.rglob("*") if p.is_file()]


__all__ = ["LEDGER", "check_outputs", "check_writable_file", "file_digest", "folder_files",
           "record_written", "referenced_files", "written_by_arlight"]
