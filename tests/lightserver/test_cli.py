"""``arlight serve-light`` / ``arlight client``: bad input exits 2; a killed server process is
followed by its clients."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

import pytest
import zmq

from arlight.cli import main
from arlight.lightserver import LightClient, SyntheticMovingLight, wire

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENE = os.path.join(ROOT, "src/arlight/data/scenes/cornell-near-field/proxy.toml")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("args,field", [
    (["--bind", "tcp://127.0.0.1:99999"], "--bind"),
    (["--bind", "127.0.0.1:5556"], "--bind"),
    (["--bind", "tcp://127.0.0.1:*", "--snapshot-bind", "udp://x"], "--snapshot-bind"),
    (["--bind", "tcp://127.0.0.1:*", "--source", "magic"], "--source"),
    (["--bind", "tcp://127.0.0.1:*", "--source", "pipeline"], "--world"),
    (["--bind", "tcp://127.0.0.1:*", "--objects", "1,2"], "--objects"),
])
def test_serve_light_bad_input_exits_2(args, field, capsys):
    assert main(["serve-light", *args, "--count", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0]


def test_serve_light_port_in_use_exits_2(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert main(["serve-light", "--bind", f"tcp://127.0.0.1:{port}", "--count", "1"]) == 2
    assert "cannot bind" in capsys.readouterr().err


def test_serve_light_runs_to_its_count(capsys):
    assert main(["serve-light", "--bind", "tcp://127.0.0.1:*", "--count", "5", "--rate",
                 "100", "--vals", "8"]) == 0
    err = capsys.readouterr().err
    assert f"published 5 updates ({48 + 32 * 8 + 108} B each)" in err


def test_client_bad_address_exits_2(tmp_path, capsys):
    rc = main(["client", SCENE, "-o", str(tmp_path / "o"), "--connect", "tcp://x:*"])
    assert rc == 2 and "--connect" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_client_without_a_server_exits_2(tmp_path, capsys):
    port = free_port()
    rc = main(["client", SCENE, "-o", str(tmp_path / "o"), "--connect",
               f"tcp://127.0.0.1:{port}", "--wait", "0.5"])
    assert rc == 2 and "no light update" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_client_of_a_newer_wire_version_exits_2(tmp_path, capsys):
    """A server answering snapshots in wire version 2: one clear line, exit 2."""
    light = SyntheticMovingLight(vals=2)(0)
    msg = bytearray(wire.encode(light))
    msg[4] = 2
    msg = wire._finish(bytes(msg[:48]), bytes(msg[48:]))
    ctx = zmq.Context()
    router = ctx.socket(zmq.ROUTER)
    try:
        router.bind("tcp://127.0.0.1:*")
        snap = router.getsockopt_string(zmq.LAST_ENDPOINT)
        import threading

        stop = threading.Event()

        def answer():
            while not stop.is_set():
                if router.poll(50):
                    ident, _ = router.recv_multipart()
                    router.send_multipart([ident, msg])

        t = threading.Thread(target=answer)
        t.start()
        try:
            rc = main(["client", SCENE, "-o", str(tmp_path / "o"), "--connect",
                       f"tcp://127.0.0.1:{free_port()}", "--snapshot", snap, "--wait", "5"])
        finally:
            stop.set()
            t.join()
    finally:
        ctx.destroy(linger=0)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "wire version 2" in err[0]


def _serve(port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "arlight.entry", "serve-light", "--bind",
                             f"tcp://127.0.0.1:{port}", "--rate", "40", "--heartbeat", "0.1",
                             *extra], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            cwd=ROOT)


def test_killed_server_process_is_followed_after_restart():
    """SIGKILL the server mid-stream: the client keeps its last state, reconnects, and takes
    the restarted server's new epoch."""
    port = free_port()
    first = _serve(port)
    second = None
    try:
        with LightClient(f"tcp://127.0.0.1:{port}", heartbeat_timeout=0.4) as client:
            client.wait_for(3, timeout=30)
            epoch1 = client.epoch
            first.send_signal(signal.SIGKILL)
            first.wait(10)
            t0 = time.monotonic()
            while client.stats().reconnects < 1 and time.monotonic() - t0 < 10:
                time.sleep(0.05)
            assert client.stats().reconnects >= 1 and client.latest is not None
            second = _serve(port)
            t0 = time.monotonic()
            while client.epoch == epoch1 and time.monotonic() - t0 < 30:
                time.sleep(0.05)
            assert client.epoch != epoch1 and client.error is None
            assert client.wait_for(2, timeout=10).sequence >= 2
            assert client.stats().restarts == 1
    finally:
        for p in (first, second):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGINT)
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(5)
    if second is not None:
        assert second.returncode == 130  # SIGINT: the usual arlight exit status
        assert "published" in second.stderr.read().decode()


def _synthetic_server(n_obj: int):
    from arlight.lightserver import LightServer

    objs = [[-0.15, 0.3, 0.2]] * n_obj
    return LightServer(SyntheticMovingLight(vals=4, objects=objs), bind="tcp://127.0.0.1:*",
                       rate_hz=30)


def test_client_renders_its_frames_with_the_servers_light(tmp_path, capsys):
    import json

    with _synthetic_server(1) as server:
        rc = main(["client", SCENE, "-o", str(tmp_path / "o"), "--connect",
                   server.endpoints[0], "--snapshot", server.endpoints[1], "--frames", "3",
                   "--size", "32x18", "--wait", "20"])
    assert rc == 0, capsys.readouterr().err
    out = tmp_path / "o"
    assert sorted(p.name for p in out.glob("frame_*.png")) == [f"frame_000{i}.png"
                                                              for i in range(3)]
    summary = json.loads((out / "client.json").read_text())
    seqs = [f["sequence"] for f in summary["per_frame"]]
    assert seqs == sorted(seqs) and seqs[0] >= 1 and summary["updates_applied"] >= 1
    assert summary["rejected"] == {} and summary["from_snapshot"] == 1


def test_client_refuses_a_light_for_other_objects(tmp_path, capsys):
    with _synthetic_server(2) as server:
        rc = main(["client", SCENE, "-o", str(tmp_path / "o"), "--connect",
                   server.endpoints[0], "--snapshot", server.endpoints[1], "--frames", "1",
                   "--size", "32x18", "--wait", "20"])
    err = capsys.readouterr().err
    assert rc == 2 and "SH for 2 virtual objects" in err and "has 1" in err
    assert not (tmp_path / "o").exists()
