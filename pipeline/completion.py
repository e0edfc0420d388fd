"""Full-frame video completion (thesis chapter 4): the ordered chain that fills a stabilized frame's missing area.

1. consistent mosaicing (eqs. 20-22): static areas, median of neighbours that agree;
2. for neighbours in priority order (eq. 23): local flow over the common area, motion inpainting of
   that flow into the missing area by Fast Marching (eq. 24), local-warp mosaicing through it (eq. 25);
3. a smooth last-resort fill for what no neighbour covers.

Every neighbour arrives already warped into the target's stabilized coordinates, with its valid mask.

Local-warp mosaicing, judged locally
------------------------------------
The thesis fills each pixel from the first neighbour (in priority order) whose warp reaches it. A single
neighbour's inpainted flow is a guess, though: where a moving object's flow bleeds into the background, or a
neighbour shows an object occluding the pixel, that neighbour's sample is simply wrong, and nothing checks it.
Here each of the ``max_warp_neighbours`` nearest neighbours yields a *candidate* for every pixel its warp
reaches, and a pixel takes the candidate whose warp best explains the visible surroundings it continues: eq. 23
made local (``_LocalError``: the mean intensity difference after the warp over the known pixels around the
pixel's nearest known pixel). A static sample that no other neighbour shows (an object that only passed there
in that frame) ranks after every confirmed one. (A first version with the thesis's first-neighbour rule
scored 2-4 dB below the mosaic+Telea baseline on the synthetic moving-object scenes: object flow painted
background.)

The same evidence corrects the mosaic where its static assumption fails: a moving object inside the missing
area is shown as background by every neighbour the object has left, so the variance test passes and paints
background (a "ghost" hole in the object). Where a clearly moving candidate (``moving_px``) explains the
surroundings better than the static scene by ``mosaic_check_margin``, it replaces the mosaic pixel. The cost:
object flow propagated just past the object's edge can replace correct background beside it
(tests/test_completion.py measures both sides).

Flows and motion inpainting run only in the bounding box of the pixels that need a local warp, grown by
``flow_margin_px``.

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
RESCUE_NEAR_MISSING_PX = 40  # large motions the flow missed are searched for this close to the missing area


@dataclass(frozen=True)
class CompletionConfig:
    radius: int = 6  # neighbours t-r..t+r take part (mosaic and local warp)
    max_warp_neighbours: int = 4  # local flow is computed for this many neighbours, nearest in time first
    residual_radius: int = 4  # local alignment error: mean over the (2r+1)^2 known pixels around the nearest one
    check_mosaic: bool = True  # let clearly moving local-warp candidates replace mosaic pixels
    moving_px: float = 2.0  # a candidate whose inpainted flow is longer than this shows moving content
    # A moving candidate replaces a mosaic pixel when its local alignment error is lower than that of the
    # static scene (no local motion) by more than this (intensity, 0..255).
    mosaic_check_margin: float = 5.0
    # Flows are computed in the bounding box of the pixels needing a local warp grown by this margin (px);
    # None: over the whole frame.
    flow_margin_px: int | None = 64
    confirm_difference: float | None = 20.0
    mosaic: mosaic.MosaicConfig = field(default_factory=mosaic.MosaicConfig)
    flow: local_flow.LocalFlowConfig = field(default_factory=local_flow.LocalFlowConfig)
    inpaint: fmm.MotionInpaintConfig = field(default_factory=fmm.MotionInpaintConfig)

    def __post_init__(self) -> None:
        if self.radius < 0:
            raise ValueError(f"completion radius must be >= 0, not {self.radius}")
        if self.max_warp_neighbours < 0:
            raise ValueError(f"max_warp_neighbours must be >= 0, not {self.max_warp_neighbours}")
        if self.residual_radius < 0:
            raise ValueError(f"residual_radius must be >= 0, not {self.residual_radius}")


@dataclass(frozen=True)
class WarpedNeighbour:
    offset: int  # t' - t
    rgb: np.ndarray  # neighbour t' in t's stabilized coordinates
    valid: np.ndarray  # bool: pixels the neighbour covers


@dataclass(frozen=True)
class NeighbourFill:
    """One neighbour of the local-warp stage: its flow, the inpainted flow, what it could and did fill."""

    offset: int
    alignment_error: float  # eq. 23 over the whole common area
    flow: local_flow.LocalFlowResult
    inpainted: fmm.MotionInpaintResult
    filled: np.ndarray  # bool: pixels this neighbour's local warp filled
    reached: np.ndarray | None = None  # bool: missing pixels its local warp had a sample for


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
class _Candidate:
    """One neighbour's local warp, sampled at the pixels to fill (vectors over those pixels)."""

    colours: np.ndarray  # (m, 3) uint8: I_t'(p + F(p))
    reached: np.ndarray  # (m,) bool: the warp landed on neighbour content
    motion: np.ndarray  # (m,) float32: |F(p)|
    error: np.ndarray  # (m,) float32: local alignment error after the warp (see _LocalError)
    confirmed: np.ndarray  # (m,) bool: moves, or another neighbour shows the same there (not a passing occluder)


