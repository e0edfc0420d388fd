"""The per-pixel work of deblurring (pipeline/stages/deblur.py), compiled: coverage of a warped neighbour as row spans,
INTER_AREA and INTER_LINEAR resampling tables, the low-resolution alignment error and its rejection bands, the
blend of eq. 30, and the blurriness maps' one-pass filtering.

Every function here reproduces a plain array computation (a whole-frame warp and mask, cv2.resize, a dilation)
that tests/test_deblur.py compares it with; pipeline/stages/deblur.py's docstring says why each one exists.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from numba import njit

_NO_REJECTED = np.zeros((1, 1, 1), np.uint8)


def error_factor(sigma: float) -> int:
    """The downscale of the alignment error's low-pass (alignment_error's docstring)."""
    return 2 ** max(1, int(math.log2(sigma / 2.0))) if sigma >= 2.0 else 1


def low_res_error(target: np.ndarray, neighbour: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """alignment_error at its working resolution: images, valid weights and sigma all at that resolution."""
    if sigma <= 0:
        difference = np.abs(cv2.subtract(neighbour, target, dtype=cv2.CV_32F))
        return np.max(difference, axis=2)
    difference = cv2.GaussianBlur(_weighted_difference(neighbour, target, weight), (0, 0), sigma,
                                  borderType=cv2.BORDER_CONSTANT)
    norm = cv2.GaussianBlur(weight, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    return _normalised_channel_max(difference, norm)


class ErrorGrid:
    """What the alignment errors of every neighbour of one target share: the working resolution, the target's
    copy there (made once, not per neighbour), and the tables between the two resolutions."""

    def __init__(self, target: np.ndarray, target_valid: np.ndarray, sigma: float, grow: int) -> None:
        height, width = target_valid.shape
        self.factor = error_factor(sigma)
        self.small_size = (max(width // self.factor, 1), max(height // self.factor, 1))
        self.sigma_small = sigma / self.factor
        small_width, small_height = self.small_size
        self.target_small = target if self.factor == 1 else \
            cv2.resize(target, self.small_size, interpolation=cv2.INTER_AREA)
        # Rows of target_valid as runs; a row whose valid pixels are one run needs no pixel-by-pixel look.
        self.target_first, self.target_last, self.target_exact = row_runs(target_valid)
        self.rejection_gap = 2 * math.ceil(grow / self.factor) + 2  # low-res rows: bands closer than this are one
        self.area_tables = (*area_table(height, small_height), *area_table(width, small_width))
        self.up_tables = (*_linear_table(small_height, height), *_linear_table(small_width, width))


@functools.lru_cache(maxsize=16)
def area_table(source: int, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """cv2.resize's INTER_AREA weights along one axis (its computeResizeAreaTab), from ``source`` to ``size``
    samples: (index (size, k) int32, weight (size, k) float32, count (size,) int32, weight sum (size,) float32);
    output sample d is the sum over j < count[d] of weight[d, j] * input[index[d, j]]."""
    scale = source / size
    entries: list[list[tuple[int, float]]] = []
    for d in range(size):
        start, stop = d * scale, (d + 1) * scale
        cell = min(scale, source - start)
        first, last = math.ceil(start), min(math.floor(stop), source - 1)
        first = min(first, last)
        row = []
        if first - start > 1e-3:
            row.append((first - 1, (first - start) / cell))
        row += [(s, 1.0 / cell) for s in range(first, last)]
        if stop - last > 1e-3:
            row.append((last, min(stop - last, 1.0, cell) / cell))
        entries.append(row)
    k = max(len(row) for row in entries)
    index = np.zeros((size, k), np.int32)
    weight = np.zeros((size, k), np.float32)
    for d, row in enumerate(entries):
        for j, (s, w) in enumerate(row):
            index[d, j], weight[d, j] = s, w
    count = np.array([len(row) for row in entries], np.int32)
    return _read_only(index, weight, count, weight.sum(axis=1, dtype=np.float32))


@functools.lru_cache(maxsize=16)
def _linear_table(source: int, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """cv2.resize's INTER_LINEAR taps along one axis, from ``source`` to ``size`` samples: (first tap int32,
    second tap int32, weight of the second float32), edges clamped as OpenCV clamps them."""
    fraction = ((np.arange(size) + 0.5) * (source / size) - 0.5).astype(np.float32)
    tap = np.floor(fraction).astype(np.int64)
    fraction -= tap.astype(np.float32)
    low, high = tap < 0, tap >= source - 1
    tap[low], fraction[low] = 0, 0.0
    tap[high], fraction[high] = source - 1, 0.0
    return _read_only(tap.astype(np.int32), np.minimum(tap + 1, source - 1).astype(np.int32), fraction)


def _read_only(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """The arrays, locked: cached tables are shared by every frame and thread."""
    for array in arrays:
        array.flags.writeable = False
    return arrays


def rejected(error: np.ndarray, threshold: float, grow: int, grid: ErrorGrid) -> np.ndarray | None:
    """(H, W) uint8, 1 where the full-resolution error (``error`` upsampled as cv2.resize INTER_LINEAR would)
    exceeds ``threshold`` or lies within ``grow`` px (a square) of such a pixel; None where nothing does."""
    bands = hot_bands(error, threshold, grid)
    if not bands:
        return None
    rejected = np.zeros((grid.up_tables[0].size, grid.up_tables[3].size), np.uint8)
    fill_rejected(error, threshold, grow, grid, bands, rejected)
    return rejected


def hot_bands(error: np.ndarray, threshold: float, grid: ErrorGrid) -> list[tuple[int, int, int, int]]:
    """Full-resolution boxes (rows r0..r1-1, columns c0..c1-1) outside which the upsampled error cannot exceed
    ``threshold``: it is a convex combination of four low-res values, so only pixels with a tap on a low-res
    value above the threshold can. One box per band of such low-res rows (bands closer than their dilation
    would reach are one), as wide as the band's hot columns."""
    first_hot, last_hot = _hot_extents(error, np.float32(threshold))
    hot_rows = np.flatnonzero(last_hot >= 0)
    if hot_rows.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(hot_rows) > grid.rejection_gap)
    starts, ends = hot_rows[np.r_[0, breaks + 1]], hot_rows[np.r_[breaks, hot_rows.size - 1]]
    row_tap0, row_tap1, _, col_tap0, col_tap1, _ = grid.up_tables
    boxes = []
    for start, end in zip(starts, ends):
        band = slice(start, end + 1)
        left = first_hot[band][last_hot[band] >= 0].min()
        right = last_hot[band].max()
        # Full-resolution rows and columns with a tap in the band (the tap tables never decrease).
        boxes.append((int(np.searchsorted(row_tap1, start, "left")), int(np.searchsorted(row_tap0, end, "right")),
                      int(np.searchsorted(col_tap1, left, "left")), int(np.searchsorted(col_tap0, right, "right"))))
    return boxes


