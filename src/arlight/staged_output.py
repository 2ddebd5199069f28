"""Output folders written as one set: checked before any work, staged, swapped in one rename.

Every command that writes a folder (``render``, ``render --progressive``, ``synth``, ``demo``,
``eval``) goes through :func:`check_output_dir` before it starts working and through
:class:`StagedOutput` when it writes:

1. the files are written into a staging folder ``.<name>.tmp-<pid>-<rand>`` next to the
   output folder (same parent, hence the same filesystem);
2. once complete (a manifest ``.arlight-output.json`` is written last) the staging folder is
   renamed ``.<name>.new-<pid>-<rand>``: a ``new`` folder is always a complete set;
3. it is swapped with the output folder by one ``renameat2(RENAME_EXCHANGE)`` (Linux) — the
   output path never stops existing and holds either the whole old set or the whole new one;
   where the exchange is not available the old folder is renamed away and the new one renamed
   in (two renames; a crash between them leaves no output folder, but a complete ``new`` one
   that the next run moves into place);
4. the swapped-out old set is renamed ``.<name>.old-<pid>-<rand>`` and deleted.

A run killed at any point leaves the output folder with the old or the new set, never a mix.
Folders left by killed runs (their process id no longer alive) are cleaned by the next run
writing to the same output: ``tmp`` and ``old`` folders are deleted; a ``new`` folder is moved
into place when the output folder is missing, else deleted. An error or an interrupt before the
swap deletes the staging folder and leaves the previous output as it was (and creates no empty
output folder).

An existing output folder is replaced only when everything in it belongs to an arlight output
(listed by its manifest or named like the files the writer produces): ``-o`` pointed at a
folder of other files is refused instead of wiping it.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fnmatch
import json
import os
import secrets
import shutil
import time
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

from arlight.errors import InputError

MANIFEST = ".arlight-output.json"
"""Written last into every staged output set: the writer and the files of the set."""

FREE_SPACE_MARGIN = 1.2
"""Free space required: the estimated output size times this, plus 16 MiB."""

_KINDS = ("tmp", "new", "old")

COMMITTED: list[Path] = []
"""Output folders this process has swapped in (for the interrupt message of the CLI)."""


@contextlib.contextmanager
def _signals_deferred() -> Iterator[None]:
    """Hold SIGINT/SIGTERM during the swap (milliseconds); deliver them afterwards."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    sigs = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda n, _f: pending.append(n)) for s in sigs}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        for n in pending[:1]:
            signal.raise_signal(n)


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _side_name(out: Path, kind: str) -> str:
    return f".{out.name}.{kind}-{os.getpid()}-{secrets.token_hex(3)}"


def _side_folders(out: Path) -> Iterator[tuple[str, int, Path]]:
    """(kind, pid, path) of the staging/old/new folders next to ``out``."""
    parent = out.parent
    if not parent.is_dir():
        return
    prefix = f".{out.name}."
    for p in parent.iterdir():
        if not p.name.startswith(prefix):
            continue
        rest = p.name[len(prefix):]
        kind, _, tail = rest.partition("-")
        pid_text = tail.split("-")[0]
        if kind in _KINDS and pid_text.isdigit():
            yield kind, int(pid_text), p


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def clean_stale(out: str | Path) -> list[Path]:
    """Finish or remove what killed runs left next to ``out``; returns the removed paths.

    Only folders of processes that are no longer alive are touched (a concurrent run's
    staging folder is left alone).
    """
    out = Path(out)
    removed: list[Path] = []
    stale = [(k, p) for k, pid, p in _side_folders(out) if not _pid_alive(pid)]
    news = sorted((p for k, p in stale if k == "new"), key=lambda p: p.stat().st_mtime)
    if news and not out.exists() and not out.is_symlink():
        newest = news.pop()  # a complete set whose swap was cut short: finish it
        os.rename(newest, out)
    for _, p in stale:
        if p.exists():  # the set just moved into place is gone from here
            _remove(p)
            removed.append(p)
    return removed


def _manifest_files(folder: Path) -> set[str]:
    try:
        d = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        return {str(f) for f in d.get("files", [])}
    except (OSError, ValueError, AttributeError):
        return set()


