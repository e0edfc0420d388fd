"""Full-frame video completion (thesis chapter 4): the ordered chain that fills a stabilized frame's missing area.

1. consistent mosaicing (eqs. 20-22): static areas, median of neighbours that agree;
2. for neighbours in priority order (eq. 23): local flow over the common area, motion inpainting of
   that flow into the missing area by Fast Marching (eq. 24), local-warp mosaicing through it (eq. 25),
   until nothing is missing;
3. a smooth last-resort fill for what no neighbour covers.

Every neighbour arrives already warped into the target's stabilized coordinates, with its valid mask.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import cv2
import numpy as np

from pipeline import fallback, fmm, local_flow, mosaic, smoothing, warping

# What filled each pixel (CompletionResult.source).
SOURCE_ORIGINAL, SOURCE_MOSAIC, SOURCE_LOCAL_WARP, SOURCE_FALLBACK = 0, 1, 2, 3
SOURCE_NAMES = ("original", "mosaic", "local warp", "fallback")
NEAR_MISSING_PX = 12  # motion inpainting works within this distance of the missing area (> flow's erosion)


@dataclass(frozen=True)
class CompletionConfig:
    radius: int = 6  # neighbours t-r..t+r take part (mosaic and local warp)
    max_warp_neighbours: int = 4  # local-warp loop stops after this many neighbours
    mosaic: mosaic.MosaicConfig = field(default_factory=mosaic.MosaicConfig)
    flow: local_flow.LocalFlowConfig = field(default_factory=local_flow.LocalFlowConfig)
    inpaint: fmm.MotionInpaintConfig = field(default_factory=fmm.MotionInpaintConfig)

    def __post_init__(self) -> None:
        if self.radius < 0:
            raise ValueError(f"completion radius must be >= 0, not {self.radius}")


@dataclass(frozen=True)
class WarpedNeighbour:
    offset: int  # t' - t
    rgb: np.ndarray  # neighbour t' in t's stabilized coordinates
    valid: np.ndarray  # bool: pixels the neighbour covers


@dataclass(frozen=True)
class NeighbourFill:
    """One turn of the local-warp loop: a neighbour, its flow, the inpainted flow, what it filled."""

    offset: int
    alignment_error: float
    flow: local_flow.LocalFlowResult
    inpainted: fmm.MotionInpaintResult
    filled: np.ndarray  # bool


@dataclass(frozen=True)
class CompletionResult:
    frame: np.ndarray  # completed (H, W, 3) uint8
    missing: np.ndarray  # the stabilized frame's missing mask this started from
    mosaic: mosaic.MosaicResult
    neighbour_order: list[int]  # offsets by priority (eq. 23)
    fills: list[NeighbourFill]
    source: np.ndarray  # (H, W) uint8: SOURCE_* per pixel
    filled_by: np.ndarray  # (H, W) int16: neighbour offset of local-warp pixels, 0 elsewhere
    fallback: np.ndarray  # (H, W) bool: pixels the last resort filled


def warp_neighbours(frames: dict[int, np.ndarray], t: int, curr_from_prev: np.ndarray, orig_from_stab_t: np.ndarray,
                    ) -> list[WarpedNeighbour]:
    """Original neighbour frames {t': rgb} brought into frame t's stabilized coordinates.

    A neighbour's pixel for stabilized point p of frame t is at t'_from_t @ S_t p; the chain t'_from_t is
    at most ``radius`` inter-frame transforms long.
    """
    if not frames:
        return []
    first, last = min(frames), max(frames)
    t_from = smoothing.neighbour_transforms(curr_from_prev, t, min(first, t), max(last, t))
    warped = []
    for t_other in sorted(frames, key=lambda i: (abs(i - t), i)):
        other_from_stab = np.linalg.inv(t_from[t_other]) @ orig_from_stab_t
        result = warping.warp_frame(frames[t_other], other_from_stab)
        warped.append(WarpedNeighbour(t_other - t, result.frame, ~result.missing))
    return warped


def complete(target: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
             config: CompletionConfig = CompletionConfig()) -> CompletionResult:
    """Fill ``missing`` pixels of the stabilized ``target`` from its warped neighbours."""
    height, width = missing.shape
    source = np.where(missing, SOURCE_FALLBACK, SOURCE_ORIGINAL).astype(np.uint8)
    filled_by = np.zeros((height, width), np.int16)
    mosaic_result = mosaic.consistent_mosaic(target, missing, [n.rgb for n in neighbours],
                                             [n.valid for n in neighbours], config.mosaic)
    frame = mosaic_result.frame.copy()
    source[mosaic_result.accepted] = SOURCE_MOSAIC
    remaining = mosaic_result.remaining.copy()

    known = ~missing
    errors = [local_flow.alignment_error(target, known, n.rgb, n.valid) for n in neighbours]
    order = sorted(range(len(neighbours)), key=lambda i: (errors[i], abs(neighbours[i].offset)))
    fills: list[NeighbourFill] = []
    near_missing = cv2.dilate(missing.astype(np.uint8), np.ones((NEAR_MISSING_PX * 2 + 1,) * 2, np.uint8)) > 0
    for i in order:
        if not remaining.any() or len(fills) >= config.max_warp_neighbours:
            break
        neighbour = neighbours[i]
        if not np.isfinite(errors[i]) or not (neighbour.valid & remaining).any():
            continue  # no overlap to measure flow on, or nothing this neighbour could fill
        flow = local_flow.local_flow(target, known, neighbour.rgb, neighbour.valid, config.flow)
        # Propagate over everything not known near the hole: the common area is eroded, so the band
        # between it and the missing area must be crossed too.
        region = ~flow.common & near_missing
        inpainted = fmm.inpaint_motion(flow.flow, flow.common, neighbour.rgb, neighbour_valid=neighbour.valid,
                                       region=region, config=config.inpaint)
        filled = _local_warp(frame, remaining, inpainted, neighbour)
        remaining &= ~filled
        source[filled] = SOURCE_LOCAL_WARP
        filled_by[filled] = neighbour.offset
        fills.append(NeighbourFill(neighbour.offset, errors[i], flow, inpainted, filled))

    if remaining.any():
        frame = fallback.smooth_fill(frame, remaining)
    return CompletionResult(frame=frame, missing=missing, mosaic=mosaic_result,
                            neighbour_order=[neighbours[i].offset for i in order], fills=fills, source=source,
                            filled_by=filled_by, fallback=remaining)


def _local_warp(frame: np.ndarray, remaining: np.ndarray, inpainted: fmm.MotionInpaintResult,
                neighbour: WarpedNeighbour) -> np.ndarray:
    """Eq. 25: I_t(p) <- I_t'(p + F(p)) for remaining pixels with a flow landing inside the neighbour.

    Writes into ``frame``; returns the pixels filled. Works inside the bounding box of what remains.
    """
    candidates = remaining & ~np.isnan(inpainted.flow[..., 0])
    ys, xs = np.nonzero(candidates)
    if len(ys) == 0:
        return np.zeros_like(remaining)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    flow = inpainted.flow[y0:y1, x0:x1]
    grid_x, grid_y = np.meshgrid(np.arange(x0, x1, dtype=np.float32), np.arange(y0, y1, dtype=np.float32))
    map_x = grid_x + np.nan_to_num(flow[..., 0], nan=-1e6)
    map_y = grid_y + np.nan_to_num(flow[..., 1], nan=-1e6)
    sampled = cv2.remap(neighbour.rgb, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    coverage = cv2.remap(neighbour.valid.astype(np.uint8) * 255, map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT)
    # Only where every bilinear tap was a valid neighbour pixel: no black bleeding in from its border.
    ok = candidates[y0:y1, x0:x1] & (coverage == 255)
    frame[y0:y1, x0:x1][ok] = sampled[ok]
    filled = np.zeros_like(remaining)
    filled[y0:y1, x0:x1] = ok
    return filled
