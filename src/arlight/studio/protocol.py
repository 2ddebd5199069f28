"""The studio's WebSocket protocol: client messages parsed and checked, nothing trusted.

Client → server, JSON text, one object per message with a ``type`` and an optional integer
``seq`` (echoed in the frame that first shows the change):

========== ==================================================================================
type       fields
========== ==================================================================================
pick       ``x``, ``y``: pixel under the pointer → answer ``picked`` (object or null)
drag       ``x``, ``y``: the picked object follows the pointer on the real surface
place      ``object``, ``x``, ``y``: stand the object's anchor on the surface at the pixel
pose       ``object``, optional ``yaw_deg`` (degrees), ``scale`` (factor)
method     ``name``: switch to a registered interactive method
exposure   ``ev``: display exposure offset, EV, in [−16, 16]
denoise    ``on`` (bool): OIDN on the Monte Carlo methods' frames (``denoise = oidn``;
           progressive refinement denoises the running mean of the raw frames)
layer      ``name``: composite, mixed, delta, mask or error
reset      put every object back in its rest pose
release    the pointer is up (a pick that found an object holds refinement until then)
save       ``name``: file stem; writes ``<name>.toml`` (+ frame) and ``<name>.png``;
           optional ``overwrite`` (bool): replace existing files this studio did not
           write (the page sends it only after the user confirmed; never an input)
========== ==================================================================================

Pixel coordinates are those of the studio's camera (``info.width × info.height``, top-left
corner (0, 0)). Server → client: JSON text (``info``, ``picked``, ``saved``, ``status``,
``error``) and binary frames: a 4-byte big-endian header length, the header (UTF-8 JSON,
``type = "frame"``) and the encoded image.

Anything malformed — not JSON, not an object, an unknown type or field, a number that is
not finite or out of range, a name with path characters — raises :class:`ProtocolError`,
which the server answers with an ``error`` message; the connection stays open.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

from arlight.studio.pose import SCALE_RANGE

MAX_MESSAGE_CHARS = 4096
"""Longest client message accepted, characters (every valid message is far shorter)."""

LAYERS = ("composite", "mixed", "delta", "mask", "error")
EV_RANGE = (-16.0, 16.0)
MAX_YAW_DEG = 1e6
SAVE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")
"""Save names: a plain file stem (no dots, slashes or drive letters), so a save can only
write into the studio's save folder."""
_NAME = re.compile(r"[A-Za-z0-9_.\-]{1,128}")

FIELDS: dict[str, tuple[set[str], set[str]]] = {  # type -> (required, optional) fields
    "pick": ({"x", "y"}, set()),
    "drag": ({"x", "y"}, set()),
    "place": ({"object", "x", "y"}, set()),
    "pose": ({"object"}, {"yaw_deg", "scale"}),
    "method": ({"name"}, set()),
    "exposure": ({"ev"}, set()),
    "denoise": ({"on"}, set()),
    "layer": ({"name"}, set()),
    "reset": (set(), set()),
    "release": (set(), set()),
    "save": ({"name"}, {"overwrite"}),
}


class ProtocolError(ValueError):
    """A client message the studio refuses; the text is sent back to that client."""


@dataclass(frozen=True)
class Message:
    """A checked client message: ``type``, ``seq`` (or None) and its fields."""

    type: str
    seq: int | None
    fields: dict[str, Any]

    def __getitem__(self, key: str) -> Any:
        return self.fields[key]

    def get(self, key: str, default: Any = None) -> Any:
        return self.fields.get(key, default)


def _number(msg: dict[str, Any], key: str, lo: float, hi: float) -> float:
    v = msg[key]
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ProtocolError(f"{key}: expected a number, got {json.dumps(v)[:40]}")
    try:
        v = float(v)
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise ProtocolError(f"{key}: must be finite, got {v}")
    if not lo <= v <= hi:
        raise ProtocolError(f"{key}: {v:g} is outside [{lo:g}, {hi:g}]")
    return v


