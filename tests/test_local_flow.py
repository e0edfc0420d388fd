"""Neighbour priority (eq. 23) and dense local flow, against known flows on a real photo and synthetic truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.stages import local_warp
from pipeline.evaluation import synthetic
from pipeline.stages.local_flow import LocalFlowConfig, fill_invalid, local_flow, mean_abs_difference
from pipeline.imaging import intensity
from pipeline.stages.neighbours import WarpedNeighbour
from pipeline.stages.warping import warp, warp_frame

W, H = 640, 360


@pytest.fixture(scope="module")
def photo() -> np.ndarray:
    return cv2.resize(synthetic.load_image("astronaut"), (W, H), interpolation=cv2.INTER_AREA)


def shifted(image: np.ndarray, dx: float, dy: float = 0.0) -> np.ndarray:
    """out(p) = image(p + (dx, dy))."""
    return warp(image, np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]]), border_value=0)


def smooth_flow(width: int = W, height: int = H) -> np.ndarray:
    """(H, W, 2): translation (1.6, -0.9) px, +-0.8 px of affine change across the frame, a 1 px sinusoid."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    u, v = xs / width - 0.5, ys / height - 0.5
    fx = 1.6 + 0.8 * u - 0.5 * v + np.sin(2 * np.pi * xs / 240.0)
    fy = -0.9 + 0.3 * u + 0.8 * v + np.cos(2 * np.pi * (ys / 160.0 + xs / 400.0))
    return np.stack([fx, fy], axis=-1).astype(np.float32)


