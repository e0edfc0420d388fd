"""Neighbour priority (thesis 4.2.2, eq. 23) and dense local motion over the common area (thesis 3.3).

After the global warp, a neighbour t' seen in frame t's stabilized coordinates still differs from frame t by
its *local* motion: moving objects, parallax and residual misregistration. Motion inpainting (4.2.3) needs that
motion as a dense field on the area both frames cover: ``local_flow`` computes it, ``mean_abs_difference`` the
eq. 23 alignment error by which neighbours are ordered.

Flow is computed on intensity images (0.30 R + 0.59 G + 0.11 B) by DIS (``dis_preset``, "fast" by default;
Farneback and the thesis's sparse Lucas-Kanade on a grid remain as ``method`` values). The invalid pixels of each
image (black in the warped frames) are first filled, so the flow does not lock onto a black edge: with the other
image's pixels where it has them (their texture keeps DIS's patches matching across the hole boundary, where
motion inpainting starts), and by push-pull (normalised pyramid interpolation) where neither has. Invariant: the
flow is valid only on ``common`` (both images valid, eroded by ``common_erosion_px``); ``reliable`` is the part
of it whose flow lands on the neighbour's content. Inside ``focus``, regions the flow leaves badly explained are
matched again by a translation search (``_rescue_large_motions``: DIS's pyramid loses fast objects).

Why DIS "fast" and not the more accurate "medium": each pixel takes the candidate whose warp best explains its
surroundings out of four neighbours', and the mosaic fills most of the missing area, so the completed pixels
hardly depend on flow accuracy while "fast" runs 3x faster. Flow accuracy of every method and the completion
PSNR behind this choice: docs/completion.md (``benchmarks/quality/local_flow_choice.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from pipeline.errors import ConfigError
from pipeline.imaging import intensity

METHODS: tuple[str, ...] = ("dis", "farneback", "lk")
DIS_PRESETS = {
    "ultrafast": cv2.DISOpticalFlow_PRESET_ULTRAFAST,
    "fast": cv2.DISOpticalFlow_PRESET_FAST,
    "medium": cv2.DISOpticalFlow_PRESET_MEDIUM,
}


@dataclass(frozen=True)
class LocalFlowConfig:
    method: str = "dis"  # "dis" | "farneback" | "lk" (sparse pyramidal LK on a grid, interpolated)
    dis_preset: str = "fast"  # "ultrafast" | "fast" | "medium" (see the module docstring)
    dis_finest_scale: int | None = None  # pyramid level DIS stops at (0 = full resolution); None: the preset's
    # Farneback (OpenCV's recommended values, one more level for hand-held residuals).
    farneback_levels: int = 4  # pyramid levels
    farneback_window: int = 15  # px: averaging window
    farneback_iterations: int = 3  # per level
    # Sparse LK on a regular grid (the thesis' choice), then bilinear interpolation of the grid.
    lk_grid_step: int = 8  # px between grid points
    lk_window: int = 21  # px: LK's search window
    lk_levels: int = 3  # pyramid levels
    lk_max_fb_error_px: float = 0.5  # tracks that do not come back to their start are dropped
    common_erosion_px: int = 3  # px: flow within this distance of an invalid pixel is unreliable
    min_common_fraction: float = 0.01  # share of the frame: with less common area, no alignment error
    # Large-motion rescue (see _rescue_large_motions): inside ``focus``, regions whose warp leaves a mean
    # intensity error above this (0..255, 5x5 mean) are matched again by a translation search; None: off.
    rescue_error: float | None = 20.0
    rescue_search_px: int = 48  # px: translations up to this far (a best match on the search's edge is dropped)
    rescue_min_px: int = 40  # pixels (an area): smaller badly explained regions are left alone

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ConfigError(f"local flow method must be one of {', '.join(METHODS)}, not {self.method!r}")
        if self.dis_preset not in DIS_PRESETS:
            raise ConfigError(f"DIS preset must be one of {', '.join(DIS_PRESETS)}, not {self.dis_preset!r}")


@dataclass(frozen=True)
class LocalFlowResult:
    flow: np.ndarray  # (H, W, 2) float32 target -> neighbour: neighbour(p + flow(p)) ~ target(p); valid on `common`
    common: np.ndarray  # (H, W) bool: valid in both images, eroded by common_erosion_px
    # (H, W) bool: common pixels whose flow is trusted: it lands on the neighbour's content (flow that
    # leaves it was invented by the smoothness prior). None: same as common.
    reliable: np.ndarray | None = None


def mean_abs_difference(target_intensity: np.ndarray, target_valid: np.ndarray, neighbour: np.ndarray,
                        neighbour_valid: np.ndarray,
                        min_common_fraction: float = LocalFlowConfig.min_common_fraction) -> float:
    """Eq. 23 (neighbour priority) as the mean absolute intensity difference over the common area of an
    intensity image and an RGB neighbour; +inf when that area is below ``min_common_fraction`` of the image.

    The thesis sums; the mean is used because a sum grows with the overlap, so it would rank a neighbour
    that shares much of the frame (usually the nearest, most useful one) below one that barely overlaps.
    pipeline/stages/completion.py evaluates it on a subsampled grid of each neighbour.
    """
    common = target_valid & neighbour_valid
    if np.count_nonzero(common) < min_common_fraction * common.size:
        return float("inf")
    return float(np.abs(target_intensity - intensity(neighbour))[common].mean())


def local_flow(target: np.ndarray, target_valid: np.ndarray, neighbour: np.ndarray, neighbour_valid: np.ndarray,
               config: LocalFlowConfig = LocalFlowConfig(), *, focus: np.ndarray | None = None) -> LocalFlowResult:
    """Dense flow from ``target`` to the (already globally warped) ``neighbour`` over their common area.

    ``focus``: where the flow matters most (e.g. around the area to complete); large motions the flow
    method missed are searched for there (``rescue_error``).
    """
    common = target_valid & neighbour_valid
    if config.common_erosion_px > 0:
        size = 2 * config.common_erosion_px + 1
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (size, size))
        common = cv2.erode(common.astype(np.uint8), kernel).astype(bool)  # the frame edge itself does not erode
    # Each image's holes take the other image's pixels (the flow there is wrong but the texture keeps patch
    # matching near the boundary honest); holes in both are filled smoothly. See the module docstring.
    first, second = _grey(target), _grey(neighbour)
    either = target_valid | neighbour_valid
    first, second = (fill_invalid(np.where(target_valid, first, second), either),
                     fill_invalid(np.where(neighbour_valid, second, first), either))
    flow = _flow(first, second, common, config)
    if focus is not None and config.rescue_error is not None:
        _rescue_large_motions(flow, target, neighbour, neighbour_valid, common & focus, config)
    reliable = common & _lands_inside(flow, neighbour_valid)
    return LocalFlowResult(flow=flow, common=common, reliable=reliable)


def _flow(first: np.ndarray, second: np.ndarray, common: np.ndarray, config: LocalFlowConfig) -> np.ndarray:
    if config.method == "dis":
        flow = _dis(first, second, config)
    elif config.method == "farneback":
        flow = _farneback(first, second, config)
    else:
        flow = _sparse_lk(first, second, common, config)
    return flow.astype(np.float32, copy=False)


def _sample_maps(flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap's maps for sampling at p + flow(p): x + flow_x, y + flow_y (float32)."""
    height, width = flow.shape[:2]
    return (np.arange(width, dtype=np.float32)[None, :] + flow[..., 0],
            np.arange(height, dtype=np.float32)[:, None] + flow[..., 1])


