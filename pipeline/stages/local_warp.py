"""Local-warp mosaicing's flows (thesis 4.2.2-4.2.3, eqs. 23-25): where and at which resolution the local flow of
each neighbour is computed and motion-inpainted, and the local warp sampled through it.

Flows run only inside work boxes around the pixels that need a local warp (``work_boxes``, each grown by the flow's
margin of context), at a working resolution of at most ``FlowSettings.max_side`` (the flow is upsampled after; the
local warp samples the full-resolution neighbour). A neighbour's flows are ``FlowPiece``s, one per box, gathered in
its ``NeighbourFill``; a pixel in several boxes takes the flow of the box that owns it (``owners``).

The candidate sources built on these (the local warps, the carried-on content) are in pipeline/stages/candidates.py.
Why boxes, margins and working sizes: docs/completion.md.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property
from typing import Sequence

import cv2
import numpy as np
from numba import njit

from pipeline import imaging
from pipeline.stages import fmm, local_flow
from pipeline.stages.neighbours import WarpedNeighbour, shrink, shrink_all, shrink_any

# Distances in pixels of the local flow's working resolution.
NEAR_MISSING_PX = 12  # motion inpainting works within this distance of the missing area (> flow's erosion)
RESCUE_NEAR_MISSING_PX = 40  # large motions the flow missed are searched for this close to the missing area


@dataclass(frozen=True)
class FlowSettings:
    """Where and how local flows run (from CompletionConfig's ``flow_max_side``, ``flow_margin_px``, ``flow``,
    ``inpaint``)."""

    max_side: int | None  # px: longest side of the working resolution; None: full resolution
    margin_px: int | None  # px of the working resolution: work boxes grow by this; None: the whole frame
    flow: local_flow.LocalFlowConfig
    inpaint: fmm.MotionInpaintConfig

    def scale(self, shape: tuple[int, int]) -> float:
        """The working resolution as a fraction of a frame of ``shape``'s."""
        return working_scale(shape, self.max_side)

    def margin(self, scale: float) -> int | None:
        """The margin in full-resolution pixels at working ``scale`` (None: the whole frame)."""
        return None if self.margin_px is None else round(self.margin_px / scale)


def working_scale(shape: tuple[int, int], max_side: int | None) -> float:
    """The fraction of a frame of ``shape`` (height, width) whose longest side is at most ``max_side`` (None: 1)."""
    return 1.0 if max_side is None else min(1.0, max_side / max(shape))


def working_size(box: tuple[slice, slice], scale: float) -> tuple[int, int] | None:
    """(width, height) of ``box`` at the flow's working resolution (``scale`` of the frame's, at least 8 px a side);
    None where that would not shrink it (work at full resolution)."""
    height, width = box[0].stop - box[0].start, box[1].stop - box[1].start
    size = (max(round(width * scale), 8), max(round(height * scale), 8))
    return size if size[0] < width and size[1] < height else None


