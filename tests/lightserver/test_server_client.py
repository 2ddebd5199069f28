"""Server and clients over loopback TCP (ephemeral ports): stream, late join, restart,
malformed messages, a stalled subscriber, atomic state swaps."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zmq

from arlight.errors import InputError
from arlight.lightserver import LightClient, LightServer, SyntheticMovingLight, wire
from arlight.lightserver.transport import SNAPSHOT_REQUEST

ANY = "tcp://127.0.0.1:*"


def f32(a):
    return np.asarray(a, np.float64).astype(np.float32).astype(np.float64)


def same_light(a, b) -> bool:
    """a (decoded) equals b (produced) to packing precision."""
    ang = np.degrees(np.arccos(np.clip((a.normals * b.normals).sum(1), -1, 1)))
    return (np.array_equal(a.positions, f32(b.positions))
            and np.array_equal(a.intensity, f32(b.intensity))
            and np.array_equal(a.area, f32(b.area)) and np.array_equal(a.sh, f32(b.sh))
            and (ang.size == 0 or ang.max() < 0.5))


def wait_until(cond, timeout=10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return False


def test_stream_ends_on_the_latest_state_equal_to_the_server():
    src = SyntheticMovingLight(vals=16, objects=np.array([[0, 0.1, 0], [0.5, 0.2, 0.3]]))
    with LightServer(src, bind=ANY, rate_hz=100, count=40) as server:
        with LightClient(*server.endpoints) as client:
            client.wait_for(1, timeout=10)
            assert server.wait(20)
            last = client.wait_for(40, timeout=10)
            st = client.stats()
    assert last.sequence == 40 and same_light(last, src(39))
    assert st.rejected_total == 0 and st.stale == 0 and st.applied >= 1
    s = server.stats()
    assert s.published == 40 and s.bytes_last == 48 + 32 * 16 + 108 * 2
    assert all(lat >= 0 for lat in st.latencies)


def test_late_joiner_gets_the_current_state_at_once():
    """The server publishes every 2 s; a client joining between updates has the state long
    before the next one (snapshot), not after up to 2 s."""
    src = SyntheticMovingLight(vals=8)
    with LightServer(src, bind=ANY, rate_hz=0.5) as server:
        assert wait_until(lambda: server.latest_sequence >= 1)
        with LightClient(*server.endpoints) as client:
            light = client.wait_for(1, timeout=1.5)
            assert server.latest_sequence == 1  # no second update yet: it came by snapshot
            assert client.stats().from_snapshot == 1 and same_light(light, src(0))


def test_server_restart_is_noticed_and_followed():
    src = SyntheticMovingLight(vals=4)
    first = LightServer(src, bind=ANY, rate_hz=50, heartbeat_s=0.05, epoch=1).start()
    pub, snap = first.endpoints
    client = LightClient(pub, snap, heartbeat_timeout=0.3).start()
    try:
        client.wait_for(3, timeout=10, epoch=1)
        first.close()  # the server goes away mid-stream
        assert wait_until(lambda: client.stats().reconnects >= 1, 5)  # heartbeat lost
        held = client.latest
        assert held is not None and client.error is None  # keeps the last state meanwhile
        with LightServer(src, bind=pub, snapshot_bind=snap, rate_hz=50, epoch=2):
            light = client.wait_for(1, timeout=10, epoch=2)  # a new epoch, sequence from 1
            assert client.epoch == 2 and light.sequence >= 1
        assert client.stats().restarts == 1
    finally:
        client.close()
        first.close()


def test_heartbeat_reveals_a_missed_update_and_the_snapshot_fills_it():
    """A client that missed the last update (conflation, HWM) still ends on it."""
    ctx = zmq.Context()
    pub, router = ctx.socket(zmq.PUB), ctx.socket(zmq.ROUTER)
    try:
        pub_ep = (pub.bind(ANY), pub.getsockopt_string(zmq.LAST_ENDPOINT))[1]
        snap_ep = (router.bind(ANY), router.getsockopt_string(zmq.LAST_ENDPOINT))[1]
        light = SyntheticMovingLight(vals=2)(7)
        with LightClient(pub_ep, snap_ep, heartbeat_timeout=30) as client:
            ident, req = router.recv_multipart() if router.poll(5000) else (None, None)
            assert req == SNAPSHOT_REQUEST
            router.send_multipart([ident, wire.encode_heartbeat(0, epoch=9)])  # nothing yet
            time.sleep(0.3)  # let the subscription settle
            pub.send(wire.encode_heartbeat(5, epoch=9))  # "I am at 5", update 5 never seen
            assert router.poll(5000), "the client did not ask for a snapshot"
            ident, req = router.recv_multipart()
            import dataclasses
            router.send_multipart([ident, wire.encode(dataclasses.replace(light, sequence=5),
                                                      epoch=9)])
            got = client.wait_for(5, timeout=5)
            assert same_light(got, light) and client.stats().from_snapshot == 1
    finally:
        ctx.destroy(linger=0)


def _valid(seq: int, epoch: int = 4) -> bytes:
    import dataclasses
    light = SyntheticMovingLight(vals=3)(seq)
    return wire.encode(dataclasses.replace(light, sequence=seq), epoch=epoch, sent=time.time())


def test_malformed_messages_never_reach_the_state():
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    try:
        pub.bind(ANY)
        ep = pub.getsockopt_string(zmq.LAST_ENDPOINT)
        with LightClient(ep, "tcp://127.0.0.1:9", heartbeat_timeout=30) as client:
            good = _valid(1)
            assert wait_until(lambda: (pub.send(good), client.latest is not None)[1], 5)
            before = client.latest
            nan = bytearray(_valid(2))
            nan[48:52] = np.float32(np.nan).tobytes()
            nan = wire._finish(bytes(nan[:48]), bytes(nan[48:]))
            version = bytearray(_valid(3))
            version[4] = 7
            version = wire._finish(bytes(version[:48]), bytes(version[48:]))
            bad = [b"", b"garbage", _valid(4)[:60], _valid(5)[:-3], b"ZZZZ" + _valid(6)[4:],
                   _valid(7)[:200] + b"\x55" + _valid(7)[201:], nan, version,
                   _valid(1)]  # the last: a duplicate sequence (stale)
            for msg in bad:
                pub.send(msg)
            assert wait_until(lambda: client.stats().received >= 1 + len(bad), 5)
            st = client.stats()
            assert client.latest is before and client.error is None
            assert st.rejected_total == len(bad) - 1 and st.stale >= 1
            assert st.rejected["version"] == 1 and st.rejected["finite"] == 1
            pub.send(_valid(8))  # a valid update after all that is applied
            assert client.wait_for(8, timeout=5).sequence == 8
    finally:
        ctx.destroy(linger=0)


def test_only_wrong_version_messages_is_a_clear_error():
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    try:
        pub.bind(ANY)
        ep = pub.getsockopt_string(zmq.LAST_ENDPOINT)
        msg = bytearray(_valid(1))
        msg[4] = 2
        msg = wire._finish(bytes(msg[:48]), bytes(msg[48:]))
        with LightClient(ep, "tcp://127.0.0.1:9", heartbeat_timeout=30) as client:
            stop = threading.Event()
            sender = threading.Thread(target=lambda: [pub.send(msg) or time.sleep(0.02)
                                                      for _ in range(200) if not stop.is_set()])
            sender.start()
            try:
                with pytest.raises(wire.WireVersionError, match="version 2"):
                    client.wait_for(1, timeout=5)
            finally:
                stop.set()
                sender.join()
    finally:
        ctx.destroy(linger=0)


def test_a_stalled_subscriber_does_not_stall_the_server_or_others():
    # 256 VALs (the wire's cap) and 1200 SH blocks: 135 KiB per update, 40 MB beyond kernel
    # buffers
    src = SyntheticMovingLight(vals=256, objects=[[0.0, 0.1, 0.0]] * 1200)
    n = 300
    ctx = zmq.Context()
    try:
        with LightServer(src, bind=ANY, rate_hz=300, count=n, sndhwm=16) as server:
            stalled = ctx.socket(zmq.SUB)
            stalled.setsockopt(zmq.RCVHWM, 4)
            stalled.setsockopt(zmq.RCVBUF, 4096)
            stalled.setsockopt(zmq.SUBSCRIBE, b"")
            stalled.connect(server.endpoints[0])
            with LightClient(*server.endpoints) as client:
                client.wait_for(1, timeout=10)
                assert server.wait(60)  # the server finished its stream
                assert client.wait_for(n, timeout=10).sequence == n
            got = 0
            while stalled.poll(200):
                stalled.recv()
                got += 1
        assert got < n // 2, f"the stalled subscriber was sent {got} of {n}: no HWM?"
        assert server.stats().published == n
    finally:
        ctx.destroy(linger=0)


def test_the_renderer_only_ever_sees_whole_states():
    """A reader polling ``latest`` during a fast stream: every state it sees is exactly the
    producer's state for its sequence (never parts of two updates)."""
    src = SyntheticMovingLight(vals=32, frame_dt=0.3)
    seen = []
    with LightServer(src, bind=ANY, rate_hz=200, count=150) as server:
        with LightClient(*server.endpoints) as client:
            while not server.wait(0.0005):
                if (cur := client.latest) is not None and (not seen or seen[-1] is not cur):
                    seen.append(cur)
    assert len(seen) >= 2
    assert all(same_light(s, src(s.sequence - 1)) for s in seen)
    assert [s.sequence for s in seen] == sorted(s.sequence for s in seen)


