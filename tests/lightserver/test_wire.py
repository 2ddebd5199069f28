"""The binary layout of a light update (Rohmer §4; digest checklist items 10 and 19)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from arlight.lightserver import wire
from arlight.lightserver.producers import SyntheticMovingLight, lower_hemisphere_sh
from arlight.nearfield.state import NearFieldLight
from arlight.sphere.sh import project_samples


def random_light(m: int, n_obj: int, seed: int = 0) -> NearFieldLight:
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return NearFieldLight(positions=rng.uniform(-3, 3, (m, 3)), normals=n,
                          intensity=rng.uniform(0, 50, (m, 3)), area=rng.uniform(0, 0.5, m),
                          sh=rng.normal(size=(n_obj, 9, 3)), sequence=int(rng.integers(1, 1e9)),
                          timestamp=1.7e9 + rng.uniform())


@pytest.mark.parametrize("m,n_obj", [(0, 0), (1, 0), (0, 1), (16, 1), (64, 3), (200, 7)])
def test_payload_is_32_per_val_and_108_per_object(m, n_obj):
    msg = wire.encode(random_light(m, n_obj))
    assert wire.HEADER_BYTES == 48 and wire.VAL_BYTES == 32 and wire.SH_BYTES == 108
    assert len(msg) == 48 + 32 * m + 108 * n_obj == wire.message_bytes(m, n_obj)


def test_round_trip_to_packing_precision():
    light = random_light(wire.MAX_VALS, 4, seed=3)  # the largest M a client renders
    header, back = wire.decode(wire.encode(light, epoch=77, sent=123.5))
    assert (header.epoch, header.sequence, header.sent) == (77, light.sequence, 123.5)
    assert back.sequence == light.sequence and back.timestamp == light.timestamp
    f32 = lambda a: a.astype(np.float32).astype(np.float64)  # noqa: E731
    np.testing.assert_array_equal(back.positions, f32(light.positions))
    np.testing.assert_array_equal(back.intensity, f32(light.intensity))
    np.testing.assert_array_equal(back.area, f32(light.area))
    np.testing.assert_array_equal(back.sh, f32(light.sh))
    ang = np.degrees(np.arccos(np.clip((back.normals * light.normals).sum(1), -1, 1)))
    assert ang.max() < 0.5 and ang.max() < 0.01  # 16-bit octahedral: ~0.003° worst case


def test_octahedral_normals_over_the_whole_sphere_and_edge_cases():
    """Both hemispheres, the poles, the axes and the fold diagonals (|x| + |y| = 1)."""
    rng = np.random.default_rng(1)
    n = rng.normal(size=(20000, 3))
    axes = np.vstack([np.eye(3), -np.eye(3), [[1, 1, 0], [1, -1, 0], [-1, 1, 0], [-1, -1, 0],
                                              [0, 1, -1e-9], [1, 0, -1], [-1, -1, -1]]])
    n = np.vstack([n, axes])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    back = wire.oct_decode(wire.oct_encode(n))
    ang = np.degrees(np.arccos(np.clip((back * n).sum(1), -1, 1)))
    assert ang.max() < 0.01
    assert wire.oct_encode(n).dtype == np.dtype("<i2")


def test_values_beyond_float32_are_refused():
    light = random_light(2, 0)
    big = NearFieldLight(positions=light.positions, normals=light.normals,
                         intensity=light.intensity * 1e300, area=light.area, sh=light.sh)
    with pytest.raises(wire.WireError, match="float32"), np.errstate(over="ignore"):
        wire.encode(big)


def _patched(msg: bytes, offset: int, fmt: str, value) -> bytes:
    b = bytearray(msg)
    struct.pack_into(fmt, b, offset, value)
    return wire._finish(bytes(b[:48]), bytes(b[48:]))  # valid CRC: only the field is wrong


@pytest.mark.parametrize("mutate,match,reason", [
    (lambda m: m[:47], "truncated", "truncated"),
    (lambda m: m[:-1], "needs", "length"),
    (lambda m: m + b"\0", "needs", "length"),
    (lambda m: b"XXXX" + m[4:], "magic", "magic"),
    (lambda m: m[:100] + bytes([m[100] ^ 1]) + m[101:], "corrupted", "corrupted"),
    (lambda m: _patched(m, 5, "<B", 9), "kind", "kind"),
    (lambda m: _patched(m, 36, "<I", 10**6), "claims", "counts"),
    (lambda m: _patched(m, 36, "<I", 3), "needs", "length"),
    (lambda m: _patched(m, 48, "<f", float("nan")), "non-finite position", "finite"),
    (lambda m: _patched(m, 48 + 16, "<f", -1.0), "intensity must be >= 0", "negative"),
    (lambda m: _patched(m, 48 + 28, "<f", -1.0), "area must be >= 0", "negative"),
    (lambda m: _patched(m, 48 + 4 * 32 + 20, "<f", float("inf")), "non-finite sh", "finite"),
    (lambda m: _patched(m, 28, "<d", float("inf")), "finite", "finite"),
])
def test_malformed_messages_are_rejected(mutate, match, reason):
    msg = wire.encode(random_light(4, 1))
    with pytest.raises(wire.WireError, match=match) as err:
        wire.decode(mutate(msg))
    assert err.value.reason == reason


def test_wrong_version_is_its_own_error():
    msg = _patched(wire.encode(random_light(4, 1)), 4, "<B", 2)
    with pytest.raises(wire.WireVersionError, match="version 2") as err:
        wire.decode(msg)
    assert err.value.version == 2 and err.value.reason == "version"


def test_heartbeat_and_restamp():
    hb = wire.encode_heartbeat(42, epoch=3, sent=5.0)
    h, light = wire.decode(hb)
    assert light is None and (h.kind, h.sequence, h.epoch, len(hb)) == (wire.KIND_HEARTBEAT,
                                                                        42, 3, 48)
    msg = wire.encode(random_light(3, 2))
    again = wire.restamp(msg, 99.0)
    assert wire.decode(again)[0].sent == 99.0 and again[48:] == msg[48:]


def test_synthetic_source_is_exact():
    """VALs tile the lamp (Eq. 6: Σ I_j = L·A), move with the frame; SH of the floor bounce
    is the exact projection of a lower-hemisphere constant."""
    src = SyntheticMovingLight(vals=12, size=0.5, radiance=(10.0, 5.0, 2.0))
    a, b = src(0), src(5)
    assert a.count == 12 and math.isclose(a.area.sum(), 0.25)
    np.testing.assert_allclose(a.intensity.sum(0), np.array([10, 5, 2]) * 0.25)
    assert not np.allclose(a.positions, b.positions) and not np.allclose(a.sh, b.sh)
    # exact quadrature of the lower hemisphere: Gauss-Legendre in y on [-1, 0] × uniform phi
    y, wy = np.polynomial.legendre.leggauss(8)
    y, wy = (y - 1) / 2, wy / 2
    phi = (np.arange(16) + 0.5) * 2 * np.pi / 16
    yy, pp = np.meshgrid(y, phi, indexing="ij")
    s = np.sqrt(1 - yy**2)
    dirs = np.stack([s * np.sin(pp), yy, -s * np.cos(pp)], -1).reshape(-1, 3)
    w = (wy[:, None] * np.full(16, 2 * np.pi / 16)[None, :]).ravel()
    L = np.array([0.3, 0.2, 0.1])
    want = project_samples(dirs, np.tile(L, (len(w), 1)), w, 2)
    np.testing.assert_allclose(lower_hemisphere_sh(L), want, atol=1e-12)
