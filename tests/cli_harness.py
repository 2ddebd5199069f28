"""Shared harness of the bad-input suites: run the installed ``arlight`` on one bad
invocation in a subprocess and check the contract of ``docs/cli.md``.

The contract for every case: the expected exit status (2 for bad input), exactly one line on
stderr starting ``error:`` and naming the file or field at fault, no traceback, every
protected path (inputs, earlier outputs) byte for byte as it was with no file added next to
it, and a peak resident memory below the case's bound (the child's own ``VmHWM``, sampled
every 10 ms while it runs).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

ARLIGHT = shutil.which("arlight", path=str(Path(sys.executable).parent))

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


def snapshot(path: Path) -> dict[str, bytes]:
    """Every file under ``path`` (or ``path`` itself) by relative name, with its bytes."""
    if path.is_file():
        return {path.name: path.read_bytes()}
    if not path.is_dir():
        return {}
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file()}


def run_all(cases: list[Case], env: dict[str, str], workers: int = 2) -> None:
    """Run every case (``workers`` at a time), measuring each child's peak memory."""
    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(lambda c: run(c, env), cases))


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
    """Run ``case`` in a subprocess; fill ``case.result`` (code, stdout, stderr and the
    child's own peak resident memory ``rss_mb``, its ``VmHWM`` sampled while it runs)."""
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
