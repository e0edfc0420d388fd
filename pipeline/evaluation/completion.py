"""Ground-truth evaluation of full-frame completion (used by tests and benchmarks).

Two sources of truth for the pixels a full-frame stabilizer has to synthesize:

- synthetic video (``completion_scores``): the world is known beyond every input frame, so for the
  virtual camera the stabilizer chose (S_t) the truth of each synthesized pixel is rendered exactly;
- a wide real clip (``crop_completion_scores``): the input is a jittered crop of each wide frame, so the
  pixels the stabilizer must synthesize outside the crop at time t are the wide frame's own pixels at
  time t: real parallax, real moving people, real noise, no camera model assumed.

Three fillers are compared on exactly the same stabilized frames and missing pixels:

- ``ours``: the completion chain (mosaic, local flow, motion inpainting, local-warp mosaicing, fallback);
- ``mosaic+telea``: what OpenCV's videostab offers on a CPU (ConsistentMosaicInpainter followed by
  ColorInpainter with Telea), rebuilt from our consistent mosaic and cv2.inpaint;
- ``telea``: plain Telea colour inpainting of the stabilized frame.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import cv2
import numpy as np

from pipeline.stages import warping
from pipeline.stages.completion import SOURCE_NAMES
from pipeline.results import FrameResult
from pipeline.runtime.observer import NullObserver
from pipeline.runtime.source import ArraySource
from pipeline.stabilize import StabilizeConfig, stabilize_source
from pipeline.evaluation.synthetic import SyntheticVideo

TELEA_RADIUS = 3.0
METHODS = ("ours", "mosaic+telea", "telea")

# truth(t, orig_from_out) -> (image the output frame t should show, bool mask where that image is true)
TruthOf = Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class CompletionScores:
    """Pooled squared errors of synthesized pixels, per method; split by what filled each pixel in our chain
    (``by_source``, keyed by completion.SOURCE_NAMES: "mosaic", "local warp", "carried on", ...) and by frame
    (``by_frame``), so a loss can be traced to a stage and to the few frames that hold it. Each split sums to the
    pooled figures."""

    squared_error: dict[str, float] = field(default_factory=lambda: {m: 0.0 for m in METHODS})
    pixels: int = 0
    frames: int = 0
    by_source: dict[str, _Split] = field(default_factory=dict)
    by_frame: dict[int, _Split] = field(default_factory=dict)

    def psnr(self, method: str) -> float:
        return _pooled_psnr(self.squared_error[method], self.pixels)

    def _add(self, t: int, source: str, errors: dict[str, float], pixels: int) -> None:
        for split in (self.by_source.setdefault(source, _Split()), self.by_frame.setdefault(t, _Split())):
            split.pixels += pixels
            for method, error in errors.items():
                split.squared_error[method] += error


@dataclass
class _Split:
    """Squared errors per method over one part of the synthesized pixels."""

    squared_error: dict[str, float] = field(default_factory=lambda: {m: 0.0 for m in METHODS})
    pixels: int = 0

    def psnr(self, method: str) -> float:
        return _pooled_psnr(self.squared_error[method], self.pixels)


def _pooled_psnr(squared_error: float, pixels: int) -> float:
    """PSNR (dB, 8-bit) of a sum of squared RGB errors over ``pixels`` pixels; inf when it is 0."""
    mse = squared_error / max(pixels * 3, 1)
    return float("inf") if mse == 0 else float(10 * np.log10(255.0**2 / mse))


class _CompletionJudge(NullObserver):
    """Scores each completed frame's synthesized pixels against the truth of the same virtual camera."""

    def __init__(self, truth_of: TruthOf, frames: set[int] | None) -> None:
        self.truth_of = truth_of
        self.frames = frames
        self.scores = CompletionScores()

    def on_frame(self, result: FrameResult) -> None:
        if result.completion is None or (self.frames is not None and result.stamp.index not in self.frames):
            return
        self._score(result.stamp.index, result.warp, result.completion, completed_frame(result))

    def _score(self, t: int, warped: warping.WarpResult, completed, ours: np.ndarray) -> None:
        missing = completed.missing
        if not missing.any():
            return
        truth, covered = self.truth_of(t, warped.orig_from_out)
        judged = missing & covered
        if not judged.any():
            return
        candidates = {
            "ours": ours,
            "mosaic+telea": mosaic_telea(completed),
            "telea": cv2.inpaint(warped.frame, missing.astype(np.uint8), TELEA_RADIUS, cv2.INPAINT_TELEA),
        }
        reference = truth.astype(np.float64)
        errors = {method: np.sum((image.astype(np.float64) - reference) ** 2, axis=2)
                  for method, image in candidates.items()}
        for method, error in errors.items():
            self.scores.squared_error[method] += float(error[judged].sum())
        for code, name in enumerate(SOURCE_NAMES):
            part = judged & (completed.source == code)
            if part.any():
                self.scores._add(t, name, {m: float(e[part].sum()) for m, e in errors.items()}, int(part.sum()))
        self.scores.pixels += int(judged.sum())
        self.scores.frames += 1


