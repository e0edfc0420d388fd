"""Full-frame completion (thesis chapter 4) against ground truth.

The PSNR tests compare, on the same stabilized frames and missing pixels, our chain with the CPU chain
OpenCV's videostab offers (consistent mosaic + Telea colour inpainting, rebuilt in pipeline/evaluation/completion.py)
and with plain Telea. Measured when written (640x360 or the clip's size, 48 frames):
- jittered 80 % crops of linyihaolyh_shaky.mp4 (real parallax, pedestrians): ours 31.4 dB, mosaic+telea 28.4,
  telea 22.1;
- synthetic coffee world with a textured object crossing the borders (seeds 1, 2): ours 35.6 / 36.2 dB,
  mosaic+telea 33.3 / 33.6, telea 20.1 / 19.2.
"""

from __future__ import annotations

import dataclasses

import itertools

import cv2
import numpy as np
import pytest
import skimage.data

from pipeline.errors import ConfigError
from pipeline.stages import candidates, completion, local_warp, neighbours
from pipeline.evaluation.completion import (METHODS, CompletionScores, completion_scores, crop_completion_scores,
                                            jittered_crop)
from pipeline.stages.smoothing import SmoothingConfig
from pipeline.runtime.source import FileSource, one_pass
from pipeline.stabilize import StabilizeConfig
from pipeline.evaluation.synthetic import SyntheticConfig, generate, psnr
from tests.conftest import real_clip

FULL = StabilizeConfig(mode="full")


def _without(*names: str, config: completion.CompletionConfig = completion.CompletionConfig()
             ) -> completion.CompletionConfig:
    """``config`` with the candidate sources ``names`` left out of its chain."""
    return dataclasses.replace(config, candidates=tuple(c for c in config.candidates if c not in names))


def _pooled(scores: list[CompletionScores]) -> CompletionScores:
    pooled = CompletionScores()
    for s in scores:
        for method, error in s.squared_error.items():
            pooled.squared_error[method] += error
        pooled.pixels += s.pixels
        pooled.frames += s.frames
    return pooled


def test_beats_the_opencv_cpu_chain_on_jittered_crops_of_a_real_clip():
    with one_pass(FileSource(real_clip("linyihaolyh_shaky.mp4"))) as frames:
        wide = [f.rgb for f in itertools.islice(frames, 48)]
    crop = jittered_crop(len(wide), (wide[0].shape[1], wide[0].shape[0]), crop_fraction=0.8, jitter_px=8.0, seed=1)
    scores = crop_completion_scores(wide, crop, config=FULL)
    assert scores.frames > 30 and scores.pixels > 100_000
    ours = scores.psnr("ours")
    assert ours >= scores.psnr("mosaic+telea") + 2.0, vars(scores)
    assert ours >= scores.psnr("telea") + 2.0, vars(scores)


def test_beats_the_opencv_cpu_chain_with_a_moving_object_crossing_the_borders():
    config = StabilizeConfig(mode="full", smoothing=SmoothingConfig(radius_frames=50))
    runs = []
    for seed in (1, 2):
        video = generate(SyntheticConfig(n_frames=48, jitter_px=10.0, object_sweep=1.3, seed=seed, blurred_frames=()))
        runs.append(completion_scores(video, config))
    scores = _pooled(runs)
    assert scores.pixels > 100_000
    assert scores.psnr("ours") >= scores.psnr("mosaic+telea") + 2.0, vars(scores)
    assert scores.psnr("ours") >= scores.psnr("telea") + 2.0, vars(scores)


def test_scores_split_by_filling_stage_and_by_frame_add_up_to_the_pooled_scores():
    config = StabilizeConfig(mode="full", smoothing=SmoothingConfig(radius_frames=50))
    video = generate(SyntheticConfig(n_frames=16, jitter_px=10.0, object_sweep=1.3, seed=1, blurred_frames=()))
    scores = completion_scores(video, config)
    assert scores.pixels > 10_000
    assert set(scores.by_source) <= set(completion.SOURCE_NAMES[1:]) and "mosaic" in scores.by_source
    assert len(scores.by_frame) == scores.frames
    for split in (scores.by_source, scores.by_frame):
        assert sum(part.pixels for part in split.values()) == scores.pixels
        for method in METHODS:
            assert sum(part.squared_error[method] for part in split.values()) == pytest.approx(
                scores.squared_error[method], rel=1e-9)
    # The mosaic takes the pixels its neighbours agree on: its share is better than the pooled PSNR.
    assert scores.by_source["mosaic"].psnr("ours") > scores.psnr("ours")


