"""Adaptive crop for ``--mode crop``: a window whose zoom follows the path over time (Warp Stabilizer's "crop less,
smooth more"; vid.stab ``optzoom=2`` with ``zoomspeed``), instead of one window valid in every frame.

The window of frame t is centred on one anchor point a for the whole clip and scaled by z_t (stab = a + z_t (out -
centre)); a is the fixed crop's centre or the frame centre, whichever keeps more (about the first, no frame keeps
less than the fixed crop). The largest valid scale m_t is the largest z whose four corners lie inside frame t's
valid region (the input frame mapped into stabilized coordinates, a convex quad; a linear bound on z per edge and
corner) and inside the frame. The chosen scales are
m_t limited to a rate (``zoom_speed``: the cone envelope min_j m_j + rate |t - j|, forward and backward), then
eroded and Gaussian-smoothed over ``radius`` frames. The mean of an erosion over a window no wider than the
erosion's stays below the input at every frame, so z_t <= m_t still: no black pixel on any frame, by
construction. Both steps keep the rate bound, and the smoothing removes the envelope's kinks: the zoom changes
gently, where the shake calls for it, and zooms back out where it calms. Shots are planned apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pipeline import geometry
from pipeline.errors import ConfigError

DEFAULT_ZOOM_SPEED = 0.1  # % of the frame's size a frame; vid.stab's 0.25 zooms visibly (docs/decisions.md D16)
SMOOTH_RADIUS = 30  # frames of erosion and of Gaussian smoothing (a second at 30 fps)
MIN_SCALE = 0.05  # a frame whose window about the anchor would be smaller than this has no usable crop
EDGE_SLACK = 1e-3  # the window is kept this fraction inside its largest valid size (bilinear reads at the edge)


@dataclass(frozen=True)
class AdaptiveCrop:
    """Per frame, the output as a window of the stabilized frame about a fixed anchor point:
    stab = anchor + scale_t (out - centre), centre the output frame's centre."""

    scales: np.ndarray  # (N,) in (0, 1]
    anchor: tuple[float, float]  # the windows' centre in stabilized coordinates (px)
    width: int
    height: int

    @property
    def stab_from_out(self) -> np.ndarray:
        """(N, 3, 3)."""
        cx, cy = (self.width - 1) / 2.0, (self.height - 1) / 2.0
        out = np.zeros((len(self.scales), 3, 3))
        out[:, 0, 0] = out[:, 1, 1] = self.scales
        out[:, 0, 2] = self.anchor[0] - cx * self.scales
        out[:, 1, 2] = self.anchor[1] - cy * self.scales
        out[:, 2, 2] = 1.0
        return out

    @property
    def cropping_ratio(self) -> float:
        """Area kept, as a fraction of the frame, averaged over the frames."""
        return float(np.mean(self.scales**2))


def largest_scales(orig_from_stab: np.ndarray, width: int, height: int, anchor: tuple[float, float],
                   valid: np.ndarray | None = None) -> np.ndarray:
    """(N,) the largest scale of a window of the frame's aspect ratio centred on ``anchor`` inside each frame's
    valid region and inside the frame; <= 0 where the anchor has no input pixel. ``valid``: (N, 4, 2) each
    frame's valid region in its own coordinates, a convex quad (default: the frame)."""
    corners = geometry.frame_corners(width, height)
    centre = np.asarray(anchor, np.float64)
    spokes = corners - corners.mean(axis=0)  # window corner k at anchor + z * spokes[k]

    def bound(quad: np.ndarray) -> float:
        inner = quad.mean(axis=0)
        best = np.inf
        for a, b in zip(quad, np.roll(quad, -1, axis=0)):
            normal = np.array([b[1] - a[1], a[0] - b[0]])
            if normal @ (inner - a) > 0:  # outward
                normal = -normal
            room = normal @ (a - centre)  # < 0: the anchor is outside this edge
            if room <= 0:
                return float(room)
            reach = spokes @ normal
            if (reach > 0).any():
                best = min(best, float(np.min(room / reach[reach > 0])))
        return best

    in_frame = bound(corners)
    return np.array([min(in_frame, bound(geometry.apply(np.linalg.inv(s_t), corners if valid is None else valid[t])))
                     for t, s_t in enumerate(np.asarray(orig_from_stab, np.float64))])


