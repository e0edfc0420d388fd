"""Warping by S_t and the crop window, against transforms whose missing areas are known exactly."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.stages.warping import blacken, largest_crop, warp, warp_frame

W, H = 160, 90


def translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def test_warp_shifts_content_and_marks_exactly_the_uncovered_stripe():
    rng = np.random.default_rng(0)
    frame = rng.integers(1, 255, size=(H, W, 3), dtype=np.uint8)
    # orig_from_stab = translate(+7, 0): stabilized pixel x samples the original at x + 7.
    result = warp_frame(frame, translation(7, 0))
    assert result.missing[:, W - 7:].all() and not result.missing[:, : W - 7].any()
    np.testing.assert_array_equal(result.frame[:, : W - 7], frame[:, 7:])
    assert (result.frame[result.missing] == 0).all()


def test_subpixel_shift_counts_partially_covered_column_as_missing():
    frame = np.full((H, W, 3), 200, np.uint8)
    result = warp_frame(frame, translation(-2.5, 0))
    assert result.missing[:, :3].all() and not result.missing[:, 3:].any()


def test_identity_warp_misses_nothing():
    frame = np.full((H, W, 3), 90, np.uint8)
    result = warp_frame(frame, np.eye(3))
    assert not result.missing.any()


def _plain_warp(image: np.ndarray, m: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    if np.array_equal(m[2], [0.0, 0.0, 1.0]):
        return cv2.warpAffine(image, m[:2], size, flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return cv2.warpPerspective(image, m, size, flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


@pytest.mark.parametrize("seed", range(6))
def test_rgb_warps_through_rgba_give_the_bytes_of_channel_by_channel_warps(seed):
    # warp/warp_frame detour RGB through RGBA for speed: the result must be each channel warped alone, and the
    # missing mask that of a warped all-255 plane, for affine and projective transforms and any sizes.
    rng = np.random.default_rng(seed)
    height, width = (int(v) for v in rng.integers(1, 300, 2))
    out_size = (int(rng.integers(1, 300)), int(rng.integers(1, 300)))
    frame = rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)
    m = np.eye(3)
    m[:2, :2] += rng.normal(0, 0.05, (2, 2))
    m[:2, 2] = rng.normal(0, 20, 2)
    if seed % 2:
        m[2, :2] = rng.normal(0, 2e-4, 2)
    expected = np.dstack([_plain_warp(np.ascontiguousarray(frame[..., c]), m, out_size) for c in range(3)])
    coverage = _plain_warp(np.full((height, width), 255, np.uint8), m, out_size)
    np.testing.assert_array_equal(warp(frame, m, out_size), expected)
    into = np.empty_like(expected)
    assert warp(frame, m, out_size, out=into) is into
    np.testing.assert_array_equal(into, expected)
    result = warp_frame(frame, m, out_size)
    np.testing.assert_array_equal(result.missing, coverage < 255)
    expected[coverage < 255] = 0
    np.testing.assert_array_equal(result.frame, expected)


@pytest.mark.parametrize("shift", [3.0, 10.0])
def test_largest_crop_of_horizontal_jitter(shift):
    # Frames sample the original at x +/- shift: valid x is [shift, W-1-shift] in every frame.
    transforms = np.array([translation(shift, 0), translation(-shift, 0), np.eye(3)])
    window = largest_crop(transforms, W, H)
    expected_scale = (W - 1 - 2 * shift) / (W - 1)
    assert window.scale == pytest.approx(expected_scale, abs=1e-6)
    assert window.x0 == pytest.approx(shift, abs=1e-6)
    # The window keeps the aspect ratio and lies inside every frame's valid area.
    corners = np.array([[0, 0, 1], [W - 1, 0, 1], [W - 1, H - 1, 1], [0, H - 1, 1]], float).T
    for s_t in transforms:
        mapped = (s_t @ window.stab_from_out @ corners)[:2]
        assert (mapped[0] >= -1e-6).all() and (mapped[0] <= W - 1 + 1e-6).all()
        assert (mapped[1] >= -1e-6).all() and (mapped[1] <= H - 1 + 1e-6).all()


def test_crop_of_rotated_frames_is_valid_everywhere():
    a = np.radians(3.0)
    c, s = np.cos(a), np.sin(a)
    cx, cy = (W - 1) / 2, (H - 1) / 2
    rot = np.array([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy], [0, 0, 1]])
    window = largest_crop(np.array([rot, np.linalg.inv(rot)]), W, H)
    assert 0.5 < window.scale < 0.95
    frame = np.full((H, W, 3), 255, np.uint8)
    for s_t in (rot, np.linalg.inv(rot)):
        assert not warp_frame(frame, s_t @ window.stab_from_out).missing.any()


def test_no_common_area_gives_none():
    transforms = np.array([translation(W, 0), translation(-W, 0)])
    assert largest_crop(transforms, W, H) is None


def test_blacken_matches_boolean_assignment_on_frames_views_and_pixel_lists():
    rng = np.random.default_rng(2)
    frame = rng.integers(0, 256, (37, 51, 3), dtype=np.uint8)
    mask = rng.random((37, 51)) < 0.3
    expected = frame.copy()
    expected[mask] = 0
    result = frame.copy()
    assert blacken(result, mask) is result
    np.testing.assert_array_equal(result, expected)
    # a crop (rows not contiguous) is written in place, the rest of the frame untouched
    whole = frame.copy()
    blacken(whole[5:25, 10:40], mask[5:25, 10:40])
    expected = frame.copy()
    expected[5:25, 10:40][mask[5:25, 10:40]] = 0
    np.testing.assert_array_equal(whole, expected)
    # a list of pixels, contiguous or not
    for pixels in (frame.reshape(-1, 3)[:500].copy(), frame.reshape(-1, 3)[:1000:2]):
        flags = mask.reshape(-1)[:500]
        expected = pixels.copy()
        expected[flags] = 0
        blacken(pixels, flags)
        np.testing.assert_array_equal(pixels, expected)
    tiny = frame[:1, :1].copy()  # one pixel: OpenCV would read it as 1x3
    blacken(tiny, np.ones((1, 1), bool))
    assert not tiny.any()
    deep = frame.astype(np.float32) + 0.25  # deeper video's float32 pixels: the same rule
    expected = deep.copy()
    expected[mask] = 0
    np.testing.assert_array_equal(blacken(deep, mask), expected)
    with pytest.raises(ValueError):
        blacken(frame.astype(np.int16), mask)