def _foreign_entries(folder: Path, known: Sequence[str]) -> list[str]:
    """Top-level entries of ``folder`` that no arlight writer would have produced."""
    listed = {f.split("/")[0] for f in _manifest_files(folder)} | {MANIFEST}
    foreign = []
    for p in sorted(folder.iterdir()):
        if p.name in listed or any(fnmatch.fnmatch(p.name, g) for g in known):
            continue
        if p.name.startswith(".layers-"):  # staging files of older versions
            continue
        foreign.append(p.name)
    return foreign


def _existing_ancestor(path: Path) -> Path:
    """The nearest entry at or above ``path`` that exists (a dangling symlink counts: it is
    where creating the folders would fail)."""
    p = path
    while not os.path.lexists(p):
        if p.parent == p:
            break
        p = p.parent
    return p


def _mkdir_error(exc: OSError, out: Path, field: str) -> InputError:
    """An OSError of creating the output's folders as the InputError naming the path."""
    why = {errno.EROFS: "the file system is read-only", errno.EACCES: "permission denied",
           errno.EPERM: "permission denied", errno.ENOSPC: "no space left",
           errno.ENOTDIR: "a path above it is not a folder",
           errno.EEXIST: "a path above it is a dangling symlink or not a folder"}.get(
        exc.errno, exc.strerror or str(exc))
    return InputError(f"cannot create the output folder: {why}", file=str(out), field=field)


def check_output_dir(out: str | Path, known: Sequence[str] = (), expected_bytes: int = 0,
                     inputs: Iterable[str | Path] = (), field: str = "--out") -> Path:
    """Check, before any work, that the folder ``out`` can be written as a new output set.

    Raises :class:`InputError` naming the path when it is a file or a dangling symlink, when
    its parent is not a writable folder, when it is (or contains) the working folder or an
    input, when an existing folder holds entries that are not an arlight output (``known``:
    glob patterns of the writer's files), or when the filesystem has less free space than
    ``expected_bytes`` (with a margin). Returns the absolute output path (a symlink to a folder
    is followed).
    """
    out = Path(os.path.abspath(Path(out).expanduser()))
    where = str(out)
    if out.is_symlink():
        if not out.exists():
            raise InputError(f"is a dangling symlink (to {os.readlink(out)})", file=where,
                             field=field)
        out = out.resolve()
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", file=where, field=field)
    cwd = Path.cwd().resolve()
    real = out.resolve()
    if real == Path(real.anchor) or real == Path.home().resolve() or cwd.is_relative_to(real):
        raise InputError("refusing to replace the working folder, the home folder, the root "
                         "or a folder above them; choose a dedicated output folder",
                         file=where, field=field)
    for inp in inputs:
        ip = Path(os.path.abspath(Path(inp).expanduser()))
        if ip.resolve().is_relative_to(real):
            raise InputError(f"contains the input {inp}; the output set would replace it",
                             file=where, field=field)
    anc = _existing_ancestor(out.parent)
    if os.path.islink(anc) and not os.path.exists(anc):
        raise InputError(f"cannot create the output folder: {anc} above it is a dangling "
                         f"symlink (to {os.readlink(anc)})", file=where, field=field)
    if not anc.is_dir():
        raise InputError(f"cannot create the output folder: {anc} is not a folder",
                         file=where, field=field)
    if not os.access(anc, os.W_OK | os.X_OK):
        raise InputError(f"cannot write: folder {anc} is not writable (or is on a read-only "
                         "mount)", file=where, field=field)
    if out.is_dir() and os.path.ismount(out):
        raise InputError("is a mount point: an output set is swapped in by renaming the "
                         "folder, which a mount point cannot be; choose a folder inside it",
                         file=where, field=field)
    if out.is_dir():
        if not os.access(out.parent, os.W_OK | os.X_OK):
            raise InputError(f"cannot replace it: folder {out.parent} is not writable",
                             file=where, field=field)
        foreign = _foreign_entries(out, known)
        if foreign:
            more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
            raise InputError(f"exists and holds {foreign[0]!r}{more}, which is not part of an "
                             "arlight output; the new output replaces the whole folder, so "
                             "choose an empty or new folder", file=where, field=field)
    need = int(expected_bytes * FREE_SPACE_MARGIN) + (16 << 20) if expected_bytes else 0
    if need:
        free = shutil.disk_usage(anc).free
        if free < need:
            raise InputError(f"not enough free space: about {need / 2**20:.0f} MiB needed, "
                             f"{free / 2**20:.0f} MiB free", file=where, field=field)
    return out