def completed_frame(result: FrameResult) -> np.ndarray:
    """Full mode's completed frame as the output has it (before deblurring): temporal consistency's where it ran."""
    return result.temporal.frame if result.temporal is not None else result.completion.frame


def mosaic_telea(completed) -> np.ndarray:
    """What OpenCV's CPU chain makes of the same frame: our consistent mosaic of the global warps (it has no local
    registration), then Telea for what it left."""
    mosaic_only = completed.unregistered_mosaic() if completed.unregistered_mosaic is not None else completed.mosaic
    return cv2.inpaint(mosaic_only.frame, mosaic_only.remaining.astype(np.uint8), TELEA_RADIUS, cv2.INPAINT_TELEA)


def _run(frames: Sequence[np.ndarray], fps: float, truth_of: TruthOf, config: StabilizeConfig,
         scored: set[int] | None) -> CompletionScores:
    if config.mode != "full":
        raise ValueError("completion is evaluated in full mode")
    judge = _CompletionJudge(truth_of, scored)
    # Completion is scored at its own stage, before deblurring: skip the deblurring work.
    config = dataclasses.replace(config, deblur=dataclasses.replace(config.deblur, enabled=False))
    stabilize_source(ArraySource(frames, fps=fps, name="evaluation"), None, config, observer=judge)
    return judge.scores


