"""Small helpers shared by the stages (pipeline/geometry.py)."""

from __future__ import annotations

import numpy as np

from pipeline import geometry


def test_mask_pixels_is_nonzero_in_raster_order():
    rng = np.random.default_rng(4)
    mask = rng.random((23, 31)) < 0.3
    for view in (mask, mask[3:20, 5:29], np.zeros((4, 6), bool)):
        rows, cols = geometry.mask_pixels(view)
        expected = np.nonzero(view)
        np.testing.assert_array_equal(rows, expected[0])
        np.testing.assert_array_equal(cols, expected[1])
