"""Writing one benchmark's section of ``benchmarks/RESULTS.md``.

Each benchmark script owns one ``## <heading>`` section; :func:`write_section` replaces that
section (or appends it) and leaves every other section as it was.
"""

from __future__ import annotations

import re
from pathlib import Path

RESULTS = Path(__file__).with_name("RESULTS.md")


def cpu_pressure() -> str:
    """Percentage of the last 60 s in which runnable tasks waited for a CPU (Linux PSI
    ``some avg60``), or '' where the kernel does not report it: how busy the shared machine
    was during a benchmark."""
    try:
        with open("/proc/pressure/cpu") as f:
            some = f.readline().split()
        return next(x.split("=")[1] for x in some if x.startswith("avg60="))
    except (OSError, StopIteration, IndexError):
        return ""


def write_section(text: str, path: Path = RESULTS) -> Path:
    """Replace the section whose heading is ``text``'s first line (``## ...``) by ``text``."""
    heading = text.lstrip().splitlines()[0]
    if not heading.startswith("## "):
        raise ValueError(f"a section must start with a '## ' heading, got {heading!r}")
    text = text.strip() + "\n"
    old = path.read_text(encoding="utf-8") if path.exists() else "# Benchmark results\n"
    pattern = re.compile(re.escape(heading) + r".*?(?=^## |\Z)", re.S | re.M)
    if pattern.search(old):
        new = pattern.sub(lambda _: text + "\n", old)
    else:
        new = old.rstrip("\n") + "\n\n" + text
    path.write_text(new.rstrip("\n") + "\n", encoding="utf-8")
    return path


def publish(text: str, write: bool) -> None:
    """Print a benchmark's section and, with ``write``, store it in RESULTS.md."""
    print(text)
    if write:
        write_section(text)
