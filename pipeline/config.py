"""The whole run's configuration: the output mode and each stage's frozen config, and the one place that derives
from it how many neighbouring frames the per-frame chain needs on each side."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from pipeline.errors import ConfigError
from pipeline.stages.adaptive_crop import CropConfig
from pipeline.stages import completion, deblur, motion, rolling_shutter, smoothing

OutputMode = Literal["full", "none", "crop"]
OUTPUT_MODES: tuple[str, ...] = ("full", "none", "crop")
# Each mode's camera path when none is given. Crop: auto, the L1 program inside the widest crop window where it is
# as steady as eq. 18's path, else eq. 18's (on every shared clip the L1 path, steadier and keeping more of the
# frame); full and none: eq. 18, since the L1 path's wider departures leave completion more to fill
# (docs/decisions.md, 2026-11-25).
DEFAULT_PATHS = {"full": "gaussian", "none": "gaussian", "crop": "auto"}
# Eq. 18's radius k by mode. Full mode (and none, its warp without completion) at 60: steadier than vid.stab's
# cropped output on every shared clip, its wider missing area kept from flickering by completion's temporal
# consistency; crop mode at 30, where a larger k only shrinks the window (docs/decisions.md 2026-11-27).
DEFAULT_RADII = {"full": 60, "none": 60, "crop": smoothing.DEFAULT_RADIUS}


@dataclass(frozen=True)
class StabilizeConfig:
    mode: OutputMode = "full"
    motion: motion.MotionConfig = field(default_factory=motion.MotionConfig)
    # None: the mode's DEFAULT_PATHS path at its DEFAULT_RADII radius (set here, so the config always holds one)
    smoothing: smoothing.SmoothingConfig = None  # type: ignore[assignment]
    completion: completion.CompletionConfig = field(default_factory=completion.CompletionConfig)
    deblur: deblur.DeblurConfig = field(default_factory=deblur.DeblurConfig)
    crop: CropConfig = field(default_factory=CropConfig)  # --mode crop's window: fixed or adaptive
    rolling_shutter: float | str | None = None  # readout time (fraction of a frame; "0.9" is read), "auto", None: off

    def __post_init__(self) -> None:
        object.__setattr__(self, "rolling_shutter", rolling_shutter.parse_readout(self.rolling_shutter))
        if self.mode not in OUTPUT_MODES:
            raise ConfigError(f"mode must be one of {', '.join(OUTPUT_MODES)}, not {self.mode!r}")
        if self.smoothing is None:
            object.__setattr__(self, "smoothing", smoothing.SmoothingConfig(path=DEFAULT_PATHS[self.mode],
                                                                           radius_frames=DEFAULT_RADII[self.mode]))
        if self.crop.scale is not None and not (self.mode == "crop" and self.smoothing.uses_l1):
            raise ConfigError("--crop-scale needs --mode crop and the l1 or tripod path (it is the L1 program's "
                              "crop-window constraint)")

    @property
    def plans_by_linear_programs(self) -> bool:
        """Whether planning the path solves linear programs (scipy.optimize): crop mode's window
        (warping.largest_crop, and the L1 program inside it), or the l1 or tripod path anywhere."""
        paths = {self.smoothing.path, *(segment.path for segment in self.smoothing.segments)}
        return self.mode == "crop" or bool(paths & {"l1", "tripod"})

    @property
    def completing(self) -> bool:
        """Whether missing pixels are filled (chapter 4): full mode only."""
        return self.mode == "full"

    @property
    def deblurring(self) -> bool:
        """Whether frames are deblurred from sharper neighbours (chapter 5)."""
        return self.deblur.enabled and self.deblur.neighbour_frames > 0

    @property
    def completion_frames(self) -> int:
        """Neighbours on each side completion draws on (0 when it does not run)."""
        return self.completion.neighbour_frames if self.completing else 0

    @property
    def deblur_frames(self) -> int:
        """Neighbours on each side deblurring draws on (0 when it does not run)."""
        return self.deblur.neighbour_frames if self.deblurring else 0

    @property
    def window_frames(self) -> int:
        """Frames the per-frame chain reads on each side of the frame it makes: the sliding window's half width,
        and what a segment of a segment-parallel run reads beyond each end so its frames equal a whole run's."""
        return max(self.completion_frames, self.deblur_frames)
