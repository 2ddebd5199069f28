"""The studio's message parser refuses everything malformed with a ProtocolError."""

from __future__ import annotations

import json

import pytest

from arlight.studio.protocol import (
    MAX_MESSAGE_CHARS,
    ProtocolError,
    frame_message,
    parse,
    split_frame,
)

W, H = 160, 120


@pytest.mark.parametrize("text, needle", [
    ("not json", "not JSON"),
    ("[1, 2]", "JSON object"),
    ('{"x": 1}', "unknown message type"),
    ('{"type": "teleport"}', "unknown message type"),
    ('{"type": "pick", "x": 1}', "missing field 'y'"),
    ('{"type": "pick", "x": 1, "y": 2, "z": 3}', "unknown field 'z'"),
    ('{"type": "pick", "x": NaN, "y": 2}', "finite"),
    ('{"type": "pick", "x": Infinity, "y": 2}', "finite"),
    ('{"type": "pick", "x": 1e999, "y": 2}', "finite"),
    ('{"type": "pick", "x": ' + "9" * 400 + ', "y": 2}', "finite"),
    ('{"type": "pick", "x": "1", "y": 2}', "expected a number"),
    ('{"type": "pick", "x": true, "y": 2}', "expected a number"),
    ('{"type": "drag", "x": -1, "y": 2}', "outside"),
    ('{"type": "drag", "x": 1, "y": 121}', "outside"),
    ('{"type": "pose", "object": "bunny", "scale": 1e30}', "outside"),
    ('{"type": "pose", "object": "bunny", "scale": 0}', "outside"),
    ('{"type": "pose", "object": "../bunny"}', "name"),
    ('{"type": "exposure", "ev": 100}', "outside"),
    ('{"type": "method", "name": "../../etc/passwd"}', "name"),
    ('{"type": "method", "name": 3}', "name"),
    ('{"type": "layer", "name": "depth"}', "unknown layer"),
    ('{"type": "save", "name": "../outside"}', "plain file stem"),
    ('{"type": "save", "name": "/etc/passwd"}', "plain file stem"),
    ('{"type": "save", "name": "a.toml"}', "plain file stem"),
    ('{"type": "save", "name": "C:evil"}', "plain file stem"),
    ('{"type": "save", "name": ""}', "plain file stem"),
    ('{"type": "reset", "seq": -1}', "seq"),
    ('{"type": "reset", "seq": 1.5}', "seq"),
    ("[" * 100000 + "]" * 100000, "characters"),
    ("[" * 2000 + "]" * 2000, "not JSON"),
])
def test_malformed_messages_are_refused(text, needle):
    with pytest.raises(ProtocolError, match=needle):
        parse(text, W, H)


def test_binary_and_oversized_messages_are_refused():
    with pytest.raises(ProtocolError, match="binary"):
        parse(b'{"type": "reset"}', W, H)
    with pytest.raises(ProtocolError, match="characters"):
        parse(json.dumps({"type": "reset", "pad": "x" * MAX_MESSAGE_CHARS}), W, H)


def test_valid_messages_parse():
    m = parse('{"type": "drag", "x": 10, "y": 119.5, "seq": 7}', W, H)
    assert (m.type, m.seq, m["x"], m["y"]) == ("drag", 7, 10.0, 119.5)
    m = parse('{"type": "pose", "object": "bunny", "yaw_deg": -90}', W, H)
    assert m["yaw_deg"] == 270.0 and "scale" not in m.fields
    assert parse('{"type": "save", "name": "my-scene_2"}', W, H)["name"] == "my-scene_2"
    assert parse('{"type": "layer", "name": "delta"}', W, H)["name"] == "delta"


def test_frame_message_round_trip():
    header = {"type": "frame", "seq": 3, "stats": {"time_trace": 0.25}}
    data = frame_message(header, b"\xff\xd8jpeg")
    assert split_frame(data) == (header, b"\xff\xd8jpeg")
    with pytest.raises(ValueError):
        frame_message({"x": float("nan")}, b"")


def test_outbox_keeps_the_newest_frame_and_a_bounded_json_queue():
    import asyncio

    from arlight.studio.server import MAX_QUEUED_JSON, Outbox

    loop = asyncio.new_event_loop()
    try:
        box = Outbox(loop)
        for i in range(3):
            box._put("frame", bytes([i]))
        for i in range(MAX_QUEUED_JSON + 10):
            box._put("json", {"i": i})
        assert len(box.json) == MAX_QUEUED_JSON and box.json[0] == {"i": 10}
        assert box.dropped == 2 + 10
        got = [loop.run_until_complete(box.next()) for _ in range(MAX_QUEUED_JSON + 1)]
        assert got[-1] == ("frame", b"\x02")  # JSON in order first, then the newest frame
        assert [m["i"] for _, m in got[:-1]] == list(range(10, MAX_QUEUED_JSON + 10))
    finally:
        loop.close()
