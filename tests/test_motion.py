"""Global motion against known transforms (thesis 3.2)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import geometry
from pipeline.stages import motion
from pipeline.evaluation.synthetic import make_two_frames

W, H = 640, 360


def about_centre(deg: float, scale: float = 1.0, tx: float = 0.0, ty: float = 0.0) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a) * scale, np.sin(a) * scale
    cx, cy = (W - 1) / 2, (H - 1) / 2
    return np.array([[c, -s, cx - c * cx + s * cy + tx], [s, c, cy - s * cx - c * cy + ty], [0, 0, 1.0]])


AFFINE = about_centre(1.5, 1.02, 5.3, -3.7) @ np.array([[1, 0.012, 0], [0.006, 1, 0], [0, 0, 1.0]])
SIMILARITY = about_centre(-2.0, 0.985, -7.2, 4.1)
HOMOGRAPHY = about_centre(1.0, 1.0, 4.0, 2.0) @ np.array([[1, 0, 0], [0, 1, 0], [2.5e-5, -1.5e-5, 1.0]])


def run(frame0: np.ndarray, frame1: np.ndarray, **options) -> motion.MotionEstimate:
    config = motion.MotionConfig(**options)
    return motion.estimate(motion.prepare(frame0, config), motion.prepare(frame1, config), config)


@pytest.mark.parametrize("model, truth, refine", [
    ("affine", AFFINE, "none"),
    ("affine", AFFINE, "ecc"),
    ("similarity", SIMILARITY, "none"),
    ("homography", HOMOGRAPHY, "none"),
    ("homography", HOMOGRAPHY, "ecc"),
])
@pytest.mark.parametrize("image", ["astronaut", "coffee"])
def test_known_transform_recovered_within_a_tenth_of_a_pixel(model, truth, refine, image):
    frame0, frame1 = make_two_frames(truth, size=(W, H), image=image)
    estimate = run(frame0, frame1, model=model, refine=refine)
    assert estimate.status == "ok"
    assert geometry.corner_error(estimate.curr_from_prev, truth, W, H) < 0.1
    assert estimate.inlier_ratio > 0.8


def test_downscaled_estimation_on_a_large_frame_is_expressed_in_full_resolution_pixels():
    width, height = 1920, 1080
    truth = np.array([[1.0, 0.0, 12.4], [0.0, 1.0, -8.6], [0.0, 0.0, 1.0]])
    frame0, frame1 = make_two_frames(truth, size=(width, height), image="coffee")
    estimate = run(frame0, frame1, max_side=960)
    # Estimated at half size: a tenth of a working pixel is two tenths here.
    assert geometry.corner_error(estimate.curr_from_prev, truth, width, height) < 0.2


def test_identical_frames_give_the_identity():
    frame0, _ = make_two_frames(np.eye(3), size=(W, H))
    for model in motion.MOTION_MODELS:
        estimate = run(frame0, frame0.copy(), model=model)
        assert estimate.status == "ok"
        np.testing.assert_allclose(estimate.curr_from_prev, np.eye(3), atol=1e-6)


@pytest.mark.parametrize("value", [0, 128])
def test_featureless_frames_fall_back_to_identity_with_a_warning(value):
    frame0, _ = make_two_frames(np.eye(3), size=(W, H))
    flat = np.full_like(frame0, value)
    for first, second in ((frame0, flat), (flat, flat.copy())):
        estimate = run(first, second)
        assert estimate.status in ("fallback", "cut")
        np.testing.assert_array_equal(estimate.curr_from_prev, np.eye(3))
        assert estimate.warning


def test_scene_cut_is_detected_and_not_a_motion():
    astronaut, _ = make_two_frames(np.eye(3), size=(W, H), image="astronaut")
    coffee, _ = make_two_frames(np.eye(3), size=(W, H), image="coffee")
    estimate = run(astronaut, coffee)
    assert estimate.status == "cut"
    np.testing.assert_array_equal(estimate.curr_from_prev, np.eye(3))
    assert "cut" in estimate.warning


def test_moving_foreground_does_not_bias_the_background_motion():
    truth = about_centre(0.8, 1.0, 3.0, -2.0)
    frame0, frame1 = make_two_frames(truth, size=(W, H), image="coffee")
    frame1 = frame1.copy()
    patch = frame0[100:220, 200:360].copy()
    frame1[110:230, 230:390] = patch  # a large object moving 30 px right, 10 down: ~8% of the frame
    estimate = run(frame0, frame1)
    assert geometry.corner_error(estimate.curr_from_prev, truth, W, H) < 0.3


def test_invalid_options_are_refused():
    with pytest.raises(ValueError):
        motion.MotionConfig(model="projective")
    with pytest.raises(ValueError):
        motion.MotionConfig(refine="bergen")
