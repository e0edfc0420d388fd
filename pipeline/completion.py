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

from scipy import ndimage

from pipeline import fallback, fmm, local_flow, mosaic, smoothing, warping

# What filled each pixel (CompletionResult.source).
SOURCE_ORIGINAL, SOURCE_MOSAIC, SOURCE_LOCAL_WARP, SOURCE_FALLBACK = 0, 1, 2, 3
SOURCE_NAMES = ("original", "mosaic", "local warp", "fallback")
NEAR_MISSING_PX = 12  # motion inpainting works within this distance of the missing area (> flow's erosion)


@dataclass(frozen=True)
class CompletionConfig:
    radius: int = 6  # neighbours t-r..t+r take part (mosaic and local warp)
    max_warp_neighbours: int = 4  # local flow is computed for at most this many neighbours
    votes: int = 4  # neighbours are added until each pixel to fill has this many local-warp candidates
    agreement: float = 12.0  # two local-warp candidates agree when their intensities differ by less (0..255)
    moving_px: float = 2.0  # a mosaic pixel is re-examined where agreeing candidates move more than this
    agreement_window: int = 1  # agreement is judged on the mean difference over this window (px, odd)
    static_votes: bool = False  # neighbours' plain samples vote for candidates that hardly move
    residual_radius: int = 4  # local alignment error window (px)
    choice: str = "residual"  # "support" (ties: residual) | "residual" | "priority" (support, ties: priority)
    residual_weight: float = 0.0  # with "support": score = support - weight * residual
    static_rule: str = "median"
    static_margin: float = 5.0
    motion_evidence: bool = False
    flow_fill: str = "neighbour"
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
    """Local-warp samples inside the bounding box of the pixels to fill, one entry per computed neighbour."""

    box: tuple[slice, slice]
    to_fill: np.ndarray  # (h, w) bool, the box's pixels to fill
    nearest_known: tuple[np.ndarray, np.ndarray]  # (h, w) row, column of each pixel's nearest known pixel
    sources: list[int] = field(default_factory=list)  # index of the neighbour behind each entry
    colours: list[np.ndarray] = field(default_factory=list)  # (h, w, 3) uint8
    reached: list[np.ndarray] = field(default_factory=list)  # (h, w) bool: the warp landed on neighbour content
    motion: list[np.ndarray] = field(default_factory=list)  # (h, w) float32: |F|
    residual: list[np.ndarray] = field(default_factory=list)  # (h, w) float32: local alignment error after the warp

    def count(self) -> np.ndarray:
        return np.sum(self.reached, axis=0) if self.reached else np.zeros(self.to_fill.shape, np.int64)


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
    check_mosaic = config.moving_px > 0 and _motion_touches(target, known, missing, neighbours)
    to_fill = missing if check_mosaic else remaining
    box = _bounding_box(to_fill, NEAR_MISSING_PX)
    if box is not None and (remaining.any() or check_mosaic):
        _, nearest = ndimage.distance_transform_edt(missing[box], return_indices=True)
        candidates = _Candidates(box, to_fill[box], (nearest[0], nearest[1]))
        near_missing = cv2.dilate(missing.astype(np.uint8), np.ones((NEAR_MISSING_PX * 2 + 1,) * 2, np.uint8)) > 0
        for i in order:
            if len(fills) >= config.max_warp_neighbours:
                break
            neighbour = neighbours[i]
            if len(fills) >= config.votes:
                # Enough candidates: further neighbours only for remaining pixels nothing has reached yet.
                unreached = remaining[box] & (candidates.count() == 0)
                if not unreached.any():
                    break
                if not (unreached & neighbour.valid[box]).any():
                    continue
            if not np.isfinite(errors[i]):
                continue  # no overlap to measure flow on
            if config.flow_fill == "mosaic":
                flow = local_flow.local_flow(target, known, neighbour.rgb, neighbour.valid, config.flow,
                                             target_fill=mosaic_result.frame, target_fill_valid=mosaic_result.accepted)
            elif config.flow_fill == "smooth":
                flow = local_flow.local_flow(target, known, neighbour.rgb, neighbour.valid, config.flow,
                                             target_fill=target, target_fill_valid=known)
            else:
                flow = local_flow.local_flow(target, known, neighbour.rgb, neighbour.valid, config.flow)
            # Propagate over everything not trusted near the hole: the common area is eroded, so the band
            # between it and the missing area must be crossed too.
            trusted = flow.common if flow.reliable is None else flow.reliable
            region = ~trusted & near_missing
            inpainted = fmm.inpaint_motion(flow.flow, trusted, neighbour.rgb, neighbour_valid=neighbour.valid,
                                           region=region, config=config.inpaint)
            colours, reached, motion = _local_warp(inpainted, neighbour, box)
            candidates.sources.append(i)
            candidates.colours.append(colours)
            candidates.reached.append(reached & candidates.to_fill)
            candidates.motion.append(motion)
            candidates.residual.append(_local_residual(target[box], known[box], colours, reached,
                                                       candidates.nearest_known, config))
            reached_image = np.zeros((height, width), bool)
            reached_image[box] = candidates.reached[-1]
            fills.append(NeighbourFill(neighbour.offset, errors[i], flow, inpainted, np.zeros((height, width), bool),
                                       reached_image))

        if fills:
            static = _static_residual(target[box], known[box], neighbours, box, candidates.nearest_known, config)
            chosen, support = _choose(candidates, neighbours, static, config)
            has = chosen >= 0
            take = remaining[box] & has
            if check_mosaic:
                take |= _mosaic_contradicted(candidates, chosen, support, static, frame[box],
                                             mosaic_result.accepted[box], config)
            ys, xs = np.nonzero(take)
            which = chosen[ys, xs]
            colours = np.stack(candidates.colours)
            frame[box][ys, xs] = colours[which, ys, xs]
            take_image = np.zeros((height, width), bool)
            take_image[box] = take
            corrected = take_image & mosaic_result.accepted
            remaining &= ~take_image
            source[take_image] = SOURCE_LOCAL_WARP
            for k, fill in enumerate(fills):
                fill.filled[box][ys[which == k], xs[which == k]] = True
                filled_by[box][ys[which == k], xs[which == k]] = fill.offset

    if remaining.any():
        frame = fallback.smooth_fill(frame, remaining)
    return CompletionResult(frame=frame, missing=missing, mosaic=mosaic_result,
                            neighbour_order=[neighbours[i].offset for i in order], fills=fills, source=source,
                            filled_by=filled_by, fallback=remaining, corrected=corrected)


