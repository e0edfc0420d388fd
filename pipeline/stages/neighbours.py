"""Neighbouring frames seen in frame t's stabilized coordinates, warped only where they are looked at.

Completion looks at a neighbour in few places: at the missing pixels (mosaic, eqs. 20-22), on a thin band of
known pixels around them (the local alignment error), inside the small boxes where local flow is computed,
and at p + F(p) for the local warp (eq. 25). Warping every neighbour over the whole frame (12 neighbours, two
warps each) would cost in proportion to the frame's area, for pixels nobody looks at (docs/benchmarks-speed.md);
here each look warps or samples just what it needs, straight from the original frame. Whole frames (``rgb``,
``valid``) are warped on first use, once; deblurring warps only the colours itself and works out coverage from
``other_from_stab`` (pipeline/stages/deblur.py).

A pixel is valid when every bilinear tap of its sample lies inside the original frame (as the target's own
missing mask in pipeline/stages/warping.py).
"""

from __future__ import annotations

from typing import Callable, Mapping

import cv2
import numpy as np
from numba import njit

from pipeline import geometry
from pipeline.stages import warping
from pipeline.stages.per_frame import PerFrame

_MAP_COLUMNS = 4096
TAP_SLACK = 1.0 / 64  # OpenCV's bilinear weights are 1/32 steps: a tap within this of the edge weighs nothing