def _photo(height: int = 180, width: int = 320) -> np.ndarray:
    return np.ascontiguousarray(skimage.data.astronaut()[100:100 + height, 60:60 + width])


def _photo_missing_right(strip_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(truth, missing, target): _photo() with its rightmost ``strip_px`` columns missing (0 in the target)."""
    truth = _photo()
    missing = np.zeros(truth.shape[:2], bool)
    missing[:, -strip_px:] = True
    target = truth.copy()
    target[missing] = 0
    return truth, missing, target


def _neighbours(frames: dict[int, np.ndarray], valid: dict[int, np.ndarray] | None = None,
                ) -> list[neighbours.WarpedNeighbour]:
    """Neighbours already in the target's coordinates (identity global motion)."""
    shape = next(iter(frames.values())).shape[:2]
    return [neighbours.WarpedNeighbour(offset, rgb, np.ones(shape, bool) if valid is None else valid[offset])
            for offset, rgb in sorted(frames.items(), key=lambda item: abs(item[0]))]


def test_nothing_missing_leaves_the_frame_untouched():
    target = _photo()
    missing = np.zeros(target.shape[:2], bool)
    result = completion.complete(target, missing, _neighbours({-1: np.roll(target, 3, axis=1), 1: target}))
    np.testing.assert_array_equal(result.frame, target)
    assert (result.source == completion.SOURCE_ORIGINAL).all() and not result.fallback.any()


def test_static_border_is_filled_from_the_neighbours_and_only_the_uncovered_corner_falls_back():
    truth = _photo()
    missing = np.zeros(truth.shape[:2], bool)
    missing[:, -30:] = True  # a right border strip, as after stabilization
    target = truth.copy()
    target[missing] = 0
    uncovered = np.zeros_like(missing)
    uncovered[:20, -30:] = True  # no neighbour sees this corner either
    valid = {o: ~uncovered for o in (-2, -1, 1, 2)}
    noisy = {o: np.clip(truth + np.random.default_rng(o + 10).normal(0, 1.0, truth.shape), 0, 255).astype(np.uint8)
             for o in valid}
    result = completion.complete(target, missing, _neighbours(noisy, valid))
    np.testing.assert_array_equal(result.frame[~missing], truth[~missing])
    np.testing.assert_array_equal(result.fallback, uncovered)
    covered = missing & ~uncovered
    assert psnr(result.frame, truth, covered) > 40
    assert (result.source[covered] != completion.SOURCE_FALLBACK).all()
    # The corner nobody saw is a smooth continuation, not a black hole.
    assert result.frame[uncovered].max(axis=1).min() > 0
    assert np.abs(result.frame[uncovered].astype(int) - truth[uncovered]).mean() < 40


def _disc_scene(offset: int, background: np.ndarray, speed: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """The background with a textured disc whose centre moves ``speed`` px per frame to the right."""
    height, width = background.shape[:2]
    texture = cv2.resize(np.ascontiguousarray(skimage.data.coffee()[100:300, 200:400]), (80, 80))
    texture = 255 - texture  # never similar to the background
    cx, cy = 262 + speed * offset, 90
    patch_from_frame = np.array([[1, 0, 40 - cx], [0, 1, 40 - cy]], np.float64)
    sprite = cv2.warpAffine(texture, patch_from_frame, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    yy, xx = np.mgrid[0:height, 0:width]
    inside = (xx - cx) ** 2 + (yy - cy) ** 2 <= 38 ** 2
    return np.where(inside[..., None], sprite, background), inside


def test_an_object_that_passed_through_the_border_in_one_neighbour_is_not_pasted_where_farther_ones_show_the_scene():
    """The nearest neighbours do not reach the lower part of a border strip; the one that does (t+2) shows an object
    passing there, over the strip and the band beside it, that frame t does not show; t-3 and t-4 show the scene."""
    truth, missing, target = _photo_missing_right(30)
    height, width = truth.shape[:2]
    lower = missing.copy()
    lower[:90] = False
    rng = np.random.default_rng(3)

    def noisy() -> np.ndarray:
        return np.clip(truth + rng.normal(0, 1.0, truth.shape), 0, 255).astype(np.uint8)

    texture = 255 - cv2.resize(np.ascontiguousarray(skimage.data.coffee()[100:300, 200:400]), (100, 100))
    passing = noisy()
    passing[85:, 250:] = texture[:height - 85, :width - 250]
    frames = {-1: noisy(), 1: noisy(), -2: noisy(), 2: passing, -3: noisy(), -4: noisy()}
    valid = {offset: np.ones((height, width), bool) for offset in frames}
    for offset in (-1, 1, -2):
        valid[offset] = ~lower

    def scene_share(config: completion.CompletionConfig) -> tuple[float, float, float]:
        """(share of the strip showing the scene, share filled by a neighbour's sample as it is, by the majority)"""
        result = completion.complete(target, missing, _neighbours(frames, valid), config)
        np.testing.assert_array_equal(result.frame[~missing], truth[~missing])
        as_is = result.source == completion.SOURCE_AS_IS
        assert np.isin(result.filled_by[as_is], (-3, -4)).all()  # the neighbours that show the scene there
        return (float((np.abs(result.frame.astype(int) - truth).max(axis=2) <= 20)[lower].mean()),
                float(as_is[lower].mean()), float((result.source == completion.SOURCE_MAJORITY)[lower].mean()))

    # The local warp of t+2 explains the band beside the strip badly (the object covers it there), so the scene as
    # t-3 and t-4 show it competes and wins, and completion/source says so; without that, t+2's guess fills most of
    # the strip. Where t-3, t-4 and t+2 all cover the strip, two of three agree: their median (the majority
    # candidate) explains the band as well as the scene does and fills most of it.
    static_only = _without("majority")
    scene_majority, _, majority = scene_share(completion.CompletionConfig())
    (scene, as_is, _), (scene_without, as_is_without, _) = (
        scene_share(static_only), scene_share(_without("neighbour as is", config=static_only)))
    # Measured: 0.999 of the strip shows the scene with the majority (0.89 of it by the majority); 0.56 without it, 0.30 of the strip t-3's or
    # t-4's sample as it is; without either, 0.26 and 0.
    assert scene_majority > 0.95 and majority > 0.8
    assert scene > 0.5 and as_is > 0.25
    assert scene_without < 0.4 and as_is_without < 0.1


def test_an_object_leaving_through_the_border_is_carried_on_by_its_own_motion_not_pasted_where_neighbours_saw_it():
    """A disc moving 8 px a frame to the right straddles the edge of a 60 px border strip: frame t's surroundings
    show only its left part, so the local warps' flows (measured there and inpainted outwards) paste the neighbours'
    copies where they saw it; t-1 and t-2 (and t+1, t+2) see it move, which carries their copy on to frame t."""
    background = _photo()

    def scene(offset: float) -> tuple[np.ndarray, np.ndarray]:
        return _disc_scene(offset, background, speed=8.0)

    truth, disc = scene(0)
    missing = np.zeros(truth.shape[:2], bool)
    missing[:, -60:] = True
    target = truth.copy()
    target[missing] = 0
    frames = {offset: scene(offset)[0] for offset in (-3, -2, -1, 1, 2, 3)}
    seen = disc.copy()
    for offset in frames:
        seen |= scene(offset)[1]
    judged = missing & seen  # where the disc is, or where a neighbour showed it

    def strip_psnr(config: completion.CompletionConfig) -> tuple[float, float, float]:
        """(PSNR over the disc's pixels, over the strip, the share of the disc's pixels carried on)"""
        result = completion.complete(target, missing, _neighbours(frames), config)
        np.testing.assert_array_equal(result.frame[~missing], truth[~missing])
        carried_on = result.source == completion.SOURCE_CARRIED_ON
        assert np.isin(result.filled_by[carried_on], (-1, 1)).all()  # t+-1's sample, moved on by a frame
        return psnr(result.frame, truth, judged), psnr(result.frame, truth, missing), float(carried_on[disc & missing].mean())

    (carried, carried_strip, carried_share), (pasted, pasted_strip, pasted_share) = (
        strip_psnr(completion.CompletionConfig()), strip_psnr(_without("carried on")))
    # completion/source shows the carried-on pixels: most of the disc's part of the strip, and none without.
    assert carried_share > 0.5 and pasted_share == 0.0
    # Measured: 23.6 against 15.9 dB over those pixels, 27.1 against 20.0 over the strip.
    assert carried > pasted + 4.0, (carried, pasted)
    assert carried_strip > pasted_strip + 3.0, (carried_strip, pasted_strip)


def test_a_moving_candidate_replaces_the_mosaic_only_where_it_halves_the_static_scenes_error():
    """On a motion-blurred frame every sharp sample explains the blurred surroundings worse, the static scene's
    included: a moving candidate must beat it by the margin and by a share, not by the margin alone."""
    def candidate(kind: str, error: float, motion: float) -> candidates.Candidate:
        return candidates.Candidate(kind, np.zeros((1, 3), np.uint8), np.ones(1, bool), np.full(1, motion, np.float32),
                                    np.full(1, error, np.float32), np.ones(1, bool), np.zeros(1, np.int16))

    doubted_mosaic = candidate("mosaic", 30.0, 0.0)  # the mosaic's sample, on a blurred frame
    default, margin_only = completion.CompletionConfig(), completion.CompletionConfig(mosaic_check_ratio=1.0)
    for error, replaces, replaces_on_margin in ((20.0, False, True), (14.0, True, True), (27.0, False, False)):
        moving = candidate("local warp", error, 6.0)
        assert (completion.choose([doubted_mosaic, moving], default)[0] == 1) == replaces
        assert (completion.choose([doubted_mosaic, moving], margin_only)[0] == 1) == replaces_on_margin
    with pytest.raises(ConfigError):
        completion.CompletionConfig(mosaic_check_ratio=0.0)


def test_moving_object_in_the_missing_area_is_synthesized_not_painted_over_with_background():
    background = _photo()
    truth, object_mask = _disc_scene(0, background)
    missing = np.zeros(truth.shape[:2], bool)
    missing[:, -40:] = True  # covers the disc's right half
    target = truth.copy()
    target[missing] = 0
    neighbours = {o: _disc_scene(o, background)[0] for o in (-3, -2, -1, 1, 2, 3)}
    result = completion.complete(target, missing, _neighbours(neighbours))
    judged = missing & object_mask
    assert judged.sum() > 800
    baseline = cv2.inpaint(result.mosaic.frame, result.mosaic.remaining.astype(np.uint8), 3, cv2.INPAINT_TELEA)
    ours, theirs = psnr(result.frame, truth, judged), psnr(baseline, truth, judged)
    # No ghost: the object's missing half comes back through its own motion (measured 20.2 vs 12.1 dB).
    assert ours > theirs + 5.0, (ours, theirs)
    # Over the whole strip the chain wins too (measured 24.6 vs 20.5 dB) ...
    assert psnr(result.frame, truth, missing) > psnr(baseline, truth, missing) + 2.0
    # ... though the object's flow, propagated past its edge, costs the static pixels beside it: measured
    # 26.6 dB there vs the mosaic's 37.1. Requiring a second neighbour to agree before a moving sample
    # replaces the mosaic fixes part of that here but lost 0.4-1.6 dB on the benchmark clips, so it is not done.
    static = missing & ~cv2.dilate(object_mask.astype(np.uint8), np.ones((11, 11), np.uint8)).astype(bool)
    assert psnr(result.frame, truth, static) > 25


def test_flow_at_reduced_resolution_from_the_downscaled_copies_matches_shrinking_after_the_warp(monkeypatch):
    """At a working resolution below the frame's (1080p in practice, here 640x360 with flow_max_side 320), local
    flow crops of frame t and its neighbours come from each frame's shared downscaled copy: completion quality
    must match the shrink-after-warp path (measured on 1080p scenes: -0.2, -0.01, -0.01 dB)."""
    config = StabilizeConfig(mode="full", smoothing=SmoothingConfig(radius_frames=50),
                             completion=completion.CompletionConfig(flow_max_side=320))
    video = generate(SyntheticConfig(n_frames=24, jitter_px=10.0, object_sweep=1.3, seed=2, blurred_frames=()))
    made = []
    shrink = neighbours.shrink
    monkeypatch.setattr(neighbours, "shrink",
                        lambda image, size: (image.ndim == 3 and made.append(size)) or shrink(image, size))
    from_copies = completion_scores(video, config)
    assert made and set(made) == {(320, 180)}  # only whole frames' colours were shrunk: crops came from the copies
    assert len(made) <= len(video.frames) + 2  # each frame once (two threads may race for one)
    import pipeline.chain
    monkeypatch.setattr(pipeline.chain.FrameChain, "_downscaled", lambda self, shape, t: None)
    shrunk = completion_scores(video, config)
    assert from_copies.pixels == shrunk.pixels > 20_000
    assert abs(from_copies.psnr("ours") - shrunk.psnr("ours")) < 0.5, (vars(from_copies), vars(shrunk))
    assert from_copies.psnr("ours") > from_copies.psnr("mosaic+telea")


def test_nan_median_columns_equals_numpy_nanmedian():
    """The static scene's error per pixel is the median over the neighbours that see its surroundings."""
    rng = np.random.default_rng(5)
    values = (rng.random((12, 5000)) * 60).astype(np.float32)
    values[rng.random(values.shape) < 0.4] = np.nan
    values[:11, 0] = np.nan  # one number
    values[:10, 1] = np.nan  # two: the mean of both
    values[:, 2] = np.arange(12)  # even count, no NaN
    values = values[:, ~np.isnan(values).all(axis=0)]
    result = candidates.nan_median_columns(values)
    assert result.dtype == np.float32
    np.testing.assert_array_equal(result, np.nanmedian(values, axis=0))


def test_dilate_by_increasing_radii_equals_square_kernels():
    rng = np.random.default_rng(6)
    mask = rng.random((90, 130)) < 0.01
    mask[:, :3] = True
    radii = (0, 2, 2, 7, 40)
    for radius, grown in zip(radii, local_warp.dilate(mask, *radii)):
        square = cv2.dilate(mask.astype(np.uint8), np.ones((2 * radius + 1,) * 2, np.uint8)) > 0
        np.testing.assert_array_equal(grown, square)
    with pytest.raises(ValueError):
        local_warp.dilate(mask, 5, 3)


def _world(pad: int, height: int = 180, width: int = 320) -> np.ndarray:
    """A photograph with fine texture, ``pad`` px wider than the frame on every side."""
    return np.ascontiguousarray(skimage.data.astronaut()[60:60 + height + 2 * pad, 40:40 + width + 2 * pad])


def _misregistration(offset: int, height: int, width: int) -> np.ndarray:
    """A global warp's error growing with the distance in time, as a chain of inter-frame motions drifts: a
    rotation about the frame's centre of 0.12 degrees and a shift of (0.4, -0.3) px per frame of distance."""
    angle = np.deg2rad(0.12 * offset)
    c, s = np.cos(angle), np.sin(angle)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    rotation = np.array([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy], [0, 0, 1]])
    return rotation @ np.array([[1, 0, 0.4 * offset], [0, 1, -0.3 * offset], [0, 0, 1]])


def _misregistered_scene(pad: int = 40):
    """Frame t of a static world with a left and bottom border missing, and neighbours t-6..t+6 whose global warps
    are off by _misregistration (0.9 px over the missing area on the nearest, 5.2 px on the farthest)."""
    world = _world(pad)
    height, width = 180, 320
    truth = world[pad:pad + height, pad:pad + width]
    missing = np.zeros((height, width), bool)
    missing[:, :24] = True
    missing[-16:, :] = True
    target = truth.copy()
    target[missing] = 0
    world_from_stab = np.array([[1.0, 0, pad], [0, 1, pad], [0, 0, 1]])
    rng = np.random.default_rng(3)
    found = []
    for offset in sorted((o for o in range(-6, 7) if o), key=lambda o: (abs(o), o)):
        noisy = np.clip(world + rng.normal(0, 1.0, world.shape), 0, 255).astype(np.uint8)
        found.append(neighbours.WarpedNeighbour(
            offset, original=noisy, other_from_stab=world_from_stab @ _misregistration(offset, height, width)))
    return truth, target, missing, found


def test_local_registration_undoes_the_global_warps_drift_before_the_mosaic():
    """Far neighbours misregistered by a pixel or two fail eq. 20's variance test on fine texture and fill the
    border with a patchwork; registered on the band next to the missing area, they agree again."""
    truth, target, missing, found = _misregistered_scene()
    off = completion.CompletionConfig(register_model=None)
    unregistered = completion.complete(target, missing, found, off)
    registered = completion.complete(target, missing, found)
    assert len(registered.registered) >= 10  # the nearest ones may be close enough already
    np.testing.assert_array_equal(registered.frame[~missing], target[~missing])
    before, after = psnr(unregistered.frame, truth, missing), psnr(registered.frame, truth, missing)
    # Measured 34.0 -> 50.6 dB; the mosaic takes all of the border instead of 69 %.
    assert after > before + 10.0 and after > 45.0, (before, after)
    assert registered.mosaic.accepted[missing].mean() > unregistered.mosaic.accepted[missing].mean() + 0.25
    # The evaluation's baseline (OpenCV's chain has no local registration) keeps the unrefined mosaic.
    assert registered.unregistered_mosaic().accepted.sum() == unregistered.mosaic.accepted.sum()


def test_registration_recovers_each_neighbours_error_over_the_missing_area():
    truth, target, missing, found = _misregistered_scene()
    refined = completion.register_neighbours(target, missing, found)
    ys, xs = np.nonzero(missing)
    points = np.stack([xs, ys, np.ones_like(xs)]).astype(np.float64)
    for before, after in zip(found, refined):
        where = after.other_from_stab @ points
        exact = before.other_from_stab @ np.linalg.inv(_misregistration(before.offset, *missing.shape)) @ points
        error = np.hypot(*(where[:2] / where[2] - exact[:2] / exact[2]))
        assert error.max() < 0.25, (before.offset, error.max())  # measured <= 0.09 px; 0.9-5.2 px before


def test_a_border_only_far_neighbours_see_takes_their_best_sample_not_the_smooth_fallback():
    """Where the mosaic refuses (the two neighbours that see the strip disagree) and no local warp reaches (the
    nearest frames do not see it), the covering neighbour whose warp continues the surroundings fills it."""
    truth, missing, target = _photo_missing_right(20)
    height, width = truth.shape[:2]
    occluded = truth.copy()
    occluded[:, -60:] = 255 - np.flip(truth[:, -60:], axis=(0, 1))  # something passes in front of +5's right side
    seen_by_far = np.ones((height, width), bool)
    near_valid = ~missing
    frames = {-5: truth, 5: occluded, -1: truth, 1: truth, -2: truth, 2: truth}
    valid = {o: seen_by_far if abs(o) == 5 else near_valid for o in frames}
    result = completion.complete(target, missing, _neighbours(frames, valid))
    plain = completion.complete(target, missing, _neighbours(frames, valid), _without("neighbour as is"))
    assert plain.fallback[missing].mean() > 0.9  # without it: the smooth last resort
    assert not result.fallback.any()
    assert (result.filled_by[missing] == -5).mean() > 0.95
    assert (result.source[missing] == completion.SOURCE_AS_IS).mean() > 0.95  # its sample as it is (no flow)
    assert psnr(result.frame, truth, missing) > psnr(plain.frame, truth, missing) + 10.0  # measured 47.9 vs 19.4 dB
