import numpy as np
import pytest

from arlight.camera_response import Transfer, srgb_decode, srgb_encode


@pytest.mark.parametrize("kind", ["srgb", "gamma", "linear"])
@pytest.mark.parametrize("exposure", [0.0, -1.5, 2.0])
def test_every_8bit_code_round_trips(kind, exposure):
    t = Transfer(kind, 2.2, exposure)
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16, 1).repeat(3, axis=2)
    radiance = t.to_radiance(codes).astype(np.float32)  # frames are stored as float32
    assert np.array_equal(t.to_display(radiance, np.uint8), codes)


def test_16bit_round_trip():
    t = Transfer("srgb", exposure=1.0)
    codes = np.arange(0, 65536, 7, dtype=np.uint16)[:, None].repeat(3, axis=1)[None]
    assert np.array_equal(t.to_display(t.to_radiance(codes).astype(np.float32), np.uint16),
                          codes)


def test_srgb_curve_known_values():
    assert srgb_decode(np.array(1.0)) == pytest.approx(1.0)
    assert srgb_decode(np.array(0.5)) == pytest.approx(0.21404, abs=1e-5)
    x = np.linspace(0, 1, 101)
    assert np.allclose(srgb_encode(srgb_decode(x)), x, atol=1e-12)


def test_exposure_scales_radiance():
    codes = np.full((1, 1, 3), 200, np.uint8)
    a = Transfer("linear", exposure=0.0).to_radiance(codes)
    b = Transfer("linear", exposure=1.0).to_radiance(codes)
    assert np.allclose(a, 2 * b)


def test_bad_transfer_rejected():
    with pytest.raises(ValueError, match="unknown transfer"):
        Transfer("log")


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_to_radiance_table_is_the_per_pixel_decode_bitwise(dtype):
    """The lookup table equals decoding each pixel (rejects a table cached per dtype only,
    so a second transfer reads the first's radiance, and an off-by-one code range)."""
    v_max = np.iinfo(dtype).max
    codes = np.random.default_rng(1).integers(0, v_max + 1, (9, 11, 3)).astype(dtype)
    codes[0, 0] = [0, 1, v_max]
    for t in (Transfer("srgb", exposure=0.0), Transfer("srgb", exposure=1.5),
              Transfer("gamma", 2.4, -1.0)):
        direct = t.decode(codes.astype(np.float64) / float(v_max)) / t.scale
        got = t.to_radiance(codes)
        assert got.dtype == np.float64 and got.flags.writeable
        assert np.array_equal(got, direct)
