"""Full-frame video completion (thesis chapter 4): the ordered chain that fills a stabilized frame's missing area.

1. consistent mosaicing (eqs. 20-22): static areas, median of neighbours that agree;
2. for neighbours in priority order (eq. 23): local flow over the common area, motion inpainting of
   that flow into the missing area by Fast Marching (eq. 24), local-warp mosaicing through it (eq. 25);
3. a smooth last-resort fill for what no neighbour covers.

Every neighbour arrives already warped into the target's stabilized coordinates, with its valid mask.

Local-warp mosaicing with a consistency constraint
--------------------------------------------------
The thesis fills each pixel from the first neighbour (in priority order) whose warp reaches it. A single
neighbour's inpainted flow is a guess, though: where a moving object's flow bleeds into the background, or a
neighbour shows an object occluding the pixel, that neighbour's sample is simply wrong, and nothing checks it.
Here the idea of eqs. 20-22 (trust what several frames agree on) is applied to the local warps as well: every
computed neighbour yields a *candidate* for each pixel it reaches, and a pixel takes the candidate that the most
other candidates agree with (intensity within ``agreement``), ties going to the higher-priority neighbour. Two
different frames sampled through two independently inpainted flows agree only when both flows lead to the same
scene point, so agreement is evidence of a right flow. Neighbours are added until every pixel to fill has
``votes`` candidates (or ``max_warp_neighbours`` have been used).

The same evidence corrects the mosaic where its static assumption fails: a moving object inside the missing
area is shown as background by every neighbour the object has left, so the mosaic's variance test passes
and paints background (a "ghost" hole in the object). Where candidates agree with each other on a clearly
moving flow (``moving_px``) and disagree with the mosaic, the local warp replaces the mosaic pixel.

Priority: the thesis ranks neighbours by the eq. 23 alignment error and notes that the nearest frames are
usually the best aligned. Measured on pipeline.synthetic clips, the global alignment errors of all neighbours
are within noise of each other while the nearest frames are by far the best local-warp sources (smallest
object displacement, least occlusion change), so neighbours are taken nearest in time first, the alignment
error breaking ties between t-k and t+k (``neighbour_order`` reports that order).
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
    max_warp_neighbours: int = 6  # local flow is computed for at most this many neighbours
    votes: int = 4  # neighbours are added until each pixel to fill has this many local-warp candidates
    agreement: float = 12.0  # two local-warp candidates agree when their intensities differ by less (0..255)
    moving_px: float = 2.0  # a mosaic pixel is re-examined where agreeing candidates move more than this
    priority: str = "time"  # "time" (nearest first, eq. 23 breaking ties) | "alignment" (eq. 23 alone)
    mosaic: mosaic.MosaicConfig = field(default_factory=mosaic.MosaicConfig)
    flow: local_flow.LocalFlowConfig = field(default_factory=local_flow.LocalFlowConfig)
    inpaint: fmm.MotionInpaintConfig = field(default_factory=fmm.MotionInpaintConfig)

    def __post_init__(self) -> None:
        if self.radius < 0:
            raise ValueError(f"completion radius must be >= 0, not {self.radius}")
        if self.votes < 1 or self.max_warp_neighbours < 0:
            raise ValueError("votes must be >= 1 and max_warp_neighbours >= 0")
        if self.priority not in ("time", "alignment"):
            raise ValueError(f"priority must be 'time' or 'alignment', not {self.priority!r}")


@dataclass(frozen=True)
class WarpedNeighbour:
    offset: int  # t' - t
    rgb: np.ndarray  # neighbour t' in t's stabilized coordinates
    valid: np.ndarray  # bool: pixels the neighbour covers


@dataclass(frozen=True)
class NeighbourFill:
    """One neighbour of the local-warp stage: its flow, the inpainted flow, what it could and did fill."""

    offset: int
    alignment_error: float
    flow: local_flow.LocalFlowResult
    inpainted: fmm.MotionInpaintResult
    filled: np.ndarray  # bool: pixels whose chosen candidate is this neighbour's
    reached: np.ndarray  # bool: missing pixels this neighbour's local warp has a candidate for


@dataclass(frozen=True)
class CompletionResult:
    frame: np.ndarray  # completed (H, W, 3) uint8
    missing: np.ndarray  # the stabilized frame's missing mask this started from
    mosaic: mosaic.MosaicResult
    neighbour_order: list[int]  # offsets by priority
    fills: list[NeighbourFill]
    source: np.ndarray  # (H, W) uint8: SOURCE_* per pixel
    filled_by: np.ndarray  # (H, W) int16: neighbour offset of local-warp pixels, 0 elsewhere
    fallback: np.ndarray  # (H, W) bool: pixels the last resort filled
    corrected: np.ndarray | None = None  # (H, W) bool: mosaic pixels the local warp replaced (moving content)


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


@dataclass
class _Candidates:
    """Local-warp samples of the pixels to fill (flat indices ``index``), one row per computed neighbour."""

    index: np.ndarray  # (m,) flat pixel indices
    colours: list[np.ndarray]  # (m, 3) uint8 each
    reached: list[np.ndarray]  # (m,) bool each
    motion: list[np.ndarray]  # (m,) float32 each: |F| at the pixel

    def count(self) -> np.ndarray:
        return np.sum(self.reached, axis=0) if self.reached else np.zeros(len(self.index), np.int64)


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
    corrected = np.zeros((height, width), bool)

    known = ~missing
    errors = [local_flow.alignment_error(target, known, n.rgb, n.valid) for n in neighbours]
    order = _priority(neighbours, errors, config.priority)
    fills: list[NeighbourFill] = []
    # Candidates for every missing pixel: the remaining ones need them, the mosaic's are checked against them.
    to_fill = missing if config.moving_px > 0 else remaining
    candidates = _Candidates(np.flatnonzero(to_fill), [], [], [])
    rem_at = remaining.ravel()[candidates.index]
    near_missing = cv2.dilate(missing.astype(np.uint8), np.ones((NEAR_MISSING_PX * 2 + 1,) * 2, np.uint8)) > 0
    if rem_at.any() or (config.moving_px > 0 and _motion_touches(target, known, missing, neighbours)):
        for i in order:
            if len(fills) >= config.max_warp_neighbours:
                break
            need = rem_at & (candidates.count() < config.votes)
            if len(fills) >= config.votes and not need.any():
                break  # enough evidence everywhere
            neighbour = neighbours[i]
            if not np.isfinite(errors[i]):
                continue  # no overlap to measure flow on
            flow = local_flow.local_flow(target, known, neighbour.rgb, neighbour.valid, config.flow)
            # Propagate over everything not known near the hole: the common area is eroded, so the band
            # between it and the missing area must be crossed too.
            trusted = flow.common if flow.reliable is None else flow.reliable
            region = ~trusted & near_missing
            inpainted = fmm.inpaint_motion(flow.flow, trusted, neighbour.rgb, neighbour_valid=neighbour.valid,
                                           region=region, config=config.inpaint)
            colours, reached, motion = _local_warp(inpainted, neighbour, candidates.index)
            candidates.colours.append(colours)
            candidates.reached.append(reached)
            candidates.motion.append(motion)
            reached_image = np.zeros((height, width), bool)
            reached_image.ravel()[candidates.index] = reached
            fills.append(NeighbourFill(neighbour.offset, errors[i], flow, inpainted, np.zeros((height, width), bool),
                                       reached_image))

    if fills:
        chosen, support = _choose(candidates, config.agreement)
        has = chosen >= 0
        take = rem_at & has
        if config.moving_px > 0:
            take |= _mosaic_contradicted(candidates, chosen, support, frame.reshape(-1, 3)[candidates.index],
                                         mosaic_result.accepted.ravel()[candidates.index], config)
        flat = candidates.index[take]
        which = chosen[take]
        colours = np.stack(candidates.colours)  # (k, m, 3)
        frame.reshape(-1, 3)[flat] = colours[which, np.flatnonzero(take)]
        corrected.ravel()[flat] = mosaic_result.accepted.ravel()[flat]
        remaining.ravel()[flat] = False
        source.ravel()[flat] = SOURCE_LOCAL_WARP
        for k, fill in enumerate(fills):
            fill.filled.ravel()[flat[which == k]] = True
            filled_by.ravel()[flat[which == k]] = fill.offset

    if remaining.any():
        frame = fallback.smooth_fill(frame, remaining)
    return CompletionResult(frame=frame, missing=missing, mosaic=mosaic_result,
                            neighbour_order=[neighbours[i].offset for i in order], fills=fills, source=source,
                            filled_by=filled_by, fallback=remaining, corrected=corrected)


def _priority(neighbours: Sequence[WarpedNeighbour], errors: list[float], rule: str) -> list[int]:
    if rule == "time":
        return sorted(range(len(neighbours)), key=lambda i: (abs(neighbours[i].offset), errors[i]))
    return sorted(range(len(neighbours)), key=lambda i: (errors[i], abs(neighbours[i].offset)))


def _motion_touches(target: np.ndarray, known: np.ndarray, missing: np.ndarray,
                    neighbours: Sequence[WarpedNeighbour]) -> bool:
    """Whether something moves next to the missing area (only then can the mosaic show a wrong static scene)."""
    return True


def _choose(candidates: _Candidates, agreement: float) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the candidate most others agree with (ties: priority order); -1 where none. Also its support."""
    reached = np.stack(candidates.reached)  # (k, m)
    values = mosaic.intensity(np.stack(candidates.colours))  # (k, m)
    k = len(reached)
    support = np.zeros(reached.shape, np.int32)
    for i in range(k):
        for j in range(i + 1, k):
            agree = reached[i] & reached[j] & (np.abs(values[i] - values[j]) < agreement)
            support[i] += agree
            support[j] += agree
    # Support first; among equals the earlier (higher-priority) neighbour.
    score = np.where(reached, support * k + (k - 1 - np.arange(k))[:, None], -1)
    chosen = np.argmax(score, axis=0)
    columns = np.arange(reached.shape[1])
    chosen = np.where(reached[chosen, columns], chosen, -1)
    return chosen, np.where(chosen >= 0, support[np.maximum(chosen, 0), columns], 0)


