"""What a run produces, typed end to end: the motion pass's estimates, the path plan every frame follows, and one
result per frame whose parts are the stages' own result types. Observers (the recorder, the judges, tests)
receive exactly these; nothing travels as a name and an untyped payload.

Invariants: a PathPlan's arrays have one entry per frame of the video (N); a FrameResult's ``output`` is the
frame as written (H x W x 3 uint8 RGB); its stage parts are None where the mode skips the stage or the run keeps
no intermediates (segment-parallel runs send only the output across processes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from pipeline.frames import Frame
from pipeline.stages.completion import CompletionResult
from pipeline.stages.adaptive_crop import AdaptiveCrop
from pipeline.stages.deblur import DeblurResult
from pipeline.stages.rolling_shutter import Correction, Tracks
from pipeline.stages.smoothing import SmoothingResult
from pipeline.stages.temporal import CompletedFrame, TemporalResult
from pipeline.stages.warping import CropWindow, WarpResult


@dataclass(frozen=True)
class Stamp:
    """Where a per-frame result belongs in time."""

    index: int
    time_s: float


@dataclass
class MotionPass:
    """Pass 1 (section 3.2, global motion): one transform and one status per frame, the frame's time, and the warnings
    raised on the way (frame index or None for the whole video)."""

    curr_from_prev: np.ndarray  # (N, 3, 3); the first frame's is the identity
    statuses: list[str]  # motion.MotionEstimate.status per frame ("ok", "cut", "fallback", ...)
    times_s: list[float]
    warnings: list[tuple[int | None, str]]
    tracks: list[Tracks | None] | None = None  # each pair's inlier tracks, kept for rolling-shutter correction only

    @property
    def n_frames(self) -> int:
        return len(self.statuses)

    @property
    def cuts(self) -> list[int]:
        return [t for t, status in enumerate(self.statuses) if status == "cut"]

    @property
    def fallbacks(self) -> list[int]:
        return [t for t, status in enumerate(self.statuses) if status == "fallback"]


@dataclass
class PathComparison:
    """Both planners on the same motion, for display: eq. 18's and the L1 program's trajectories (x, y px, angle deg,
    zoom %, as SmoothingResult's), whichever the run follows, and in crop mode the crop-window constraint of each
    frame: the output's corners in its input frame and how far the nearest lies inside that frame."""

    gaussian: np.ndarray  # (N, 4) eq. 18 (the run's radius and smoothness)
    l1: np.ndarray  # (N, 4) the L1 program (the run's margins; the run's own path, crop window and all, if L1)
    crop_corners: np.ndarray | None = None  # (N, 4, 2) crop mode: the output frame's corners in input pixels
    crop_room_px: np.ndarray | None = None  # (N,) crop mode: their least distance inside the input frame (< 0: out)


@dataclass
class PathPlan:
    """Everything decided for the whole video before any frame is rendered: the estimates, the smoothed path
    (eq. 18, or the L1 path), the transform from each output frame to its input frame, and the crop window in
    crop mode."""

    motion: MotionPass
    smoothing: SmoothingResult
    orig_from_out: np.ndarray  # (N, 3, 3): output pixel -> input pixel (orig_from_stab, times the crop in crop mode)
    crop: CropWindow | None  # crop mode with one window; None also where no area is common to all frames
    warnings: list[str]  # about the path as a whole (limits reached, crop given up, a single frame)
    adaptive_crop: AdaptiveCrop | None = None  # crop mode with --crop adaptive: a window per frame
    rolling_shutter: Correction | None = None  # --rolling-shutter: each frame's rows against its middle row
    # eq. 18 and the L1 path side by side, for the recording and figures: made on request (it solves the other path)
    paths: Callable[[], PathComparison] | None = None


@dataclass
class FrameResult:
    """One frame through the chain: warp (eq. 19) -> completion (chapter 4) -> deblurring (chapter 5)."""

    stamp: Stamp
    pts: int | None  # the input frame's presentation timestamp, kept for the output
    output: np.ndarray  # the frame as written
    input: Frame | None = None
    warp: WarpResult | None = None  # the stabilized frame and its missing pixels (built in crop mode only when kept)
    completion: CompletionResult | None = None  # full mode, and crop mode's frames its window leaves
    deblur: DeblurResult | None = None  # where deblurring runs
    # where completion ran: the synthesized pixels averaged with the neighbouring completed frames (the output has
    # them, with deblurring's change added)
    temporal: TemporalResult | None = None
    # where completion ran: its frame and its synthesized pixels, held only until the frames next to it are made
    # temporally consistent (without completion's other intermediates, which a run that does not record drops)
    completed: CompletedFrame | None = None
    cpu_seconds: dict[str, float] = field(default_factory=dict)  # this thread's CPU time per stage
    # What observers made of the intermediates as the frame was rendered (Observer.keep), by observer: each keeps its
    # own digest (e.g. the recorder's pictures at a viewing size) so that the run need not hold the intermediates.
    digests: dict[str, Any] = field(default_factory=dict)

    @property
    def has_intermediates(self) -> bool:
        return any(part is not None for part in (self.input, self.warp, self.completion, self.deblur))

    def without_intermediates(self) -> "FrameResult":
        """What the run itself needs of this frame: the output, the frame held for temporal consistency, the
        timings and the observers' digests (a run that records nothing keeps only these)."""
        return FrameResult(self.stamp, self.pts, self.output, completed=self.completed, cpu_seconds=self.cpu_seconds,
                           digests=self.digests)