def smooth_scales(largest: np.ndarray, rate: float, radius: int = SMOOTH_RADIUS) -> np.ndarray:
    """Scales <= ``largest`` everywhere, changing by at most ``rate`` a frame, smooth (see the module docstring)."""
    z = np.asarray(largest, np.float64).copy()
    n = len(z)
    for t in range(1, n):  # the cone envelope: the largest rate-limited curve below the bound
        z[t] = min(z[t], z[t - 1] + rate)
    for t in range(n - 2, -1, -1):
        z[t] = min(z[t], z[t + 1] + rate)
    if radius <= 0 or n < 2:
        return z
    padded = np.pad(z, radius, mode="edge")
    eroded = np.array([padded[t:t + 2 * radius + 1].min() for t in range(n)])
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (offsets / (radius / 2.0)) ** 2)
    out = np.empty(n)
    for t in range(n):  # truncated at the ends, weights renormalised (each window lies within the erosion's reach)
        lo, hi = max(t - radius, 0), min(t + radius, n - 1)
        w = kernel[lo - t + radius: hi - t + radius + 1]
        out[t] = float(w @ eroded[lo:hi + 1] / w.sum())
    return np.minimum(out, z)


def adaptive_crop(orig_from_stab: np.ndarray, width: int, height: int, *, zoom_speed: float = DEFAULT_ZOOM_SPEED,
                  segment_starts: Sequence[int] = (0,), valid: np.ndarray | None = None) -> AdaptiveCrop | None:
    """The adaptive crop of a path (``zoom_speed`` in % of the frame a frame), shot by shot, about whichever
    keeps more on average: the frame centre, or the centre of the fixed crop (``warping.largest_crop``; about
    it every frame keeps at least the fixed crop's area). None when no frame centre has a usable window.
    ``valid``: as ``largest_scales``'."""
    from pipeline.stages import warping

    fixed = warping.largest_crop(orig_from_stab, width, height, valid=valid)
    centre = ((width - 1) / 2.0, (height - 1) / 2.0)
    anchors = [centre]
    if fixed is not None:
        anchors.append((fixed.x0 + fixed.scale * centre[0], fixed.y0 + fixed.scale * centre[1]))
    starts = sorted({0, *segment_starts})
    ends = [*starts[1:], len(orig_from_stab)]
    best: AdaptiveCrop | None = None
    for anchor in anchors:
        largest = largest_scales(orig_from_stab, width, height, anchor, valid) * (1.0 - EDGE_SLACK)
        if len(largest) == 0 or largest.min() < MIN_SCALE:
            continue
        scales = np.concatenate([smooth_scales(largest[a:b], zoom_speed / 100.0) for a, b in zip(starts, ends)])
        crop = AdaptiveCrop(scales, anchor, width, height)
        if best is None or crop.cropping_ratio > best.cropping_ratio:
            best = crop
    return best


CROPS = ("fixed", "adaptive")
MAX_FILL = 0.1  # more than a tenth of the output synthesized is full mode's job


@dataclass(frozen=True)
class CropConfig:
    """How ``--mode crop`` chooses its window: one for the whole clip (``warping.largest_crop``) or adaptive."""

    kind: str = "fixed"  # "fixed": one window for the whole clip; "adaptive": its zoom follows the path
    zoom_speed: float = DEFAULT_ZOOM_SPEED  # adaptive: % of the frame's size the zoom may change a frame
    # The L1 path's crop window, its scale of the frame each way (0.9: 81 % of the area); None: the window the path
    # without it keeps.
    scale: float | None = None
    # Eq. 18's path with a fixed window: the share of the output's pixels (mean over the clip) completion may
    # synthesize where the window leaves the frames (pipeline/config.py's crop_fill); 0: a window inside every
    # frame, nothing synthesized; None: the default where it applies.
    fill: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in CROPS:
            raise ConfigError(f"crop must be one of {', '.join(CROPS)}, not {self.kind!r}")
        if self.scale is not None and not 0.3 <= self.scale < 1.0:  # False for nan
            raise ConfigError(f"crop scale must be in [0.3, 1) (the window's share of the frame each way), "
                              f"not {self.scale}")
        if self.fill is not None and not 0.0 <= self.fill <= MAX_FILL:  # False for nan
            raise ConfigError(f"crop fill must be in [0, {MAX_FILL}] (a share of the output's pixels), not {self.fill}")
        if not 0 < self.zoom_speed <= 10:
            raise ConfigError(f"zoom speed must be in (0, 10] % a frame, not {self.zoom_speed}")