@dataclass(frozen=True)
class FlowPiece:
    """Local flow and its motion inpainting inside one box, at ``scale`` of the frame's resolution."""

    box: tuple[slice, slice]  # in full-resolution frame coordinates
    scale: float
    flow: local_flow.LocalFlowResult  # at the working resolution of the box
    inpainted: fmm.MotionInpaintResult
    # The pixels this piece answers for (disjoint from every other piece's): boxes may overlap, and a pixel in
    # several takes the flow of the one computed for it, whose box holds its full margin of context.
    owned: tuple[tuple[slice, slice], ...] = ()

    def inpainted_flow_at(self, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
        """(m, 2) float32 full-resolution flow at full-frame pixels inside the box: bilinear between the
        defined coarse vectors only (exact at scale 1); NaN where there is none."""
        rows, cols = self.box
        # Pixel centres: full-resolution (x + 0.5) is working (x + 0.5) * scale.
        u = (xs - cols.start + 0.5) * self.scale - 0.5
        v = (ys - rows.start + 0.5) * self.scale - 0.5
        out = fmm.sample_flow(self.inpainted.flow, u, v)
        if self.scale != 1.0:
            out /= np.float32(self.scale)
        return out


@dataclass
class NeighbourFill:
    """One neighbour of the local-warp stage: its flow, the inpainted flow, what it could and did fill.

    The flows live in ``pieces`` (boxes at the flow's working resolution); ``flow`` and ``inpainted`` are the
    full-frame views of them, made on first use (the debugger's), never by the pipeline itself."""

    offset: int
    alignment_error: float  # eq. 23 over the common area (on a grid, see priority)
    pieces: list[FlowPiece]
    shape: tuple[int, int]
    filled: np.ndarray  # bool: pixels this neighbour's local warp filled
    reached: np.ndarray | None = None  # bool: pixels needing a local warp that its local warp had a sample for

    @cached_property
    def _full_frame_views(self) -> tuple[local_flow.LocalFlowResult, fmm.MotionInpaintResult]:
        return _full_frame(self.pieces, self.shape)  # both views at once: they share the pasting

    @property
    def flow(self) -> local_flow.LocalFlowResult:
        return self._full_frame_views[0]

    @property
    def inpainted(self) -> fmm.MotionInpaintResult:
        return self._full_frame_views[1]

    def inpainted_flow_at(self, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
        """(m, 2) float32 inpainted flow at full-frame pixels; NaN outside every box or where there is none."""
        out = np.full((len(ys), 2), np.nan, np.float32)
        owner = owners(self.pieces, ys, xs)
        for k, piece in enumerate(self.pieces):
            mine = owner == k
            if mine.any():
                out[mine] = piece.inpainted_flow_at(ys[mine], xs[mine])
        return out


def claims(pieces: Sequence[FlowPiece]) -> list[tuple[int, tuple[slice, slice]]]:
    """(piece index, rectangle) in the order they claim pixels, a later claim winning: every box, then each
    piece's owned rectangles. So a pixel takes the flow of the piece owning it, else of the last box holding
    it (a pixel near, not among, the ones that needed the flow, e.g. on the local error's band)."""
    return ([(k, piece.box) for k, piece in enumerate(pieces)]
            + [(k, rect) for k, piece in enumerate(pieces) for rect in piece.owned])


def owners(pieces: Sequence[FlowPiece], ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """Per pixel, the index of the piece whose flow it takes (``claims``); -1: none."""
    ordered = claims(pieces)
    rects = np.array([(rows.start, rows.stop, cols.start, cols.stop) for _, (rows, cols) in ordered],
                     np.int64).reshape(-1, 4)
    return _last_claim(np.array([k for k, _ in ordered], np.int64), rects, np.asarray(ys), np.asarray(xs))


@njit(cache=True, nogil=True)
def _last_claim(piece: np.ndarray, rects: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """Per pixel, ``piece`` of the last rectangle (y0, y1, x0, x1; half-open) holding it; -1: none."""
    owner = np.full(len(ys), -1, np.int64)
    for i in range(len(ys)):
        for c in range(len(rects) - 1, -1, -1):
            if rects[c, 0] <= ys[i] < rects[c, 1] and rects[c, 2] <= xs[i] < rects[c, 3]:
                owner[i] = piece[c]
                break
    return owner


def by_distance(neighbours: Sequence[WarpedNeighbour]) -> list[int]:
    """Neighbour indices nearest in time first, t-k before t+k."""
    return sorted(range(len(neighbours)), key=lambda i: (abs(neighbours[i].offset), neighbours[i].offset))


def priority(target: np.ndarray, known: np.ndarray, neighbours: Sequence[WarpedNeighbour], needed: int,
             ) -> tuple[list[int], list[float]]:
    """Neighbour indices nearest in time first, the eq. 23 alignment error breaking ties; and those errors.

    Errors are measured only until ``needed`` neighbours with a finite one are ordered (NaN for the rest, which
    stay ordered by time): the local-warp stage never looks further.
    """
    errors = [float("nan")] * len(neighbours)
    order: list[int] = []
    usable = 0
    # A grid about 320 pixels wide (every other pixel at 640x360): the same mean within noise, a fraction of
    # the work.
    step = max(2, max(target.shape[:2]) // 320)
    grid_y, grid_x = np.mgrid[0:target.shape[0]:step, 0:target.shape[1]:step].astype(np.float32)
    target_grid = imaging.intensity(target[::step, ::step])
    known_grid = known[::step, ::step]
    for _, group in itertools.groupby(by_distance(neighbours), key=lambda i: abs(neighbours[i].offset)):
        group = list(group)
        if usable < needed:
            for i in group:
                colours, valid = neighbours[i].sample(grid_x, grid_y)
                errors[i] = local_flow.mean_abs_difference(target_grid, known_grid, colours, valid)
            group.sort(key=lambda i: errors[i])  # stable: t-k before t+k on equal errors
            usable += sum(np.isfinite(errors[i]) for i in group)
        order += group
    return order, errors


@dataclass(frozen=True)
class BoxView:
    """Frame t's side of one work box at the flow's working resolution: made once, used for every neighbour."""

    box: tuple[slice, slice]  # full-resolution frame coordinates
    size: tuple[int, int] | None  # (width, height) at the working resolution; None: full resolution
    scale: float  # working / full resolution (exact along x)
    target: np.ndarray
    known: np.ndarray
    focus: np.ndarray  # where large motions are searched for (local_flow's rescue)
    near_missing: np.ndarray  # where motion inpainting may fill
    owned: tuple[tuple[slice, slice], ...]  # the pixels its flow answers for (WorkBox.owned)

    @staticmethod
    def of(work: WorkBox, target: np.ndarray, known: np.ndarray, focus: np.ndarray, near_missing: np.ndarray,
           scale: float, target_original: WarpedNeighbour | None = None) -> BoxView:
        box = work.box
        size = working_size(box, scale)
        if size is None:
            return BoxView(box, None, 1.0, target[box], known[box], focus[box], near_missing[box], work.owned)
        width = box[1].stop - box[1].start
        if target_original is not None:
            small_target, small_known = target_original.crop(box, size)  # resampled as the neighbours are
        else:
            small_target, small_known = shrink(target[box], size), shrink_all(known[box], size)
        return BoxView(box, size, size[0] / width, small_target, small_known, shrink_any(focus[box], size),
                       shrink_any(near_missing[box], size), work.owned)


def box_views(ys: np.ndarray, xs: np.ndarray, target: np.ndarray, missing: np.ndarray, settings: FlowSettings,
              target_original: WarpedNeighbour | None = None) -> list[BoxView]:
    """Frame t's side of the work boxes around pixels (ys, xs) that need a local warp, at the working resolution:
    where large motions are searched for (``RESCUE_NEAR_MISSING_PX`` of the missing area) and where motion
    inpainting may fill (``NEAR_MISSING_PX``). ``target_original``: see pipeline/stages/completion.py: complete."""
    scale = settings.scale(missing.shape)
    near_missing, rescue_focus = dilate(missing, round(NEAR_MISSING_PX / scale),
                                        round(RESCUE_NEAR_MISSING_PX / scale))
    wanted = np.zeros(missing.shape, bool)
    wanted[ys, xs] = True
    return [BoxView.of(work, target, ~missing, rescue_focus, near_missing, scale, target_original)
            for work in work_boxes(wanted, settings.margin(scale))]


def neighbour_fill(neighbour: WarpedNeighbour, alignment_error: float, views: Sequence[BoxView],
                   settings: FlowSettings, shape: tuple[int, int]) -> NeighbourFill:
    """One neighbour's local flow and its motion inpainting in every work box (nothing filled yet)."""
    pieces = [_flow_in_box(view, *neighbour.crop(view.box, view.size), settings) for view in views]
    return NeighbourFill(neighbour.offset, alignment_error, pieces, shape, np.zeros(shape, bool))


def _flow_in_box(view: BoxView, neighbour_rgb: np.ndarray, neighbour_valid: np.ndarray,
                 settings: FlowSettings) -> FlowPiece:
    """Local flow and its motion inpainting (eq. 24) in one box, from the neighbour's crop of it at the box view's
    working resolution."""
    flow = local_flow.local_flow(view.target, view.known, neighbour_rgb, neighbour_valid, settings.flow,
                                 focus=view.focus)
    trusted = flow.common if flow.reliable is None else flow.reliable
    # Propagate over everything untrusted near the hole: the common area is eroded, so the band between
    # it and the missing area must be crossed too.
    inpainted = fmm.inpaint_motion(flow.flow, trusted, neighbour_rgb, neighbour_valid=neighbour_valid,
                                   region=~trusted & view.near_missing, config=settings.inpaint)
    return FlowPiece(view.box, view.scale, flow, inpainted, view.owned)


def samples_through(flow: np.ndarray, neighbour: WarpedNeighbour, ys: np.ndarray, xs: np.ndarray,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 25 at pixels (ys, xs) with their inpainted flow ``flow`` (m, 2), NaN where none: I_t'(p + F(p))
    wherever p has a flow landing on neighbour content.

    The neighbour is sampled straight from its original frame (one resampling, not a warp of a warp). Returns
    (colours (m, 3) uint8, landed (m,) bool, |F| (m,) float32, inf where p has no flow).
    """
    has_flow = ~np.isnan(flow[:, 0])
    flow = np.where(has_flow[:, None], flow, np.float32(0))
    colours, covered = neighbour.sample(xs + flow[:, 0], ys + flow[:, 1])
    # Only where every bilinear tap was a neighbour pixel: no black bleeding in from its border.
    landed = has_flow & covered
    motion = np.where(has_flow, np.hypot(flow[:, 0], flow[:, 1]), np.inf).astype(np.float32)
    return colours, landed, motion


@dataclass(frozen=True)
class WorkBox:
    box: tuple[slice, slice]  # where the flow is computed
    owned: tuple[tuple[slice, slice], ...]  # the pixels needing it that take it from here (disjoint across boxes)


def work_boxes(wanted: np.ndarray, margin: int | None, max_cells: int = 16) -> list[WorkBox]:
    """Where flows are computed: boxes around the ``wanted`` pixels (those that need a local warp), grown by
    ``margin`` (their flow's context); ``margin`` None: the whole frame.

    The pixels needing a local warp are what the mosaic left, mostly along the borders, and one box per connected
    cluster is most of the frame where a border missing on two sides is joined along a third. Instead the pixels
    are taken by cells (half a margin wide, at most ``max_cells`` along a side), each cell's pixels in a grown box
    of their own, and boxes are merged while one box around two costs no more area than both (``_merged``): a
    compact cluster ends in one box, the strips of a U-shaped border in three (docs/completion.md). Boxes may
    overlap; each wanted pixel is owned by exactly one box, which holds it with its full margin."""
    height, width = wanted.shape
    if margin is None:
        whole = (slice(0, height), slice(0, width))
        return [WorkBox(whole, (whole,))] if wanted.any() else []
    cell = max(margin // 2, -(-max(height, width) // max_cells), 1)
    rows, cols = -(-height // cell), -(-width // cell)
    padded = np.zeros((rows * cell, cols * cell), bool)
    padded[:height, :width] = wanted
    blocks = padded.reshape(rows, cell, cols, cell)
    row_any, col_any = blocks.any(axis=3), blocks.any(axis=1)  # (rows, cell, cols), (rows, cols, cell)
    r, c = np.nonzero(row_any.any(axis=1))
    if len(r) == 0:
        return []
    # Each occupied cell's own pixels' bounding box (y0, x0, y1, x1), then grown by the margin.
    owned = np.stack([r * cell + np.argmax(row_any[r, :, c], axis=1),
                      c * cell + np.argmax(col_any[r, c, :], axis=1),
                      r * cell + cell - np.argmax(row_any[r, ::-1, c], axis=1),
                      c * cell + cell - np.argmax(col_any[r, c, ::-1], axis=1)], axis=1)
    boxes = np.stack([np.maximum(owned[:, 0] - margin, 0), np.maximum(owned[:, 1] - margin, 0),
                      np.minimum(owned[:, 2] + margin, height), np.minimum(owned[:, 3] + margin, width)], axis=1)

    def rect(y0: int, x0: int, y1: int, x1: int) -> tuple[slice, slice]:
        return slice(int(y0), int(y1)), slice(int(x0), int(x1))

    return [WorkBox(rect(*box), tuple(rect(*owned[m]) for m in members)) for box, members in _merged(boxes)]


def _merged(boxes: np.ndarray) -> list[tuple[np.ndarray, list[int]]]:
    """Boxes (y0, x0, y1, x1 rows; changed in place) merged greedily, the largest saving of area first, while one
    box around two costs no more area than both: (box, the indices of the boxes it holds) per box left."""
    members = [[k] for k in range(len(boxes))]
    alive = list(range(len(boxes)))
    while len(alive) > 1:
        b = boxes[alive]
        area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
        joint = ((np.maximum.outer(b[:, 2], b[:, 2]) - np.minimum.outer(b[:, 0], b[:, 0]))
                 * (np.maximum.outer(b[:, 3], b[:, 3]) - np.minimum.outer(b[:, 1], b[:, 1])))
        saving = area[:, None] + area[None, :] - joint
        np.fill_diagonal(saving, -1)
        i, j = np.unravel_index(int(np.argmax(saving)), saving.shape)
        if saving[i, j] < 0:
            break
        keep, gone = alive[i], alive[j]
        boxes[keep, :2] = np.minimum(boxes[keep, :2], boxes[gone, :2])
        boxes[keep, 2:] = np.maximum(boxes[keep, 2:], boxes[gone, 2:])
        members[keep] += members[gone]
        del alive[j]
    return [(boxes[k], members[k]) for k in alive]


def _full_frame(pieces: list[FlowPiece], shape: tuple[int, int],
                ) -> tuple[local_flow.LocalFlowResult, fmm.MotionInpaintResult]:
    """Flow pieces as full-frame, full-resolution arrays (no flow outside them). Where boxes overlap, each
    pixel shows the piece whose flow it takes (``claims``)."""
    owner = np.full(shape, -1, np.int64)
    for k, (rows, cols) in claims(pieces):
        owner[rows, cols] = k
    mine = [owner[piece.box] == k for k, piece in enumerate(pieces)]  # within each box, the pixels it shows

    def paste(values: list[np.ndarray], fill: float | bool) -> np.ndarray:
        """Per-pixel values (masks, order, arrival): nearest coarse pixel."""
        out = np.full(shape, fill, values[0].dtype)
        for piece, value, shown in zip(pieces, values, mine):
            rows, cols = piece.box
            size = (cols.stop - cols.start, rows.stop - rows.start)
            if value.shape != (size[1], size[0]):
                value = cv2.resize(value.view(np.uint8) if value.dtype == bool else value, size,
                                   interpolation=cv2.INTER_NEAREST).view(value.dtype)
            out[rows, cols][shown] = value[shown]
        return out

    def paste_flow(inpainted: bool) -> np.ndarray:
        out = np.full(shape + (2,), np.nan if inpainted else 0.0, np.float32)
        for piece, shown in zip(pieces, mine):
            rows, cols = piece.box
            if inpainted:
                ys, xs = np.mgrid[rows, cols]
                out[rows, cols][shown] = piece.inpainted_flow_at(ys[shown], xs[shown])
            else:
                size = (cols.stop - cols.start, rows.stop - rows.start)
                flow = cv2.resize(piece.flow.flow, size, interpolation=cv2.INTER_LINEAR) / piece.scale
                out[rows, cols][shown] = flow[shown]
        return out

    flows = [piece.flow for piece in pieces]
    inpainted = [piece.inpainted for piece in pieces]
    # One visiting order over all boxes: each box's marching continues after the previous box's.
    orders, visited = [], 0
    for result in inpainted:
        orders.append(np.where(result.order >= 0, result.order + visited, -1).astype(result.order.dtype))
        visited += int(result.order.max(initial=-1)) + 1
    arrival = [result.arrival / np.float32(piece.scale) for piece, result in zip(pieces, inpainted)]
    reliable = None if flows[0].reliable is None else paste([f.reliable for f in flows], False)
    return (local_flow.LocalFlowResult(paste_flow(False), paste([f.common for f in flows], False), reliable),
            fmm.MotionInpaintResult(paste_flow(True), paste(orders, -1), paste(arrival, np.inf),
                                    paste([r.filled for r in inpainted], False)))


def dilate(mask: np.ndarray, *radii: int) -> list[np.ndarray]:
    """``mask`` dilated by the square of each radius (increasing). A square is a row then a column, and each
    dilation grows the one before: 2x faster than a square kernel per radius at 1080p, the same masks."""
    grown, done, out = mask.astype(np.uint8), 0, []
    for radius in radii:
        step = radius - done
        if step < 0:
            raise ValueError(f"radii must increase, got {radii}")
        if step:
            grown = cv2.dilate(grown, np.ones((1, 2 * step + 1), np.uint8))
            grown = cv2.dilate(grown, np.ones((2 * step + 1, 1), np.uint8))
        done = radius
        out.append(grown.astype(bool))
    return out
