"""Ground-truth evaluation of full-frame completion on synthetic video (used by tests and benchmarks).

The synthetic world is known beyond every input frame, so for the virtual camera the stabilizer
chose (S_t) the truth of each synthesized pixel is known too. Three fillers are compared on exactly
the same stabilized frames and missing pixels:

- ``ours``: the completion chain (mosaic, local flow, motion inpainting, local-warp mosaicing, fallback);
- ``mosaic+telea``: what OpenCV's videostab offers on a CPU (ConsistentMosaicInpainter followed by
  ColorInpainter with Telea), rebuilt from our consistent mosaic and cv2.inpaint;
- ``telea``: plain Telea colour inpainting of the stabilized frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from pipeline.observer import NullObserver, Stamp
from pipeline.source import ArraySource
from pipeline.stabilize import StabilizeConfig, stabilize_source
from pipeline.synthetic import SyntheticVideo

TELEA_RADIUS = 3.0


@dataclass
class CompletionScores:
    """Pooled squared errors of synthesized pixels, per method."""

    squared_error: dict[str, float] = field(default_factory=lambda: {m: 0.0 for m in METHODS})
    pixels: int = 0
    frames: int = 0

    def psnr(self, method: str) -> float:
        mse = self.squared_error[method] / max(self.pixels * 3, 1)
        return float("inf") if mse == 0 else float(10 * np.log10(255.0**2 / mse))


METHODS = ("ours", "mosaic+telea", "telea")


class _CompletionJudge(NullObserver):
    """Scores each completed frame against the truth rendered through the same virtual camera."""

    def __init__(self, video: SyntheticVideo, frames: set[int] | None, config: StabilizeConfig) -> None:
        self.video = video
        self.frames = frames
        self.config = config
        self.scores = CompletionScores()
        self._warp: dict[int, object] = {}

    def on_stage(self, stage: str, stamp: Stamp | None, result) -> None:
        if stamp is None or (self.frames is not None and stamp.index not in self.frames):
            return
        if stage == "warp":
            self._warp[stamp.index] = result
        elif stage == "completion":
            self._score(stamp.index, self._warp.pop(stamp.index), result)

    def _score(self, t: int, warped, completed) -> None:
        missing = completed.missing
        if not missing.any():
            return
        stab_from_orig = np.linalg.inv(warped.orig_from_out)
        truth = self.video.render_view(t, stab_from_orig)
        judged = missing & self.video.view_coverage(t, stab_from_orig)
        if not judged.any():
            return
        mosaic_only = completed.mosaic
        candidates = {
            "ours": completed.frame,
            "mosaic+telea": cv2.inpaint(mosaic_only.frame, mosaic_only.remaining.astype(np.uint8), TELEA_RADIUS,
                                        cv2.INPAINT_TELEA),
            "telea": cv2.inpaint(warped.frame, missing.astype(np.uint8), TELEA_RADIUS, cv2.INPAINT_TELEA),
        }
        reference = truth[judged].astype(np.float64)
        for method, image in candidates.items():
            self.scores.squared_error[method] += float(np.sum((image[judged].astype(np.float64) - reference) ** 2))
        self.scores.pixels += int(judged.sum())
        self.scores.frames += 1


def completion_scores(video: SyntheticVideo, config: StabilizeConfig = StabilizeConfig(),
                      frames: set[int] | None = None) -> CompletionScores:
    """Run the real orchestrator in full mode on the synthetic frames and score the synthesized pixels."""
    if config.mode != "full":
        raise ValueError("completion is evaluated in full mode")
    judge = _CompletionJudge(video, frames, config)
    stabilize_source(ArraySource(video.frames, fps=video.config.fps, name="synthetic"), None, config, observer=judge)
    return judge.scores

