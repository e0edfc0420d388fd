"""Motion smoothing of local displacements (thesis 3.4, eq. 18).

For frame t the correcting transform is a Gaussian-weighted sum of the local displacements to its
neighbours, S_t = sum_{i in N_t} T_t^i G(i - t), with T_t^i = ``t_from_i`` (maps frame i's pixel
coordinates into frame t) and N_t = [t-k, t+k]. Each T_t^i is a chain of at most k inter-frame
transforms, so no error accumulates over the video, unlike smoothing the cumulative path.

S_t maps stabilized coordinates to original ones (I'_t(p') = I_t(S_t p'), eq. 19): ``orig_from_stab``.
Windows are truncated at the ends of the video and at scene cuts, and the weights re-normalised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pipeline import geometry
from pipeline.stages import l1_path
from pipeline.errors import ConfigError

DEFAULT_RADIUS = 30  # chosen from measurements on the real clips: see docs/how-it-works.md, "Choosing k"


PATHS = ("gaussian", "l1", "tripod")
TRIPOD_STILL = 0.05  # px or degrees a frame: a tripod path moving more than this is following the camera


@dataclass(frozen=True)
class SmoothingConfig:
    radius: int = DEFAULT_RADIUS  # k: neighbours on each side
    sigma: float | None = None  # Gaussian sigma in frames; None -> sqrt(k) as in the thesis
    path: str = "gaussian"  # "gaussian": eq. 18; "l1": the L1-optimal path (pipeline/stages/l1_path.py); "tripod": held
    l1: l1_path.L1PathConfig = l1_path.L1PathConfig()  # its bounds, when path is "l1"
    horizon_lock: bool = False  # the output keeps the rotation of each shot's first frame (any path)

    def __post_init__(self) -> None:
        if self.path not in PATHS:
            raise ConfigError(f"smoothing path must be one of {', '.join(PATHS)}, not {self.path!r}")
        if self.radius < 0:
            raise ConfigError(f"smoothing radius must be >= 0, not {self.radius}")
        if self.sigma is not None and self.sigma <= 0:
            raise ConfigError(f"smoothing sigma must be > 0, not {self.sigma}")

    @property
    def effective_sigma(self) -> float:
        return self.sigma if self.sigma is not None else max(math.sqrt(self.radius), 1e-6)


@dataclass(frozen=True)
class SmoothingResult:
    orig_from_stab: np.ndarray  # (N, 3, 3): S_t
    segment_starts: tuple[int, ...]  # frames where a smoothing segment begins (0 and every scene cut)
    # Camera trajectories for plots (frame centre displacement x, y in px and angle in degrees,
    # relative to the segment's first frame): original vs smoothed. Shape (N, 3).
    original_trajectory: np.ndarray
    smoothed_trajectory: np.ndarray

    @property
    def stab_from_orig(self) -> np.ndarray:
        return np.linalg.inv(self.orig_from_stab)


def gaussian_weights(radius: int, sigma: float) -> np.ndarray:
    """G(i) for i in [-k, k], not normalised (normalisation happens per truncated window)."""
    offsets = np.arange(-radius, radius + 1, dtype=np.float64)
    return np.exp(-(offsets**2) / (2.0 * sigma**2))


def neighbour_transforms(curr_from_prev: np.ndarray, t: int, first: int, last: int,
                         prev_from_curr: np.ndarray | None = None) -> dict[int, np.ndarray]:
    """t_from_i for every i in [first, last]: chains of inter-frame transforms outward from t."""
    if prev_from_curr is None:
        prev_from_curr = np.linalg.inv(curr_from_prev)
    t_from = {t: geometry.IDENTITY.copy()}
    for i in range(t - 1, first - 1, -1):  # t_from_i = t_from_(i+1) @ (i+1)_from_i
        t_from[i] = t_from[i + 1] @ curr_from_prev[i + 1]
    for i in range(t + 1, last + 1):  # t_from_i = t_from_(i-1) @ (i-1)_from_i
        t_from[i] = t_from[i - 1] @ prev_from_curr[i]
    return {i: m / m[2, 2] for i, m in t_from.items()}


def smooth(curr_from_prev: np.ndarray, config: SmoothingConfig = SmoothingConfig(), *,
           cuts: Sequence[int] = (), width: int = 0, height: int = 0) -> SmoothingResult:
    """S_t for every frame from the inter-frame transforms ``curr_from_prev`` ((N, 3, 3), [0] unused).

    ``cuts`` are frame indices that start a new shot: no window reaches across them.
    ``width``/``height`` only serve the trajectories' reference point (the frame centre).
    """
    curr_from_prev = np.asarray(curr_from_prev, dtype=np.float64)
    n_frames = len(curr_from_prev)
    segment_starts = tuple(sorted({0, *(c for c in cuts if 0 < c < n_frames)}))
    segment_of = np.searchsorted(segment_starts, np.arange(n_frames), side="right") - 1
    segment_end = [*(s - 1 for s in segment_starts[1:]), n_frames - 1]

    if config.path != "gaussian":
        planner = l1_path.L1PathConfig.tripod() if config.path == "tripod" else config.l1
        orig_from_stab = _l1_paths(curr_from_prev, segment_starts, segment_end, planner, width, height)
        return _finish(curr_from_prev, orig_from_stab, segment_starts, config, width, height)

    radius = config.radius
    kernel = gaussian_weights(radius, config.effective_sigma)
    prev_from_curr = np.linalg.inv(curr_from_prev)
    orig_from_stab = np.empty((n_frames, 3, 3))
    for t in range(n_frames):
        seg = segment_of[t]
        first = max(t - radius, segment_starts[seg])
        last = min(t + radius, segment_end[seg])
        t_from = neighbour_transforms(curr_from_prev, t, first, last, prev_from_curr)
        weights = kernel[first - t + radius: last - t + radius + 1]
        weights = weights / weights.sum()
        s_t = sum(w * t_from[i] for w, i in zip(weights, range(first, last + 1)))
        orig_from_stab[t] = s_t / s_t[2, 2]

    return _finish(curr_from_prev, orig_from_stab, segment_starts, config, width, height)


def path_warnings(result: SmoothingResult, config: SmoothingConfig) -> list[str]:
    """What a user should hear about the planned path: a tripod that had to move (the input camera went further
    than the held view can reach), as frame ranges."""
    if config.path != "tripod":
        return []
    moving = np.flatnonzero(np.abs(np.diff(result.smoothed_trajectory, axis=0)).max(axis=1) > TRIPOD_STILL)
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
    return SmoothingResult(orig_from_stab, segment_starts, original, smoothed)


def _l1_paths(curr_from_prev: np.ndarray, segment_starts: Sequence[int], segment_end: Sequence[int],
              config: l1_path.L1PathConfig, width: int, height: int) -> np.ndarray:
    """S_t of the L1-optimal path, shot by shot (each from its own accumulated path)."""
    orig_from_stab = np.empty((len(curr_from_prev), 3, 3))
    for first, last in zip(segment_starts, segment_end):
        first_from_t = np.empty((last - first + 1, 3, 3))
        first_from_t[0] = geometry.IDENTITY
        for t in range(first + 1, last + 1):
            m = first_from_t[t - first - 1] @ np.linalg.inv(curr_from_prev[t])
            first_from_t[t - first] = m / m[2, 2]
        orig_from_stab[first:last + 1] = l1_path.orig_from_stab(first_from_t, config, max(width, 1), max(height, 1))
    return orig_from_stab


def trajectories(curr_from_prev: np.ndarray, orig_from_stab: np.ndarray, segment_starts: Sequence[int],
                 width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Accumulated camera paths for display only (x, y, angle per frame), original and smoothed.

    The original path of frame t is first_from_t (its pixels in the segment's first frame); the smoothed
    path is first_from_t @ S_t. Accumulation is fine here: these curves are never fed back.
    """
    n_frames = len(curr_from_prev)
    starts = set(segment_starts)
    original = np.zeros((n_frames, 3))
    smoothed = np.zeros((n_frames, 3))
    first_from_t = geometry.IDENTITY.copy()
    for t in range(n_frames):
        if t not in starts:
            first_from_t = first_from_t @ np.linalg.inv(curr_from_prev[t])
            first_from_t /= first_from_t[2, 2]
        original[t] = geometry.decompose(first_from_t, width, height)[:3]
        smoothed[t] = geometry.decompose(first_from_t @ orig_from_stab[t], width, height)[:3]
    return original, smoothed
