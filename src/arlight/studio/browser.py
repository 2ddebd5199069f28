"""Finding a browser for the studio's Playwright tests, benchmark and screenshot: Debian's chromium
(``apt-get install -y chromium``), never a downloaded one."""

from __future__ import annotations

import os
import shutil

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def chromium_path() -> str | None:
    """``$ARLIGHT_CHROMIUM``, else the first Chromium on PATH or in /usr/bin (None)."""
    env = os.environ.get("ARLIGHT_CHROMIUM")
    if env:
        return env if os.path.isfile(env) else None
    for name in CANDIDATES:
        path = shutil.which(name) or (f"/usr/bin/{name}" if os.path.isfile(
            f"/usr/bin/{name}") else None)
        if path:
            return path
    return None


def why_no_browser() -> str | None:
    """Why the browser tests cannot run here (None when they can)."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the python package playwright is not installed (pip install -e '.[dev]')"
    if chromium_path() is None:
        return ("no Chromium found: apt-get install -y chromium (or ./dev setup as root), or "
                "set ARLIGHT_CHROMIUM=/path/to/chromium")
    return None


def launch(playwright):
    """Headless Chromium from :func:`chromium_path` (no sandbox: tests may run as root)."""
    return playwright.chromium.launch(executable_path=chromium_path(), headless=True,
                                      args=["--no-sandbox", "--disable-gpu"])