@pytest.mark.parametrize("address,match", [
    ("tcp://127.0.0.1:99999", "outside 1..65535"),
    ("localhost:5556", "not a ZeroMQ endpoint"),
    ("tcp://256.1.1.1:5556", "cannot bind"),
])
def test_bad_bind_address(address, match):
    with pytest.raises(InputError, match=match) as err:
        LightServer(SyntheticMovingLight(), bind=address, insecure=True)
    assert err.value.field == "--bind"


def test_port_in_use_names_the_option():
    with LightServer(SyntheticMovingLight(), bind=ANY) as first:
        with pytest.raises(InputError, match="cannot bind") as err:
            LightServer(SyntheticMovingLight(), bind="tcp://127.0.0.1:*",
                        snapshot_bind=first.endpoints[1])
    assert err.value.field == "--snapshot-bind"


def test_client_rejects_a_wildcard_port():
    with pytest.raises(InputError, match="not '\\*'"):
        LightClient("tcp://127.0.0.1:*")


def test_a_group_of_clients_on_one_thread_all_end_on_the_latest():
    from arlight.lightserver import ClientGroup

    src = SyntheticMovingLight(vals=8)
    ctx = zmq.Context()
    try:
        with LightServer(src, bind=ANY, rate_hz=100, count=30) as server:
            clients = [LightClient(*server.endpoints, context=ctx) for _ in range(12)]
            with ClientGroup(clients):
                assert server.wait(30)
                finals = [c.wait_for(30, timeout=10) for c in clients]
        assert all(same_light(f, src(29)) for f in finals)
        assert all(c.stats().rejected_total == 0 and c.error is None for c in clients)
    finally:
        ctx.destroy(linger=0)


def test_a_conflating_client_keeps_only_the_newest_and_ends_on_it():
    src = SyntheticMovingLight(vals=8)
    with LightServer(src, bind=ANY, rate_hz=200, count=100) as server:
        with LightClient(*server.endpoints, conflate=True) as client:
            assert server.wait(30)
            assert same_light(client.wait_for(100, timeout=10), src(99))

