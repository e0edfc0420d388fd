"""Motion smoothing of local displacements (thesis 3.4, eq. 18).

For frame t the correcting transform is a Gaussian-weighted sum of the local displacements to its
neighbours, S_t = sum_{i in N_t} T_t^i G(i - t), with T_t^i = ``t_from_i`` (maps frame i's pixel
coordinates into frame t) and N_t = [t-k, t+k]. Each T_t^i is a chain of at most k inter-frame
transforms, so no error accumulates over the video, unlike smoothing the cumulative path.

S_t maps stabilized coordinates to original ones (I'_t(p') = I_t(S_t p'), eq. 19): ``orig_from_stab``.
Windows are truncated at the ends of the video and at scene cuts, and the weights re-normalised.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pipeline import geometry
from pipeline.geometry import neighbour_transforms
from pipeline.stages import l1_path, path_control
from pipeline.errors import ConfigError

# k of a SmoothingConfig made without one, and of crop mode with a window inside every frame (a run's default is
# pipeline/config.default_radius's), chosen from measurements on the real clips: docs/how-it-works.md, "Choosing k"
DEFAULT_RADIUS = 30


PATHS = ("gaussian", "l1", "tripod", "auto")
TRIPOD_STILL = 0.05  # px or degrees a frame: a tripod path moving more than this is following the camera


@dataclass(frozen=True)
class SmoothingConfig:
    radius_frames: int = DEFAULT_RADIUS  # k (eq. 18): frames on each side of t in N_t
    sigma: float | None = None  # Gaussian sigma in frames; None -> sqrt(k) as in the thesis
    # "gaussian": eq. 18; "l1": the L1-optimal path (pipeline/stages/l1_path.py); "tripod": held; "auto": in crop mode
    # the L1 path in the widest crop window where it is as steady as eq. 18's, else eq. 18's (pipeline/chain.py),
    # in other modes eq. 18's
    path: str = "gaussian"
    l1: l1_path.L1PathConfig = l1_path.L1PathConfig()  # its bounds, when path is "l1"
    horizon_lock: bool = False  # the output keeps the rotation of each shot's first frame (any path)
    # Per-axis strength 0-100 (path_control.Smoothness); None: radius/sigma (eq. 18) or l1's margins as given.
    smoothness: path_control.Smoothness | None = None
    max_shift: float | None = None  # px: no output frame's centre departs further from its input's (x, y each)
    max_angle: float | None = None  # degrees: nor turns further
    segments: tuple[path_control.PathSegment, ...] = ()  # time ranges with their own path and smoothness

    def __post_init__(self) -> None:
        if self.path not in PATHS:
            raise ConfigError(f"smoothing path must be one of {', '.join(PATHS)}, not {self.path!r}")
        if self.radius_frames < 0:
            raise ConfigError(f"smoothing radius must be >= 0, not {self.radius_frames}")
        if self.sigma is not None and self.sigma <= 0:
            raise ConfigError(f"smoothing sigma must be > 0, not {self.sigma}")
        if self.path == "tripod" and self.smoothness is not None:
            raise ConfigError("the tripod path holds the camera still: smoothness does not apply to it")
        for name in ("max_shift", "max_angle"):
            value = getattr(self, name)
            if value is not None and not value >= 0:
                raise ConfigError(f"{name.replace('_', ' ')} must be >= 0, not {value}")
        for segment in self.segments:
            if segment.path not in PATHS:
                raise ConfigError(f"path segment {segment.label()}: the path must be one of {', '.join(PATHS)}")
        path_control.check_segments(self.segments)

    @property
    def effective_sigma(self) -> float:
        return self.sigma if self.sigma is not None else max(math.sqrt(self.radius_frames), 1e-6)

    def for_segment(self, segment: path_control.PathSegment) -> SmoothingConfig:
        """The setting a segment plans its frames with: its path and smoothness, this config's other values."""
        smoothness = segment.smoothness
        if smoothness is None and segment.path != "tripod" and segment.path == self.path:
            smoothness = self.smoothness
        return dataclasses.replace(self, path=segment.path, smoothness=smoothness, segments=())

    def l1_planner(self, width: int, height: int) -> l1_path.L1PathConfig:
        """The L1 program's config for this path: tripod's, or l1's margins scaled by the smoothness and cut to
        the departure bound (so the program is optimal within it, rather than clipped after)."""
        config = self.l1
        if self.path == "tripod":
            config = dataclasses.replace(l1_path.L1PathConfig.tripod(), crop_scale=config.crop_scale,
                                         crop_offset=config.crop_offset)
        fraction, degrees, scale = config.margin_fraction, config.margin_deg, config.margin_scale
        share = config.crop_room_share  # crop mode: the translation's bound is the room the crop window leaves
        if self.smoothness is not None:
            fraction *= self.smoothness.margin_factor("translation")
            share *= min(self.smoothness.margin_factor("translation"), 1.0)
            degrees *= self.smoothness.margin_factor("rotation")
            scale *= self.smoothness.margin_factor("zoom")
        if self.max_shift is not None:
            fraction = min(fraction, self.max_shift / max(width, height, 1))
            if config.crop_scale is not None and config.crop_scale < 1:
                room = (1.0 - config.crop_scale) / 2.0 * max(max(width, height) - 1, 1)
                share = min(share, self.max_shift / room)
        if self.max_angle is not None:
            degrees = min(degrees, self.max_angle)
        return dataclasses.replace(config, margin_fraction=fraction, margin_deg=degrees, margin_scale=scale,
                                   crop_room_share=share)

    @property
    def uses_l1(self) -> bool:
        """Whether any frame may be planned by the L1 program (the l1, tripod or, in crop mode, auto path, here or
        in a segment)."""
        return self.path != "gaussian" or any(segment.path != "gaussian" for segment in self.segments)

    def label(self) -> str:
        """The setting in the command line's words (for warnings, recordings and figures)."""
        text = self.path + (f":{self.smoothness.label()}" if self.smoothness is not None else "")
        return text if self.path != "gaussian" or self.smoothness is not None else f"gaussian:k={self.radius_frames}"