def resample(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """out(p) = image(p + flow(p)): so flow is exactly the target -> neighbour flow from out to image."""
    ys, xs = np.mgrid[0 : flow.shape[0], 0 : flow.shape[1]].astype(np.float32)
    return cv2.remap(image, xs + flow[..., 0], ys + flow[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def with_holes(image: np.ndarray, valid: np.ndarray) -> np.ndarray:
    out = image.copy()
    out[~valid] = 0
    return out


def epe(flow: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    return float(np.linalg.norm(flow - truth, axis=-1)[mask].mean())


# ---------------------------------------------------------------------- eq. 23


def test_alignment_error_prefers_the_well_aligned_neighbour_whatever_the_overlap(photo):
    target_valid = np.ones((H, W), bool)
    aligned, misaligned = shifted(photo, 0.5), shifted(photo, 3.0, 2.0)
    aligned_valid = np.ones((H, W), bool)
    misaligned_valid = np.zeros((H, W), bool)
    misaligned_valid[:, : W // 8] = True  # a neighbour that barely overlaps

    good = mean_abs_difference(intensity(photo), target_valid, aligned, aligned_valid)
    bad = mean_abs_difference(intensity(photo), target_valid, misaligned, misaligned_valid)
    assert good < bad
    # Eq. 23's plain sum would get this backwards: the misaligned neighbour has far fewer pixels to sum over.
    assert good * aligned_valid.sum() > bad * misaligned_valid.sum()


def test_alignment_error_is_infinite_without_common_area(photo):
    valid = np.ones((H, W), bool)
    sliver = np.zeros((H, W), bool)
    sliver[:, :5] = True  # 0.8% of the frame
    assert mean_abs_difference(intensity(photo), valid, photo, sliver) == float("inf")
    assert mean_abs_difference(intensity(photo), valid, photo, valid) == 0.0


def test_priority_is_nearest_in_time_first_with_eq_23_breaking_ties(photo):
    valid = np.ones((H, W), bool)
    misaligned = shifted(photo, 3.0, 2.0)
    neighbours = [WarpedNeighbour(offset, rgb, valid) for offset, rgb in
                  ((-1, misaligned), (1, photo), (-2, photo), (2, photo), (3, photo))]
    order, errors = local_warp.priority(photo, valid, neighbours, needed=4)
    assert [neighbours[i].offset for i in order] == [1, -1, -2, 2, 3]  # equal errors: t-k first
    assert errors[1] == 0.0 and errors[0] > 5.0
    assert np.isnan(errors[4])  # four usable neighbours were ordered before t+3: its error is never measured


# ---------------------------------------------------------------------- local flow


# (preset, mean EPE bound, EPE bound near the holes); measured medium 0.18 / 0.21 px, fast (the default) 0.39 / 0.52
FLOW_BOUNDS = [("medium", 0.3, 0.5), ("fast", 0.5, 0.7)]


@pytest.mark.parametrize("preset, mean_bound, near_bound", FLOW_BOUNDS)
def test_recovers_a_known_smooth_flow_on_a_real_photo(photo, preset, mean_bound, near_bound):
    truth = smooth_flow()
    target_valid = np.ones((H, W), bool)
    target_valid[:, :48] = target_valid[:20] = False  # the target's missing area
    neighbour_valid = np.ones((H, W), bool)
    neighbour_valid[:, -40:] = neighbour_valid[-30:] = False
    target = with_holes(resample(photo, truth), target_valid)
    neighbour = with_holes(photo, neighbour_valid)

    result = local_flow(target, target_valid, neighbour, neighbour_valid, LocalFlowConfig(dis_preset=preset))

    assert result.flow.shape == (H, W, 2) and result.flow.dtype == np.float32
    # Mean end-point error over the common area (~0.43 px with ultrafast).
    assert epe(result.flow, truth, result.common) < mean_bound
    # Next to the target's holes, where motion inpainting starts, the black border must not drag the flow
    # (~1.3 px with DIS medium and the holes left black).
    near_holes = cv2.distanceTransform(target_valid.astype(np.uint8), cv2.DIST_L2, 5) < 24
    assert epe(result.flow, truth, result.common & near_holes) < near_bound


@pytest.mark.parametrize("method", ["farneback", "lk"])
def test_other_methods_recover_the_smooth_flow_roughly(photo, method):
    truth = smooth_flow()
    valid = np.ones((H, W), bool)
    result = local_flow(resample(photo, truth), valid, photo, valid, LocalFlowConfig(method=method))
    assert epe(result.flow, truth, result.common) < 0.8  # measured: farneback ~0.63, lk ~0.18


def test_identical_images_give_near_zero_flow(photo):
    target_valid = np.ones((H, W), bool)
    target_valid[:, -60:] = False
    neighbour_valid = np.ones((H, W), bool)
    neighbour_valid[:40] = False
    target, neighbour = with_holes(photo, target_valid), with_holes(photo, neighbour_valid)
    result = local_flow(target, target_valid, neighbour, neighbour_valid)
    assert np.linalg.norm(result.flow, axis=-1)[result.common].mean() < 0.05


def test_common_area_excludes_invalid_pixels_with_a_margin():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (90, 160, 3), np.uint8)
    target_valid = np.ones((90, 160), bool)
    target_valid[:, :30] = False
    neighbour_valid = np.ones((90, 160), bool)
    neighbour_valid[70:] = False

    config = LocalFlowConfig(common_erosion_px=3)
    common = local_flow(image, target_valid, image, neighbour_valid, config).common

    assert not common[:, :33].any() and not common[67:].any()
    assert common[:67, 33:].all()  # the frame's own edge does not erode


def test_flow_of_the_moving_object_matches_its_motion():
    video = synthetic.generate(synthetic.SyntheticConfig(n_frames=30, blurred_frames=(), seed=3))
    t, other = 12, 13
    world_from_stab = np.linalg.inv(video.intended_frame_from_world[t])
    target = warp_frame(video.frames[t], video.frame_from_world[t] @ world_from_stab)
    neighbour = warp_frame(video.frames[other], video.frame_from_world[other] @ world_from_stab)
    # The object's own motion, in t's stabilized coordinates.
    pose = video.object_world_from_patch
    moved_from_stab = np.linalg.inv(world_from_stab) @ pose[other] @ np.linalg.inv(pose[t]) @ world_from_stab
    footprint = warp(video.object_mask[t].astype(np.uint8), video.frame_from_world[t] @ world_from_stab,
                     interpolation=cv2.INTER_NEAREST)
    interior = cv2.erode(footprint, np.ones((9, 9), np.uint8)).astype(bool)
    ys, xs = np.nonzero(interior)
    moved = moved_from_stab @ np.stack([xs, ys, np.ones_like(xs)]).astype(np.float64)
    truth = np.stack([moved[0] - xs, moved[1] - ys], axis=-1)
    assert np.linalg.norm(truth, axis=-1).mean() > 8  # a real displacement, not a near-zero one

    result = local_flow(target.frame, ~target.missing, neighbour.frame, ~neighbour.missing)

    inside = result.common[ys, xs]
    assert inside.mean() > 0.9
    errors = np.linalg.norm(result.flow[ys, xs] - truth, axis=-1)[inside]
    assert errors.mean() < 1.0  # measured ~0.09 px (zero flow: ~12 px)
    # The static background, globally registered exactly, has (almost) no local motion.
    far = ~cv2.dilate(footprint, np.ones((41, 41), np.uint8)).astype(bool) & result.common
    assert np.linalg.norm(result.flow, axis=-1)[far].mean() < 0.3  # measured ~0.05 px


@pytest.mark.parametrize("motion", [(36, -20), (44, 10), (-40, 0)])
def test_large_motion_rescue_finds_what_the_flow_misses(photo, motion):
    """An 80 px textured object moved 40-45 px over a static photo: DIS (fast) keeps it at the background's
    zero motion; the rescue's translation search (inside ``focus``) finds its motion."""
    dx, dy = motion
    item = cv2.resize(synthetic.load_image("coffee"), (80, 80), interpolation=cv2.INTER_AREA)
    target, neighbour = photo.copy(), photo.copy()
    y0, x0 = 140, 280
    target[y0:y0 + 80, x0:x0 + 80] = item
    neighbour[y0 + dy:y0 + dy + 80, x0 + dx:x0 + dx + 80] = item
    valid, focus = np.ones((H, W), bool), np.ones((H, W), bool)
    interior = np.zeros((H, W), bool)
    interior[y0 + 8:y0 + 72, x0 + 8:x0 + 72] = True

    def share_found(config: LocalFlowConfig) -> float:
        flow = local_flow(target, valid, neighbour, valid, config, focus=focus).flow
        return float((np.linalg.norm(flow[interior] - (dx, dy), axis=1) < 1.0).mean())

    assert share_found(LocalFlowConfig()) > 0.8  # measured 0.87-0.95
    assert share_found(LocalFlowConfig(rescue_error=None)) < 0.1  # measured 0: DIS alone misses it


def test_rounding_to_uint8_equals_numpys_for_nonnegative_values():
    from pipeline.stages.local_flow import _round_to_uint8

    rng = np.random.default_rng(2)
    values = np.concatenate([rng.uniform(0, 300, 100_000), np.arange(0, 258, 0.5),  # every .5 tie up to 257.5
                             [254.49999, 255.49998, 1e-7, 0.0]]).astype(np.float32).reshape(-1, 1)
    np.testing.assert_array_equal(_round_to_uint8(values), np.clip(np.round(values), 0, 255).astype(np.uint8))


def test_config_rejects_unknown_method():
    with pytest.raises(ValueError):
        LocalFlowConfig(method="horn-schunck")
    with pytest.raises(ValueError):
        LocalFlowConfig(dis_preset="slow")


def test_fill_invalid_keeps_valid_pixels_and_fills_smoothly(photo):
    grey = np.clip(np.round(intensity(photo)), 0, 255).astype(np.uint8)
    valid = np.ones(grey.shape, bool)
    valid[100:160, 200:300] = False  # a hole inside
    valid[:, :40] = False  # and a band at the edge
    filled = fill_invalid(grey, valid)
    np.testing.assert_array_equal(filled[valid], grey[valid])
    # Push-pull averages valid pixels: the fill stays within their range, and a constant comes back exactly.
    assert grey[valid].min() <= filled[~valid].min() and filled[~valid].max() <= grey[valid].max()
    np.testing.assert_array_equal(fill_invalid(np.where(valid, 77, 0).astype(np.uint8), valid), 77)
