"""``arlight serve-light`` and ``arlight client`` under bad input (issue #28): generated cases
run by the installed console script in subprocesses (tests/cli_harness.py).

Contract per case: exit 2, one ``error:`` line naming the option at fault, no traceback, key
folders and earlier outputs byte for byte as they were, peak memory bounded (a --size or
--camera-size that would exhaust memory is refused from an estimate before any work).
Every float option gets NaN, ±inf, −1 and a huge value; sizes beyond the bound; bad
endpoints; missing, garbage and wrong-kind key files; keygen into a folder with keys; an
exposed or wildcard bind without keys. Nothing here binds or connects (all are refused
first).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from arlight.lightserver import security
from tests.cli_harness import Case, check, clean_env

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "src/arlight/data/scenes/cornell-near-field/proxy.toml"
MAX_RSS_MB = 1024
"""A refused case never gets near the memory a bad size asked for (tens of GiB)."""

SERVE_FLOATS = {"--rate": ["nan", "inf", "-1", "1e9"],
                "--duration": ["nan", "inf", "-1", "1e300"],
                "--heartbeat": ["nan", "inf", "-1", "1e9"],
                "--tau": ["nan", "inf", "-1", "2"]}
CLIENT_FLOATS = {"--orbit": ["nan", "inf", "-inf", "1e9"],
                 "--wait": ["nan", "inf", "-1", "1e9"],
                 "--heartbeat-timeout": ["nan", "inf", "-1", "1e9"]}


def _build(root: Path) -> list[Case]:
    keys = root / "keys"
    security.keygen(keys)
    garbage = root / "garbage.key"
    garbage.write_bytes(os.urandom(200))
    empty = root / "empty-allow"
    empty.mkdir()
    prev = root / "previous"
    prev.mkdir()
    (prev / "client.json").write_text("{}")
    (prev / "frame_0000.png").write_bytes(b"old frame")
    loop = ["--bind", "tcp://127.0.0.1:1"]  # never reached: every case is refused first
    cli = ["client", str(SCENE), "-o", str(prev), "--connect", "tcp://127.0.0.1:1"]
    keep = [keys, prev]
    cases: list[Case] = []

    def add(id_, args, needles):
        cases.append(Case(id_, args, needles, keep=keep, max_rss_mb=MAX_RSS_MB))

    # every float option with NaN here (typer's ranges let it through); the rest of each
    # option's matrix runs in-process below (a subprocess costs ~1.5 s of CPU)
    for opt in SERVE_FLOATS:
        add(f"serve{opt}=nan", ["serve-light", *loop, opt, "nan"], [opt])
    for opt in CLIENT_FLOATS:
        add(f"client{opt}=nan", [*cli, opt, "nan"], [opt])
    # sizes beyond the bound, or within it but beyond the memory/time estimate
    add("serve--vals=257", ["serve-light", *loop, "--vals", "257"], ["--vals"])
    add("serve--camera-size=4096", ["serve-light", *loop, "--source", "pipeline", "--world",
                                    str(SCENE), "--camera-size", "4096", "--spp", "4096"],
        ["--camera-size"])
    add("serve--camera-size=99999", ["serve-light", *loop, "--camera-size", "99999"],
        ["--camera-size"])
    add("serve--max-clients=0", ["serve-light", *loop, "--max-clients", "0"],
        ["--max-clients"])
    add("client--size=8192x8192", [*cli, "--size", "8192x8192", "--spp", "4096"], ["--size"])
    add("client--size=9000x10", [*cli, "--size", "9000x10"], ["--size"])
    # endpoints: malformed, exposed without keys, wildcard without keys
    for opt, bad in (("--bind", "udp://127.0.0.1:5556"), ("--snapshot-bind",
                                                          "tcp://127.0.0.1:70000"),
                     ("--bind", "tcp://192.0.2.1:5556"), ("--bind", "tcp://0.0.0.0:5556"),
                     ("--bind", "tcp://*:5556")):
        add(f"serve{opt}={bad}", ["serve-light", *loop, opt, bad], [opt])
    for opt, bad in (("--connect", "tcp://127.0.0.1:*"), ("--snapshot", "tcp://192.0.2.1:5557")):
        add(f"client{opt}={bad}", [*cli, opt, bad], [opt])
    # keys
    add("serve--server-key=missing", ["serve-light", *loop, "--server-key",
                                      str(root / "nope.key_secret")], ["--server-key"])
    add("serve--server-key=garbage", ["serve-light", *loop, "--server-key", str(garbage)],
        ["--server-key"])
    add("serve--server-key=public", ["serve-light", *loop, "--server-key",
                                     str(keys / "server.key")], ["--server-key"])
    add("serve--allow-clients-without-key", ["serve-light", *loop, "--allow-clients",
                                             str(keys)], ["--allow-clients"])
    add("serve--allow-clients=empty", ["serve-light", *loop, "--server-key",
                                       str(keys / "server.key_secret"), "--allow-clients",
                                       str(empty)], ["--allow-clients"])
    add("serve--keygen=existing", ["serve-light", "--keygen", str(keys)], ["--keygen"])
    add("client--server-public-key=missing", [*cli, "--server-public-key",
                                              str(root / "nope.key")],
        ["--server-public-key"])
    add("client--server-public-key=garbage", [*cli, "--server-public-key", str(garbage)],
        ["--server-public-key"])
    add("client--client-key-without-server-key", [*cli, "--client-key",
                                                  str(keys / "client.key_secret")],
        ["--client-key"])
    add("client--client-key=public", [*cli, "--server-public-key", str(keys / "server.key"),
                                      "--client-key", str(keys / "client.key")],
        ["--client-key"])
    return cases


def test_serve_light_and_client_bad_input_contract(tmp_path):
    cases = _build(tmp_path)
    assert len(cases) >= 30
    failures = check(cases, clean_env(tmp_path))
    assert not failures, "\n".join(failures)


IN_PROCESS = (
    [(["serve-light", "--bind", "tcp://127.0.0.1:1", o, v], o)
     for o, vs in SERVE_FLOATS.items() for v in vs if v != "nan"]
    + [(["client", str(SCENE), "-o", "OUT", "--connect", "tcp://127.0.0.1:1", o, v], o)
       for o, vs in CLIENT_FLOATS.items() for v in vs if v != "nan"]
    + [(["serve-light", "--vals", "65536"], "--vals"),
       (["serve-light", "--bind", "127.0.0.1:5556"], "--bind"),
       (["serve-light", "--bind", "tcp://127.0.0.1:0"], "--bind"),
       (["serve-light", "--bind", "tcp://[::]:5556"], "--bind"),
       (["serve-light", "--bind", "tcp://eth0:5556"], "--bind")]
    + [(["client", str(SCENE), "-o", "OUT", *extra], opt) for extra, opt in (
        (["--size", "0x10"], "--size"), (["--size", "abc"], "--size"),
        (["--size", "-5x5"], "--size"), (["--connect", "udp://x:1"], "--connect"),
        (["--connect", "tcp://192.0.2.1:5556"], "--connect"),
        (["--connect", "tcp://[2001:db8::1]:5556"], "--connect"))]
)


@pytest.mark.parametrize("args,opt", IN_PROCESS, ids=lambda a: " ".join(map(str, a))[-40:]
                         if isinstance(a, list) else a)
def test_bad_option_values_in_process(args, opt, tmp_path, capsys):
    """The rest of the matrix (±inf, −1, huge; more sizes and endpoints) through the same
    entry point in-process: exit 2, one error line naming the option, nothing written."""
    from arlight.cli import main

    out = tmp_path / "out"
    assert main([str(out) if a == "OUT" else a for a in args]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error: ") and opt in err[0], err
    assert "Traceback" not in err[0] and not out.exists()


def test_keygen_then_serve_with_keys_starts(tmp_path):
    """The good path of the same options: keygen writes four files (secrets 0600) and exits
    0; a second keygen into the folder exits 2 and leaves them as they were."""
    from tests.cli_harness import run

    keys = tmp_path / "k"
    ok = Case("keygen", ["serve-light", "--keygen", str(keys)], [], code=0)
    run(ok, clean_env(tmp_path))
    assert ok.result["code"] == 0, ok.result["stderr"]
    assert sorted(p.name for p in keys.iterdir()) == ["client.key", "client.key_secret",
                                                      "server.key", "server.key_secret"]
    assert (keys / "server.key_secret").stat().st_mode & 0o777 == 0o600
    failures = check([Case("again", ["serve-light", "--keygen", str(keys)], ["--keygen"],
                           keep=keys)], clean_env(tmp_path))
    assert not failures, failures


@pytest.mark.parametrize("extra,warn", [
    (["--insecure", "--bind", "tcp://0.0.0.0:*"], "WITHOUT authentication"),
    (["--bind", "tcp://*:*", "--server-key", "KEY"], "binding every interface"),
])
def test_exposed_binds_warn(tmp_path, extra, warn):
    """--insecure off loopback and a wildcard bind with keys: served, with a warning line.
    (Binds every interface for a moment: one update, then exit.)"""
    from tests.cli_harness import run

    security.keygen(tmp_path / "k")
    args = [a.replace("KEY", str(tmp_path / "k" / "server.key_secret")) for a in extra]
    c = Case("warn", ["serve-light", *args, "--count", "1", "--rate", "50"], [], code=0)
    run(c, clean_env(tmp_path), timeout=60)
    assert c.result["code"] == 0, c.result["stderr"]
    lines = c.result["stderr"].splitlines()
    assert sum(ln.startswith("warning: ") and warn in ln for ln in lines) >= 1, lines
