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


def test_is_affine_is_allclose_to_the_affine_last_row():
    rng = np.random.default_rng(5)
    rows = [[0.0, 0.0, 1.0], [1e-8, -1e-8, 1.0 + 1.001e-5], [2e-8, 0.0, 1.0], [0.0, 0.0, 1.0 + 1.1e-5],
            [0.0, 0.0, 1.0 - 1e-5], [1e-4, 0.0, 1.0], [np.nan, 0.0, 1.0], [0.0, 0.0, np.inf]]
    rows += list(rng.choice([0.0, 1.0, 1e-9, 5e-9, 2e-8, 9e-6, 1.1e-5], size=(200, 3)) * rng.choice([-1, 1], (200, 3))
                 + [0.0, 0.0, 1.0])
    for row in rows:
        m = np.vstack([rng.normal(size=(2, 3)), row])
        assert geometry.is_affine(m) == np.allclose(m[2], [0.0, 0.0, 1.0]), row