@dataclass(frozen=True)
class SmoothingResult:
    orig_from_stab: np.ndarray  # (N, 3, 3): S_t
    segment_starts: tuple[int, ...]  # frames where a smoothing segment begins (0 and every scene cut)
    # Camera trajectories for plots (frame centre displacement x, y in px, angle in degrees and zoom in % of the
    # shot's first frame's scale, relative to the shot's first frame): original vs smoothed. Shape (N, 4).
    original_trajectory: np.ndarray
    smoothed_trajectory: np.ndarray
    settings: tuple[str, ...] = ()  # the path settings used, in the command line's words (path_control segments)
    setting_of: np.ndarray | None = None  # (N,) index into settings of the one each frame was planned with
    # The planner that made the path: "gaussian" (eq. 18), "l1" or "tripod" (the L1 program); never "auto", which
    # is eq. 18's here and whichever crop mode's planner chose there (pipeline/chain.py)
    planner: str = "gaussian"

    @property
    def stab_from_orig(self) -> np.ndarray:
        return np.linalg.inv(self.orig_from_stab)


def gaussian_weights(radius: int, sigma: float) -> np.ndarray:
    """G(i) for i in [-k, k], not normalised (normalisation happens per truncated window)."""
    offsets = np.arange(-radius, radius + 1, dtype=np.float64)
    return np.exp(-(offsets**2) / (2.0 * sigma**2))


def smooth(curr_from_prev: np.ndarray, config: SmoothingConfig = SmoothingConfig(), *,
           cuts: Sequence[int] = (), width: int = 0, height: int = 0,
           times_s: Sequence[float] | None = None) -> SmoothingResult:
    """S_t for every frame from the inter-frame transforms ``curr_from_prev`` ((N, 3, 3), [0] unused).

    ``cuts`` are frame indices that start a new shot: no window reaches across them.
    ``width``/``height`` serve the trajectories' reference point (the frame centre) and the L1 path's margins.
    ``times_s``: each frame's time, needed only for ``config.segments`` (which are in seconds).
    """
    curr_from_prev = np.asarray(curr_from_prev, dtype=np.float64)
    n_frames = len(curr_from_prev)
    segment_starts = tuple(sorted({0, *(c for c in cuts if 0 < c < n_frames)}))
    segment_end = [*(s - 1 for s in segment_starts[1:]), n_frames - 1]
    settings = [config]
    setting_of = np.zeros(n_frames, dtype=np.int64)
    if config.segments:
        if times_s is None or len(times_s) != n_frames:
            raise ConfigError("path segments are in seconds: smooth() needs each frame's time (times_s)")
        settings += [config.for_segment(segment) for segment in config.segments]
        setting_of = path_control.setting_of_frames(config.segments, np.asarray(times_s, np.float64))
    blend = path_control.blend_frames(np.asarray(times_s, np.float64)) if times_s is not None else 30
    prev_from_curr = np.linalg.inv(curr_from_prev)
    orig_from_stab = np.empty((n_frames, 3, 3))
    for first, last in zip(segment_starts, segment_end):
        orig_from_stab[first:last + 1] = _plan_shot(curr_from_prev, prev_from_curr, first, last, settings,
                                                    setting_of, blend, width, height)
    result = _finish(curr_from_prev, orig_from_stab, segment_starts, config, width, height)
    labels = (config.label(), *(segment.label() for segment in config.segments))
    return dataclasses.replace(result, settings=labels, setting_of=setting_of,
                               planner="gaussian" if config.path == "auto" else config.path)


