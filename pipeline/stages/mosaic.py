"""Mosaicing with the consistency constraint (thesis 4.2.1, eqs. 20-22).

Each neighbour t' arrives already warped into frame t's stabilized coordinates (the caller composes S_t' with
the inter-frame chain) with its validity mask. For every missing pixel p of frame t covered by
n >= ``min_neighbours`` neighbours, eq. 20 gives the variance of their intensities (0.30 R + 0.59 G + 0.11 B,
0..255) with the n-1 denominator and eq. 21's mean. A low variance (below ``variance_threshold``) means the
neighbours agree, i.e. p shows static, well-registered scene, and p is filled with the median (eq. 22); a high
variance means a moving object or misregistration, and p stays missing for motion inpainting.

The median of colour pixels is the colour of the neighbour whose *intensity* is the median (for an even count,
the mean of the two middle neighbours' colours). So the filled intensity is exactly eq. 22's median, and the
colour is an observed one, never a per-channel mix of different frames.

Threshold 100 (intensities spread by ~10 grey levels) keeps ~97 % of the static pixels at half a pixel of
misregistration while leaving ~98 % of a moving object's footprint to motion inpainting: a larger one accepts
objects (ghosts), a smaller one hands textured static edges on to the costlier local warp (measurements:
docs/completion.md).

Only the missing pixels are gathered, as (n, m) samples, so the cost follows the missing area, not the frame;
the median uses pairwise rank counting (faster than argsort along a short axis). ``majority_median`` applies eqs.
20-22 to the tightest strict majority of the samples, for completion's majority candidate; the mosaic stays eqs. 20-22.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numba import njit

from pipeline.errors import ConfigError
from pipeline.imaging import intensity



@dataclass(frozen=True)
class MosaicConfig:
    # Largest eq. 20 variance (intensity, 0..255 units) at which the neighbours count as consistent.
    variance_threshold: float = 100.0
    # A pixel needs at least this many covering neighbours to be judged (eq. 20 divides by n-1).
    min_neighbours: int = 2

    def __post_init__(self) -> None:
        if self.min_neighbours < 2:
            raise ConfigError(f"min_neighbours must be >= 2 (eq. 20 divides by n-1), not {self.min_neighbours}")
        if not self.variance_threshold > 0:
            raise ConfigError(f"variance_threshold must be positive, not {self.variance_threshold}")


@dataclass(frozen=True)
class MosaicResult:
    frame: np.ndarray  # (H, W, 3) as the target (uint8 or float32): accepted missing pixels filled (eq. 22)
    variance: np.ndarray  # (H, W) float32: eq. 20; NaN outside the missing area or with < min_neighbours covering
    accepted: np.ndarray  # (H, W) bool: missing pixels filled here (variance < threshold)
    remaining: np.ndarray  # (H, W) bool: still missing after this stage
    coverage: np.ndarray  # (H, W) uint8: how many neighbours cover each pixel


def _ranks(values: np.ndarray) -> np.ndarray:
    """(n, m) -> the rank of each sample among its column's n samples, ties broken by row order.

    Pairwise counting: n(n-1)/2 vectorised comparisons, faster than argsort along a short axis for n <~ 16.
    """
    n = len(values)
    rank = np.zeros(values.shape, np.uint8)
    for i in range(n):
        for j in range(i + 1, n):
            j_first = values[j] < values[i]
            rank[i] += j_first
            rank[j] += ~j_first
    return rank


def consistent_mosaic(
    target: np.ndarray,
    missing: np.ndarray,
    neighbours: Sequence[np.ndarray],
    neighbour_valid: Sequence[np.ndarray],
    config: MosaicConfig = MosaicConfig(),
) -> MosaicResult:
    """Fill the missing pixels of ``target`` on which the warped neighbours agree (eqs. 20-22)."""
    height, width = missing.shape
    if len(neighbours) != len(neighbour_valid):
        raise ValueError(f"{len(neighbours)} neighbours but {len(neighbour_valid)} validity masks")
    coverage = np.zeros((height, width), np.uint8)
    for valid in neighbour_valid:
        coverage += valid
    # Gather only the missing pixels, as (n, m) samples instead of n full frames (np.take on flat indices is
    # several times faster than boolean indexing of (H, W, 3) arrays).
    flat = np.flatnonzero(missing)
    colours = np.stack([np.take(image.reshape(-1, 3), flat, axis=0) for image in neighbours]) if neighbours else None
    valid = np.stack([np.take(v.reshape(-1), flat) for v in neighbour_valid]) if neighbours else None
    return mosaic_from_samples(target, missing, colours, valid, config, coverage=coverage)


def mosaic_from_samples(target: np.ndarray, missing: np.ndarray, colours: np.ndarray | None, valid: np.ndarray | None,
                        config: MosaicConfig = MosaicConfig(), *, coverage: np.ndarray | None = None) -> MosaicResult:
    """Eqs. 20-22 from the neighbours' samples at the missing pixels only (row-major order, as np.nonzero gives
    them): ``colours`` (n, m, 3) uint8 and ``valid`` (n, m) bool, or None without neighbours. So the neighbours
    need never be warped over the whole frame. ``coverage``: the full map if known; else it is counted at the
    missing pixels only (0 elsewhere)."""
    height, width = missing.shape
    frame = target.copy()
    variance = np.full((height, width), np.nan, np.float32)
    accepted = np.zeros((height, width), bool)
    flat = np.flatnonzero(missing)
    if coverage is None:
        coverage = np.zeros((height, width), np.uint8)
        if valid is not None and len(flat):
            coverage.reshape(-1)[flat] = valid.sum(axis=0)
    if len(flat) == 0 or colours is None or len(colours) == 0:
        return MosaicResult(frame, variance, accepted, missing.copy(), coverage)

    count = valid.sum(axis=0)
    judged = count >= config.min_neighbours

    values = intensity(colours) * valid
    mean = values.sum(axis=0) / np.maximum(count, 1)  # eq. 21
    deviation = (values - mean) * valid
    sample_variance = np.einsum("nm,nm->m", deviation, deviation) / np.maximum(count - 1, 1)  # eq. 20
    sample_variance = np.where(judged, sample_variance, np.nan).astype(np.float32)
    ok = judged & (sample_variance < config.variance_threshold)

    # Median by intensity (eq. 22): invalid samples rank last, so ranks (count-1)//2 and count//2 are the middle.
    rank = _ranks(np.where(valid, values, np.inf))
    lower = np.argmax(rank == np.maximum(count - 1, 0) // 2, axis=0)
    upper = np.argmax(rank == count // 2, axis=0)
    median = _middle(colours, lower, upper)

    frame.reshape(-1, 3)[flat[ok]] = median[ok]
    variance.reshape(-1)[flat] = sample_variance
    accepted.reshape(-1)[flat[ok]] = True
    return MosaicResult(frame, variance, accepted, missing & ~accepted, coverage)


def _middle(colours: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Per column of ``colours`` (n, m, 3), the mean of the samples ``lower`` and ``upper`` (rows; the same one for an
    odd count): rounded for uint8, exact for float32 (deeper video)."""
    columns = np.arange(colours.shape[1])
    if colours.dtype == np.uint8:
        return ((colours[lower, columns].astype(np.uint16) + colours[upper, columns] + 1) // 2).astype(np.uint8)
    return (colours[lower, columns] + colours[upper, columns]) * np.float32(0.5)


def majority_median(colours: np.ndarray, values: np.ndarray, valid: np.ndarray, variance_threshold: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eqs. 20-22 on a strict majority: per column of ``colours`` (n, m, 3) with intensities ``values`` (n, m) and
    ``valid`` (n, m), the tightest run of k = count // 2 + 1 samples in intensity order (the majority whose eq. 20
    variance is lowest), accepted where that variance is below ``variance_threshold``, with eq. 22's median of the
    run as the colour (an observed colour; the mean of the two middle ones for an even k).

    Why: where an object passed in front of the background in a few neighbours, eq. 20 over all of them rejects a
    pixel the others agree on. Returns (ok (m,) bool: three or more samples and such a majority, median (m, 3),
    member (n, m) bool: the samples in the run)."""
    ok, lower, upper, member = _tightest_majority(np.ascontiguousarray(values), np.ascontiguousarray(valid, np.bool_),
                                                  float(variance_threshold))
    return ok, _middle(colours, lower, upper), member


@njit(cache=True, nogil=True)
def _tightest_majority(values: np.ndarray, valid: np.ndarray, variance_threshold: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """majority_median's search, a column at a time: the valid samples in stable intensity order (invalid ones last),
    prefix sums of their intensities and squares in float64, and the run of k = count // 2 + 1 with the lowest eq.
    20 variance (the first on a tie). Returns (ok (m,), the run's two middle samples' rows lower and upper (m,), the
    run's members (n, m)). The arithmetic is numpy's for the same formulas, in the same order: the same bits."""
    n, m = values.shape
    ok = np.zeros(m, np.bool_)
    lower = np.zeros(m, np.int64)
    upper = np.zeros(m, np.int64)
    member = np.zeros((n, m), np.bool_)
    order = np.empty(n, np.int64)
    keys = np.empty(n, values.dtype)
    first = np.zeros(n + 1)
    second = np.zeros(n + 1)
    for j in range(m):
        count = 0
        for i in range(n):  # insertion sort: stable, NaN after every number, as np.argsort(kind="stable")
            key = values[i, j] if valid[i, j] else np.inf
            count += valid[i, j]
            p = i
            while p > 0 and (key < keys[p - 1] or (keys[p - 1] != keys[p - 1] and key == key)):
                keys[p], order[p] = keys[p - 1], order[p - 1]
                p -= 1
            keys[p], order[p] = key, i
        for i in range(n):
            v = np.float64(values[order[i], j]) if i < count else 0.0
            first[i + 1] = first[i] + v if i > 0 else v
            second[i + 1] = second[i] + v * v if i > 0 else v * v
        k = count // 2 + 1
        best, start = np.inf, 0
        for s in range(n):
            end = min(s + k, n)
            total = first[end] - first[s]
            variance = (second[end] - second[s] - total * total / k) / max(k - 1, 1)
            if s + k <= count and variance < best:
                best, start = variance, s
        ok[j] = count >= 3 and best < variance_threshold
        lower[j] = order[min(start + (k - 1) // 2, n - 1)]
        upper[j] = order[min(start + k // 2, n - 1)]
        if ok[j]:
            for p in range(start, min(start + k - 1, n - 1) + 1):
                member[order[p], j] = valid[order[p], j]
    return ok, lower, upper, member