class _LocalError:
    """Eq. 23 made local: for a pixel to fill, the mean |I_t - warped neighbour| over the known pixels
    within ``radius`` of its nearest known pixel, so that each pixel can be judged by how well a warp
    explains the visible surroundings it continues. Works inside ``box``."""

    def __init__(self, target: np.ndarray, known: np.ndarray, box: tuple[slice, slice], ys: np.ndarray,
                 xs: np.ndarray, radius: int) -> None:
        self.box = box
        self.known = known[box]
        self.intensity = mosaic.intensity(target[box])
        _, (near_y, near_x) = ndimage.distance_transform_edt(~self.known, return_indices=True)
        self.near_y, self.near_x = near_y[ys, xs], near_x[ys, xs]
        self.size = (2 * radius + 1,) * 2

    def __call__(self, warped: np.ndarray, landed: np.ndarray) -> np.ndarray:
        """(m,) errors for a warped image of the box; NaN where the warp reached none of those known pixels."""
        usable = (self.known & landed).astype(np.float32)
        difference = np.abs(self.intensity - mosaic.intensity(warped)) * usable
        total = cv2.boxFilter(difference, -1, self.size, normalize=False)[self.near_y, self.near_x]
        count = cv2.boxFilter(usable, -1, self.size, normalize=False)[self.near_y, self.near_x]
        return np.where(count > 0.5, total / np.maximum(count, 1), np.float32(np.nan))


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
    order = sorted(range(len(neighbours)), key=lambda i: (abs(neighbours[i].offset), errors[i]))
    fills: list[NeighbourFill] = []
    box = _bounding_box(missing, NEAR_MISSING_PX)
    if box is not None and config.max_warp_neighbours > 0 and neighbours:
        ys, xs = np.nonzero(missing[box])  # the pixels to fill, in box coordinates
        local_error = _LocalError(target, known, box, ys, xs, config.residual_radius)
        accepted = mosaic_result.accepted[box][ys, xs]
        # Mosaic pixels can only be replaced where the static scene explains the surroundings worse than the
        # margin (a candidate's error is >= 0): elsewhere nothing needs a flow.
        static_error = np.full(len(ys), -np.inf, np.float32)
        if config.check_mosaic and accepted.any():
            per_neighbour = np.stack([local_error(n.rgb[box], n.valid[box])[accepted] for n in neighbours])
            covered = ~np.isnan(per_neighbour).all(axis=0)  # no neighbour sees the surroundings: no evidence
            static_error[np.flatnonzero(accepted)[covered]] = np.nanmedian(per_neighbour[:, covered], axis=0)
        checked = accepted & (static_error > config.mosaic_check_margin)
        wanted = remaining[box][ys, xs] | checked
        if wanted.any():
            wanted_image = np.zeros((height, width), bool)
            wanted_image[box][ys[wanted], xs[wanted]] = True
            fills, candidates = _local_warps(target, known, missing, neighbours, order, errors, box, ys, xs,
                                             local_error, _work_box(wanted_image, config.flow_margin_px), config)
        if fills:
            chosen = _best_candidate(candidates)
            take = wanted & (chosen >= 0)
            take &= ~checked | _moving_and_better(candidates, chosen, static_error, config)
            pick = np.flatnonzero(take)
            which = chosen[pick]
            frame_box, source_box, filled_by_box = frame[box], source[box], filled_by[box]
            py, px = ys[pick], xs[pick]
            frame_box[py, px] = np.stack([c.colours for c in candidates])[which, pick]
            source_box[py, px] = SOURCE_LOCAL_WARP
            corrected[box][py, px] = accepted[pick]
            remaining[box][py, px] = False
            for k, fill in enumerate(fills):
                fill.filled[box][py[which == k], px[which == k]] = True
                filled_by_box[py[which == k], px[which == k]] = fill.offset

    if remaining.any():
        frame = fallback.smooth_fill(frame, remaining)
    return CompletionResult(frame=frame, missing=missing, mosaic=mosaic_result,
                            neighbour_order=[neighbours[i].offset for i in order], fills=fills, source=source,
                            filled_by=filled_by, fallback=remaining, corrected=corrected)


