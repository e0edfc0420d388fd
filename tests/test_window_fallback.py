"""The sliding frame window and the last-resort fill."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.stages.fallback import nearest_known, smooth_fill
from pipeline.runtime.window import sliding_window


def test_window_gives_every_item_with_its_clipped_neighbours_and_holds_few_items():
    held = []

    def source():
        for i in range(20):
            held.append(i)
            yield i

    seen = []
    for w in sliding_window(source(), 3):
        assert w.centre == w.index
        assert w.neighbours == {o: w.index + o for o in range(-3, 4) if o and 0 <= w.index + o < 20}
        # Read-ahead never goes beyond the window's right edge.
        assert len(held) <= w.index + 4
        seen.append(w.index)
    assert seen == list(range(20))


@pytest.mark.parametrize("n", [0, 1, 2])
def test_window_on_tiny_streams(n):
    windows = list(sliding_window(range(n), 5))
    assert [w.index for w in windows] == list(range(n))


def test_fill_of_a_constant_image_is_exact_and_keeps_known_pixels():
    image = np.full((60, 90, 3), 137, np.uint8)
    image[:, :5] = 0
    missing = np.zeros((60, 90), bool)
    missing[:, :5] = True
    missing[20:40, 30:70] = True
    out = smooth_fill(image, missing)
    assert (out[missing] == 137).all()
    np.testing.assert_array_equal(out[~missing], image[~missing])


def test_fill_of_a_smooth_gradient_is_close_and_continuous():
    yy, xx = np.mgrid[0:120, 0:200]
    image = np.dstack([xx, yy, (xx + yy) // 2]).astype(np.uint8)
    missing = np.zeros((120, 200), bool)
    missing[:, 170:] = True  # a wide border strip, as after a fast pan
    missing[40:80, 50:110] = True
    out = smooth_fill(image, missing)
    error = np.abs(out.astype(int) - image.astype(int))[missing]
    # Smooth, not exact: interior holes within a few levels; the border strip extrapolates flat.
    interior = np.zeros_like(missing)
    interior[40:80, 50:110] = True
    assert np.abs(out.astype(int) - image.astype(int))[interior].mean() < 4
    assert error.max() < 40
    # No seam: the first filled column continues the last known one.
    assert np.abs(out[:, 170].astype(int) - out[:, 169].astype(int)).max() <= 3


def test_fill_of_a_hole_does_not_depend_on_holes_elsewhere():
    rng = np.random.default_rng(8)
    image = cv2.GaussianBlur(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), (0, 0), 3)
    corner = np.zeros((240, 320), bool)
    corner[:6, :9] = True
    far = np.zeros((240, 320), bool)
    far[200:230, 280:320] = True
    far[100:104, 150:153] = True
    together = smooth_fill(image, corner | far)
    np.testing.assert_array_equal(together[corner], smooth_fill(image, corner)[corner])
    np.testing.assert_array_equal(together[far], smooth_fill(image, far)[far])
    np.testing.assert_array_equal(together[~(corner | far)], image[~(corner | far)])


def test_fill_with_nothing_known_or_nothing_missing():
    image = np.full((10, 10, 3), 50, np.uint8)
    assert (smooth_fill(image, np.zeros((10, 10), bool)) == image).all()
    assert smooth_fill(image, np.ones((10, 10), bool)).shape == image.shape


def test_nearest_known_is_at_the_smallest_euclidean_distance():
    rng = np.random.default_rng(7)
    missing = rng.random((60, 90)) < 0.6
    missing[:20, :40] = True  # a large hole: nearest pixels far away
    ys, xs = np.nonzero(missing)
    near = nearest_known(missing, ys, xs)
    assert not missing.reshape(-1)[near].any()
    known_y, known_x = np.nonzero(~missing)
    brute = np.sqrt(((ys[:, None] - known_y[None]) ** 2 + (xs[:, None] - known_x[None]) ** 2).min(axis=1))
    found = np.hypot(ys - near // 90, xs - near % 90)
    np.testing.assert_allclose(found, brute, atol=1e-9)