def _rename_exchange(a: Path, b: Path) -> bool:
    """Atomically exchange two paths (Linux ``renameat2``); False where unsupported."""
    if os.environ.get("ARLIGHT_NO_RENAME_EXCHANGE"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                   ctypes.c_uint]
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _test_hook(point: str) -> None:
    """Interruption tests: with ``ARLIGHT_TEST_SWAP_HOOK=PREFIX`` create ``PREFIX.<point>``
    at each point of the swap and sleep ``ARLIGHT_TEST_SWAP_SLEEP`` seconds (default 5) there
    — only at ``ARLIGHT_TEST_SWAP_POINT`` when that is set."""
    prefix = os.environ.get("ARLIGHT_TEST_SWAP_HOOK")
    if not prefix:
        return
    Path(f"{prefix}.{point}").touch()
    if os.environ.get("ARLIGHT_TEST_SWAP_POINT", point) == point:
        time.sleep(float(os.environ.get("ARLIGHT_TEST_SWAP_SLEEP", "5")))


class StagedOutput:
    """Context manager: yields a staging folder; on success swaps it in as ``out``.

    On an exception (KeyboardInterrupt included) the staging folder is deleted and the
    previous output is left as it was.
    """

    def __init__(self, out: str | Path, writer: str, known: Sequence[str] = ()):
        self.out = Path(os.path.abspath(Path(out).expanduser()))
        if self.out.is_symlink() and self.out.is_dir():
            self.out = self.out.resolve()
        self.writer = writer
        self.known = tuple(known)
        self.staging: Path | None = None

    def __enter__(self) -> Path:
        clean_stale(self.out)
        check_output_dir(self.out, self.known)
        try:
            self.out.parent.mkdir(parents=True, exist_ok=True)
            staging = self.out.parent / _side_name(self.out, "tmp")
            staging.mkdir()
        except OSError as exc:  # e.g. a read-only mount that access() did not reveal
            raise _mkdir_error(exc, self.out, "--out") from exc
        self.staging = staging
        return self.staging

    def __exit__(self, exc_type, exc, tb) -> None:
        assert self.staging is not None
        if exc_type is not None:
            _remove(self.staging)
            return
        with _signals_deferred():
            try:
                self.commit()
            except BaseException:
                if not self.out.exists() and self.staging.name.startswith(f".{self.out.name}.new-"):
                    os.rename(self.staging, self.out)  # the old set is gone: finish the swap
                else:
                    _remove(self.staging)
                raise
            # recorded before a signal held during the swap is delivered (its message names
            # this output as written)
            COMMITTED.append(self.out)

    def commit(self) -> None:
        """Write the manifest, mark the set complete, swap it in, delete the old set."""
        assert self.staging is not None
        files = sorted(str(p.relative_to(self.staging)) for p in self.staging.rglob("*")
                       if p.is_file())
        (self.staging / MANIFEST).write_text(json.dumps(
            {"writer": self.writer, "files": files}, indent=1),
            encoding="utf-8")
        os.chmod(self.staging, 0o777 & ~_umask())
        new = self.out.parent / self.staging.name.replace(".tmp-", ".new-", 1)
        os.rename(self.staging, new)
        self.staging = new
        _test_hook("complete")
        if not self.out.exists():
            os.rename(new, self.out)
        elif _rename_exchange(new, self.out):
            _test_hook("exchanged")
            old = self.out.parent / new.name.replace(".new-", ".old-", 1)
            os.rename(new, old)
            _remove(old)
        else:
            old = self.out.parent / new.name.replace(".new-", ".old-", 1)
            os.rename(self.out, old)
            _test_hook("between")
            os.rename(new, self.out)
            _remove(old)
        _test_hook("done")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


__all__ = ["COMMITTED", "MANIFEST", "StagedOutput", "check_output_dir", "clean_stale"]