def _bounding_box(mask: np.ndarray, margin: int = 0) -> tuple[slice, slice] | None:
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    height, width = mask.shape
    return (slice(max(int(rows[0]) - margin, 0), min(int(rows[-1]) + 1 + margin, height)),
            slice(max(int(cols[0]) - margin, 0), min(int(cols[-1]) + 1 + margin, width)))


def _local_residual(target: np.ndarray, known: np.ndarray, warped: np.ndarray, reached: np.ndarray,
                    nearest_known: tuple[np.ndarray, np.ndarray], config: CompletionConfig) -> np.ndarray:
    """Eq. 23 made local and measured after the local warp: mean |I_t - warped| over the known pixels
    around each pixel's nearest known pixel (255 where none was reached)."""
    usable = (known & reached).astype(np.float32)
    error = np.abs(mosaic.intensity(target) - mosaic.intensity(warped)) * usable
    size = (2 * config.residual_radius + 1,) * 2
    total = cv2.boxFilter(error, -1, size, normalize=False)
    count = cv2.boxFilter(usable, -1, size, normalize=False)
    local = np.where(count > 0, total / np.maximum(count, 1), np.float32(255))
    return local[nearest_known]


def _priority(neighbours: Sequence[WarpedNeighbour], errors: list[float], rule: str) -> list[int]:
    if rule == "time":
        return sorted(range(len(neighbours)), key=lambda i: (abs(neighbours[i].offset), errors[i]))
    return sorted(range(len(neighbours)), key=lambda i: (errors[i], abs(neighbours[i].offset)))


def _motion_touches(target: np.ndarray, known: np.ndarray, missing: np.ndarray,
                    neighbours: Sequence[WarpedNeighbour]) -> bool:
    """Whether something moves next to the missing area (only then can the mosaic show a wrong static scene)."""
    return True


def _agreement(a: np.ndarray, reached_a: np.ndarray, b: np.ndarray, reached_b: np.ndarray,
               config: CompletionConfig) -> np.ndarray:
    """Where two candidate intensity images agree: mean |a - b| over a small window below ``agreement``."""
    both = (reached_a & reached_b).astype(np.float32)
    difference = np.abs(a - b) * both
    if config.agreement_window > 1:
        size = (config.agreement_window, config.agreement_window)
        difference = cv2.boxFilter(difference, -1, size, normalize=False)
        count = cv2.boxFilter(both, -1, size, normalize=False)
        return (both > 0) & (difference < config.agreement * np.maximum(count, 1))
    return (both > 0) & (difference < config.agreement)