def _plan_shot(curr_from_prev: np.ndarray, prev_from_curr: np.ndarray, first: int, last: int,
               settings: Sequence[SmoothingConfig], setting_of: np.ndarray, blend: int, width: int, height: int
               ) -> np.ndarray:
    """S_t of one shot: each run of frames with one setting planned alone, over its frames and one more on each
    side (within the shot); from a switch on, the new run's S_t times an offset that starts at the old run's
    S_t there (no jump) and eases to the identity over ``blend`` frames."""
    runs = [first, *(t for t in range(first + 1, last + 1) if setting_of[t] != setting_of[t - 1]), last + 1]
    out = np.empty((last - first + 1, 3, 3))
    carried: np.ndarray | None = None  # the previous run's final S_t at this run's first frame
    for a, b in zip(runs, runs[1:]):
        lo, hi = max(a - 1, first), min(b, last)  # one frame beyond each end: where the runs meet
        planned = _plan_range(curr_from_prev, prev_from_curr, lo, hi, settings[setting_of[a]], width, height)
        s = planned[a - lo:]  # frames a .. hi
        if carried is not None:
            start_offset = np.linalg.solve(s[0], carried)  # S_new(a) @ offset = S_old(a)
            weights = path_control.ease_out(np.arange(len(s)), blend)
            s = np.array([m @ path_control.eased(start_offset, w) for m, w in zip(s, weights)])
            s /= s[:, 2:3, 2:3]
        out[a - first:b - first] = s[:b - a]
        carried = s[b - a] if hi == b else None
    return out


def _plan_range(curr_from_prev: np.ndarray, prev_from_curr: np.ndarray, first: int, last: int,
                config: SmoothingConfig, width: int, height: int) -> np.ndarray:
    """S_t for frames ``first``..``last`` planned as one shot with one setting."""
    if config.path in ("l1", "tripod"):  # "auto" is eq. 18's here; crop mode's planner chooses (pipeline/chain.py)
        planner = config.l1_planner(max(width, 1), max(height, 1))
        return _l1_path(curr_from_prev, first, last, planner, width, height)
    if config.smoothness is None or config.smoothness.uniform:
        radius = (config.radius_frames if config.smoothness is None
                  else config.smoothness.radius("translation", config.radius_frames))
        sigma = config.effective_sigma if config.smoothness is None else max(math.sqrt(radius), 1e-6)
        return _gaussian(curr_from_prev, prev_from_curr, first, last, radius, sigma)
    # Per axis: eq. 18 at each axis's radius; the translation run's S_t turned and zoomed about the output centre
    # (which it sends to the same place) to the rotation and zoom runs' angle and scale.
    radius_of = {axis: config.smoothness.radius(axis, config.radius_frames) for axis in path_control.AXES}
    by_axis = {}
    for radius in radius_of.values():
        if radius not in by_axis:
            by_axis[radius] = _gaussian(curr_from_prev, prev_from_curr, first, last, radius,
                                        max(math.sqrt(radius), 1e-6))
    moved, turned, zoomed = (by_axis[radius_of[axis]] for axis in ("translation", "rotation", "zoom"))
    out = np.empty_like(moved)
    for i in range(len(moved)):
        _, _, angle, scale = geometry.decompose(moved[i], width, height)
        _, _, want_angle, _ = geometry.decompose(turned[i], width, height)
        _, _, _, want_scale = geometry.decompose(zoomed[i], width, height)
        change = l1_path.similarity((0.0, 0.0, math.radians(want_angle - angle), math.log(want_scale / scale)),
                                    max(width, 1), max(height, 1))
        m = moved[i] @ change
        out[i] = m / m[2, 2]
    return out


