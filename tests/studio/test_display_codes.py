"""The studio's display codes from a table (:func:`arlight.studio.imaging.to_display`,
issue #32): bit for bit ``Transfer.to_display``, at 0.3× its time."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.camera_response import Transfer
from arlight.studio.imaging import AMBIGUOUS, BUCKET_BITS, code_table, to_display

TRANSFERS = [Transfer(), Transfer(exposure=1.3), Transfer(kind="gamma", gamma=2.2,
                                                          exposure=-0.7),
             Transfer(kind="linear", exposure=4.0)]


def _exact(tr: Transfer, x: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", over="ignore"):
        return tr.to_display(x)


@pytest.mark.parametrize("tr", TRANSFERS)
def test_table_codes_equal_the_transfer(tr):
    """Every bucket's first and last float, a dense sweep of all positive floats, random
    radiance and NaN/±inf/±0 give ``to_display``'s codes. Rejects thresholds counted with
    the wrong side (a code too low or high at a bucket whose first float is a threshold),
    a bucket that holds a threshold not marked ambiguous, the table of another exposure,
    and NaN or negative radiance not displayed as 0."""
    b = np.arange((0x7F800000 >> BUCKET_BITS) + 1, dtype=np.uint32) << BUCKET_BITS
    edges = np.concatenate([b, b | ((1 << BUCKET_BITS) - 1)]).view(np.float32)
    dense = np.arange(0, 0x7F800000, 997, dtype=np.uint32).view(np.float32)
    rng = np.random.default_rng(2)
    radiance = rng.uniform(-0.1, 3.0, (120, 160, 3)).astype(np.float32)
    radiance[0, :6] = [[np.nan] * 3, [np.inf] * 3, [-np.inf] * 3, [-0.0] * 3, [0.0] * 3,
                       [-np.nan] * 3]
    for x in (edges, dense, radiance, np.asarray(radiance[10:50, 20:90])):  # a window too
        with np.errstate(invalid="ignore", over="ignore"):  # NaN, inf: as to_display
            got = to_display(tr, x)
        assert got.dtype == np.uint8 and got.shape == x.shape
        np.testing.assert_array_equal(got, _exact(tr, x))
    table = code_table(tr)
    assert np.count_nonzero(table == AMBIGUOUS) <= 256  # one per code step, and +inf
    assert not table.flags.writeable


def test_other_dtypes_go_through_the_transfer():
    """float64 radiance is displayed by ``to_display`` itself (the table is for float32)."""
    x = np.linspace(-0.5, 2.0, 1001)
    np.testing.assert_array_equal(to_display(Transfer(), x), Transfer().to_display(x))
