"""Moving people must never turn see-through: deblurring and completion on a dynamic scene with ground truth.

The case (pipeline.evaluation.synthetic, object_kind="person"): a figure a fifth of the frame wide and over half its height,
dressed in a texture cut from the world photograph itself (so colour alone cannot tell it from the background),
walking 10-25 px a frame with random turns, on a clip with motion-blurred frames. The truth keeps the figure's
mask and the background it hides, so show-through is measurable (pipeline.evaluation.completion.dynamic_scores).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.stages import deblur
from pipeline.evaluation.completion import dynamic_scores
from pipeline.stabilize import StabilizeConfig
from pipeline.evaluation.synthetic import SyntheticConfig, generate, psnr

SHARED_VIDEOS = Path(__file__).resolve().parents[2] / "shared" / "videos"


def person_clip(image: str, seed: int, sweep: float = 0.6, n_frames: int = 30):
    return generate(SyntheticConfig(n_frames=n_frames, object_kind="person", image=image, seed=seed,
                                    object_sweep=sweep))


@pytest.fixture(scope="module")
def chelsea():
    return person_clip("chelsea", 3)


def test_the_person_clip_is_the_hard_case(chelsea):
    """Person-sized, fast and irregular, dressed in the background's colour statistics, with blurred frames."""
    video = chelsea
    width, height = video.size
    for mask in video.object_mask:
        ys, xs = np.nonzero(mask)
        assert xs.max() - xs.min() + 1 >= 0.2 * width and ys.max() - ys.min() + 1 >= 0.5 * height
    # Speed relative to the background (the world), irregular.
    step = np.abs(np.diff(video.object_world_from_patch[:, 0, 2]))
    assert step.min() >= 10.0 - 1e-9 and step.max() <= 25.0 + 1e-9 and step.std() > 2.0
    assert len(video.blurred) >= 5
    # Colour: the figure's pixels and the background's have close means and spreads per channel.
    t = 0
    inside, outside = video.sharp_frames[t][video.object_mask[t]], video.sharp_frames[t][~video.object_mask[t]]
    assert np.all(np.abs(inside.mean(axis=0) - outside.mean(axis=0)) < 25)
    assert np.all((inside.std(axis=0) / outside.std(axis=0) > 0.6) & (inside.std(axis=0) / outside.std(axis=0) < 1.6))
    # The truth keeps what the figure hides: another picture there.
    hidden = video.hidden_background(t, np.eye(3))
    assert psnr(hidden, video.sharp_frames[t], video.object_mask[t]) < 20.0
    np.testing.assert_array_equal(video.object_view_mask(t, np.eye(3)), video.object_mask[t])


def test_structure_guard_tells_other_content_from_blur():
    """The contrast-structure term is high for the same picture blurred and sharp, low for other content of the
    same colours (the photograph turned half a turn), and 1 where both are flat."""
    rng = np.random.default_rng(0)
    photo = np.ascontiguousarray(cv2.resize(generate(SyntheticConfig(n_frames=1, moving_object=False,
                                                                      blurred_frames=())).frames[0], (320, 180),
                                            interpolation=cv2.INTER_AREA))
    blurred = cv2.blur(photo, (7, 1))
    other = np.ascontiguousarray(photo[::-1, ::-1])
    guard = deblur.StructureGuard(blurred, 2.0, 4, deblur.STRUCTURE_MIN)
    same = guard.agreement(photo)
    different = guard.agreement(other)
    assert np.percentile(same, 10) > 0.85 and np.median(same) > 0.97
    assert np.median(different) < 0.4 and (different < deblur.STRUCTURE_MIN).mean() > 0.8
    weight = np.ones(photo.shape[:2], np.float32)
    assert guard.refused(photo, weight) is None or guard.refused(photo, weight).mean() < 0.05
    assert guard.refused(other, weight).mean() > 0.7
    flat = np.full_like(photo, 90) + rng.integers(0, 2, photo.shape, dtype=np.uint8)
    assert deblur.StructureGuard(flat, 2.0, 4, 0.75).agreement(flat[::-1]).min() > 0.9


