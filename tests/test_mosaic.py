"""Mosaicing with the consistency constraint (eqs. 20-22) against synthetic truth and hand-made examples."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.evaluation import synthetic
from pipeline.stages.mosaic import MosaicConfig, consistent_mosaic
from pipeline.stages.warping import warp, warp_frame

RADIUS = 5  # neighbours t-5..t+5


def stabilized_window(video: synthetic.SyntheticVideo, t: int):
    """Frame t and its neighbours in t's stabilized (intended) coordinates, warped by the exact transforms."""
    world_from_stab = np.linalg.inv(video.intended_frame_from_world[t])
    target = warp_frame(video.frames[t], video.frame_from_world[t] @ world_from_stab)
    neighbours, valid = [], []
    for other in range(t - RADIUS, t + RADIUS + 1):
        if other != t and 0 <= other < video.n_frames:
            warped = warp_frame(video.frames[other], video.frame_from_world[other] @ world_from_stab)
            neighbours.append(warped.frame)
            valid.append(~warped.missing)
    stab_from_frame = video.intended_frame_from_world[t] @ np.linalg.inv(video.frame_from_world[t])
    truth = video.render_view(t, stab_from_frame)
    truth_valid = video.view_coverage(t, stab_from_frame)
    return target, neighbours, valid, truth, truth_valid


