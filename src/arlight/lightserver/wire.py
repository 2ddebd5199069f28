"""The binary layout of a near-field light update on the wire (Rohmer §4, §5.3–5.4).

One message = a 48-byte versioned header, then M VAL records of 32 bytes, then n_obj SH
blocks of 108 bytes (Rohmer: "32 B per VAL", "9×3×4 = 108 B" per virtual object), so an
update carries exactly ``48 + 32·M + 108·n_obj`` bytes (digest §8, checklist item 19).
Everything is little-endian.

Header (``HEADER``, 48 B)::

    magic     4s   b"ARNF"
    version   u8   WIRE_VERSION (1)
    kind      u8   KIND_UPDATE (a light state) or KIND_HEARTBEAT (no payload, M = n_obj = 0;
                   its ``sequence`` is the server's latest update number)
    flags     u16  0 (reserved)
    epoch     u32  random per server start: a restarted server starts a new sequence
    sequence  u64  update number, +1 per update within an epoch
    timestamp f64  when the light state was made, seconds since the epoch (NearFieldLight)
    sent      f64  when this message was published, seconds since the epoch (latency)
    count     u32  M, the number of VALs
    n_obj     u32  the number of SH blocks
    crc32     u32  zlib CRC-32 of the whole message with this field zeroed

VAL record (``VAL_DTYPE``, 32 B): position 3×f32 (m), normal as an octahedral map in
2×int16 (snorm, 4 B), RGB intensity 3×f32 (W/sr), disc area f32 (m²).
SH block: 9×3 f32, coefficient-major (``sh[k, c]``), W/(sr·m²).

:func:`decode` checks everything (size, magic, version, kind, CRC, finite and non-negative
values, counts within :data:`MAX_VALS` / :data:`MAX_OBJECTS` — read from the header before
anything is allocated — and radiometry within :data:`MAX_INTENSITY`, :data:`MAX_COORDINATE`,
:data:`MAX_AREA`, :data:`MAX_SH`) before it builds the immutable
:class:`~arlight.nearfield.NearFieldLight`, so a client can swap its state in one reference
assignment and never render a half-applied (or absurd) update. :func:`encode` refuses the
same, so a server never sends what its clients would drop. :data:`MAX_MESSAGE_BYTES` (the
largest legal message) sizes every socket's ``ZMQ_MAXMSGSIZE``.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np

from arlight.errors import ArlightError
from arlight.nearfield.state import MAX_VALS as NEARFIELD_MAX_VALS
from arlight.nearfield.state import SH_BLOCK_BYTES, VAL_RECORD_BYTES, NearFieldLight

MAGIC = b"ARNF"
WIRE_VERSION = 1
KIND_UPDATE = 1
KIND_HEARTBEAT = 2
HEADER = struct.Struct("<4sBBHIQddIII")
HEADER_BYTES = HEADER.size  # 48
_CRC_OFFSET = HEADER_BYTES - 4
VAL_DTYPE = np.dtype([("position", "<f4", (3,)), ("normal", "<i2", (2,)),
                      ("intensity", "<f4", (3,)), ("area", "<f4")])
VAL_BYTES = VAL_DTYPE.itemsize  # 32
SH_BYTES = SH_BLOCK_BYTES  # 108
MAX_VALS: int = NEARFIELD_MAX_VALS
"""Largest M a decoder accepts: what the ``nearfield`` method renders (256)."""
MAX_OBJECTS = 4096
"""Largest n_obj a decoder accepts (442 KiB of SH)."""
MAX_INTENSITY = 1.0e8
"""Largest VAL radiant intensity, W/sr, per RGB channel: far above any real emitter seen by a
light probe (the sun's disc through a 1 m² window is ≈ 2·10⁷ W/sr), far below float32 range
so that shading (I / r², sums over M) stays finite."""
MAX_COORDINATE = 1.0e4
"""Largest |x|, |y|, |z| of a VAL position, m (a 10 km room)."""
MAX_AREA = 1.0e4
"""Largest VAL disc area, m²."""
MAX_SH = 1.0e8
"""Largest |coefficient| of an SH block, W/(sr·m²)."""
MAX_MESSAGE_BYTES = 48 + 32 * MAX_VALS + 108 * MAX_OBJECTS
"""The largest legal message (450 608 B): the ``ZMQ_MAXMSGSIZE`` of the clients' sockets."""
_SNORM = 32767.0

assert HEADER_BYTES == 48 and VAL_BYTES == VAL_RECORD_BYTES
assert MAX_MESSAGE_BYTES == HEADER_BYTES + VAL_BYTES * MAX_VALS + SH_BYTES * MAX_OBJECTS


class WireError(ArlightError):
    """A message that is not a valid light update (truncated, corrupted, bad values).

    ``reason`` is a short key for counters: ``truncated``, ``magic``, ``version``, ``kind``,
    ``counts``, ``length``, ``corrupted``, ``finite``, ``negative``, ``normal``, ``range``
    (beyond float32 when encoding, beyond the documented caps when decoding).
    """

    def __init__(self, message: str, reason: str = "invalid"):
        self.reason = reason
        super().__init__(message)


class WireVersionError(WireError):
    """A well-formed header of another wire version (a server or client of another release)."""

    def __init__(self, version: int):
        self.version = version
        super().__init__(f"light message of wire version {version}; this arlight reads "
                         f"version {WIRE_VERSION} (upgrade the older of server and client)",
                         "version")


@dataclass(frozen=True)
class Header:
    """The decoded header of a message (see the module docstring for the fields)."""

    version: int
    kind: int
    flags: int
    epoch: int
    sequence: int
    timestamp: float
    sent: float
    count: int
    n_obj: int
    crc32: int


def payload_bytes(count: int, n_obj: int) -> int:
    """Bytes after the header: 32·M + 108·n_obj (Rohmer §4)."""
    return VAL_BYTES * count + SH_BYTES * n_obj


def message_bytes(count: int, n_obj: int) -> int:
    """Whole message size: header + 32·M + 108·n_obj."""
    return HEADER_BYTES + payload_bytes(count, n_obj)


# -- octahedral normals ----------------------------------------------------------------------

def _sign_not_zero(v: np.ndarray) -> np.ndarray:
    return np.where(v >= 0.0, 1.0, -1.0)


def oct_encode(normals: np.ndarray) -> np.ndarray:
    """Unit vectors (N, 3) → octahedral map (N, 2) int16 snorm.

    The octahedral parameterisation (Meyer et al. 2010, the "compressed" 4-byte normal of
    Rohmer §5.3): project onto |x|+|y|+|z| = 1, fold the lower half (z < 0) over the
    diagonals. With 16 bits per coordinate the worst angular error is about 0.003°.
    """
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    p = n[:, :2] / np.maximum(np.abs(n).sum(axis=1, keepdims=True), 1e-30)
    low = n[:, 2] < 0.0
    folded = (1.0 - np.abs(p[:, ::-1])) * _sign_not_zero(p)
    p = np.where(low[:, None], folded, p)
    return np.round(np.clip(p, -1.0, 1.0) * _SNORM).astype("<i2")


def oct_decode(code: np.ndarray) -> np.ndarray:
    """Octahedral map (N, 2) int16 snorm → unit vectors (N, 3) float64."""
    p = np.clip(np.asarray(code, dtype=np.float64).reshape(-1, 2) / _SNORM, -1.0, 1.0)
    z = 1.0 - np.abs(p).sum(axis=1)
    low = z < 0.0
    folded = (1.0 - np.abs(p[:, ::-1])) * _sign_not_zero(p)
    xy = np.where(low[:, None], folded, p)
    v = np.concatenate([xy, z[:, None]], axis=1)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# -- messages --------------------------------------------------------------------------------

def _crc(header: bytes | memoryview, body: bytes | memoryview) -> int:
    """CRC-32 of the header (its CRC field as zeros) followed by the body."""
    return zlib.crc32(body, zlib.crc32(bytes(header[:_CRC_OFFSET]) + b"\0\0\0\0"))


def _finish(header: bytes, body: bytes) -> bytes:
    crc = _crc(header, body)
    return header[:_CRC_OFFSET] + struct.pack("<I", crc) + body


def _f32(a: np.ndarray, what: str) -> np.ndarray:
    """float64 → float32, refusing values that overflow float32 (they would decode as inf)."""
    with np.errstate(over="ignore"):
        out = np.asarray(a, dtype=np.float64).astype(np.float32)
    if not np.all(np.isfinite(out)):
        raise WireError(f"NearFieldLight.{what}: values beyond float32 range cannot be sent",
                        "range")
    return out


_CAPS = {"position": (MAX_COORDINATE, "m"), "intensity": (MAX_INTENSITY, "W/sr"),
         "area": (MAX_AREA, "m²"), "sh": (MAX_SH, "W/(sr·m²)")}


def _check_caps(fields: dict[str, np.ndarray], what: str) -> None:
    """Finite, non-negative intensity and area, every magnitude within :data:`_CAPS`."""
    for name, a in fields.items():
        if not np.all(np.isfinite(a)):
            raise WireError(f"{what}: non-finite {name}", "finite")
    for name in ("intensity", "area"):
        if np.any(fields[name] < 0):
            raise WireError(f"{what}: {name} must be >= 0", "negative")
    for name, (cap, unit) in _CAPS.items():
        a = fields[name]
        if a.size and float(np.max(np.abs(a))) > cap:
            raise WireError(f"{what}: {name} {float(np.max(np.abs(a))):.3g} {unit} beyond "
                            f"the wire limit {cap:g}", "range")


def encode(light: NearFieldLight, *, epoch: int = 0, sent: float = 0.0) -> bytes:
    """Pack a light state: header (kind update) + 32·M + 108·n_obj bytes.

    ``light.sequence`` and ``light.timestamp`` go into the header; ``sent`` is the
    publication time (seconds since the epoch) the receiver measures latency against.
    """
    m, n_obj = light.count, light.n_objects
    if m > MAX_VALS or n_obj > MAX_OBJECTS:
        raise WireError(f"NearFieldLight: {m} VALs / {n_obj} objects exceed the wire "
                        f"limits ({MAX_VALS} / {MAX_OBJECTS})", "counts")
    vals = np.empty(m, dtype=VAL_DTYPE)
    vals["position"] = _f32(light.positions, "positions")
    vals["normal"] = oct_encode(light.normals)
    vals["intensity"] = _f32(light.intensity, "intensity")
    vals["area"] = _f32(light.area, "area")
    sh = _f32(light.sh, "sh").astype("<f4")
    _check_caps({"position": vals["position"], "intensity": vals["intensity"],
                 "area": vals["area"], "sh": sh}, f"NearFieldLight {light.sequence}")
    body = vals.tobytes() + sh.tobytes()
    header = HEADER.pack(MAGIC, WIRE_VERSION, KIND_UPDATE, 0, epoch & 0xFFFFFFFF,
                         int(light.sequence), float(light.timestamp), float(sent), m, n_obj, 0)
    return _finish(header, body)


def encode_heartbeat(sequence: int, *, epoch: int = 0, sent: float = 0.0,
                     timestamp: float = 0.0) -> bytes:
    """A heartbeat: header only (M = n_obj = 0), ``sequence`` = the latest update number."""
    header = HEADER.pack(MAGIC, WIRE_VERSION, KIND_HEARTBEAT, 0, epoch & 0xFFFFFFFF,
                         int(sequence), float(timestamp), float(sent), 0, 0, 0)
    return _finish(header, b"")


def restamp(message: bytes, sent: float) -> bytes:
    """The same message with a new publication time (and CRC); the payload is not re-packed."""
    header = bytearray(message[:HEADER_BYTES])
    struct.pack_into("<d", header, 28, float(sent))
    return _finish(bytes(header), message[HEADER_BYTES:])


def decode_header(message: bytes) -> Header:
    """Parse and check the header (size, magic, version, kind, counts, total length, CRC)."""
    buf = memoryview(message)
    if len(buf) < HEADER_BYTES:
        raise WireError(f"light message truncated: {len(buf)} bytes, a header is "
                        f"{HEADER_BYTES}", "truncated")
    fields = HEADER.unpack_from(buf, 0)
    if fields[0] != MAGIC:
        raise WireError(f"not a light message: magic {bytes(fields[0])!r}, expected {MAGIC!r}",
                        "magic")
    h = Header(*fields[1:])
    if h.version != WIRE_VERSION:
        raise WireVersionError(h.version)
    if h.kind not in (KIND_UPDATE, KIND_HEARTBEAT):
        raise WireError(f"light message of unknown kind {h.kind}", "kind")
    if h.count > MAX_VALS or h.n_obj > MAX_OBJECTS:
        raise WireError(f"light message claims {h.count} VALs and {h.n_obj} objects (limits "
                        f"{MAX_VALS}, {MAX_OBJECTS})", "counts")
    if h.kind == KIND_HEARTBEAT and (h.count or h.n_obj):
        raise WireError("heartbeat with a payload", "counts")
    want = message_bytes(h.count, h.n_obj)
    if len(buf) != want:
        raise WireError(f"light message of {len(buf)} bytes; its header (M = {h.count}, "
                        f"n_obj = {h.n_obj}) needs {want}", "length")
    crc = _crc(buf, buf[HEADER_BYTES:])
    if crc != h.crc32:
        raise WireError(f"light message corrupted: CRC-32 {crc:08x}, header says "
                        f"{h.crc32:08x}", "corrupted")
    if not (np.isfinite(h.timestamp) and np.isfinite(h.sent)):
        raise WireError("light message with a non-finite timestamp", "finite")
    return h


def decode(message: bytes) -> tuple[Header, NearFieldLight | None]:
    """Check and unpack a message: ``(header, light)``; ``light`` is None for a heartbeat.

    Raises :class:`WireError` (or :class:`WireVersionError`) for anything invalid; nothing
    is returned half-built.
    """
    h = decode_header(message)
    if h.kind == KIND_HEARTBEAT:
        return h, None
    vals = np.frombuffer(message, dtype=VAL_DTYPE, count=h.count, offset=HEADER_BYTES)
    sh = np.frombuffer(message, dtype="<f4", count=27 * h.n_obj,
                       offset=HEADER_BYTES + VAL_BYTES * h.count).reshape(h.n_obj, 9, 3)
    _check_caps({"position": vals["position"], "intensity": vals["intensity"],
                 "area": vals["area"], "sh": sh}, f"light message {h.sequence}")
    try:
        light = NearFieldLight(positions=vals["position"].astype(np.float64),
                               normals=oct_decode(vals["normal"]),
                               intensity=vals["intensity"].astype(np.float64),
                               area=vals["area"].astype(np.float64),
                               sh=sh.astype(np.float64), sequence=int(h.sequence),
                               timestamp=float(h.timestamp))
    except ArlightError as exc:  # e.g. a normal that does not decode to a unit vector
        raise WireError(f"light message {h.sequence}: {exc}", "normal") from exc
    return h, light