@pytest.mark.slow
def test_deblurring_never_ghosts_a_person_dressed_like_the_background(chelsea):
    """With deblurring: the figure on blurred frames is as good as without (within 0.1 dB), none of the hidden
    background's detail shows through it, and the blurred frames as a whole still gain >= 3 dB. Without the
    structure guard (colour test only) the figure turns see-through: the same bounds fail."""
    scores = dynamic_scores(chelsea)
    assert scores.blurred_frames >= 5
    assert scores.object_psnr["deblurred"] >= scores.object_psnr["not deblurred"] - 0.1
    assert scores.show_through["deblurred"] <= scores.show_through["not deblurred"] + 0.005
    assert scores.blurred_psnr["deblurred"] >= scores.blurred_psnr["not deblurred"] + 3.0
    # Completion stays 5 dB above OpenCV's CPU chain over the synthesized pixels. Measured +5.20; +4.54 when a moving
    # candidate could replace the mosaic on the additive margin alone (CompletionConfig.mosaic_check_ratio 1).
    assert scores.synthesized_psnr >= scores.mosaic_telea_psnr + 5.0
    colour_only = StabilizeConfig(deblur=deblur.DeblurConfig(structure_min=None))
    ghosted = dynamic_scores(chelsea, colour_only)
    assert ghosted.object_psnr["deblurred"] < ghosted.object_psnr["not deblurred"] - 0.5
    assert ghosted.show_through["deblurred"] > ghosted.show_through["not deblurred"] + 0.01


@pytest.mark.slow
def test_person_crossing_the_border_deblurred_and_completed_without_show_through():
    """The figure walks into the area completion synthesizes: deblurring keeps the bounds above, completion shows
    none of the hidden background inside the figure and stays well above OpenCV's CPU chain (mosaic + Telea)."""
    scores = dynamic_scores(person_clip("astronaut", 2, sweep=1.0))
    assert scores.object_psnr["deblurred"] >= scores.object_psnr["not deblurred"] - 0.1
    assert scores.show_through["deblurred"] <= scores.show_through["not deblurred"] + 0.005
    assert scores.blurred_psnr["deblurred"] >= scores.blurred_psnr["not deblurred"] + 3.0
    assert np.isfinite(scores.synthesized_show_through) and scores.synthesized_show_through < 0.02
    # Today's margin on this clip: docs/benchmarks-dynamic.md (person astronaut border).
    assert scores.synthesized_psnr >= scores.mosaic_telea_psnr + 3.0
    split = scores.synthesized_split_psnr
    assert split["ours"]["background"] >= split["mosaic+telea"]["background"] + 1.0  # no stale copies pasted


def test_deblur_result_says_where_pixels_came_from_and_where_they_were_refused():
    """Per pixel: the main source offset where neighbours gave weight, and the refused mask where a sharper
    neighbour showed other content (a square the target does not show)."""
    photo = generate(SyntheticConfig(n_frames=1, moving_object=False, blurred_frames=())).frames[0]
    height, width = photo.shape[:2]
    target = cv2.blur(photo, (9, 1))
    other = photo.copy()
    other[120:240, 200:360] = photo[::-1, ::-1][120:240, 200:360]  # other content, the same colours
    from pipeline.stages.neighbours import WarpedNeighbour
    valid = np.ones((height, width), bool)
    result = deblur.deblur(target, valid, [WarpedNeighbour(2, other, valid)], ratios={2: 3.0})
    assert result.neighbours == (2,)
    assert result.refused is not None and result.main_source is not None
    assert result.refused[130:230, 210:350].all()
    assert result.refused[:, :120].mean() < 0.05
    assert (result.main_source[:, :120] == 2).mean() > 0.9
    assert (result.main_source[130:230, 210:350] == 0).all()
    assert result.weights[130:230, 210:350].max() == 0