def _choose(candidates: _Candidates, neighbours: Sequence[WarpedNeighbour], static: np.ndarray,
            config: CompletionConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the candidate most others agree with (ties: priority order); -1 where none. Also its support."""
    reached = np.stack(candidates.reached)  # (k, h, w)
    values = [mosaic.intensity(c) for c in candidates.colours]
    k = len(values)
    support = np.zeros(reached.shape, np.int32)
    for i in range(k):
        for j in range(i + 1, k):
            agree = _agreement(values[i], reached[i], values[j], reached[j], config)
            support[i] += agree
            support[j] += agree
    if config.static_votes:
        # A candidate that hardly moves claims static scene: the other neighbours' plain samples can confirm it.
        box = candidates.box
        for i in range(k):
            static = reached[i] & (candidates.motion[i] <= config.moving_px)
            for n, neighbour in enumerate(neighbours):
                if n == candidates.sources[i]:
                    continue
                valid = neighbour.valid[box]
                support[i] += _agreement(values[i], static, mosaic.intensity(neighbour.rgb[box]), valid, config)
    residual = np.stack(candidates.residual)
    if config.choice == "priority":
        # Support first; among equals the earlier (higher-priority) neighbour.
        score = np.where(reached, support * k + (k - 1 - np.arange(k))[:, None, None], -1)
    elif config.choice == "residual":
        # Neighbours computed beyond the first ``votes`` only fill pixels none of those reached.
        late = (np.arange(k) >= config.votes)[:, None, None] * np.float32(1e4)
        score = np.where(reached, -residual - late, -np.inf)
        if config.motion_evidence:
            # A moving candidate must explain the surroundings clearly better than the static scene does.
            unproven = (np.stack(candidates.motion) > config.moving_px) & ~(residual + config.static_margin < static)
            score -= unproven * np.float32(1e3)
    else:
        score = np.where(reached, config.residual_weight * support - residual, -np.inf)
    chosen = np.argmax(score, axis=0)
    chosen_reached = np.take_along_axis(reached, chosen[None], 0)[0]
    chosen_support = np.take_along_axis(support, chosen[None], 0)[0]
    return np.where(chosen_reached, chosen, -1), np.where(chosen_reached, chosen_support, 0)


def _static_residual(target: np.ndarray, known: np.ndarray, neighbours: Sequence[WarpedNeighbour],
                     box: tuple[slice, slice], nearest_known: tuple[np.ndarray, np.ndarray],
                     config: CompletionConfig) -> np.ndarray:
    """Local alignment error of the static hypothesis (no local motion) that the mosaic rests on."""
    residuals = np.stack([_local_residual(target, known, n.rgb[box], n.valid[box], nearest_known, config)
                          for n in neighbours])
    return np.median(residuals, axis=0) if config.static_rule == "median" else residuals.min(axis=0)


def _mosaic_contradicted(candidates: _Candidates, chosen: np.ndarray, support: np.ndarray, static: np.ndarray,
                         mosaic_colours: np.ndarray, accepted: np.ndarray, config: CompletionConfig) -> np.ndarray:
    """Mosaic pixels where a moving local-warp candidate explains the surroundings clearly better than
    the static scene the mosaic assumes, and shows something else."""
    safe = np.maximum(chosen, 0)[None]
    motion = np.take_along_axis(np.stack(candidates.motion), safe, 0)[0]
    colour = np.take_along_axis(np.stack(candidates.colours), safe[..., None], 0)[0]
    residual = np.take_along_axis(np.stack(candidates.residual), safe, 0)[0]
    differs = np.abs(mosaic.intensity(colour) - mosaic.intensity(mosaic_colours)) >= config.agreement
    moving = accepted & (chosen >= 0) & (motion > config.moving_px) & differs
    if config.static_rule == "support":
        return moving & (support >= 1)
    return moving & (residual + config.static_margin < static)


def _local_warp(inpainted: fmm.MotionInpaintResult, neighbour: WarpedNeighbour, box: tuple[slice, slice],
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 25 over the box: I_t'(p + F(p)) wherever p has a flow that lands inside the neighbour.

    Returns (colours (h, w, 3) uint8, reached (h, w) bool, |F| (h, w) float32).
    """
    rows, cols = box
    flow = inpainted.flow[box]
    has_flow = ~np.isnan(flow[..., 0])
    flow = np.where(has_flow[..., None], flow, np.float32(-1e6))
    grid_x, grid_y = np.meshgrid(np.arange(cols.start, cols.stop, dtype=np.float32),
                                 np.arange(rows.start, rows.stop, dtype=np.float32))
    map_x, map_y = grid_x + flow[..., 0], grid_y + flow[..., 1]
    sampled = cv2.remap(neighbour.rgb, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    coverage = cv2.remap(neighbour.valid.astype(np.uint8) * 255, map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT)
    # Only where every bilinear tap was a valid neighbour pixel: no black bleeding in from its border.
    reached = has_flow & (coverage == 255)
    motion = np.where(has_flow, np.hypot(flow[..., 0], flow[..., 1]), np.inf).astype(np.float32)
    return sampled, reached, motion
