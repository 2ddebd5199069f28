"""Shared harness of the bad-input suites: run the installed ``arlight`` on one bad
invocation in a subprocess and check the contract of ``docs/cli.md``.

The contract for every case: the expected exit status (2 for bad input), exactly one line on
stderr starting ``error:`` and naming the file or field at fault, no traceback, every
protected path (inputs, earlier outputs) byte for byte as it was with no file added next to
it, and a peak resident memory below the case's bound (the child's own high-water mark).

How a case runs (:func:`run_all`): the first case of each command through the installed
console script in a fresh subprocess (its ``VmHWM`` sampled every 10 ms), the others in
children forked from a server that has done the imports once (``tests/cli_forkserver.py``):
the same ``arlight.entry.main`` in a separate process with its own exit status, streams,
environment and peak memory (``wait4``'s), for about half the CPU of a fresh process.
``ARLIGHT_TEST_CLI=script`` runs every case through the console script.
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

ARLIGHT = shutil.which("arlight", path=str(Path(sys.executable).parent))
FORK_SERVER = Path(__file__).with_name("cli_forkserver.py")

DEFAULT_MAX_RSS_MB = 2048
"""Peak resident memory a failing run may reach (MiB): the imports take ~400 MiB; a run that
allocated what a bad size asked for would go far beyond."""


@dataclass
class Case:
    """One bad invocation: arguments, expected status, words the message must contain.

    ``keep``: paths that must stay byte for byte as they were (files, or folders with
    everything in them, including files added to them); ``max_rss_mb``: the memory bound.
    """

    id: str
    args: list[str]
    needles: list[str]
    code: int = 2
    keep: Path | list[Path] | None = None
    max_rss_mb: float = DEFAULT_MAX_RSS_MB
    stdin: bytes | None = None
    result: dict = field(default_factory=dict)

    @property
    def kept(self) -> list[Path]:
        if self.keep is None:
            return []
        return list(self.keep) if isinstance(self.keep, list) else [self.keep]


def previous_output(root: Path, name: str) -> Path:
    """A folder holding an earlier arlight output (manifest + composite): a bad-input case
    writing there must leave it untouched."""
    prev = root / name
    prev.mkdir()
    (prev / "composite.png").write_bytes(b"old composite")
    (prev / ".arlight-output.json").write_text(json.dumps({"writer": "render",
                                                           "files": ["composite.png"]}))
    return prev


def snapshot(path: Path) -> dict[str, bytes]:
    """Every file under ``path`` (or ``path`` itself) by relative name, with its bytes."""
    if path.is_file():
        return {path.name: path.read_bytes()}
    if not path.is_dir():
        return {}
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file()}


def command_of(case: Case) -> tuple[str, ...]:
    """The command a case runs (``light estimate`` for the light group, else the first
    argument)."""
    return tuple(case.args[:2]) if case.args[:1] == ["light"] else tuple(case.args[:1])


def script_sample(cases: list[Case]) -> set[int]:
    """Indices of the cases run through the installed console script: the first case of
    each command."""
    first: dict[tuple[str, ...], int] = {}
    for i, c in enumerate(cases):
        first.setdefault(command_of(c), i)
    return set(first.values())


def _forking_allowed() -> bool:
    """Whether cases may run as children of the fork server (``ARLIGHT_TEST_CLI=script``
    runs every case through the console script)."""
    return os.environ.get("ARLIGHT_TEST_CLI") != "script"


FORKED_CPU = [0.0]
"""CPU seconds of the cases run by the fork server so far (they count in this process'
``RUSAGE_CHILDREN`` only once the server has ended)."""

_SERVER: list[ForkServer] = []
_SERVER_LOCK = threading.Lock()


def fork_server() -> ForkServer:
    """The session's fork server, started on first use (it ends with the test process)."""
    with _SERVER_LOCK:
        if not _SERVER:
            _SERVER.append(ForkServer())
            atexit.register(_SERVER[0].close)
        return _SERVER[0]


