"""Deblurring by sharper neighbours (thesis ch. 5, eqs. 28-31) against synthetic ground truth.

Clips are pipeline.synthetic at 320x180 with a 6 px blur (the default 12 px at half the size): real photographs
filmed by a known hand-held camera path, a textured disc moving through them, and frames t % 10 in {2, 5, 8}
blurred by a known linear kernel. Frames are placed as the orchestrator places them: in their stabilized view
(the intended, jitter-free one), with the neighbours warped there by the exact transforms; the truth is the world
rendered sharp through that view.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ffviz import cli
from pipeline import deblur, synthetic, warping
from pipeline.neighbours import warp_neighbours
from pipeline.observer import StageCollector
from pipeline.source import ArraySource
from pipeline.stabilize import StabilizeConfig, stabilize_source
from pipeline.synthetic import psnr

SMALL = dict(width=320, height=180, blur_length_px=6.0)


@pytest.fixture(scope="module")
def clip() -> synthetic.SyntheticVideo:
    return synthetic.generate(synthetic.SyntheticConfig(n_frames=24, seed=4, image="astronaut", **SMALL))


def placed(video: synthetic.SyntheticVideo, t: int, radius: int = 6):
    """Frame t in its stabilized view: (frames by index, orig_from_stab, stabilized, warped neighbours, truth,
    judged pixels)."""
    frames = {i: video.frames[i] for i in range(max(t - radius, 0), min(t + radius + 1, video.n_frames))}
    stab_from_orig = video.intended_from_frame[t]
    orig_from_stab = np.linalg.inv(stab_from_orig)
    stabilized = warping.warp_frame(video.frames[t], orig_from_stab)
    neighbours = warp_neighbours({i: f for i, f in frames.items() if i != t}, t, video.curr_from_prev,
                                            orig_from_stab)
    truth = video.render_view(t, stab_from_orig)
    judged = ~stabilized.missing & video.view_coverage(t, stab_from_orig)
    return frames, orig_from_stab, stabilized, neighbours, truth, judged


def deblur_placed(video, t, config=deblur.DeblurConfig()):
    frames, orig_from_stab, stabilized, neighbours, truth, judged = placed(video, t)
    result = deblur.deblur_frame(stabilized.frame, ~stabilized.missing, t, frames, video.curr_from_prev,
                                 orig_from_stab, config, warped=neighbours)
    return result, truth, judged


def object_in_view(video, i: int, t: int, orig_from_stab: np.ndarray) -> np.ndarray:
    """Frame i's object footprint in frame t's stabilized view."""
    i_from_t = video.frame_from_world[i] @ np.linalg.inv(video.frame_from_world[t])
    return warping.warp(video.object_mask[i].astype(np.uint8) * 255, i_from_t @ orig_from_stab) > 127


def test_blurriness_ranks_frames_with_graded_blur():
    """Eq. 28 over the window's common coverage ranks 7 frames of a moving camera by their blur length, given out
    of time order, down to steps of 1 px; the per-frame series value (own whole frame) ranks them too."""
    video = synthetic.generate(synthetic.SyntheticConfig(n_frames=7, seed=2, image="coffee", blurred_frames=(),
                                                         **SMALL))
    lengths = [3.0, 0.0, 6.0, 1.0, 5.0, 2.0, 4.0]  # px, frame by frame
    frames = {t: synthetic.apply_blur(video.sharp_frames[t], synthetic.motion_blur_kernel(length, 20.0))
              for t, length in enumerate(lengths)}
    measured = deblur.window_blurriness(frames, 3, video.curr_from_prev)
    assert measured.common_fraction > 0.5
    # b_t' relative to b_3 = 1 / (b_3 / b_t').
    relative = [1.0 if t == 3 else 1.0 / measured.ratios[t - 3] for t in range(7)]
    assert list(np.argsort(relative)) == list(np.argsort(lengths))
    own = [deblur.blurriness(frame) for frame in frames.values()]
    assert list(np.argsort(own)) == list(np.argsort(lengths))
    # A flat image has no gradient: infinitely blurry, not a division error.
    assert deblur.blurriness(np.full((20, 30), 128, np.uint8)) == math.inf


def test_blurriness_ratios_survive_a_window_without_common_area():
    """When the frames of the window share too little scene, each pair is compared over its own overlap."""
    photo = cv2.resize(synthetic.load_image("chelsea"), (800, 180), interpolation=cv2.INTER_AREA)
    step = 80  # px per frame: frames 0 and 4 do not overlap at all
    frames = {i: np.ascontiguousarray(photo[:, step * i:step * i + 320]) for i in range(5)}
    frames[2] = synthetic.apply_blur(frames[2], synthetic.motion_blur_kernel(10.0, 20.0))
    curr_from_prev = np.array([np.eye(3)] + [[[1, 0, -step], [0, 1, 0], [0, 0, 1]]] * 4, float)
    measured = deblur.window_blurriness(frames, 2, curr_from_prev)
    assert measured.common_fraction == 0.0
    assert sorted(measured.ratios) == [-2, -1, 1, 2]
    assert all(ratio > 1.2 for ratio in measured.ratios.values())  # every neighbour is clearly sharper
    sharp = deblur.window_blurriness(frames, 1, curr_from_prev)
    # The same pixels seen twice: equally sharp to within 1%.
    assert sharp.ratios[1] < 1 / 1.2 and all(abs(r - 1) < 0.01 for o, r in sharp.ratios.items() if o != 1)


def test_deblurred_frames_are_closer_to_the_sharp_truth(clip):
    """Blurred frames gain >= 1 dB against the sharp truth (measured here: +3.2 to +3.6 dB, ratios b_t / b_t' ~2.2;
    at 640x360 with 12 px blur, benchmarks/deblur_psnr.py: +3.4 to +7.3, mean +5.7). Sharp frames lose no more
    than 0.2 dB: with the default threshold on the ratio (1.1) they are untouched; with eq. 31's own threshold
    of 1, neighbours a hair sharper do contribute (measured: -0.13 to +0.44 dB)."""
    thesis_used = 0
    for t in range(6, 18):
        result, truth, judged = deblur_placed(clip, t)
        change = psnr(result.frame, truth, judged) - psnr(result.before, truth, judged)
        if clip.is_blurred(t):
            assert change >= 1.0, (t, change)
            assert len(result.neighbours) >= 6 and result.weights[judged].mean() > 0.7
            assert all(result.ratios[o] > 1.5 for o in result.neighbours)
        else:
            assert change == 0.0 and result.neighbours == ()
            thesis, _, _ = deblur_placed(clip, t, deblur.DeblurConfig(min_ratio=1.0))
            thesis_used += bool(thesis.neighbours)
            change = psnr(thesis.frame, truth, judged) - psnr(thesis.before, truth, judged)
            assert change >= -0.2, (t, change)
        assert math.isfinite(result.blurriness) and result.blurriness > 0
    assert thesis_used >= 5  # most sharp frames have a neighbour a hair sharper: the threshold of 1 was exercised


def test_moving_object_does_not_ghost(clip):
    """Where a neighbour shows the moving object and frame t does not, the background comes back sharper (no ghost:
    measured +5.9 to +10.6 dB there); on the object itself next to nothing is taken from neighbours (measured share
    0.5-1.1%; they show the object elsewhere). Without the rejection of large alignment errors, eq. 31's
    alpha / (E + alpha) alone takes 74% of the object from neighbours (-3.7 dB there): the checks have teeth."""
    for t in (c for c in clip.blurred if 6 <= c < 18):
        frames, orig_from_stab, stabilized, neighbours, truth, judged = placed(clip, t)
        own = object_in_view(clip, t, t, orig_from_stab)
        elsewhere = np.zeros_like(own)
        for i in frames:
            if i != t:
                elsewhere |= object_in_view(clip, i, t, orig_from_stab)
        ghost_zone = elsewhere & ~(cv2.dilate(own.astype(np.uint8), np.ones((13, 13), np.uint8)) > 0) & judged
        inner = (cv2.erode(own.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0) & judged
        assert ghost_zone.sum() > 500 and inner.sum() > 500
        results = {}
        for name, config in (("default", deblur.DeblurConfig()),
                             ("no rejection", deblur.DeblurConfig(reject_error=1e9, reject_grow_px=0))):
            results[name] = deblur.deblur_frame(stabilized.frame, ~stabilized.missing, t, frames, clip.curr_from_prev,
                                                orig_from_stab, config, warped=neighbours)
        result = results["default"]
        assert psnr(result.frame, truth, ghost_zone) > psnr(result.before, truth, ghost_zone) + 3.0
        assert result.weights[inner].mean() < 0.02
        assert psnr(result.frame, truth, inner) > psnr(result.before, truth, inner) - 0.2
        assert results["no rejection"].weights[inner].mean() > 0.25  # the failure the rejection prevents


def test_only_pixels_with_content_change_and_shapes_are_checked(clip):
    frames, orig_from_stab, stabilized, neighbours, truth, judged = placed(clip, 12)
    valid = ~stabilized.missing
    valid[:, :100] = False  # as if missing: black in --mode none, and it must stay so
    measured = deblur.window_blurriness(frames, 12, clip.curr_from_prev)
    result = deblur.deblur(stabilized.frame, valid, neighbours, ratios=measured.ratios)
    assert result.neighbours
    np.testing.assert_array_equal(result.frame[~valid], stabilized.frame[~valid])
    assert (result.weights[~valid] == 0).all() and result.weights[valid].mean() > 0.7
    with pytest.raises(ValueError, match="valid mask"):
        deblur.deblur(stabilized.frame, valid[:-1], neighbours, ratios=measured.ratios)
    with pytest.raises(ValueError, match="alpha"):
        deblur.DeblurConfig(alpha=0)


def test_orchestrator_sharpens_blurred_output_frames_and_keeps_the_frame_full():
    """Through stabilize_source in full mode (estimated motion, completion first): blurred frames, scored against
    the world rendered through the virtual camera the stabilizer chose, gain >= 1 dB (measured +3.3 to +4.5 dB);
    sharp frames are not touched."""
    video = synthetic.generate(synthetic.SyntheticConfig(n_frames=20, seed=5, image="coffee", **SMALL))
    collector = StageCollector("warp", "deblur", "output")
    stabilize_source(ArraySource(video.frames, fps=video.config.fps), None, StabilizeConfig(mode="full"),
                     observer=collector)
    warps = {stamp.index: result for stamp, result in collector.results["warp"]}
    outputs = {stamp.index: frame for stamp, frame in collector.results["output"]}
    assert len(collector.results["deblur"]) == video.n_frames
    gains = []
    for stamp, result in collector.results["deblur"]:
        t = stamp.index
        stab_from_orig = np.linalg.inv(warps[t].orig_from_out)
        truth = video.render_view(t, stab_from_orig)
        judged = video.view_coverage(t, stab_from_orig)
        change = psnr(result.frame, truth, judged) - psnr(result.before, truth, judged)
        assert outputs[t] is result.frame
        assert np.mean(np.all(result.frame < 8, axis=2)) < 1e-3  # full frame: completion's fill is kept
        if video.is_blurred(t):
            gains.append(change)
            assert change >= 1.0, (t, change)
        else:
            assert abs(change) <= 0.2, (t, change)
    assert len(gains) == len(video.blurred)


def test_cli_switches_deblurring_and_its_alpha():
    parser = cli.build_parser()
    config = cli._stabilize_config(parser.parse_args(["stabilize", "in.mp4", "-o", "out.mp4"]))
    assert config.deblur.enabled and config.deblur.alpha == deblur.DEBLUR_ALPHA
    config = cli._stabilize_config(parser.parse_args(["stabilize", "in.mp4", "-o", "out.mp4", "--no-deblur",
                                                      "--deblur-alpha", "3"]))
    assert not config.deblur.enabled and config.deblur.alpha == 3.0
