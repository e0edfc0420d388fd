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
# Every mode's camera path when none is given: eq. 18 at k = DEFAULT_RADIUS, steadier than vid.stab's cropped output,
# full mode's wider missing area kept from flickering by completion's temporal consistency (docs/decisions.md D40).
# Crop mode's window is then the largest centred one whose parts outside the input frames are at most
# DEFAULT_CROP_FILL of the output's pixels, completed as in full mode, as vid.stab's default fills its window's
# corners from the previous frame (D41).
DEFAULT_PATH = "gaussian"
DEFAULT_RADIUS = 60  # frames on each side of t (eq. 18's k)
# Crop mode with its window inside every frame (--crop-fill 0, --crop-scale, --crop adaptive): the L1 program in the
# widest window where it is as steady as eq. 18's, pricing the path's shake (D33), at the radius a SmoothingConfig
# has by default, since a larger k there only shrinks the window (D41).
HARD_CROP_PATH = "auto"
HARD_CROP_RADIUS = smoothing.DEFAULT_RADIUS
# The share of the output's pixels (mean over the clip) crop mode may synthesize by default: the smallest fill tried
# whose window is larger than vid.stab's on every shared clip (D41).
DEFAULT_CROP_FILL = 0.003


def crop_window_inside(crop: CropConfig, *, l1: bool) -> bool:
    """Whether crop mode keeps its window inside every frame (nothing synthesized): with --crop-fill 0, --crop-scale,
    --crop adaptive, or a path the L1 program plans in the window (``l1``: the l1, tripod or auto path, here or in a
    segment). Otherwise its window may leave the frames by the fill, to be completed."""
    return crop.fill == 0 or crop.kind != "fixed" or crop.scale is not None or l1


def default_path(mode: str, crop: CropConfig, *, l1_segments: bool = False) -> str:
    """The camera path of ``mode`` when none is given (crop mode: eq. 18 where its window may be completed, so not
    with ``l1_segments``, path segments planned by the L1 program in the window)."""
    if mode == "crop" and crop_window_inside(crop, l1=l1_segments):
        return HARD_CROP_PATH
    return DEFAULT_PATH


def default_radius(mode: str, path: str, crop: CropConfig, *, l1_segments: bool = False) -> int:
    """Eq. 18's k when none is given, for ``mode`` on ``path``."""
    if mode == "crop" and crop_window_inside(crop, l1=l1_segments or path != "gaussian"):
        return HARD_CROP_RADIUS
    return DEFAULT_RADIUS


@dataclass(frozen=True)
class StabilizeConfig:
    """A whole run's settings: the output mode and each stage's own config (their fields say their units)."""

    mode: OutputMode = "full"  # full: missing areas completed; crop: a window scaled back up; none: left black
    motion: motion.MotionConfig = field(default_factory=motion.MotionConfig)  # pass 1, thesis 3.2
    # The camera path (eq. 18 or the L1 program) and its settings. None, the default: the mode's own path and radius
    # (default_path, default_radius), which __post_init__ puts here, so a constructed config always holds one.
    smoothing: smoothing.SmoothingConfig | None = None
    completion: completion.CompletionConfig = field(default_factory=completion.CompletionConfig)  # chapter 4
    deblur: deblur.DeblurConfig = field(default_factory=deblur.DeblurConfig)  # chapter 5
    crop: CropConfig = field(default_factory=CropConfig)  # --mode crop's window: fixed or adaptive, its size and fill
    # Rolling-shutter correction: the sensor's readout time as a fraction of the frame interval (a number or its text,
    # "0.9"), "auto" to fit it from the motion, None: off.
    rolling_shutter: float | str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "rolling_shutter", rolling_shutter.parse_readout(self.rolling_shutter))
        if self.mode not in OUTPUT_MODES:
            raise ConfigError(f"mode must be one of {', '.join(OUTPUT_MODES)}, not {self.mode!r}")
        if self.smoothing is None:
            path = default_path(self.mode, self.crop)
            object.__setattr__(self, "smoothing", smoothing.SmoothingConfig(
                path=path, radius_frames=default_radius(self.mode, path, self.crop)))
        if self.crop.fill and self._window_inside:
            raise ConfigError("--crop-fill needs --mode crop with eq. 18's path (--path gaussian) and a fixed window "
                              "of its own choosing: the l1, tripod and auto paths, --crop-scale and --crop adaptive "
                              "keep the window inside every frame")
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
    def _window_inside(self) -> bool:
        """Whether no crop window leaves the frames: every mode but crop, and crop mode's window inside every frame."""
        return self.mode != "crop" or crop_window_inside(self.crop, l1=self.smoothing.uses_l1)

    @property
    def crop_fill(self) -> float:
        """The share of the output's pixels (mean over the clip) crop mode's window may leave the frames by, to be
        completed (0 in every other case)."""
        if self._window_inside:
            return 0.0
        return DEFAULT_CROP_FILL if self.crop.fill is None else self.crop.fill

    @property
    def completing(self) -> bool:
        """Whether missing pixels are filled (chapter 4): full mode, and crop mode's window where it leaves the
        frames."""
        return self.mode == "full" or self.crop_fill > 0

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