def cut(target, missing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    frame = target.frame.copy()
    missing = target.missing | missing
    frame[missing] = 0
    return frame, missing


@pytest.fixture(scope="module")
def static_video() -> synthetic.SyntheticVideo:
    return synthetic.generate(synthetic.SyntheticConfig(n_frames=21, moving_object=False, blurred_frames=(), seed=3))


@pytest.fixture(scope="module")
def moving_video() -> synthetic.SyntheticVideo:
    # 30 frames: the object crosses 0.6 of the width, ~13 px per frame, so t-5..t+5 disagree on its footprint.
    return synthetic.generate(synthetic.SyntheticConfig(n_frames=30, blurred_frames=(), seed=3))


def test_static_scene_is_filled_from_neighbours_with_high_psnr(static_video):
    target, neighbours, valid, truth, truth_valid = stabilized_window(static_video, 10)
    band = np.zeros_like(target.missing)
    band[:, :120] = True  # a wide border missing area, well covered by the neighbours
    frame, missing = cut(target, band)

    result = consistent_mosaic(frame, missing, neighbours, valid)

    judged = ~np.isnan(result.variance)
    assert judged.sum() > 0.9 * band.sum()
    assert result.accepted.sum() > 0.97 * judged.sum()  # exact registration: nearly everything is consistent
    psnr = synthetic.psnr(result.frame, truth, result.accepted & truth_valid)
    assert psnr > 30.0  # measured ~45 dB (interpolation differences only)
    np.testing.assert_array_equal(result.frame[~missing], frame[~missing])
    np.testing.assert_array_equal(result.remaining, missing & ~result.accepted)


def test_moving_object_in_missing_area_is_rejected_without_ghosts(moving_video):
    t = 8
    target, neighbours, valid, truth, truth_valid = stabilized_window(moving_video, t)
    world_from_stab = np.linalg.inv(moving_video.intended_frame_from_world[t])
    orig_from_stab = moving_video.frame_from_world[t] @ world_from_stab
    footprint = warp(moving_video.object_mask[t].astype(np.uint8), orig_from_stab, interpolation=cv2.INTER_NEAREST)
    footprint = footprint.astype(bool)
    # Cut from the nearest vertical border to past the object, so the object passes through the missing area.
    cx = np.nonzero(footprint)[1].mean()
    band = np.zeros_like(footprint)
    if cx < band.shape[1] / 2:
        band[:, : int(cx) + 80] = True
    else:
        band[:, int(cx) - 80 :] = True
    frame, missing = cut(target, band)

    result = consistent_mosaic(frame, missing, neighbours, valid)

    object_judged = footprint & missing & ~np.isnan(result.variance)
    assert object_judged.sum() > 2000
    threshold = MosaicConfig().variance_threshold
    assert np.median(result.variance[object_judged]) > 5 * threshold  # neighbours disagree there
    assert result.accepted[object_judged].mean() < 0.15  # mostly rejected (measured ~3% accepted)
    assert result.remaining[object_judged].mean() > 0.85
    # No ghost: measured ~35 dB (~21 dB with no threshold, where the object's smear is pasted in).
    assert synthetic.psnr(result.frame, truth, result.accepted & truth_valid) > 28.0


def grey(value: float) -> np.ndarray:
    return np.full((1, 1, 3), value, np.uint8)


def test_variance_is_eq_20_with_n_minus_1_and_fill_is_the_median():
    target = np.zeros((1, 1, 3), np.uint8)
    missing = np.ones((1, 1), bool)
    neighbours = [grey(10), grey(60), grey(20)]
    valid = [np.ones((1, 1), bool)] * 3

    result = consistent_mosaic(target, missing, neighbours, valid, MosaicConfig(variance_threshold=701.0))

    # mean 30, deviations -20, 30, -10: (400 + 900 + 100) / (3 - 1) = 700
    assert result.variance[0, 0] == pytest.approx(700.0, rel=1e-5)
    assert result.accepted[0, 0] and not result.remaining[0, 0]
    np.testing.assert_array_equal(result.frame[0, 0], [20, 20, 20])
    assert result.coverage[0, 0] == 3
    # The threshold is strict: v < T.
    strict = consistent_mosaic(target, missing, neighbours, valid, MosaicConfig(variance_threshold=700.0 - 1e-3))
    assert not strict.accepted[0, 0] and strict.remaining[0, 0]
    np.testing.assert_array_equal(strict.frame[0, 0], [0, 0, 0])


def test_colour_median_is_the_neighbour_with_the_median_intensity():
    target = np.zeros((1, 2, 3), np.uint8)
    missing = np.ones((1, 2), bool)
    # Intensities (0.30 R + 0.59 G + 0.11 B): 100, 110, 104.
    reddish = np.array([[[200, 50, 100], [0, 0, 0]]], np.uint8)
    greenish = np.array([[[70, 140, 60], [0, 0, 0]]], np.uint8)
    bluish = np.array([[[100, 100, 140], [0, 0, 0]]], np.uint8)
    valid = np.array([[True, False]])
    config = MosaicConfig(variance_threshold=1000.0)

    result = consistent_mosaic(target, missing, [reddish, greenish, bluish], [valid] * 3, config)
    np.testing.assert_array_equal(result.frame[0, 0], bluish[0, 0])  # an observed colour, not a per-channel mix

    # Even count: the mean of the two middle colours.
    pair = consistent_mosaic(target, missing, [reddish, greenish], [valid] * 2, config)
    np.testing.assert_array_equal(pair.frame[0, 0], [135, 95, 80])


def test_pixels_covered_by_too_few_neighbours_stay_missing():
    target = np.zeros((1, 3, 3), np.uint8)
    missing = np.ones((1, 3), bool)
    neighbours = [np.full((1, 3, 3), 50, np.uint8)] * 3
    # Pixel 0: covered by 1 neighbour, pixel 1 by 2, pixel 2 by 3.
    valid = [np.array([[True, True, True]]), np.array([[False, True, True]]), np.array([[False, False, True]])]

    result = consistent_mosaic(target, missing, neighbours, valid)
    np.testing.assert_array_equal(result.coverage, [[1, 2, 3]])
    assert np.isnan(result.variance[0, 0]) and result.variance[0, 1] == 0.0
    np.testing.assert_array_equal(result.accepted, [[False, True, True]])
    np.testing.assert_array_equal(result.remaining, [[True, False, False]])
    assert (result.frame[0, 0] == 0).all()

    stricter = consistent_mosaic(target, missing, neighbours, valid, MosaicConfig(min_neighbours=3))
    np.testing.assert_array_equal(stricter.accepted, [[False, False, True]])


def test_no_missing_area_returns_the_frame_unchanged():
    rng = np.random.default_rng(0)
    target = rng.integers(0, 256, (36, 64, 3), np.uint8)
    missing = np.zeros((36, 64), bool)
    neighbours = [rng.integers(0, 256, (36, 64, 3), np.uint8) for _ in range(4)]
    valid = [np.ones((36, 64), bool)] * 4

    result = consistent_mosaic(target, missing, neighbours, valid)
    np.testing.assert_array_equal(result.frame, target)
    assert result.frame is not target
    assert np.isnan(result.variance).all()
    assert not result.accepted.any() and not result.remaining.any()
    assert (result.coverage == 4).all()


def test_config_needs_two_neighbours_for_a_variance():
    with pytest.raises(ValueError):
        MosaicConfig(min_neighbours=1)


def test_majority_median_leaves_out_what_a_minority_of_neighbours_showed():
    """Eqs. 20-22 on the tightest strict majority: three of five samples agree (an object passed in the other two),
    so the pixel is accepted with the median of the three; two against two has no majority; fewer than three
    samples are not judged; the threshold applies to the majority's own variance."""
    from pipeline.imaging import intensity
    from pipeline.stages.mosaic import majority_median

    def judge(levels, valid=None, threshold=100.0):
        colours = np.array([[[v, v, v]] for v in levels], np.uint8)  # (n, 1, 3)
        ok_valid = np.ones((len(levels), 1), bool) if valid is None else np.array(valid)[:, None]
        return majority_median(colours, intensity(colours), ok_valid, threshold)

    ok, median, member = judge([100, 230, 104, 20, 102])
    assert ok[0] and (median[0] == 102).all()
    np.testing.assert_array_equal(member[:, 0], [True, False, True, False, True])
    ok, _, member = judge([100, 101, 200, 201])  # k = 3 of 4: no three agree
    assert not ok[0] and not member.any()
    ok, _, _ = judge([100, 101, 0], valid=[True, True, False])  # two samples: eq. 20's own rule, not a majority
    assert not ok[0]
    ok, median, _ = judge([90, 110, 100, 250, 10], threshold=99.5)  # the majority's variance is 100
    assert not ok[0]
    ok, median, _ = judge([90, 110, 100, 250, 10], threshold=100.5)
    assert ok[0] and (median[0] == 100).all()
    ok, median, member = judge([100, 102, 104, 106])  # even majority (3 of 4): the two middle ones' mean
    assert ok[0] and member[:, 0].sum() == 3


def _majority_median_numpy(colours, values, valid, variance_threshold):
    """majority_median as numpy arrays compute it (its first implementation): the reference the compiled search
    must equal bit for bit."""
    from pipeline.stages.mosaic import _middle

    n, m = values.shape
    count = valid.sum(axis=0)
    order = np.argsort(np.where(valid, values, np.inf), axis=0, kind="stable")
    ordered = np.where(np.arange(n)[:, None] < count, np.take_along_axis(values, order, axis=0), 0).astype(np.float64)
    first = np.vstack([np.zeros((1, m)), np.cumsum(ordered, axis=0)])
    second = np.vstack([np.zeros((1, m)), np.cumsum(ordered ** 2, axis=0)])
    k = count // 2 + 1
    columns = np.arange(m)
    best = np.full(m, np.inf)
    start = np.zeros(m, np.int64)
    for s in range(n):
        end = np.minimum(s + k, n)
        total = first[end, columns] - first[s, columns]
        variance = (second[end, columns] - second[s, columns] - total ** 2 / k) / np.maximum(k - 1, 1)
        better = (s + k <= count) & (variance < best)
        best = np.where(better, variance, best)
        start = np.where(better, s, start)
    ok = (count >= 3) & (best < variance_threshold)
    last = np.minimum(start + k - 1, n - 1)
    lower = order[np.minimum(start + (k - 1) // 2, n - 1), columns]
    upper = order[np.minimum(start + k // 2, n - 1), columns]
    rank = np.argsort(order, axis=0)
    return ok, _middle(colours, lower, upper), valid & (rank >= start) & (rank <= last) & ok


@pytest.mark.parametrize("n", [1, 2, 5, 12])
def test_majority_median_equals_its_numpy_form(n):
    """The compiled search gives numpy's results exactly: samples with ties (few grey levels), invalid ones,
    columns with 0..n samples, uint8 and float32 colours."""
    from pipeline.imaging import intensity
    from pipeline.stages.mosaic import majority_median

    rng = np.random.default_rng(n)
    m = 4000
    for levels in (4, 256):
        colours = (rng.integers(0, levels, (n, m, 3)) * (255 // (levels - 1))).astype(np.uint8)
        valid = rng.random((n, m)) < rng.random(m)  # every share of valid samples, some columns none
        values = intensity(colours)
        for threshold in (30.0, 100.0, 1e9):
            expected = _majority_median_numpy(colours, values, valid, threshold)
            for got, want in zip(majority_median(colours, values, valid, threshold), expected):
                np.testing.assert_array_equal(got, want)
            deep = colours.astype(np.float32) / 255
            for got, want in zip(majority_median(deep, values, valid, threshold),
                                 _majority_median_numpy(deep, values, valid, threshold)):
                np.testing.assert_array_equal(got, want)
        if n >= 3:  # (fewer samples are never judged)
            assert expected[0].any() and not expected[0].all()