def run_all(cases: list[Case], env: dict[str, str], workers: int = 2) -> None:
    """Run every case (``workers`` at a time), measuring each child's peak memory: the
    :func:`script_sample` through the console script, the rest as children of the
    session's :class:`ForkServer`."""
    sample = script_sample(cases) if _forking_allowed() else set(range(len(cases)))
    server = fork_server() if len(sample) < len(cases) else None
    with tempfile.TemporaryDirectory(prefix="arlight-cli-cases-") as streams:
        def one(i: int, case: Case) -> None:
            if i in sample:
                run(case, env)
            else:
                server.run(case, env, Path(streams) / f"case{i}")

        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(one, range(len(cases)), cases))


def _hwm_kib(pid: int) -> int:
    """The peak resident memory (KiB) of process ``pid``'s own address space so far
    (``VmHWM``), 0 once it is gone. ``wait4``'s ``ru_maxrss`` cannot be used: Linux keeps the
    parent's resident size across fork + exec, so every child of a 1.5 GB pytest "peaked" at
    1.5 GB."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return 0


def run(case: Case, env: dict[str, str], timeout: float = 120.0) -> None:
    """Run ``case`` through the console script in a subprocess; fill ``case.result`` (code,
    stdout, stderr and the child's own peak resident memory ``rss_mb``, its ``VmHWM``
    sampled while it runs)."""
    assert ARLIGHT, "the arlight console script is not installed next to the interpreter"
    proc = subprocess.Popen([ARLIGHT, *case.args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE,
                            stdin=subprocess.PIPE if case.stdin is not None
                            else subprocess.DEVNULL)
    if case.stdin is not None:
        proc.stdin.write(case.stdin)
        proc.stdin.close()
    deadline = time.monotonic() + timeout
    outs: dict[str, bytes] = {}

    def drain(name: str, stream) -> None:
        outs[name] = stream.read()

    with ThreadPoolExecutor(max_workers=2) as readers:
        futs = [readers.submit(drain, "out", proc.stdout), readers.submit(drain, "err",
                                                                          proc.stderr)]
        peak_kib = 0
        while True:
            peak_kib = max(peak_kib, _hwm_kib(proc.pid))
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                status = None
                break
            time.sleep(0.01)
        for f in futs:
            f.result()
    proc.returncode = 0  # reaped by wait4: keep Popen from waiting again
    code = "timeout" if status is None else os.waitstatus_to_exitcode(status)
    case.result = {"code": code, "stdout": outs["out"].decode(errors="replace"),
                   "stderr": outs["err"].decode(errors="replace"),
                   "rss_mb": peak_kib / 1024.0}


class ForkServer:
    """A ``tests/cli_forkserver.py`` process: runs cases in forked children of a process that
    has imported arlight once (see that module for what a child shares with the console
    script and what not). Thread-safe: cases run concurrently."""

    START_TIMEOUT = 600.0
    """Seconds the first case may wait for the server's imports (a loaded machine)."""

    def __init__(self):
        env = {k: v for k, v in os.environ.items() if k != "ARLIGHT_DEBUG"}
        self.home = Path(tempfile.mkdtemp(prefix="arlight-forkserver-"))
        env["ARLIGHT_CACHE"] = str(self.home / "cache")  # imports never touch a real cache
        self.log = self.home / "server.log"
        requests_r, self._requests = os.pipe()
        self._replies, replies_w = os.pipe()
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(
                [sys.executable, str(FORK_SERVER), str(requests_r), str(replies_w)],
                pass_fds=(requests_r, replies_w), env=env, stdin=subprocess.DEVNULL,
                stdout=log, stderr=log)
        os.close(requests_r)
        os.close(replies_w)
        self._lock = threading.Condition()
        self._answers: dict[str, dict[str, list[str]]] = {}
        self._ended = False
        self._next = 0
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        """Hand the server's replies to the cases waiting for them."""
        with os.fdopen(self._replies, "rb") as replies:
            for line in replies:
                kind, id_, *rest = line.decode().split()
                with self._lock:
                    self._answers.setdefault(id_, {})[kind] = rest
                    self._lock.notify_all()
        with self._lock:
            self._ended = True
            self._lock.notify_all()

    def _await(self, id_: str, kind: str, timeout: float | None) -> list[str] | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._lock:
            while kind not in self._answers.get(id_, {}):
                if self._ended:
                    raise RuntimeError("the CLI fork server ended: "
                                       + self.log.read_text(errors="replace")[-3000:])
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return None
                self._lock.wait(left)
            return self._answers[id_][kind]

    def run(self, case: Case, env: dict[str, str], stem: Path, timeout: float = 120.0) -> None:
        """Run ``case`` in a forked child; fill ``case.result`` as :func:`run` does (the peak
        memory is the child's own high-water mark, from ``wait4`` in the server)."""
        stdin = None
        if case.stdin is not None:
            stdin = stem.with_suffix(".in")
            stdin.write_bytes(case.stdin)
        out, err = stem.with_suffix(".out"), stem.with_suffix(".err")
        with self._lock:
            id_ = str(self._next)
            self._next += 1
            request = {"id": id_, "args": [str(a) for a in case.args], "env": env,
                       "cwd": os.getcwd(), "argv0": ARLIGHT,
                       "stdin": str(stdin) if stdin else None, "stdout": str(out),
                       "stderr": str(err)}
            os.write(self._requests, (json.dumps(request) + "\n").encode())
        started = self._await(id_, "pid", self.START_TIMEOUT)
        if started is None:
            raise RuntimeError(f"the CLI fork server did not start a case in "
                               f"{self.START_TIMEOUT:.0f} s")
        ended = self._await(id_, "status", timeout)
        if ended is None:
            os.kill(int(started[0]), signal.SIGKILL)
            self._await(id_, "status", None)
        status, maxrss_kib, cpu = ended or (None, 0, 0)
        with self._lock:
            del self._answers[id_]
            FORKED_CPU[0] += float(cpu)
        case.result = {"code": "timeout" if status is None
                       else os.waitstatus_to_exitcode(int(status)),
                       "stdout": out.read_bytes().decode(errors="replace"),
                       "stderr": err.read_bytes().decode(errors="replace"),
                       "rss_mb": int(maxrss_kib) / 1024.0, "cpu_s": float(cpu)}

    def close(self) -> None:
        """End the server (it waits for its running children)."""
        os.close(self._requests)
        try:
            self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        shutil.rmtree(self.home, ignore_errors=True)