def completion_scores(video: SyntheticVideo, config: StabilizeConfig = StabilizeConfig(),
                      frames: set[int] | None = None) -> CompletionScores:
    """Run the real orchestrator in full mode on synthetic frames and score the synthesized pixels."""
    def truth_of(t: int, orig_from_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out_from_orig = np.linalg.inv(orig_from_out)
        return video.render_view(t, out_from_orig), video.view_coverage(t, out_from_orig)

    return _run(video.frames, video.config.fps, truth_of, config, frames)


@dataclass(frozen=True)
class JitteredCrop:
    """The input made from a wide clip: a (width, height) window whose top-left corner follows the
    wide frame's centre plus hand-held-like jitter (integer pixels, so input pixels are the wide ones)."""

    corners: np.ndarray  # (N, 2) int: x, y of each crop's top-left corner in its wide frame
    width: int
    height: int

    def crops(self, wide: Sequence[np.ndarray]) -> list[np.ndarray]:
        return [np.ascontiguousarray(w[y:y + self.height, x:x + self.width]) for w, (x, y) in zip(wide, self.corners)]


def jittered_crop(n_frames: int, wide_size: tuple[int, int], crop_fraction: float = 0.8, jitter_px: float = 8.0,
                  seed: int = 0) -> JitteredCrop:
    """Band-limited jitter (a few frames' correlation, like hand shake) clipped to stay inside the wide frame."""
    wide_w, wide_h = wide_size
    width = int(round(wide_w * crop_fraction)) // 2 * 2
    height = int(round(wide_h * crop_fraction)) // 2 * 2
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((n_frames + 16, 2))
    kernel = np.exp(-0.5 * (np.arange(-6, 7) / 2.0) ** 2)
    smooth = np.stack([np.convolve(noise[:, i], kernel, mode="same") for i in range(2)], axis=1)[8:8 + n_frames]
    smooth *= jitter_px / max(float(smooth.std()), 1e-9)
    centre = np.array([(wide_w - width) / 2, (wide_h - height) / 2])
    corners = np.rint(centre + smooth)
    corners = np.clip(corners, 0, [wide_w - width, wide_h - height]).astype(int)
    return JitteredCrop(corners, width, height)


def crop_completion_scores(wide: Sequence[np.ndarray], crop: JitteredCrop, fps: float = 30.0,
                           config: StabilizeConfig = StabilizeConfig(),
                           frames: set[int] | None = None) -> CompletionScores:
    """Stabilize jittered crops of a wide clip in full mode; score synthesized pixels against the wide frames."""
    wide_h, wide_w = wide[0].shape[:2]

    def truth_of(t: int, orig_from_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, y = crop.corners[t]
        wide_from_out = np.array([[1.0, 0, x], [0, 1.0, y], [0, 0, 1]]) @ orig_from_out
        size = (crop.width, crop.height)
        truth = warping.warp(wide[t], wide_from_out, size)
        inside = warping.warp(np.full((wide_h, wide_w), 255, np.uint8), wide_from_out, size) == 255
        return truth, inside

    return _run(crop.crops(wide), fps, truth_of, config, frames)


# ---------------------------------------------------------------------------------------------- dynamic scenes

SHOW_THROUGH_SIGMA_PX = 1.5  # high-pass: intensity minus its Gaussian low-pass at this sigma (360-row frames)


@dataclass
class _Pooled:
    """Sums over pixels from many frames: squared error for PSNR, and the products for a correlation."""

    squared_error: float = 0.0
    pixels: int = 0
    cross: float = 0.0
    own_energy: float = 0.0
    other_energy: float = 0.0

    def add_error(self, image: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> None:
        d = image[mask].astype(np.float64) - truth[mask].astype(np.float64)
        self.squared_error += float(np.sum(d * d))
        self.pixels += int(mask.sum())

    def add_correlation(self, high: np.ndarray, other_high: np.ndarray, mask: np.ndarray) -> None:
        a, b = high[mask].astype(np.float64), other_high[mask].astype(np.float64)
        self.cross += float(np.dot(a, b))
        self.own_energy += float(np.dot(a, a))
        self.other_energy += float(np.dot(b, b))

    @property
    def psnr(self) -> float:
        return float("nan") if self.pixels == 0 else _pooled_psnr(self.squared_error, self.pixels)

    @property
    def correlation(self) -> float:
        denominator = math.sqrt(self.own_energy * self.other_energy)
        return float("nan") if denominator == 0 else self.cross / denominator


@dataclass
class DynamicScores:
    """Ground-truth scores of a full-mode run on a clip with a moving foreground object (``generate`` with
    ``object_kind="person"``), each for the output as written ("deblurred") and as deblurring received it
    ("not deblurred", which is exactly the --no-deblur output).

    object_psnr: PSNR over the object's pixels on the blurred frames, against the sharp truth.
    show_through: normalised correlation of the high-passed output with the high-passed background the object
        hides, over the object's pixels (0: none of the hidden background's detail shows; 1: a copy of it).
        ``truth_show_through`` is the same figure for the true frames (chance level).
    blurred_psnr: PSNR over every covered pixel of the blurred frames.
    synthesized_psnr / synthesized_show_through: over completion's synthesized pixels (all frames), against
        the truth, and inside the object; ``mosaic_telea_psnr``: what OpenCV's CPU chain gives on them;
        ``synthesized_split_psnr``: both methods' PSNR over the synthesized pixels the object covers in the truth
        and over the rest (where a stale copy of the object pasted from a neighbour would show).
    """

    object_psnr: dict[str, float]
    show_through: dict[str, float]
    truth_show_through: float
    blurred_psnr: dict[str, float]
    synthesized_psnr: float
    mosaic_telea_psnr: float
    synthesized_show_through: float
    synthesized_split_psnr: dict[str, dict[str, float]]  # method -> {"object", "background"} -> PSNR
    frames: int
    blurred_frames: int


class _DynamicJudge(NullObserver):
    """Scores every frame's completed and deblurred pixels against the synthetic truth."""

    def __init__(self, video: SyntheticVideo) -> None:
        self.video = video
        self.object = {k: _Pooled() for k in ("deblurred", "not deblurred")}
        self.show = {k: _Pooled() for k in ("deblurred", "not deblurred", "truth")}
        self.blurred = {k: _Pooled() for k in ("deblurred", "not deblurred")}
        self.synthesized = {k: _Pooled() for k in ("ours", "mosaic+telea")}
        self.synthesized_show = _Pooled()
        self.synthesized_on = {m: {"object": _Pooled(), "background": _Pooled()} for m in self.synthesized}
        self.frames = 0
        self.blurred_frames = 0

    def on_frame(self, result: FrameResult) -> None:
        if result.deblur is not None:
            self._score(result.stamp.index, result.warp, result.completion, result.deblur, completed_frame(result))

    def _score(self, t: int, warped: warping.WarpResult, completed, deblurred, ours: np.ndarray) -> None:
        video = self.video
        out_from_orig = np.linalg.inv(warped.orig_from_out)
        truth = video.render_view(t, out_from_orig)
        covered = video.view_coverage(t, out_from_orig)
        hidden = video.hidden_background(t, out_from_orig)
        inside = video.object_view_mask(t, out_from_orig) & covered
        sigma = SHOW_THROUGH_SIGMA_PX * truth.shape[0] / 360.0
        hidden_high = _high_pass(hidden, sigma)
        images = {"deblurred": deblurred.frame, "not deblurred": deblurred.before}
        self.frames += 1
        if video.is_blurred(t):
            self.blurred_frames += 1
            for name, image in images.items():
                self.object[name].add_error(image, truth, inside)
                self.blurred[name].add_error(image, truth, covered)
        for name, image in {**images, "truth": truth}.items():
            self.show[name].add_correlation(_high_pass(image, sigma), hidden_high, inside)
        synthesized = completed.missing & covered
        if synthesized.any():
            for name, image in (("ours", ours), ("mosaic+telea", mosaic_telea(completed))):
                self.synthesized[name].add_error(image, truth, synthesized)
                self.synthesized_on[name]["object"].add_error(image, truth, synthesized & inside)
                self.synthesized_on[name]["background"].add_error(image, truth, synthesized & ~inside)
            self.synthesized_show.add_correlation(_high_pass(ours, sigma), hidden_high,
                                                  synthesized & inside)

    def scores(self) -> DynamicScores:
        return DynamicScores(
            object_psnr={k: p.psnr for k, p in self.object.items()},
            show_through={k: self.show[k].correlation for k in ("deblurred", "not deblurred")},
            truth_show_through=self.show["truth"].correlation,
            blurred_psnr={k: p.psnr for k, p in self.blurred.items()},
            synthesized_psnr=self.synthesized["ours"].psnr,
            mosaic_telea_psnr=self.synthesized["mosaic+telea"].psnr,
            synthesized_show_through=self.synthesized_show.correlation,
            synthesized_split_psnr={m: {k: p.psnr for k, p in parts.items()} for m, parts in self.synthesized_on.items()},
            frames=self.frames,
            blurred_frames=self.blurred_frames,
        )


def _high_pass(rgb: np.ndarray, sigma: float) -> np.ndarray:
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return grey - cv2.GaussianBlur(grey, (0, 0), sigma)


def dynamic_scores(video: SyntheticVideo, config: StabilizeConfig = StabilizeConfig()) -> DynamicScores:
    """Run the real orchestrator in full mode with deblurring on a synthetic clip and score it (DynamicScores)."""
    if config.mode != "full" or not config.deblur.enabled:
        raise ValueError("dynamic scenes are evaluated in full mode with deblurring on")
    judge = _DynamicJudge(video)
    stabilize_source(ArraySource(video.frames, fps=video.config.fps, name="evaluation"), None, config,
                     observer=judge)
    return judge.scores()
