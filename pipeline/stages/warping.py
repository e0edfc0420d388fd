"""Warping by the smoothing transform (eq. 19), the mask of missing pixels, and the crop window.

A stabilized pixel p' takes the original's value at S_t p' (``orig_from_stab``); where S_t p' falls outside
the original frame the pixel is missing: black in ``--mode none``, cropped away in ``--mode crop`` (or, by
its fill, completed where the window leaves a frame), completed from neighbours in full-frame mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipeline import geometry


@dataclass(frozen=True)
class WarpResult:
    frame: np.ndarray  # (H, W, 3) as the input (uint8, or float32 0..255 for deeper video), missing pixels black
    missing: np.ndarray  # (H, W) bool: no original pixel maps here
    orig_from_out: np.ndarray  # 3x3 transform the frame was sampled with


def _warp(image: np.ndarray, m: np.ndarray, out_size: tuple[int, int], flags: int, border_value: float,
          out: np.ndarray | None) -> np.ndarray:
    if geometry.is_affine(m):
        return cv2.warpAffine(image, m[:2], out_size, dst=out, flags=flags, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=border_value)
    return cv2.warpPerspective(image, m, out_size, dst=out, flags=flags, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=border_value)


def _is_rgb8(image: np.ndarray) -> bool:
    return image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8


def _warp_rgba(rgb: np.ndarray, m: np.ndarray, out_size: tuple[int, int], border_value: float) -> np.ndarray:
    """Bilinear warp of (H, W, 3) uint8 pixels as RGBA with alpha 255: OpenCV 5.0's warps vectorise 1 and 4
    channels of 8 bits but not 3, and the detour is ~1.8x faster with the same bytes (each channel is
    interpolated alone; tested). The warped alpha is the warp of an all-255 plane: the coverage."""
    return _warp(cv2.cvtColor(rgb, cv2.COLOR_RGB2RGBA), m, out_size, cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                 border_value, None)


def warp(image: np.ndarray, orig_from_out: np.ndarray, size: tuple[int, int] | None = None, *,
         interpolation: int = cv2.INTER_LINEAR, border_value: float = 0, out: np.ndarray | None = None) -> np.ndarray:
    """out(p) = image(orig_from_out p), for an affine or projective 3x3 transform. ``out``: a contiguous array of
    the result's shape and type to write into (returned), instead of a new one."""
    height, width = image.shape[:2]
    out_size = size or (width, height)
    m = np.asarray(orig_from_out, dtype=np.float64)
    if interpolation == cv2.INTER_LINEAR and _is_rgb8(image):
        return cv2.cvtColor(_warp_rgba(image, m, out_size, border_value), cv2.COLOR_RGBA2RGB, dst=out)
    return _warp(image, m, out_size, interpolation | cv2.WARP_INVERSE_MAP, border_value, out)


def blacken(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``image[mask] = 0`` in place, for uint8 (or float32) pixels with channels last and a bool mask over the pixels
    (2-D, or 1-D for a list of pixels); returns ``image``. OpenCV's masked AND: ~15x faster than numpy's boolean
    assignment on a 1080p frame (it ANDs the bytes, so any pixel type works)."""
    if image.dtype not in (np.uint8, np.float32) or mask.dtype != np.bool_ or image.shape[:mask.ndim] != mask.shape:
        raise ValueError(f"expected uint8 or float32 pixels over a bool mask, got {image.dtype} {image.shape} and "
                         f"{mask.dtype} {mask.shape}")
    # numpy for: few pixels (OpenCV reads a 1x1x3 array as 1x3), a list the reshape below would copy
    if mask.size < 64 or (mask.ndim == 1 and not image.flags.c_contiguous):
        image[mask] = 0
        return image
    pixels = image if mask.ndim == 2 else image.reshape(len(mask), 1, -1)
    plane = np.ascontiguousarray(mask if mask.ndim == 2 else mask[:, None]).view(np.uint8)
    cv2.bitwise_and(pixels, 0, dst=pixels, mask=plane)
    return image


def warp_frame(rgb: np.ndarray, orig_from_out: np.ndarray, size: tuple[int, int] | None = None) -> WarpResult:
    """The stabilized frame and its missing mask (pixels not fully covered by the original); ``size`` (width,
    height) of the output, default the input's."""
    height, width = rgb.shape[:2]
    m = np.asarray(orig_from_out, dtype=np.float64)
    if _is_rgb8(rgb):
        rgba = _warp_rgba(rgb, m, size or (width, height), 0)
        frame, coverage = cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB), rgba[..., 3]
    else:
        frame = warp(rgb, m, size)
        coverage = warp(np.full((height, width), 255, np.uint8), m, size)
    # Anything short of full coverage blended in black from outside the frame: count it as missing.
    missing = coverage < 255
    blacken(frame, missing)
    return WarpResult(frame=frame, missing=missing, orig_from_out=m)