@njit(cache=True, nogil=True)
def _hot_extents(error: np.ndarray, threshold: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``error``, the first and last column above ``threshold`` (-1, -1 when none)."""
    height, width = error.shape
    first = np.full(height, -1, np.int64)
    last = np.full(height, -1, np.int64)
    for y in range(height):
        for x in range(width):
            if error[y, x] > threshold:
                if first[y] < 0:
                    first[y] = x
                last[y] = x
    return first, last


def fill_rejected(error: np.ndarray, threshold: float, grow: int, grid: ErrorGrid,
                   boxes: list[tuple[int, int, int, int]], out: np.ndarray) -> None:
    """rejected's mask into ``out`` (zeros, (H, W) uint8), upsampling and dilating within ``boxes`` only."""
    height, width = out.shape
    above = out if grow <= 0 else np.zeros((height, width), np.uint8)
    for r0, r1, c0, c1 in boxes:
        _mark_above(error, *grid.up_tables, np.float32(threshold), above, r0, r1, c0, c1)
    if grow <= 0:
        return
    kernel = np.ones((2 * grow + 1,) * 2, np.uint8)
    for r0, r1, c0, c1 in boxes:
        rows = slice(max(r0 - grow, 0), min(r1 + grow, height))
        cols = slice(max(c0 - grow, 0), min(c1 + grow, width))
        out[rows, cols] |= cv2.dilate(above[rows, cols], kernel)


@njit(cache=True, nogil=True)
def _weighted_difference(neighbour: np.ndarray, target: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(I_t' - I_t) * weight, float32 (H, W, 3)."""
    height, width = weight.shape
    out = np.empty((height, width, 3), np.float32)
    for y in range(height):
        for x in range(width):
            w = weight[y, x]
            for c in range(3):
                out[y, x, c] = (np.float32(neighbour[y, x, c]) - np.float32(target[y, x, c])) * w
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _normalised_channel_max(difference: np.ndarray, norm: np.ndarray) -> np.ndarray:
    """max over channels of |difference| / max(norm, 1e-3): the normalised convolution's result."""
    height, width = norm.shape
    out = np.empty((height, width), np.float32)
    for y in range(height):
        for x in range(width):
            largest = max(abs(difference[y, x, 0]), abs(difference[y, x, 1]), abs(difference[y, x, 2]))
            out[y, x] = largest / max(norm[y, x], np.float32(1e-3))
    return out


@njit(cache=True, nogil=True)
def row_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: the first and last set column (last < first when none), and whether every column between
    them is set."""
    height, width = mask.shape
    first = np.zeros(height, np.int32)
    last = np.full(height, -1, np.int32)
    exact = np.ones(height, np.bool_)
    for y in range(height):
        count = 0
        for x in range(width):
            if mask[y, x]:
                if count == 0:
                    first[y] = x
                last[y] = x
                count += 1
        exact[y] = count == 0 or count == last[y] - first[y] + 1
    return first, last, exact


@njit(cache=True, nogil=True)
def energy_area(rgb: np.ndarray, intensity_weights: np.ndarray, row_index: np.ndarray, row_weight: np.ndarray,
                 row_count: np.ndarray, col_index: np.ndarray, col_weight: np.ndarray, col_count: np.ndarray,
                 block: int) -> np.ndarray:
    """gradient_energy of an RGB frame (intensity, 3x3 Sobel, BORDER_REFLECT) reduced by the INTER_AREA tables
    of area_table, a row at a time: Sobel's separable halves of three intensity rows are kept in a ring.
    ``block`` > 0: the column table is runs of ``block`` consecutive columns (an integer factor)."""
    height, width = rgb.shape[:2]
    small_height, small_width = row_count.size, col_count.size
    # Each source row's destination rows and weights (a row falls in at most two cells of a downscale).
    dest = np.full((height, 2), -1, np.int64)
    dest_weight = np.zeros((height, 2), np.float32)
    for dy in range(small_height):
        for j in range(row_count[dy]):
            sy = row_index[dy, j]
            slot = 0 if dest[sy, 0] < 0 else 1
            dest[sy, slot], dest_weight[sy, slot] = dy, row_weight[dy, j]
    out = np.zeros((small_height, small_width), np.float32)
    gray = np.empty(width + 2, np.float32)  # one intensity row, its reflected border at both ends
    difference = np.empty((3, width), np.float32)  # I(x + 1) - I(x - 1), by row % 3
    smooth = np.empty((3, width), np.float32)  # I(x - 1) + 2 I(x) + I(x + 1), by row % 3
    held = np.full(3, -1, np.int64)
    energy = np.empty(width, np.float32)
    reduced = np.empty(small_width, np.float32)
    flat_rgb = rgb.reshape(height, 3 * width)
    samples = np.empty(3 * width, np.float32)
    r, g, b = intensity_weights[0], intensity_weights[1], intensity_weights[2]
    two = np.float32(2.0)
    for y in range(height):
        above, below = max(y - 1, 0), min(y + 1, height - 1)  # BORDER_REFLECT repeats the edge row
        for row in (above, y, below):
            slot = row % 3
            if held[slot] == row:
                continue
            # To float first, then combine: ~4x faster than converting each strided uint8 (it vectorises).
            source = flat_rgb[row]
            for i in range(np.uint64(3 * width)):
                samples[i] = source[i]
            for x in range(np.uint64(width)):
                gray[x + 1] = r * samples[3 * x] + g * samples[3 * x + 1] + b * samples[3 * x + 2]
            gray[0], gray[width + 1] = gray[1], gray[width]
            for x in range(width):
                difference[slot, x] = gray[x + 2] - gray[x]
                smooth[slot, x] = gray[x] + two * gray[x + 1] + gray[x + 2]
            held[slot] = row
        up, mid, down = above % 3, y % 3, below % 3
        for x in range(width):
            gx = difference[up, x] + two * difference[mid, x] + difference[down, x]
            gy = smooth[down, x] - smooth[up, x]
            energy[x] = gx * gx + gy * gy
        if block > 0:  # integer factor: cells are consecutive runs of columns, no index lookups
            for dx in range(np.uint64(small_width)):
                total = np.float32(0.0)
                for i in range(np.uint64(block)):
                    total += col_weight[dx, i] * energy[np.uint64(block) * dx + i]
                reduced[dx] = total
        else:
            for dx in range(small_width):
                total = np.float32(0.0)
                for i in range(col_count[dx]):
                    total += col_weight[dx, i] * energy[col_index[dx, i]]
                reduced[dx] = total
        for slot in range(2):
            dy = dest[y, slot]
            if dy >= 0:
                out_row, wy = out[dy], dest_weight[y, slot]
                for dx in range(small_width):
                    out_row[dx] += wy * reduced[dx]
    return out


@njit(cache=True, nogil=True)
def _inside(m: np.ndarray, x: float, y: float, right: float, bottom: float, slack: float) -> bool:
    """Whether stabilized pixel (x, y) samples the source frame with every bilinear tap inside it."""
    w = m[2, 0] * x + m[2, 1] * y + m[2, 2]
    if not w > 0.0:
        return False
    sx = (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / w
    sy = (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / w
    return sx > -slack and sx < right and sy > -slack and sy < bottom


@njit(cache=True, nogil=True)
def _clip_run(p: float, q: float, lo: float, hi: float) -> tuple[float, float]:
    """The run lo..hi of a row cut down to where p * x + q > 0."""
    if p > 0.0:
        return max(lo, -q / p), hi
    if p < 0.0:
        return lo, min(hi, -q / p)
    return (lo, hi) if q > 0.0 else (hi + 3.0, hi)  # nowhere: an empty run (lo > hi + 2)


@njit(cache=True, nogil=True)
def covered_spans(m: np.ndarray, src_height: int, src_width: int, height: int, width: int,
                   slack: float) -> tuple[np.ndarray, np.ndarray]:
    """Per target row y, the columns first[y]..last[y] (none when last < first) that the source frame covers
    through ``m`` (source from target), by WarpedNeighbour.sample's rule.

    Covered points form a convex region, one run per row: the run is solved from the region's five half-planes
    (w > 0 and the four frame edges, each linear in x along a row), then its ends are checked pixel by pixel."""
    right = src_width - 1 + slack
    bottom = src_height - 1 + slack
    first = np.zeros(height, np.int32)
    last = np.full(height, -1, np.int32)
    for y in range(height):
        wq = m[2, 1] * y + m[2, 2]
        xq = m[0, 1] * y + m[0, 2]
        yq = m[1, 1] * y + m[1, 2]
        lo, hi = -2.0, width + 1.0
        lo, hi = _clip_run(m[2, 0], wq, lo, hi)
        lo, hi = _clip_run(m[0, 0] + slack * m[2, 0], xq + slack * wq, lo, hi)
        lo, hi = _clip_run(right * m[2, 0] - m[0, 0], right * wq - xq, lo, hi)
        lo, hi = _clip_run(m[1, 0] + slack * m[2, 0], yq + slack * wq, lo, hi)
        lo, hi = _clip_run(bottom * m[2, 0] - m[1, 0], bottom * wq - yq, lo, hi)
        if not lo <= hi + 2.0:
            continue
        a = int(max(math.floor(lo) - 1.0, 0.0))
        b = int(min(math.ceil(hi) + 1.0, width - 1.0))
        while a <= b and not _inside(m, a, y, right, bottom, slack):
            a += 1
        if a > b:
            continue
        while not _inside(m, b, y, right, bottom, slack):
            b -= 1
        while a > 0 and _inside(m, a - 1, y, right, bottom, slack):
            a -= 1
        while b < width - 1 and _inside(m, b + 1, y, right, bottom, slack):
            b += 1
        first[y], last[y] = a, b
    return first, last


@njit(cache=True, nogil=True)
def zero_outside_spans(rgb: np.ndarray, first: np.ndarray, last: np.ndarray) -> None:
    """Black outside each row's span first[y]..last[y]."""
    height, width = rgb.shape[:2]
    for y in range(height):
        for x in range(min(first[y], width)):
            rgb[y, x] = 0
        for x in range(max(last[y] + 1, 0), width):
            rgb[y, x] = 0


@njit(cache=True, nogil=True)
def area_coverage(first: np.ndarray, last: np.ndarray, exact: np.ndarray, mask: np.ndarray,
                   row_index: np.ndarray, row_weight: np.ndarray, row_count: np.ndarray, row_sum: np.ndarray,
                   col_index: np.ndarray, col_weight: np.ndarray, col_count: np.ndarray,
                   col_sum: np.ndarray) -> np.ndarray:
    """cv2.resize INTER_AREA (by the tables of area_table) of the float mask of pixels in their row's span and,
    in rows not ``exact``, in ``mask``."""
    columns = col_count.size
    col_first = col_index[:, 0].copy()
    col_last = np.empty(columns, np.int32)
    for dx in range(columns):
        col_last[dx] = col_index[dx, col_count[dx] - 1]
    out = np.zeros((row_count.size, columns), np.float32)
    for dy in range(row_count.size):
        # Consecutive exact rows with the same span (the usual case) are added once, with their weights summed.
        held_a, held_b, held_weight = 0, -1, np.float32(0.0)
        for j in range(row_count[dy]):
            sy = row_index[dy, j]
            a, b = first[sy], last[sy]
            if b < a:
                continue
            wy = row_weight[dy, j]
            if not exact[sy]:
                _add_span_coverage(out[dy], a, b, False, mask[sy], wy, col_index, col_weight, col_count, col_sum,
                                   col_first, col_last)
            elif a == held_a and b == held_b:
                held_weight += wy
            else:
                if held_b >= held_a:
                    _add_span_coverage(out[dy], held_a, held_b, True, mask[0], held_weight, col_index, col_weight,
                                       col_count, col_sum, col_first, col_last)
                held_a, held_b, held_weight = a, b, wy
        if held_b >= held_a:
            _add_span_coverage(out[dy], held_a, held_b, True, mask[0], held_weight, col_index, col_weight, col_count,
                               col_sum, col_first, col_last)
    return out


@njit(cache=True, nogil=True)
def _add_span_coverage(out_row: np.ndarray, a: int, b: int, every: bool, mask_row: np.ndarray, wy: np.float32,
                       col_index: np.ndarray, col_weight: np.ndarray, col_count: np.ndarray, col_sum: np.ndarray,
                       col_first: np.ndarray, col_last: np.ndarray) -> None:
    """out_row += wy * (INTER_AREA along the row of the pixels a..b that are, unless ``every``, in ``mask_row``)."""
    # Cells overlapping the span: lo..hi; of those, wholly inside it (when every): inner_lo..inner_hi.
    lo, hi = np.searchsorted(col_last, a), np.searchsorted(col_first, b, side="right") - 1
    inner_lo, inner_hi = hi + 1, hi
    if every:
        inner_lo = np.searchsorted(col_first, a)
        inner_hi = np.searchsorted(col_last, b, side="right") - 1
        for dx in range(inner_lo, inner_hi + 1):
            out_row[dx] += wy * col_sum[dx]
    for dx in range(lo, hi + 1):
        if inner_lo <= dx <= inner_hi:
            continue
        s = np.float32(0.0)
        for i in range(col_count[dx]):
            sx = col_index[dx, i]
            if a <= sx <= b and (every or mask_row[sx]):
                s += col_weight[dx, i]
        out_row[dx] += wy * s


@njit(cache=True, nogil=True)
def _upsample_row(error_row: np.ndarray, tap0: np.ndarray, tap1: np.ndarray, fraction: np.ndarray,
                  out: np.ndarray, repeat: int) -> None:
    """cv2.resize INTER_LINEAR's horizontal pass over one row (taps and weights from _linear_table), each value
    written ``repeat`` times in a row (3: once per colour sample)."""
    one = np.float32(1.0)
    for x in range(tap0.size):
        value = error_row[tap0[x]] * (one - fraction[x]) + error_row[tap1[x]] * fraction[x]
        for j in range(repeat):
            out[repeat * x + j] = value


@njit(cache=True, nogil=True)
def _upsampled_rows(error: np.ndarray, y: int, row_tap0: np.ndarray, row_tap1: np.ndarray,
                    col_tap0: np.ndarray, col_tap1: np.ndarray, col_fraction: np.ndarray, upper: np.ndarray,
                    lower: np.ndarray, tags: np.ndarray, repeat: int) -> None:
    """Fill ``upper`` and ``lower`` with the horizontally upsampled error rows that full-res row y interpolates
    (_upsample_row); ``tags`` holds the low-res rows they hold, so consecutive rows reuse them."""
    y0, y1 = row_tap0[y], row_tap1[y]
    if tags[0] != y0:
        if tags[1] == y0:
            upper[:] = lower
        else:
            _upsample_row(error[y0], col_tap0, col_tap1, col_fraction, upper, repeat)
        tags[0] = y0
    if tags[1] != y1:
        _upsample_row(error[y1], col_tap0, col_tap1, col_fraction, lower, repeat)
        tags[1] = y1


@njit(cache=True, nogil=True)
def _mark_above(error: np.ndarray, row_tap0: np.ndarray, row_tap1: np.ndarray, row_fraction: np.ndarray,
                col_tap0: np.ndarray, col_tap1: np.ndarray, col_fraction: np.ndarray, threshold: np.float32,
                above: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> None:
    """above = 1 where the error upsampled as cv2.resize INTER_LINEAR would exceeds ``threshold``, in rows
    r0..r1-1, columns c0..c1-1."""
    width = col_tap0.size
    upper, lower = np.empty(width, np.float32), np.empty(width, np.float32)
    tags = np.full(2, -1, np.int64)
    one = np.float32(1.0)
    for y in range(r0, r1):
        _upsampled_rows(error, y, row_tap0, row_tap1, col_tap0, col_tap1, col_fraction, upper, lower, tags, 1)
        fy = row_fraction[y]
        gy = one - fy
        row = above[y]
        for x in range(c0, c1):  # branch-free, so that it vectorises
            row[x] |= np.uint8(upper[x] * gy + lower[x] * fy > threshold)


@njit(cache=True, nogil=True, error_model="numpy")
def blend(target: np.ndarray, rgbs: np.ndarray, masks: np.ndarray, mask_index: np.ndarray, rejecteds: np.ndarray,
           has_rejected: np.ndarray, errors: np.ndarray, firsts: np.ndarray, lasts: np.ndarray, exacts: np.ndarray,
           ratios: np.ndarray, row_tap0: np.ndarray, row_tap1: np.ndarray, row_fraction: np.ndarray,
           col_tap0: np.ndarray, col_tap1: np.ndarray, col_fraction: np.ndarray,
           alpha: np.float32, half: np.float32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 30 row by row over every neighbour k: (I_t + sum_k w_k I_k) / (1 + sum_k w_k), with w_k of eq. 31 on
    the pixels in k's row span, in masks[mask_index[k]] (rows not exacts[k]) and not in rejecteds[k] (looked at
    on the rows has_rejected[k] marks); E_k is the low-res errors[k] upsampled as cv2.resize INTER_LINEAR would.
    Returns the frame (the target's type: uint8 rounded with ``half`` 0.5, float32 0..255 with ``half`` 0), the
    share taken from neighbours 1 - 1 / (1 + sum w), and the number of pixels each neighbour gave weight to.

    A row's sums stay in cache while every neighbour adds to them. The loops run over colour samples (weights
    and sums repeated per sample) with unsigned indices and numpy's error model (no zero-division check), so
    that they vectorise."""
    height, width = target.shape[:2]
    count = rgbs.shape[0]
    samples = 3 * width
    frame = np.empty_like(target)
    share = np.empty((height, width), np.float32)
    counts = np.zeros(count, np.int64)
    sums = np.empty(samples, np.float32)  # I_t + sum w I, eq. 30's numerator
    totals = np.empty(samples, np.float32)  # 1 + sum w, its denominator
    weights = np.empty(samples, np.float32)
    uppers, lowers = np.empty((count, samples), np.float32), np.empty((count, samples), np.float32)
    tags = np.full((count, 2), -1, np.int64)
    flat_target, flat_frame = target.reshape(height, samples), frame.reshape(height, samples)
    one, zero, top, three = np.float32(1.0), np.float32(0.0), np.float32(255.0), np.uint64(3)
    for y in range(height):
        target_row = flat_target[y]
        for i in range(samples):
            sums[i] = target_row[i]
        totals[:] = one
        for k in range(count):
            if lasts[k, y] < firsts[k, y]:
                continue
            a, b = three * np.uint64(firsts[k, y]), three * np.uint64(lasts[k, y] + 1)
            upper, lower = uppers[k], lowers[k]
            _upsampled_rows(errors[k], y, row_tap0, row_tap1, col_tap0, col_tap1, col_fraction, upper, lower,
                            tags[k], 3)
            fy = row_fraction[y]
            gy = one - fy
            scale = ratios[k] * alpha
            for i in range(a, b):
                weights[i] = scale / (upper[i] * gy + lower[i] * fy + alpha)
            taken = np.int64((b - a) // three)  # pixels given weight in this row
            if not exacts[k, y]:
                mask_row = masks[mask_index[k], y]
                for x in range(a // three, b // three):
                    if not mask_row[x]:
                        weights[three * x:three * x + three] = zero  # adding 0 changes nothing
                        taken -= 1
            if has_rejected[k, y]:
                rejected_row = rejecteds[k, y]
                dropped = np.int64(0)
                for x in range(a // three, b // three):  # branch-free, so that it vectorises
                    hit = np.int64(rejected_row[x] != 0) & np.int64(weights[three * x] != zero)
                    keep = one - np.float32(rejected_row[x] != 0)
                    dropped += hit
                    weights[three * x] *= keep
                    weights[three * x + 1] *= keep
                    weights[three * x + 2] *= keep
                taken -= dropped
            counts[k] += taken
            rgb_row = rgbs[k, y].reshape(samples)
            for i in range(a, b):
                totals[i] += weights[i]
                sums[i] += weights[i] * rgb_row[i]
        frame_row, share_row = flat_frame[y], share[y]
        for x in range(np.uint64(width)):
            share_row[x] = one - one / totals[three * x]
        for i in range(samples):
            frame_row[i] = min(max(sums[i] / totals[i] + half, zero), top)  # truncated into uint8: rounded
    return frame, share, counts


class Contributions:
    """The neighbours that take part in eq. 30, in the arrays blend reads: a slot each, filled in order (the
    colours warped straight into theirs)."""

    def __init__(self, capacity: int, grid: ErrorGrid, target_valid: np.ndarray, dtype: type = np.uint8) -> None:
        height, width = target_valid.shape
        self.count = 0
        self.offsets: list[int] = []
        self.rgbs = np.empty((capacity, height, width, 3), dtype)  # the target's pixel type
        self.errors = np.empty((capacity, grid.small_size[1], grid.small_size[0]), np.float32)
        self.firsts = np.empty((capacity, height), np.int32)
        self.lasts = np.empty((capacity, height), np.int32)
        self.exacts = np.empty((capacity, height), np.bool_)
        self.ratios = np.empty(capacity, np.float32)
        self.masks = [target_valid]  # a neighbour's valid pixels: the target's, or one of its own (warped given)
        self.mask_index = np.zeros(capacity, np.int64)
        self.rejected: np.ndarray | None = None  # zeros until written; made on first need
        self.has_rejected = np.zeros((capacity, height), np.bool_)  # rows of rejected[k] with a pixel set

    def next_rgb(self) -> np.ndarray:
        return self.rgbs[self.count]

    def next_rejected(self) -> np.ndarray:
        if self.rejected is None:
            self.rejected = np.zeros(self.rgbs.shape[:3], np.uint8)  # untouched pages cost nothing
        return self.rejected[self.count]

    def add(self, offset: int, first: np.ndarray, last: np.ndarray, exact: np.ndarray, mask: np.ndarray | None,
            has_rejected: bool, error: np.ndarray, ratio: float) -> None:
        k = self.count
        self.offsets.append(offset)
        self.firsts[k], self.lasts[k], self.exacts[k] = first, last, exact
        if mask is not None:
            self.mask_index[k] = len(self.masks)
            self.masks.append(mask)
        self.has_rejected[k] = self.rejected[k].any(axis=1) if has_rejected else False
        self.errors[k] = error
        self.ratios[k] = ratio
        self.count += 1

    def arrays(self) -> tuple:
        """blend's arguments from rgbs to ratios."""
        k = self.count
        masks = self.masks[0][None] if len(self.masks) == 1 else np.stack(self.masks)
        rejected = _NO_REJECTED if self.rejected is None else self.rejected[:k]
        return (self.rgbs[:k], masks, self.mask_index[:k], rejected, self.has_rejected[:k], self.errors[:k],
                self.firsts[:k], self.lasts[:k], self.exacts[:k], self.ratios[:k])


@njit(cache=True, nogil=True)
def structure_products(target: np.ndarray, other: np.ndarray, weight: np.ndarray, out: np.ndarray) -> None:
    """The per-cell terms whose window means StructureGuard (pipeline/stages/deblur.py) needs, into ``out``
    (2, h, w, 4), term k at out[k // 4, ..., k % 4] (two 4-channel images: OpenCV's box filter takes four channels
    at once for the cost of about two planes, with the same sums). The terms: o, o^2, t o, then t times o one cell
    to the left, right, above and below (clamped at the edge: o(p - d) for d = (0, 1), (0, -1), (1, 0), (-1, 0) in
    (row, column)), and the coverage weight."""
    height, width = target.shape
    for y in range(height):
        up, down = max(y - 1, 0), min(y + 1, height - 1)
        for x in range(width):
            left, right = max(x - 1, 0), min(x + 1, width - 1)
            t, o = target[y, x], other[y, x]
            first, second = out[0, y, x], out[1, y, x]
            first[0] = o
            first[1] = o * o
            first[2] = t * o
            first[3] = t * other[y, left]
            second[0] = t * other[y, right]
            second[1] = t * other[up, x]
            second[2] = t * other[down, x]
            second[3] = weight[y, x]


@njit(cache=True, nogil=True, error_model="numpy")
def structure_refusal(means: np.ndarray, target_mean: np.ndarray, target_var: np.ndarray, c: np.float32,
                      minimum: np.float32, margin: np.float32, min_var: np.float32, edge: int,
                      agreement: np.ndarray, flat_var: np.float32, flat_difference: np.float32) -> np.ndarray:
    """StructureGuard's decision per cell from the window means of structure_products' terms: the contrast-
    structure term (2 cov + c) / (var_t + var_o + c) into ``agreement``; refused (uint8 1) where the window lies
    wholly in the neighbour's coverage and the term is below ``minimum``, or both windows are flat (variances
    below ``flat_var``) with means more than ``flat_difference`` apart, or, where both windows have structure
    (variances >= ``min_var``) and lie ``edge`` cells from the image's edge, the neighbour moved one cell agrees
    better by more than ``margin``."""
    height, width = target_mean.shape
    refused = np.zeros((height, width), np.uint8)
    full = np.float32(0.999)
    zero = np.float32(0.0)
    two = np.float32(2.0)
    for y in range(height):
        for x in range(width):
            mean_o = means[0, y, x, 0]
            var_o = max(means[0, y, x, 1] - mean_o * mean_o, zero)
            var_t = max(target_var[y, x], zero)
            mean_t = target_mean[y, x]
            aligned = (two * (means[0, y, x, 2] - mean_t * mean_o) + c) / (var_t + var_o + c)
            agreement[y, x] = aligned
            if means[1, y, x, 3] < full:
                continue
            if aligned < minimum:
                refused[y, x] = 1
                continue
            if max(var_t, var_o) < flat_var and abs(mean_t - mean_o) > flat_difference:
                refused[y, x] = 1  # both flat, yet not the same level: another flat surface
                continue
            if min(var_t, var_o) < min_var or y < edge or y >= height - edge or x < edge or x >= width - edge:
                continue
            for k in range(4):
                yy = y - (1 if k == 2 else 0) + (1 if k == 3 else 0)
                xx = x - (1 if k == 0 else 0) + (1 if k == 1 else 0)
                mean_moved = means[0, yy, xx, 0]
                var_moved = max(means[0, yy, xx, 1] - mean_moved * mean_moved, zero)
                term = 3 + k  # t times o moved by the k-th shift (structure_products' layout)
                moved = (two * (means[term // 4, y, x, term % 4] - mean_t * mean_moved) + c) / (var_t + var_moved + c)
                if moved > aligned + margin:
                    refused[y, x] = 1
                    break
    return refused

