"""Temporal consistency of the synthesized pixels (pipeline/stages/temporal.py) against known truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data

from pipeline.errors import ConfigError
from pipeline.stages.temporal import CompletedNeighbour, TemporalConfig, smooth

H, W, STRIP = 120, 160, 40


def _scene() -> np.ndarray:
    """A wide textured photograph: frames are windows of it."""
    return np.ascontiguousarray(data.astronaut()[100:260, 100:320])


def _view(scene: np.ndarray, x0: int, y0: int) -> np.ndarray:
    return scene[y0:y0 + H, x0:x0 + W].copy()


def _translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def _strip() -> np.ndarray:
    synthesized = np.zeros((H, W), bool)
    synthesized[:, W - STRIP:] = True
    return synthesized


def _with_error(image: np.ndarray, synthesized: np.ndarray, seed: int, sd: float) -> np.ndarray:
    """What completion makes of a strip when each frame picks its own near-equal sample: the truth plus an error of
    its own."""
    noisy = image.astype(np.float64)
    noisy[synthesized] += np.random.default_rng(seed).normal(0.0, sd, (int(synthesized.sum()), 3))
    return np.clip(noisy, 0, 255).astype(np.uint8)


def _rms(image: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean((image[mask].astype(np.float64) - truth[mask]) ** 2)))


def test_each_frames_own_error_in_the_strip_is_averaged_towards_the_truth_and_real_pixels_stay():
    scene, synthesized = _scene(), _strip()
    truth = _view(scene, 30, 20)
    frame = _with_error(truth, synthesized, 0, 12.0)
    neighbours = [CompletedNeighbour(offset, _with_error(truth, synthesized, seed, 12.0), np.eye(3), synthesized)
                  for offset, seed in ((-1, 1), (1, 2))]

    result = smooth(frame, synthesized, neighbours, TemporalConfig())

    before, after = _rms(frame, truth, synthesized), _rms(result.frame, truth, synthesized)
    assert after < 0.7 * before, (before, after)  # three independent errors: about 1/sqrt(3) of one
    np.testing.assert_array_equal(result.frame[~synthesized], frame[~synthesized])
    assert result.neighbours == (-1, 1)
    assert np.all(result.share[~synthesized] == 0)
    assert 0.5 < float(result.share[synthesized].mean()) <= 2 / 3 + 1e-6


def test_neighbours_are_sampled_where_the_output_transform_puts_the_scene_point():
    """Frame j sees the scene from 7 px right and 3 px up of frame t: with the true other_from_t the average lands
    on the truth; with the identity it samples other scene points, which disagree and are left out."""
    scene, synthesized = _scene(), _strip()
    truth = _view(scene, 30, 20)
    frame = _with_error(truth, synthesized, 0, 12.0)
    later = _view(scene, 37, 17)  # t's pixel (x, y) is at (x - 7, y + 3) in it
    right, wrong = _translation(-7.0, 3.0), np.eye(3)

    everywhere = np.ones((H, W), bool)  # frame j synthesized all of it (its own strip is elsewhere)
    at_right = smooth(frame, synthesized, [CompletedNeighbour(1, later, right, everywhere)], TemporalConfig()).frame
    at_wrong = smooth(frame, synthesized, [CompletedNeighbour(1, later, wrong, everywhere)], TemporalConfig()).frame

    assert _rms(at_right, truth, synthesized) < 0.8 * _rms(frame, truth, synthesized)
    assert _rms(at_right, truth, synthesized) < 0.8 * _rms(at_wrong, truth, synthesized)


def test_a_moving_object_shown_by_the_neighbours_does_not_ghost_into_frame_t():
    """An object the neighbours show inside t's strip (t itself shows the background there), 127 grey levels from
    t's own in every channel: such a sample weighs e^-6.5; frame t's pixels come out as they were."""
    scene, synthesized = _scene(), _strip()
    frame = _view(scene, 30, 20)
    neighbours = []
    for offset in (-1, 1):
        other = frame.copy()
        patch = frame[30:90, W - 30:W - 5]
        other[30:90, W - 30:W - 5] = np.where(patch < 128, patch + 127, patch - 127)  # 127 from t's own in every channel
        neighbours.append(CompletedNeighbour(offset, other, np.eye(3), synthesized))

    result = smooth(frame, synthesized, neighbours, TemporalConfig())

    difference = np.abs(result.frame.astype(np.int16) - frame)
    assert int(difference[30:90, W - 30:W - 5].max()) <= 1
    np.testing.assert_array_equal(result.frame[:30], frame[:30])  # elsewhere the neighbours agree exactly


def test_a_neighbours_real_pixels_are_not_averaged_in():
    """Where frame j saw the scene point itself (a real pixel), its pixel is not averaged in: j may be motion-blurred,
    and completion has drawn on it already. A blurred neighbour that synthesized only half of t's strip leaves the
    other half exactly as t had it."""
    scene, synthesized = _scene(), _strip()
    truth = _view(scene, 30, 20)
    frame = _with_error(truth, synthesized, 0, 4.0)
    blurred = cv2.blur(truth, (13, 1))
    own_strip = np.zeros((H, W), bool)
    own_strip[:, W - STRIP // 2:] = True  # j synthesized the right half of t's strip only

    result = smooth(frame, synthesized, [CompletedNeighbour(1, blurred, np.eye(3), own_strip)], TemporalConfig())

    seen_by_j = synthesized & ~own_strip
    np.testing.assert_array_equal(result.frame[seen_by_j], frame[seen_by_j])
    assert np.all(result.share[seen_by_j] == 0) and np.all(result.share[own_strip] > 0)


def test_nothing_to_average_leaves_the_frame_as_it_is():
    frame = _view(_scene(), 0, 0)
    no_strip = np.zeros((H, W), bool)
    assert smooth(frame, no_strip, [CompletedNeighbour(1, frame, np.eye(3), no_strip)], TemporalConfig()).frame is frame
    alone = smooth(frame, _strip(), [], TemporalConfig())
    assert alone.frame is frame and alone.neighbours == () and not alone.share.any()


@pytest.mark.parametrize("kwargs", [{"radius": -1}, {"sigma": 0.0}, {"sigma": float("nan")}])
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(ConfigError):
        TemporalConfig(**kwargs)


def test_a_strip_wider_than_one_remap_row_is_averaged_too():
    """Synthesized areas of 720p and larger hold more points than cv2.remap takes in one row (32767)."""
    rng = np.random.default_rng(3)
    frame = rng.integers(0, 256, (300, 400, 3), dtype=np.uint8)
    synthesized = np.zeros((300, 400), bool)
    synthesized[:, :130] = True  # 39000 pixels
    brighter = np.clip(frame.astype(np.int16) + 6, 0, 255).astype(np.uint8)
    result = smooth(frame, synthesized, [CompletedNeighbour(1, brighter, np.eye(3), synthesized)], TemporalConfig())
    gained = result.frame[synthesized].astype(np.int16) - frame[synthesized]
    assert int(synthesized.sum()) > 32767 and np.median(gained) == 3  # halfway, on every row
    np.testing.assert_array_equal(result.frame[~synthesized], frame[~synthesized])