def problems(case: Case, before: dict[str, dict[str, bytes]]) -> list[str]:
    """What ``case`` did wrong against the contract (empty when it kept it)."""
    r = case.result
    err = r["stderr"]
    lines = [ln for ln in err.splitlines() if ln.strip()]
    found = []
    if r["code"] != case.code:
        found.append(f"exit {r['code']}")
    if "Traceback" in err + r["stdout"]:
        found.append("traceback")
    if case.code != 0:
        if len(lines) != 1:
            found.append(f"{len(lines)} stderr lines")
        elif not lines[0].startswith("error: "):
            found.append("no 'error:' prefix")
        if not any(n.lower() in err.lower() for n in case.needles):
            found.append(f"message names none of {case.needles}")
    for p in case.kept:
        if snapshot(p) != before[str(p)]:
            found.append(f"{p} changed")
    if r["rss_mb"] > case.max_rss_mb:
        found.append(f"peak memory {r['rss_mb']:.0f} MiB > {case.max_rss_mb:.0f} MiB")
    return found


def check(cases: Iterable[Case], env: dict[str, str], workers: int = 2) -> list[str]:
    """Snapshot every protected path, run the cases, return one line per failed case."""
    cases = list(cases)
    before = {str(p): snapshot(p) for c in cases for p in c.kept}
    run_all(cases, env, workers)
    return [f"{c.id}: {', '.join(p)} :: {c.result['stderr'].strip()[:300]!r}"
            for c in cases if (p := problems(c, before))]


def clean_env(root: Path) -> dict[str, str]:
    """The environment of a case: narrow terminal, a private cache, no debug tracebacks."""
    env = {**os.environ, "COLUMNS": "80", "ARLIGHT_CACHE": str(root / "cache")}
    env.pop("ARLIGHT_DEBUG", None)
    return env