def _local_warps(target: np.ndarray, known: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
                 order: list[int], errors: list[float], box: tuple[slice, slice], ys: np.ndarray, xs: np.ndarray,
                 local_error: _LocalError, work: tuple[slice, slice], config: CompletionConfig,
                 ) -> tuple[list[NeighbourFill], list[_Candidate]]:
    """Steps 2-4 for the nearest ``max_warp_neighbours`` neighbours: local flow, motion inpainting, local warp.

    Flow and motion inpainting run inside the ``work`` box only (results are pasted into full-frame arrays).
    """
    height, width = missing.shape
    near_missing = _dilate(missing, NEAR_MISSING_PX)[work]
    rescue_focus = _dilate(missing, RESCUE_NEAR_MISSING_PX)[work]
    target_work, known_work = target[work], known[work]
    fills: list[NeighbourFill] = []
    candidates: list[_Candidate] = []
    for i in order:
        if len(fills) >= config.max_warp_neighbours:
            break
        neighbour = neighbours[i]
        if not np.isfinite(errors[i]):
            continue  # no overlap to measure flow on
        flow = local_flow.local_flow(target_work, known_work, neighbour.rgb[work], neighbour.valid[work], config.flow,
                                     focus=rescue_focus)
        trusted = flow.common if flow.reliable is None else flow.reliable
        # Propagate over everything untrusted near the hole: the common area is eroded, so the band between
        # it and the missing area must be crossed too.
        inpainted = fmm.inpaint_motion(flow.flow, trusted, neighbour.rgb[work], neighbour_valid=neighbour.valid[work],
                                       region=~trusted & near_missing, config=config.inpaint)
        flow, inpainted = _full_frame(flow, inpainted, work, (height, width))
        colours, landed, motion = _local_warp(inpainted, neighbour, box)
        # A warp whose surroundings cannot be checked ranks after every checked one.
        error = np.nan_to_num(local_error(colours, landed), nan=255.0)
        sample, moving = colours[ys, xs], motion[ys, xs] > config.moving_px
        confirmed = moving | _seen_by_another(sample, i, neighbours, box, ys, xs, config.confirm_difference)
        candidates.append(_Candidate(sample, landed[ys, xs], motion[ys, xs], error, confirmed))
        reached = np.zeros((height, width), bool)
        reached[box][ys, xs] = candidates[-1].reached
        fills.append(NeighbourFill(neighbour.offset, errors[i], flow, inpainted, np.zeros((height, width), bool),
                                   reached))
    return fills, candidates


def _work_box(wanted: np.ndarray, margin: int | None) -> tuple[slice, slice]:
    """Where flows are computed: around the pixels that need a local warp (``margin`` None: the whole frame)."""
    if margin is None:
        return slice(0, wanted.shape[0]), slice(0, wanted.shape[1])
    box = _bounding_box(wanted, margin)
    assert box is not None
    return box