def _lands_inside(flow: np.ndarray, neighbour_valid: np.ndarray) -> np.ndarray:
    """Pixels whose flow lands where every bilinear tap is neighbour content (else the flow was invented)."""
    map_x, map_y = _sample_maps(flow)
    coverage = cv2.remap(neighbour_valid.astype(np.uint8) * 255, map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT)
    return coverage == 255


def _warp_error(target: np.ndarray, neighbour: np.ndarray, flow: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
    """5x5 mean of |I_t(p) - I_t'(p + F(p))| for a crop of the target whose top-left pixel is ``origin``."""
    map_x, map_y = _sample_maps(flow)
    map_x += origin[1]
    map_y += origin[0]
    warped = cv2.remap(neighbour, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return cv2.blur(np.abs(intensity(target) - intensity(warped)), (5, 5))


def _rescue_large_motions(flow: np.ndarray, target: np.ndarray, neighbour: np.ndarray, neighbour_valid: np.ndarray,
                          where: np.ndarray, config: LocalFlowConfig) -> None:
    """Re-match, by a translation search, the regions of ``where`` that the flow leaves badly explained.

    Each connected badly explained region gets the translation minimising its masked SSD against the
    neighbour (landing entirely on neighbour content); its pixels that this translation explains at least
    twice as well as the flow (and below ``rescue_error``) take it. Writes into ``flow``.

    The search compares intensities, as the error that flags a region does: a third of the work of comparing
    R, G and B, for completion as good on balance (docs/decisions.md D29; figures: docs/benchmarks-completion.md).
    """
    rows = np.flatnonzero(where.any(axis=1))
    if len(rows) == 0:
        return
    cols = np.flatnonzero(where.any(axis=0))
    height, width = where.shape
    # Work on the focus' box: error maps and warps are only needed there.
    y0, y1 = max(rows[0] - 2, 0), min(rows[-1] + 3, height)
    x0, x1 = max(cols[0] - 2, 0), min(cols[-1] + 3, width)
    box_target, box_flow = target[y0:y1, x0:x1], flow[y0:y1, x0:x1]
    error = _warp_error(box_target, neighbour, box_flow, (y0, x0))
    bad = where[y0:y1, x0:x1] & (error > config.rescue_error)
    if not bad.any():
        return
    count, labels, stats, _ = cv2.connectedComponentsWithStats(bad.astype(np.uint8), connectivity=8)
    search = config.rescue_search_px
    for label in range(1, count):
        if stats[label, cv2.CC_STAT_AREA] < config.rescue_min_px:
            continue
        bx, by, bw, bh = (int(v) for v in stats[label, :4])
        region = labels[by:by + bh, bx:bx + bw] == label
        # The region in frame coordinates, and the neighbour's window it may move to.
        fy, fx = y0 + by, x0 + bx
        sy0, sx0 = max(fy - search, 0), max(fx - search, 0)
        sy1, sx1 = min(fy + bh + search, height), min(fx + bw + search, width)
        region_weight = region.astype(np.float32)
        cost = cv2.matchTemplate(intensity(neighbour[sy0:sy1, sx0:sx1]), intensity(target[fy:fy + bh, fx:fx + bw]),
                                 cv2.TM_SQDIFF, mask=region_weight)
        outside = cv2.matchTemplate((~neighbour_valid[sy0:sy1, sx0:sx1]).astype(np.float32), region_weight,
                                    cv2.TM_CCORR)
        cost[outside > 0.5] = np.inf  # placements touching pixels the neighbour does not have
        if not np.isfinite(cost).any():
            continue
        iy, ix = np.unravel_index(int(np.argmin(cost)), cost.shape)
        dx, dy = sx0 + ix - fx, sy0 + iy - fy
        if abs(dx) >= search or abs(dy) >= search:
            continue  # the best match is on the search's edge: the true one may lie beyond, do not guess
        translation = np.empty((bh, bw, 2), np.float32)
        translation[...] = (dx, dy)
        sub = (slice(by, by + bh), slice(bx, bx + bw))
        error_after = _warp_error(box_target[sub], neighbour, translation, (fy, fx))
        better = region & (error_after < 0.5 * error[sub]) & (error_after < config.rescue_error)
        box_flow[sub][better] = (dx, dy)


def fill_invalid(grey: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``grey`` (uint8) with its invalid pixels replaced by a smooth push-pull interpolation of the valid ones."""
    if valid.all() or not valid.any():
        return grey.copy()
    weight = valid.astype(np.float32)
    values = grey.astype(np.float32) * weight
    levels: list[tuple[np.ndarray, np.ndarray]] = []
    # Push: average the valid pixels down the pyramid until every pixel has some weight.
    while True:
        levels.append((values, weight))
        if weight.min() > 0 or min(weight.shape) <= 2:
            break
        values, weight = cv2.pyrDown(values), cv2.pyrDown(weight)
    filled = values / np.maximum(weight, np.float32(1e-6))
    # Pull: fill each finer level's weak pixels from the coarser estimate, blending by the level's weight.
    for values, weight in reversed(levels[:-1]):
        coarse = cv2.pyrUp(filled, dstsize=(weight.shape[1], weight.shape[0]))
        _blend_in_place(coarse, values, weight)
        filled = coarse
    # (numpy, not a numba loop: numba 0.68.1 miscompiles that masked uint8 store and writes valid pixels too)
    return np.where(valid, grey, _round_to_uint8(filled))


@njit(cache=True, nogil=True)
def _blend_in_place(coarse: np.ndarray, values: np.ndarray, weight: np.ndarray) -> None:
    """coarse = w * (values / w) + (1 - w) * coarse, weights in 0..1 (the pull step; one pass, no temporaries)."""
    for y in range(coarse.shape[0]):
        for x in range(coarse.shape[1]):
            w = weight[y, x]
            coarse[y, x] = w * (values[y, x] / max(w, np.float32(1e-6))) + (np.float32(1.0) - w) * coarse[y, x]


# ---------------------------------------------------------------------- methods


def _grey(rgb: np.ndarray) -> np.ndarray:
    return _round_to_uint8(intensity(rgb))


def _round_to_uint8(values: np.ndarray) -> np.ndarray:
    """``np.clip(np.round(values), 0, 255).astype(np.uint8)`` for float32 values >= 0 (intensities, averages of
    them), in one OpenCV pass instead of three: its saturating cast rounds half to even as np.round does, and
    the absolute value it takes first changes nothing there."""
    return cv2.convertScaleAbs(values)


def _dis(first: np.ndarray, second: np.ndarray, config: LocalFlowConfig) -> np.ndarray:
    dis = cv2.DISOpticalFlow_create(DIS_PRESETS[config.dis_preset])
    if config.dis_finest_scale is not None:
        dis.setFinestScale(config.dis_finest_scale)
    return dis.calc(first, second, None)


def _farneback(first: np.ndarray, second: np.ndarray, config: LocalFlowConfig) -> np.ndarray:
    return cv2.calcOpticalFlowFarneback(first, second, None, pyr_scale=0.5, levels=config.farneback_levels,
                                        winsize=config.farneback_window, iterations=config.farneback_iterations,
                                        poly_n=5, poly_sigma=1.1, flags=0)


def _sparse_lk(first: np.ndarray, second: np.ndarray, common: np.ndarray, config: LocalFlowConfig) -> np.ndarray:
    """LK at grid cell centres inside the common area, the grid's gaps filled, then resized to full resolution."""
    height, width = first.shape
    step = config.lk_grid_step
    rows, cols = -(-height // step), -(-width // step)
    # Cell (i, j) has its centre at ((j + 0.5) step - 0.5, (i + 0.5) step - 0.5): exactly where cv2.resize
    # (INTER_LINEAR, by `step`) puts coarse pixel (i, j).
    gy, gx = np.mgrid[0:rows, 0:cols]
    px = np.minimum((gx + 0.5) * step - 0.5, width - 1).astype(np.float32)
    py = np.minimum((gy + 0.5) * step - 0.5, height - 1).astype(np.float32)
    inside = common[np.round(py).astype(int), np.round(px).astype(int)]
    grid = np.zeros((rows, cols, 2), np.float32)
    tracked = np.zeros((rows, cols), bool)
    if inside.any():
        points = np.stack([px[inside], py[inside]], axis=1).reshape(-1, 1, 2)
        lk = dict(winSize=(config.lk_window, config.lk_window), maxLevel=config.lk_levels,
                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01))
        moved, status, _ = cv2.calcOpticalFlowPyrLK(first, second, points, None, **lk)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(second, first, moved, None, **lk)
        fb_error = np.linalg.norm((back - points).reshape(-1, 2), axis=1)
        ok = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb_error < config.lk_max_fb_error_px)
        index = np.flatnonzero(inside.ravel())[ok]
        grid.reshape(-1, 2)[index] = (moved - points).reshape(-1, 2)[ok]
        tracked.reshape(-1)[index] = True
    if not tracked.any():
        return np.zeros((height, width, 2), np.float32)
    grid = np.stack([_fill_float(grid[..., c], tracked) for c in range(2)], axis=-1)
    dense = cv2.resize(grid, (cols * step, rows * step), interpolation=cv2.INTER_LINEAR)
    return dense[:height, :width]


def _fill_float(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Unknown entries of a grid take the value of the nearest known one."""
    if known.all():
        return values
    from scipy.ndimage import distance_transform_edt  # here: scipy.ndimage takes ~0.3 s to import, LK alone needs it

    _, (iy, ix) = distance_transform_edt(~known, return_indices=True)
    return values[iy, ix]
