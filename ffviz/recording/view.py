"""The size a recording's pictures are kept at: the input's, scaled so that its long side is at most what a screen
shows of it (``RECORD_SIZE``), and how each kind of picture is brought to that size.

Frames are area-averaged. Class maps take, per recorded pixel, the class most of its input pixels that are not
class 0 have (0 only where all are 0): every recorded class is one of the input's, and a band one input pixel
wide stays visible. Float maps (and flow) are the mean of the finite values under each recorded pixel, no value
where there is none; values keep their units (flow vectors are scaled to recorded pixels, to be drawn there).
Statistics and charts are computed from the full-resolution results before any of this.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

# Long side of the recorded pictures: two panels side by side on a 1920-pixel-wide screen show 960 each, and the
# recorder's CPU grows with the pixels it encodes (the choice is measured in docs/benchmarks-recording.md).
RECORD_SIZE = 960


def parse_record_size(text: str | int | None) -> int | None:
    """``--record-size``: 'full' -> None (native size), else a long side in pixels (at least 64)."""
    if text is None or (isinstance(text, str) and text.strip().lower() == "full"):
        return None
    try:
        long_side = int(text)
    except ValueError:
        raise ValueError(f"--record-size must be a long side in pixels (e.g. {RECORD_SIZE}) or 'full', "
                         f"not {text!r}") from None
    if long_side < 64:
        raise ValueError(f"--record-size must be at least 64 pixels (or 'full'), not {long_side}")
    return long_side


@dataclass(frozen=True)
class ViewSize:
    """Recorded pictures' size for an input of ``width`` x ``height``: ``scale`` recorded pixels per input pixel."""

    width: int
    height: int
    scale: float

    @classmethod
    def of(cls, width: int, height: int, long_side: int | None) -> "ViewSize":
        scale = 1.0 if long_side is None else min(1.0, long_side / max(width, height, 1))
        if scale >= 1.0:
            return cls(width, height, 1.0)
        return cls(max(round(width * scale), 1), max(round(height * scale), 1), scale)

    @property
    def native(self) -> bool:
        return self.scale == 1.0

    def _fits(self, image: np.ndarray) -> bool:
        return image.shape[:2] == (self.height, self.width)

    def frame(self, rgb: np.ndarray) -> np.ndarray:
        """A frame, area-averaged to the recorded size."""
        if self._fits(rgb):
            return rgb
        return cv2.resize(rgb, (self.width, self.height), interpolation=cv2.INTER_AREA)

    def classes(self, classes: np.ndarray) -> np.ndarray:
        """A class map (uint8): each recorded pixel the commonest non-zero class under it, 0 where all are 0."""
        if self._fits(classes):
            return classes
        classes = np.ascontiguousarray(classes, np.uint8)
        return _majority_nonzero(classes, self.height, self.width, self._occupied(classes))

    def _occupied(self, classes: np.ndarray) -> np.ndarray:
        """The recorded pixels whose input block may hold a non-zero class: the area-averaged non-zero mask, widened
        by a recorded pixel (a block's edge row or column can weigh next to nothing in the average). Class maps are
        zero outside the missing area, so the majority is counted on a few blocks only."""
        _, nonzero = cv2.threshold(classes, 0, 255, cv2.THRESH_BINARY)
        averaged = cv2.resize(nonzero, (self.width, self.height), interpolation=cv2.INTER_AREA)
        return cv2.dilate(averaged, np.ones((3, 3), np.uint8))

    def mask(self, mask: np.ndarray) -> np.ndarray:
        """A boolean mask: true where any pixel under the recorded one is."""
        return self.classes(mask.view(np.uint8) if mask.dtype == bool else mask).astype(bool)

    def values(self, values: np.ndarray) -> np.ndarray:
        """A float map: the mean of the finite values under each recorded pixel, NaN where there are none."""
        values = np.asarray(values, np.float32)
        if self._fits(values):
            return values
        finite = np.isfinite(values)
        summed = cv2.resize(np.where(finite, values, np.float32(0)), (self.width, self.height),
                            interpolation=cv2.INTER_AREA)
        weight = cv2.resize(finite.astype(np.float32), (self.width, self.height), interpolation=cv2.INTER_AREA)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = summed / weight
        mean[weight <= 0] = np.nan
        return mean.astype(np.float32, copy=False)

    def flow(self, flow: np.ndarray) -> np.ndarray:
        """A flow field (H, W, 2) in input pixels -> the recorded size, its vectors in recorded pixels."""
        if self._fits(flow):
            return flow
        return np.dstack([self.values(flow[..., 0]), self.values(flow[..., 1])]) * np.float32(self.scale)

    def points(self, xy: np.ndarray) -> np.ndarray:
        """Coordinates (and lengths) in input pixels -> recorded pixels: the recorded picture spans the input's
        extent, so the 2D space of the views is scaled as a whole."""
        xy = np.asarray(xy, np.float32)
        return xy if self.native else xy * np.float32(self.scale)

    def describe(self, width: int, height: int) -> str:
        if self.native:
            return f"at the input's size, {width}x{height}"
        return f"at {self.width}x{self.height} (the input's {width}x{height} scaled by {self.scale:.3g})"


@njit(cache=True, nogil=True)
def _majority_nonzero(classes: np.ndarray, height: int, width: int, occupied: np.ndarray) -> np.ndarray:
    """Per output pixel, the commonest non-zero class of the input block it covers (0 where all are 0; blocks not
    ``occupied`` are taken to be all 0)."""
    in_h, in_w = classes.shape
    out = np.zeros((height, width), np.uint8)
    counts = np.zeros(256, np.int32)
    for i in range(height):
        r0 = (i * in_h) // height
        r1 = max(((i + 1) * in_h) // height, r0 + 1)
        for j in range(width):
            if occupied[i, j] == 0:
                continue
            c0 = (j * in_w) // width
            c1 = max(((j + 1) * in_w) // width, c0 + 1)
            first = 0
            mixed = False
            for r in range(r0, r1):
                for c in range(c0, c1):
                    v = classes[r, c]
                    if v != 0:
                        if first == 0:
                            first = v
                        elif v != first:
                            mixed = True
            if not mixed:
                out[i, j] = first
                continue
            best, best_count = 0, 0
            for r in range(r0, r1):
                for c in range(c0, c1):
                    v = classes[r, c]
                    if v != 0:
                        counts[v] += 1
                        if counts[v] > best_count:
                            best, best_count = v, counts[v]
            for r in range(r0, r1):  # reset only what was counted
                for c in range(c0, c1):
                    counts[classes[r, c]] = 0
            out[i, j] = best
    return out