def _full_frame(flow: local_flow.LocalFlowResult, inpainted: fmm.MotionInpaintResult, work: tuple[slice, slice],
                shape: tuple[int, int]) -> tuple[local_flow.LocalFlowResult, fmm.MotionInpaintResult]:
    """Results computed inside ``work`` as full-frame arrays (no flow outside it)."""
    def paste(values: np.ndarray, fill: float | bool) -> np.ndarray:
        out = np.full(shape + values.shape[2:], fill, values.dtype)
        out[work] = values
        return out

    reliable = None if flow.reliable is None else paste(flow.reliable, False)
    return (local_flow.LocalFlowResult(paste(flow.flow, 0.0), paste(flow.common, False), reliable),
            fmm.MotionInpaintResult(paste(inpainted.flow, np.nan), paste(inpainted.order, -1),
                                    paste(inpainted.arrival, np.inf), paste(inpainted.filled, False)))


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    return cv2.dilate(mask.astype(np.uint8), np.ones((2 * radius + 1,) * 2, np.uint8)) > 0


def _bounding_box(mask: np.ndarray, margin: int = 0) -> tuple[slice, slice] | None:
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    height, width = mask.shape
    return (slice(max(int(rows[0]) - margin, 0), min(int(rows[-1]) + 1 + margin, height)),
            slice(max(int(cols[0]) - margin, 0), min(int(cols[-1]) + 1 + margin, width)))


def _seen_by_another(sample: np.ndarray, source: int, neighbours: Sequence[WarpedNeighbour], box: tuple[slice, slice],
                     ys: np.ndarray, xs: np.ndarray, threshold: float | None) -> np.ndarray:
    """Whether some other neighbour shows (as it is, no local motion) the sample's intensity at each pixel."""
    if threshold is None:
        return np.ones(len(ys), bool)
    value = mosaic.intensity(sample)
    seen = np.zeros(len(ys), bool)
    for n, neighbour in enumerate(neighbours):
        if n != source:
            other = mosaic.intensity(neighbour.rgb[box][ys, xs])
            seen |= neighbour.valid[box][ys, xs] & (np.abs(other - value) < threshold)
    return seen


def _best_candidate(candidates: list[_Candidate]) -> np.ndarray:
    """Per pixel, the index of the reached candidate with the lowest local alignment error; -1 where none.

    Unconfirmed static samples (an object that only passed there in that neighbour) rank after all others.
    """
    error = np.stack([np.where(c.reached, c.error + np.where(c.confirmed, 0, np.float32(1e4)), np.inf)
                      for c in candidates])
    best = np.argmin(error, axis=0)
    return np.where(np.isfinite(np.min(error, axis=0)), best, -1)


def _moving_and_better(candidates: list[_Candidate], chosen: np.ndarray, static_error: np.ndarray,
                       config: CompletionConfig) -> np.ndarray:
    """Pixels whose chosen candidate moves and explains the surroundings clearly better than the static scene."""
    pick = np.maximum(chosen, 0)[None]
    motion = np.take_along_axis(np.stack([c.motion for c in candidates]), pick, 0)[0]
    error = np.take_along_axis(np.stack([c.error for c in candidates]), pick, 0)[0]
    return (chosen >= 0) & (motion > config.moving_px) & (error + config.mosaic_check_margin < static_error)


def _local_warp(inpainted: fmm.MotionInpaintResult, neighbour: WarpedNeighbour, box: tuple[slice, slice],
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 25 over the box: I_t'(p + F(p)) wherever p has a flow landing on neighbour content.

    Returns (colours (h, w, 3) uint8, landed (h, w) bool, |F| (h, w) float32, inf where p has no flow).
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
    landed = has_flow & (coverage == 255)
    motion = np.where(has_flow, np.hypot(flow[..., 0], flow[..., 1]), np.inf).astype(np.float32)
    return sampled, landed, motion
