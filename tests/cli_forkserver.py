"""A fork server for the bad-input suites (``tests/cli_harness.py``): a Python process that
imports ``arlight`` once and then forks one child per case.

A fresh ``arlight`` process spends most of a bad-input case importing (typer, NumPy, SciPy,
OpenCV, the command modules) before it looks at its arguments; a forked child starts with
that done. Each child is the installed console script from its ``main`` on: ``sys.argv`` is
set, ``arlight.entry.main()`` runs with the case's environment, working folder and standard
streams (files), and the child ends through ``sys.exit`` (Python's normal shutdown, ``atexit``
handlers and all), as ``.venv/bin/arlight`` does.

What the child keeps of a fresh process: its own exit status, streams, environment and peak
memory (``wait4``'s ``ru_maxrss``: a forked child's own high-water mark, which Linux starts
at its resident size at the fork, i.e. what the imports took, as in a fresh process); a
signal, crash or hang ends or blocks only the child; nothing of the test process (caches,
monkeypatches, captured warnings) reaches it; Python's default warning filters apply.

What differs: the imports are done, and a warning printed *while importing* went to the
server's log, not to the case's stderr. The imported objects are frozen out of the cyclic
collector (``gc.freeze``): a child's collections skip them, as they would find nothing to
free there. The console script's own start-up is run for the
first case of every command (``cli_harness.script_sample``).

Mitsuba and Dr.Jit are never imported here (:data:`WITHHELD`), nor the ``arlight`` modules
that need them: importing Dr.Jit starts threads a fork does not copy, and a child of a
process holding them hangs at exit (Dr.Jit's ``atexit`` handler and a C++ destructor wait
for the missing threads). A child that needs them imports them itself, as a fresh process
does (~1 s of the ~2 s a fresh ``arlight render`` spends before it can refuse a bad input).

Protocol (on two pipes given as file descriptors ``argv[1]``, ``argv[2]``): the harness
writes one JSON line per case, ``{"id", "args", "env", "cwd", "argv0", "stdin", "stdout",
"stderr"}`` (the streams are file paths; ``stdin`` may be null); the server answers
``pid <id> <pid>`` once the child runs and ``status <id> <wait status> <peak KiB> <cpu s>``
when it has ended. Cases run concurrently. End of input ends the server (after its children).
"""

from __future__ import annotations

import gc
import json
import os
import select
import sys


class _Withheld(BaseException):
    """Raised for an import of :data:`WITHHELD` while the server preloads (a BaseException,
    so no ``except ImportError`` fallback in a module can swallow it)."""


WITHHELD = ("drjit", "mitsuba")
"""Packages the server never imports (see the module docstring)."""

LAZY = ("typer._adapters", "typer._click.decorators", "click", "zoneinfo",
        "pydantic.plugin._loader")
"""Modules Typer imports only when it parses a command line (Pydantic and Click: ~0.2 s of
CPU in every child that did not find them imported)."""


class _Withhold:
    """A meta-path finder that refuses :data:`WITHHELD`."""

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in WITHHELD:
            raise _Withheld(name)
        return None


def _preload() -> None:
    """Import every ``arlight`` module that does not need Mitsuba or Dr.Jit (what a command
    may import before it fails), and so the libraries they use."""
    import importlib
    import pkgutil

    import arlight

    def walk(package) -> None:
        for info in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
            try:
                module = importlib.import_module(info.name)
            except (Exception, _Withheld):  # noqa: BLE001 - the child imports it itself
                continue
            if info.ispkg:
                walk(module)

    finder = _Withhold()
    sys.meta_path.insert(0, finder)
    try:
        walk(arlight)
    finally:
        sys.meta_path.remove(finder)
    for name in LAZY:
        try:
            importlib.import_module(name)
        except ImportError:  # another Typer version: the child imports what it needs
            pass
    loaded = [m for m in sys.modules if m.split(".")[0] in WITHHELD]
    assert not loaded, f"imported past the finder: {loaded}"
    # the imports are done for good: keep the collector off their objects, so that a child's
    # collections (and the one at its shutdown) do not write to, and so copy, every page of
    # them (the child's CPU time: 0.6 -> 0.3 s for a case that fails while parsing)
    gc.freeze()


def _serve(ctl_in: int, ctl_out: int) -> dict | None:
    """Fork a child per request and report it; return the request in the child, None in the
    server once the input has ended and every child has been reaped."""
    buffer = b""
    running: dict[int, str] = {}  # pid -> request id
    open_input = True

    def reply(text: str) -> None:
        os.write(ctl_out, (text + "\n").encode())

    while open_input or running:
        ready = select.select([ctl_in] if open_input else [], [], [],
                              0.005 if running else None)[0]
        if ready:
            data = os.read(ctl_in, 65536)
            open_input = bool(data)
            buffer += data
        while b"\n" in buffer:
            line, buffer = buffer.split(b"\n", 1)
            request = json.loads(line)
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                os.close(ctl_in)
                os.close(ctl_out)
                return request
            running[pid] = request["id"]
            reply(f"pid {request['id']} {pid}")
        for pid in list(running):
            done, status, usage = os.wait4(pid, os.WNOHANG)
            if done:
                reply(f"status {running.pop(pid)} {status} {usage.ru_maxrss} "
                      f"{usage.ru_utime + usage.ru_stime:.3f}")
    return None


def _become(request: dict) -> None:
    """Turn this child into ``arlight ARGS`` as the console script runs it."""
    for fd, path, flags in ((0, request["stdin"] or os.devnull, os.O_RDONLY),
                            (1, request["stdout"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC),
                            (2, request["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)):
        f = os.open(path, flags, 0o600)
        os.dup2(f, fd)
        os.close(f)
    os.environ.clear()
    os.environ.update(request["env"])
    os.chdir(request["cwd"])
    sys.argv = [request["argv0"], *request["args"]]
    sys.path[0] = os.path.dirname(request["argv0"])  # as for the script, not tests/


if __name__ == "__main__":
    _preload()
    req = _serve(int(sys.argv[1]), int(sys.argv[2]))
    if req is None:
        sys.exit(0)
    _become(req)
    from arlight.entry import main

    sys.exit(main())