def remap_points(image: np.ndarray, x: np.ndarray, y: np.ndarray,
                 border_mode: int = cv2.BORDER_CONSTANT, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Samples of ``image`` at points (x, y) (float arrays of one size m), bilinear unless told: (m, channels).

    cv2.remap wants its points as a 2-D map whose sides stay below 32767: they are laid out in rows of at
    most 4096 (the last row padded, its samples dropped)."""
    x = np.asarray(x, np.float32).reshape(-1)
    y = np.asarray(y, np.float32).reshape(-1)
    count = len(x)
    channels = 1 if image.ndim == 2 else image.shape[2]
    if count == 0:
        return np.zeros((0, channels), image.dtype)
    columns = min(count, _MAP_COLUMNS)
    rows = -(-count // columns)

    def as_map(values: np.ndarray) -> np.ndarray:
        if count == rows * columns:
            return np.ascontiguousarray(values).reshape(rows, columns)
        padded = np.full(rows * columns, -2.0, np.float32)
        padded[:count] = values
        return padded.reshape(rows, columns)

    sampled = cv2.remap(image, as_map(x), as_map(y), interpolation, borderMode=border_mode)
    return sampled.reshape(-1, channels)[:count]


@njit(cache=True, nogil=True)
def _source_points(m: np.ndarray, x: np.ndarray, y: np.ndarray, width: int, height: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (x, y) (float32) mapped by the 3x3 ``m`` into a width x height source: (x, y) float32 there,
    computed in float64 and rounded once (w is exactly 1 for an affine m, so it is not divided by), and whether
    every bilinear tap lies inside (within TAP_SLACK). One pass over the points instead of numpy's temporaries."""
    n = len(x)
    src_x = np.empty(n, np.float32)
    src_y = np.empty(n, np.float32)
    valid = np.empty(n, np.bool_)
    projective = m[2, 0] != 0.0 or m[2, 1] != 0.0 or m[2, 2] != 1.0
    for i in range(n):
        px, py = np.float64(x[i]), np.float64(y[i])
        u = m[0, 0] * px + m[0, 1] * py + m[0, 2]
        v = m[1, 0] * px + m[1, 1] * py + m[1, 2]
        if projective:
            w = m[2, 0] * px + m[2, 1] * py + m[2, 2]
            u /= w
            v /= w
        su, sv = np.float32(u), np.float32(v)
        src_x[i], src_y[i] = su, sv
        valid[i] = (su > -TAP_SLACK and su < width - 1 + TAP_SLACK
                    and sv > -TAP_SLACK and sv < height - 1 + TAP_SLACK)
    return src_x, src_y, valid


class WarpedNeighbour:
    """Neighbour frame t' = t + ``offset`` in frame t's stabilized coordinates.

    Either already warped (``rgb``, ``valid`` given: tests, callers with their own warps) or lazy: the
    ``original`` frame and the ``other_from_stab`` transform, warped on demand by ``crop``, ``sample`` and the
    whole-frame ``rgb``/``valid`` (computed once, then reused by every later call).
    """

    def __init__(self, offset: int, rgb: np.ndarray | None = None, valid: np.ndarray | None = None, *,
                 original: np.ndarray | None = None, other_from_stab: np.ndarray | None = None,
                 small_original: Callable[[], np.ndarray] | None = None) -> None:
        if (rgb is None) == (original is None) or (rgb is None) != (valid is None) or \
                (original is None) != (other_from_stab is None):
            raise ValueError("give either rgb and valid, or original and other_from_stab")
        self.offset = offset
        self._rgb, self._valid = rgb, valid
        self.original = original
        self.other_from_stab = None if other_from_stab is None else np.asarray(other_from_stab, np.float64)
        # A downscaled (INTER_AREA) copy of the original, shared by every frame this one is a neighbour of:
        # crops at a working resolution are warped from it instead of warped whole-size and shrunk.
        self._small_original = small_original

    @property
    def shape(self) -> tuple[int, int]:
        image = self._rgb if self._rgb is not None else self.original
        return image.shape[:2]

    @property
    def warped_whole(self) -> bool:
        """Whether the whole-frame ``rgb`` and ``valid`` are at hand (given, or warped on an earlier look)."""
        return self._rgb is not None

    def _warp_whole(self) -> None:
        if self._rgb is None:
            warped = warping.warp_frame(self.original, self.other_from_stab)
            self._rgb, self._valid = warped.frame, ~warped.missing

    @property
    def rgb(self) -> np.ndarray:
        """(H, W, 3) uint8, black where not valid."""
        self._warp_whole()
        return self._rgb

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: pixels the neighbour covers."""
        self._warp_whole()
        return self._valid

    def crop(self, box: tuple[slice, slice], size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(rgb, valid) of the box only (what ``rgb[box]``, ``valid[box]`` are, without the rest); with ``size``
        (width, height), shrunk to it as ``shrink`` and ``shrink_all`` would (taken from the downscaled original
        when there is one: nearly the same, a fraction of the work)."""
        if size is not None:
            if self._small_original is not None and self._rgb is None:
                return self._crop_small(box, size)
            rgb, valid = self.crop(box)
            return shrink(rgb, size), shrink_all(valid, size)
        if self._rgb is not None:
            return self._rgb[box], self._valid[box]
        rows, cols = box
        stab_from_box = np.array([[1.0, 0.0, cols.start], [0.0, 1.0, rows.start], [0.0, 0.0, 1.0]])
        size = (cols.stop - cols.start, rows.stop - rows.start)
        orig_from_box = self.other_from_stab @ stab_from_box
        warped = warping.warp_frame(self.original, orig_from_box, size)
        return warped.frame, ~warped.missing

    def _crop_small(self, box: tuple[slice, slice], size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        small = self._small_original()
        rows, cols = box
        height, width = self.original.shape[:2]
        # Pixel centres: a pixel u of an image shrunk by s from a full-size one sits at (u + 0.5) / s - 0.5.
        step_x, step_y = (cols.stop - cols.start) / size[0], (rows.stop - rows.start) / size[1]
        stab_from_work = np.array([[step_x, 0.0, cols.start + 0.5 * step_x - 0.5],
                                   [0.0, step_y, rows.start + 0.5 * step_y - 0.5], [0.0, 0.0, 1.0]])
        scale_x, scale_y = small.shape[1] / width, small.shape[0] / height
        small_from_orig = np.array([[scale_x, 0.0, 0.5 * scale_x - 0.5], [0.0, scale_y, 0.5 * scale_y - 0.5],
                                    [0.0, 0.0, 1.0]])
        small_from_work = small_from_orig @ self.other_from_stab @ stab_from_work
        warped = warping.warp_frame(small, small_from_work, size)
        return warped.frame, ~warped.missing

    def sample(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear samples at stabilized points (float arrays of one shape): (colours (..., 3) uint8,
        valid (...) bool); invalid samples are black."""
        shape = np.shape(x)
        x = np.asarray(x, np.float32).reshape(-1)
        y = np.asarray(y, np.float32).reshape(-1)
        if self._rgb is not None:
            colours = remap_points(self._rgb, x, y)
            valid = remap_points(self._valid.astype(np.uint8) * 255, x, y)[:, 0] == 255
        else:
            height, width = self.original.shape[:2]
            src_x, src_y, valid = _source_points(self.other_from_stab, x, y, width, height)
            colours = remap_points(self.original, src_x, src_y)
        warping.blacken(colours, ~valid)
        return colours.reshape(shape + (3,)), valid.reshape(shape)

    def refined(self, other_from_here: np.ndarray) -> WarpedNeighbour:
        """This neighbour with its warp corrected: the new one's pixel at stabilized point p is this one's pixel at
        ``other_from_here`` p (a 3x3 transform close to the identity, e.g. a local registration's)."""
        correction = np.asarray(other_from_here, np.float64)
        if self.original is not None:
            return WarpedNeighbour(self.offset, original=self.original, other_from_stab=self.other_from_stab @ correction,
                                   small_original=self._small_original)
        warped = warping.warp_frame(self._rgb, correction)
        valid = ~warped.missing & (warping.warp(self._valid.astype(np.uint8) * 255, correction) == 255)
        warping.blacken(warped.frame, ~valid)
        return WarpedNeighbour(self.offset, warped.frame, valid)

    def at(self, ys: np.ndarray, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(colours (m, 3), valid (m,)) at integer pixels."""
        if self._rgb is not None:
            return self._rgb[ys, xs], self._valid[ys, xs]
        return self.sample(xs.astype(np.float32), ys.astype(np.float32))


def warp_neighbours(frames: Mapping[int, np.ndarray], t: int, curr_from_prev: np.ndarray,
                    orig_from_stab_t: np.ndarray, *, downscaled: Downscaled | None = None) -> list[WarpedNeighbour]:
    """Original neighbour frames {t': rgb} as lazy neighbours in frame t's stabilized coordinates, nearest first.

    A neighbour's pixel for stabilized point p of frame t is at t'_from_t @ S_t p; the chain t'_from_t is
    at most ``radius`` inter-frame transforms long. ``downscaled``: where their downscaled copies are kept.
    """
    if not frames:
        return []
    first, last = min(frames), max(frames)
    t_from = geometry.neighbour_transforms(curr_from_prev, t, min(first, t), max(last, t))

    def small_of(index: int) -> Callable[[], np.ndarray] | None:
        return None if downscaled is None else lambda: downscaled.get(index, frames[index])

    return [WarpedNeighbour(t_other - t, original=frames[t_other],
                            other_from_stab=np.linalg.inv(t_from[t_other]) @ orig_from_stab_t,
                            small_original=small_of(t_other))
            for t_other in sorted(frames, key=lambda i: (abs(i - t), i))]


class Downscaled(PerFrame[np.ndarray, np.ndarray]):
    """Frames shrunk to ``size`` (width, height; INTER_AREA) by frame index, each made once while it is in the
    window."""

    def __init__(self, size: tuple[int, int]) -> None:
        super().__init__(lambda rgb: shrink(rgb, size))
        self.size = size


def shrink(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` resized to ``size`` (width, height) by area averaging."""
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def shrink_all(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``mask`` resized to ``size``: a coarse pixel is in only if all its fine pixels are."""
    return shrink(mask.astype(np.uint8) * 255, size) == 255


def shrink_any(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``mask`` resized to ``size``: a coarse pixel is in if any of its fine pixels is."""
    return shrink(mask.astype(np.uint8) * 255, size) > 0