@dataclass(frozen=True)
class CropWindow:
    """The output frame as a window of the stabilized frame: stab = (x0, y0) + scale * out."""

    x0: float
    y0: float
    scale: float  # < 1: the window is smaller than the frame and is enlarged back to full size

    @property
    def stab_from_out(self) -> np.ndarray:
        return np.array([[self.scale, 0.0, self.x0], [0.0, self.scale, self.y0], [0.0, 0.0, 1.0]])

    @property
    def cropping_ratio(self) -> float:
        """Area kept, as a fraction of the frame."""
        return self.scale**2


def largest_crop(orig_from_stab: np.ndarray, width: int, height: int,
                 valid: np.ndarray | None = None) -> CropWindow | None:
    """The largest window of the input's aspect ratio valid in every stabilized frame.

    Each frame's valid region is the original frame mapped into stabilized coordinates (a convex quad);
    the window's four corners must lie inside all of them and inside the frame. That is a linear
    programme in (x0, y0, scale), maximising scale. None when no area is common to all frames.
    ``valid``: (N, 4, 2) each frame's valid region in its own coordinates, a convex quad (default: the frame).
    """
    from scipy.optimize import linprog  # here, not at the top: importing scipy.optimize takes ~0.5 s

    corners = geometry.frame_corners(width, height)
    offsets = corners  # window corner j sits at (x0, y0) + scale * corners[j]
    rows: list[np.ndarray] = []
    bounds: list[float] = []

    def inside_convex(polygon: np.ndarray) -> None:
        centre = polygon.mean(axis=0)
        for a, b in zip(polygon, np.roll(polygon, -1, axis=0)):
            normal = np.array([b[1] - a[1], a[0] - b[0]])
            if normal @ (centre - a) > 0:  # make the normal point outward
                normal = -normal
            for offset in offsets:  # normal . ((x0, y0) + scale * offset) <= normal . a
                rows.append(np.array([normal[0], normal[1], normal @ offset]))
                bounds.append(float(normal @ a))

    inside_convex(corners)
    for t, s_t in enumerate(np.asarray(orig_from_stab)):
        inside_convex(geometry.apply(np.linalg.inv(s_t), corners if valid is None else valid[t]))

    result = linprog(c=[0.0, 0.0, -1.0], A_ub=np.array(rows), b_ub=np.array(bounds),
                     bounds=[(None, None), (None, None), (0.0, 1.0)], method="highs")
    if not result.success or result.x[2] <= 1e-3:
        return None  # no area is valid in every frame

    x0, y0, scale = result.x
    return CropWindow(float(x0), float(y0), float(scale))


FILL_GRID = (96, 54)  # output points a frame at which window_for_fill measures what leaves the frame
FILL_MIN_SCALE = 0.3  # the smallest window window_for_fill considers (--crop-scale's least)
FILL_STEP = 1e-4  # window_for_fill's scales are multiples of this
FILL_CHUNK_FRAMES = 256  # frames measured at once (memory: a chunk's frames times FILL_GRID's points)