def _gaussian(curr_from_prev: np.ndarray, prev_from_curr: np.ndarray, first: int, last: int, radius: int,
              sigma: float) -> np.ndarray:
    """Eq. 18 for frames ``first``..``last`` of one shot: windows truncated at its ends, weights re-normalised."""
    kernel = gaussian_weights(radius, sigma)
    out = np.empty((last - first + 1, 3, 3))
    for t in range(first, last + 1):
        lo, hi = max(t - radius, first), min(t + radius, last)
        t_from = neighbour_transforms(curr_from_prev, t, lo, hi, prev_from_curr)
        weights = kernel[lo - t + radius: hi - t + radius + 1]
        weights = weights / weights.sum()
        s_t = sum(w * t_from[i] for w, i in zip(weights, range(lo, hi + 1)))
        out[t - first] = s_t / s_t[2, 2]
    return out


def path_warnings(result: SmoothingResult, config: SmoothingConfig) -> list[str]:
    """What a user should hear about the planned path: a tripod that had to move (the input camera went further
    than the held view can reach), as frame ranges."""
    tripods = [config.path == "tripod", *(segment.path == "tripod" for segment in config.segments)]
    if not any(tripods):
        return []
    steps = np.abs(np.diff(result.smoothed_trajectory[:, :3], axis=0)).max(axis=1)
    of = result.setting_of if result.setting_of is not None else np.zeros(len(steps) + 1, np.int64)
    held = np.asarray(tripods)[of[1:]]
    moving = np.flatnonzero((steps > TRIPOD_STILL) & held)
    if moving.size == 0:
        return []
    starts = set(result.segment_starts)
    ranges, first, last = [], moving[0], moving[0]
    for t in moving[1:]:
        if t != last + 1:
            ranges.append((first, last + 1))
            first = t
        last = t
    ranges.append((first, last + 1))
    shown = ", ".join(f"{a}-{b}" for a, b in ranges[:5] if b not in starts) + (" ..." if len(ranges) > 5 else "")
    return [f"tripod: the camera moved further than a still view can reach; the view follows it in frames {shown}"]


def _finish(curr_from_prev: np.ndarray, orig_from_stab: np.ndarray, segment_starts: Sequence[int],
            config: SmoothingConfig, width: int, height: int) -> SmoothingResult:
    """The result with its trajectories; with horizon lock, each S_t first turned about the frame centre so
    that the output's rotation (relative to its shot's first frame) is 0."""
    original, smoothed = trajectories(curr_from_prev, orig_from_stab, segment_starts, width, height)
    if config.horizon_lock:
        for t in range(len(orig_from_stab)):
            turned = orig_from_stab[t] @ l1_path.similarity((0.0, 0.0, -math.radians(smoothed[t, 2]), 0.0),
                                                             width, height)
            orig_from_stab[t] = turned / turned[2, 2]
        original, smoothed = trajectories(curr_from_prev, orig_from_stab, segment_starts, width, height)
    if config.max_shift is not None or config.max_angle is not None:
        orig_from_stab = path_control.bound_departure(orig_from_stab, width, height, config.max_shift,
                                                      config.max_angle)
        original, smoothed = trajectories(curr_from_prev, orig_from_stab, segment_starts, width, height)
    return SmoothingResult(orig_from_stab, segment_starts, original, smoothed)


def _l1_path(curr_from_prev: np.ndarray, first: int, last: int, config: l1_path.L1PathConfig, width: int,
             height: int) -> np.ndarray:
    """S_t of the L1-optimal path for frames ``first``..``last`` of one shot (from its inter-frame transforms)."""
    return l1_path.orig_from_stab(curr_from_prev[first:last + 1], config, max(width, 1), max(height, 1))


def trajectories(curr_from_prev: np.ndarray, orig_from_stab: np.ndarray, segment_starts: Sequence[int],
                 width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Accumulated camera paths for display only (x, y, angle, zoom per frame), original and smoothed.

    The original path of frame t is first_from_t (its pixels in the segment's first frame); the smoothed
    path is first_from_t @ S_t. Accumulation is fine here: these curves are never fed back.
    """
    n_frames = len(curr_from_prev)
    starts = set(segment_starts)
    original = np.zeros((n_frames, 4))
    smoothed = np.zeros((n_frames, 4))
    first_from_t = geometry.IDENTITY.copy()
    for t in range(n_frames):
        if t not in starts:
            first_from_t = first_from_t @ np.linalg.inv(curr_from_prev[t])
            first_from_t /= first_from_t[2, 2]
        original[t] = _trajectory_point(first_from_t, width, height)
        smoothed[t] = _trajectory_point(first_from_t @ orig_from_stab[t], width, height)
    return original, smoothed


def _trajectory_point(first_from_t: np.ndarray, width: int, height: int) -> tuple[float, float, float, float]:
    dx, dy, angle, scale = geometry.decompose(first_from_t, width, height)
    return dx, dy, angle, 100.0 * (scale - 1.0)