@pytest.mark.slow
@pytest.mark.real_video
def test_vplab_woman_stays_as_sharp_as_without_deblurring():
    """vplab_C frames 224-233 (the woman walking past the lamp post): the deblurred frames keep the sharpness of
    the input (gradient energy within 7 %) and differ little from it (>= 38 dB); before the structure guard the
    lamp post showed through her and the frames lost up to 23 % of their gradient energy (34-35 dB)."""
    path = SHARED_VIDEOS / "vplab_C.avi"
    if not path.exists():
        pytest.skip("shared clip vplab_C.avi absent")
    from pipeline.runtime import video_reader
    from pipeline.runtime.observer import StageCollector
    from pipeline.runtime.source import ArraySource
    from pipeline.stabilize import stabilize_source

    first = 196
    with video_reader.VideoReader(path) as reader:
        frames = [f.rgb for f in reader if f.index >= first]
    collector = StageCollector("deblur")
    stabilize_source(ArraySource(frames, fps=30, name="vplab_C"), None, StabilizeConfig(), observer=collector)

    def energy(image):
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
        return float(np.mean(cv2.Sobel(grey, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(grey, cv2.CV_32F, 0, 1) ** 2))

    checked = 0
    for stamp, result in collector.results["deblur"]:
        if 224 <= stamp.index + first <= 233 and result.neighbours:
            box = (slice(40, 330), slice(200, 420))  # the woman and the lamp post behind her
            assert energy(result.frame[box]) >= 0.93 * energy(result.before[box])
            assert psnr(result.frame[box], result.before[box]) >= 38.0
            checked += 1
    assert checked >= 5


def test_flat_windows_take_no_other_flat_surface():
    """Two flat surfaces a few levels apart (a plain coat over a plain wall) pass the colour test (E far below 32)
    and agree in structure (both flat); a transfer could sharpen nothing there, only shift the colour, so it is
    refused. One level apart (noise, exposure) it is not."""
    rng = np.random.default_rng(1)
    target = np.clip(100 + rng.normal(0, 0.5, (180, 320, 3)), 0, 255).astype(np.uint8)
    guard = deblur.StructureGuard(target, 2.0, 4, deblur.STRUCTURE_MIN)
    weight = np.ones((180, 320), np.float32)
    refused = guard.refused(np.clip(target.astype(int) + 6, 0, 255).astype(np.uint8), weight)
    assert refused is not None and refused[10:-10, 10:-10].all()
    assert guard.refused(np.clip(target.astype(int) + 1, 0, 255).astype(np.uint8), weight) is None


@pytest.mark.slow
def test_completion_holds_5_db_over_the_opencv_chain_where_the_figure_passed_in_the_nearest_neighbours():
    """Issue 20's bar on the two person clips where a strip the figure has left, still shown by the nearest frames,
    competes with the local warps: the median of the neighbours' majority fills it. Rocket's margin is held over
    five seeds (median 5 dB, none under 3.5): one seed's moves by a dB with sub-pixel differences in the motion of
    its blurred pairs (benchmarks/quality/dynamic_scene.py --seeds)."""
    coffee = person_clip("coffee", 1)
    scores = {"coffee": dynamic_scores(coffee)}
    assert scores["coffee"].synthesized_psnr >= scores["coffee"].mosaic_telea_psnr + 5.0
    margins = []
    for seed in range(5):
        rocket = dynamic_scores(person_clip("rocket", seed, sweep=0.8))
        margins.append(rocket.synthesized_psnr - rocket.mosaic_telea_psnr)
    assert np.median(margins) >= 5.0 and min(margins) >= 3.5, margins
    config = StabilizeConfig()
    chain = tuple(name for name in config.completion.candidates if name != "majority")
    without = dataclasses.replace(config, completion=dataclasses.replace(config.completion, candidates=chain))
    before = dynamic_scores(coffee, without)
    assert scores["coffee"].synthesized_psnr >= before.synthesized_psnr + 1.0