def _leaving_scales(orig_from_stab: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, P): for each frame and each of the FILL_GRID's output points p (the centres of equal cells), the scale s
    from which the centred window's point c + s (p - c) maps outside the input frame. Along s the mapped point
    moves on a line (x and y are ratios of functions linear in s, the denominator positive), so it leaves the
    frame once, where the first of its four edges is crossed, and never comes back: a point outside at s is outside
    at every larger s. 0 where the window's centre itself is outside."""
    xs = (np.arange(FILL_GRID[0]) + 0.5) * width / FILL_GRID[0] - 0.5
    ys = (np.arange(FILL_GRID[1]) + 0.5) * height / FILL_GRID[1] - 0.5
    gx, gy = np.meshgrid(xs, ys)
    centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0, 1.0])
    m = np.asarray(orig_from_stab, np.float64)
    at_centre = (m @ centre)[:, :, None]  # (N, 3, 1): the mapped point at s = 0
    per_scale = m[:, :, :2] @ np.stack([gx.ravel() - centre[0], gy.ravel() - centre[1]])  # (N, 3, P): its change
    x0, y0, w0 = at_centre[:, 0], at_centre[:, 1], at_centre[:, 2]
    x1, y1, w1 = per_scale[:, 0], per_scale[:, 1], per_scale[:, 2]
    leaving = np.full(x1.shape, np.inf)
    # each edge as g0 + s g1 >= 0: x >= 0, x <= W - 1, y >= 0, y <= H - 1 (times the positive denominator), w > 0
    for g0, g1 in ((x0, x1), ((width - 1) * w0 - x0, (width - 1) * w1 - x1), (y0, y1),
                   ((height - 1) * w0 - y0, (height - 1) * w1 - y1), (w0, w1)):
        with np.errstate(divide="ignore", invalid="ignore"):
            crossing = np.where(g1 < 0, g0 / -np.minimum(g1, -1e-300), np.inf)
        leaving = np.minimum(leaving, np.where(g0 < 0, 0.0, crossing))
    return leaving


def window_share_outside(orig_from_stab: np.ndarray, width: int, height: int, scale: float) -> np.ndarray:
    """(N,) for each frame, the share of the centred window of ``scale`` (stab = c + scale (out - c), c the frame's
    centre) whose input pixel lies outside the input frame: what completion must synthesize there (FILL_GRID's
    points)."""
    return np.concatenate([(_leaving_scales(orig_from_stab[i:i + FILL_CHUNK_FRAMES], width, height) < scale)
                           .mean(axis=1) for i in range(0, len(orig_from_stab), FILL_CHUNK_FRAMES)])


def window_for_fill(orig_from_stab: np.ndarray, width: int, height: int,
                    fill: float) -> tuple[CropWindow, float]:
    """The largest centred window of the input's aspect ratio (a multiple of FILL_STEP, FILL_MIN_SCALE to 1) whose
    parts outside the input frames are at most ``fill`` of the output's pixels, averaged over the frames
    (``window_share_outside``), and that share; completion fills them (more than ``fill`` only where even
    FILL_MIN_SCALE's window leaves the frames by more). Each point leaves at one scale (``_leaving_scales``), so the
    share is a count of leaving scales below the window's: one histogram of them over the clip gives every window's
    share, in memory bounded by FILL_CHUNK_FRAMES."""
    steps = int(round(1.0 / FILL_STEP))
    below = np.zeros(steps + 2, np.int64)  # below[i]: points leaving at scales in [(i - 1) step, i step)
    total = 0
    for i in range(0, len(orig_from_stab), FILL_CHUNK_FRAMES):
        leaving = _leaving_scales(orig_from_stab[i:i + FILL_CHUNK_FRAMES], width, height)
        index = np.floor(np.minimum(leaving.ravel(), 2.0) / FILL_STEP).astype(np.int64) + 1
        below += np.bincount(np.minimum(index, steps + 1), minlength=steps + 2)
        total += leaving.size
    outside = np.cumsum(below)[:steps + 1] / max(total, 1)  # outside[i]: share leaving at scales below i step
    fitting = np.nonzero(outside <= fill + 1e-12)[0]
    step = max(int(fitting[-1]) if len(fitting) else 0, int(round(FILL_MIN_SCALE / FILL_STEP)))
    scale = step * FILL_STEP
    centre = ((width - 1) / 2.0, (height - 1) / 2.0)
    return CropWindow(centre[0] * (1.0 - scale), centre[1] * (1.0 - scale), scale), float(outside[step])
