"""``import arlight.cli`` stays cheap, and the ``light`` group holds its four commands.

Every bad-input case of the contract suites runs ``arlight`` in a fresh process, so what the
command line imports before a command runs is paid hundreds of times by the fast tier.
Rejects: a command module importing numpy, scipy, ZeroMQ, Mitsuba, matplotlib or rich at
module level (the commands import them when they run); ``light probeless``/``light atlas``
registered by a sideways import in ``light/cli.py`` instead of being mounted from
``arlight.cli`` (a lost command, or one registered twice).
"""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("numpy", "scipy", "zmq", "mitsuba", "drjit", "matplotlib", "rich", "cv2", "open3d",
         "trimesh")


def test_import_loads_no_heavy_module():
    code = ("import sys, arlight.cli\n"
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == []


def test_light_group_mounts_its_commands_once():
    import typer

    from arlight import cli
    from arlight.light import cli as light_cli

    group = typer.main.get_command(cli.app).commands["light"]
    assert list(group.commands) == ["estimate", "show", "probeless", "atlas"]
    assert group.commands["probeless"].help.startswith("Probeless light estimate from an "
                                                        "RGB-D sequence")
    assert group.commands["atlas"].help.startswith("Run one server update of the near-field")
    sideways = ("arlight.probeless.cli", "arlight.nearfield.cli")
    assert not any(getattr(v, "__module__", "") in sideways for v in vars(light_cli).values())