def _name(msg: dict[str, Any], key: str) -> str:
    v = msg[key]
    if not isinstance(v, str) or not _NAME.fullmatch(v):
        raise ProtocolError(f"{key}: expected a name of letters, digits, '_', '-', '.', "
                            f"got {json.dumps(v)[:60]}")
    return v


def parse(text: str | bytes, width: int, height: int) -> Message:
    """Parse and check one client message for a ``width × height`` studio view."""
    if isinstance(text, bytes):
        raise ProtocolError("binary messages are not accepted; send JSON text")
    if len(text) > MAX_MESSAGE_CHARS:
        raise ProtocolError(f"message of {len(text)} characters; at most "
                            f"{MAX_MESSAGE_CHARS}")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, too many digits, nesting
        raise ProtocolError(f"not JSON: {exc}") from None
    if not isinstance(msg, dict):
        raise ProtocolError(f"expected a JSON object, got {type(msg).__name__}")
    kind = msg.get("type")
    if not isinstance(kind, str) or kind not in FIELDS:
        raise ProtocolError(f"unknown message type {json.dumps(kind)[:40]}; known: "
                            f"{', '.join(FIELDS)}")
    required, optional = FIELDS[kind]
    given = set(msg) - {"type", "seq"}
    if missing := sorted(required - given):
        raise ProtocolError(f"{kind}: missing field {missing[0]!r}")
    if unknown := sorted(given - required - optional):
        raise ProtocolError(f"{kind}: unknown field {unknown[0][:40]!r}")
    seq = msg.get("seq")
    if seq is not None and (isinstance(seq, bool) or not isinstance(seq, int)
                            or not 0 <= seq < 2**53):
        raise ProtocolError("seq: expected an integer in [0, 2^53)")
    out: dict[str, Any] = {}
    if "x" in required:
        out["x"] = _number(msg, "x", 0.0, float(width))
        out["y"] = _number(msg, "y", 0.0, float(height))
    if "object" in required:
        out["object"] = _name(msg, "object")
    if kind == "pose":
        if "yaw_deg" in msg:
            out["yaw_deg"] = _number(msg, "yaw_deg", -MAX_YAW_DEG, MAX_YAW_DEG) % 360.0
        if "scale" in msg:
            out["scale"] = _number(msg, "scale", *SCALE_RANGE)
    elif kind == "exposure":
        out["ev"] = _number(msg, "ev", *EV_RANGE)
    elif kind == "method":
        out["name"] = _name(msg, "name")
    elif kind == "denoise":
        if not isinstance(msg["on"], bool):
            raise ProtocolError("denoise: on must be true or false")
        out["on"] = msg["on"]
    elif kind == "layer":
        if msg["name"] not in LAYERS:
            raise ProtocolError(f"layer: unknown layer {json.dumps(msg['name'])[:40]}; "
                                f"known: {', '.join(LAYERS)}")
        out["name"] = msg["name"]
    elif kind == "save":
        name = msg["name"]
        if not isinstance(name, str) or not SAVE_NAME.fullmatch(name):
            raise ProtocolError("save: name must be a plain file stem (letters, digits, '_', "
                                f"'-'; no dots or slashes), got {json.dumps(name)[:60]}")
        out["name"] = name
        if "overwrite" in msg:
            if not isinstance(msg["overwrite"], bool):
                raise ProtocolError("save: overwrite must be true or false")
            out["overwrite"] = msg["overwrite"]
    return Message(kind, seq, out)


def frame_message(header: dict[str, Any], image: bytes) -> bytes:
    """A binary frame: 4-byte big-endian header length, UTF-8 JSON header, image bytes."""
    head = json.dumps(header, allow_nan=False).encode()
    return len(head).to_bytes(4, "big") + head + image


def split_frame(data: bytes) -> tuple[dict[str, Any], bytes]:
    """Inverse of :func:`frame_message` (for clients and tests)."""
    n = int.from_bytes(data[:4], "big")
    return json.loads(data[4:4 + n]), data[4 + n:]