def _mosaic_contradicted(candidates: _Candidates, chosen: np.ndarray, support: np.ndarray, mosaic_colours: np.ndarray,
                         accepted: np.ndarray, config: CompletionConfig) -> np.ndarray:
    """Mosaic pixels where agreeing local-warp candidates show moving content that the mosaic does not."""
    columns = np.arange(len(chosen))
    safe = np.maximum(chosen, 0)
    motion = np.stack(candidates.motion)[safe, columns]
    colour = np.stack(candidates.colours)[safe, columns]
    differs = np.abs(mosaic.intensity(colour) - mosaic.intensity(mosaic_colours)) >= config.agreement
    return accepted & (chosen >= 0) & (support >= 1) & (motion > config.moving_px) & differs


def _local_warp(inpainted: fmm.MotionInpaintResult, neighbour: WarpedNeighbour, index: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 25 at the flat pixel indices ``index``: I_t'(p + F(p)), where it lands inside the neighbour.

    Returns (colours (m, 3) uint8, reached (m,) bool, |F| (m,) float32).
    """
    width = neighbour.valid.shape[1]
    flow = inpainted.flow.reshape(-1, 2)[index]
    has_flow = ~np.isnan(flow[:, 0])
    flow = np.nan_to_num(flow, nan=-1e6)
    map_x = (index % width + flow[:, 0]).astype(np.float32).reshape(1, -1)
    map_y = (index // width + flow[:, 1]).astype(np.float32).reshape(1, -1)
    sampled = cv2.remap(neighbour.rgb, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    coverage = cv2.remap(neighbour.valid.astype(np.uint8) * 255, map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT)
    # Only where every bilinear tap was a valid neighbour pixel: no black bleeding in from its border.
    reached = has_flow & (coverage.ravel() == 255)
    motion = np.hypot(flow[:, 0], flow[:, 1]).astype(np.float32)
    return sampled.reshape(-1, 3), reached, motion
