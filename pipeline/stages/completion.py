"""Full-frame video completion (thesis chapter 4): the ordered chain that fills a stabilized frame's missing area.

0. local registration (``register_neighbours``): each neighbour's global warp refined on the band next to the
   missing area, where a chain of global motions has drifted by pixels on far neighbours;
1. consistent mosaicing (eqs. 20-22, ``mosaic``): static areas, median of neighbours that agree;
2. local-warp mosaicing: for the ``max_warp_neighbours`` nearest neighbours, local flow over the common area
   (``local_flow``), motion inpainting by Fast Marching (eq. 24, ``fmm``), a candidate through it (eq. 25); beside
   them a neighbour's sample as it is, the median of the neighbours' majority, and moving content carried on;
3. a smooth last-resort fill (``fallback``) for what no neighbour covers.

Invariants: every neighbour arrives already warped into the target's stabilized coordinates, with its valid
mask; pixels outside ``missing`` are never changed; every missing pixel leaves filled, and ``source`` says by
which stage.

Eq. 23 made local: the thesis fills a pixel from the first neighbour whose warp reaches it, but one
neighbour's inpainted flow is a guess (object flow bleeds into background, an occluder hides the pixel). So
each pixel takes the candidate whose warp best explains the known surroundings it continues (``_LocalError``:
mean intensity difference after the warp around the pixel's nearest known pixel); a static sample no other
neighbour confirms ranks after every confirmed one. The same evidence corrects the mosaic where its static
assumption fails (a moving object shown as background by every neighbour it has left): a clearly moving
candidate (``moving_px``) replaces the mosaic pixel where it clearly beats the static scene's error (``mosaic_check_*``).

Neighbours are taken nearest in time first, eq. 23's global alignment error breaking ties between t-k and
t+k (``neighbour_order``); flows and inpainting run only in boxes around the pixels that need a local warp
(``_work_boxes``, grown by ``flow_margin_px``). Why, with the measurements: docs/completion.md.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable, Sequence

import cv2
import numpy as np
from numba import njit

from pipeline.stages import fallback, fmm, local_flow, mosaic, registration, temporal
from pipeline import geometry, imaging
from pipeline.errors import ConfigError
from pipeline.stages.neighbours import WarpedNeighbour, remap_points, shrink, shrink_all, shrink_any

# What filled each pixel (CompletionResult.source). Step 2 fills by three kinds of sample, each from one neighbour
# (CompletionResult.filled_by): its local warp (flow + motion inpainting, eq. 25), its moving content carried on by a
# frame (``extrapolate_motion``), or its sample as it is, with no local motion (the static candidate and fill). A
# fourth kind is the median of the neighbours' majority (``majority_candidate``): no one neighbour's.
SOURCE_ORIGINAL, SOURCE_MOSAIC, SOURCE_LOCAL_WARP, SOURCE_FALLBACK, SOURCE_CARRIED_ON, SOURCE_AS_IS = 0, 1, 2, 3, 4, 5
SOURCE_MAJORITY = 6
SOURCE_NAMES = ("original", "mosaic", "local warp", "fallback", "carried on", "neighbour as is", "majority")
NEIGHBOUR_SOURCES = (SOURCE_LOCAL_WARP, SOURCE_CARRIED_ON, SOURCE_AS_IS)  # step 2's: filled_by names the neighbour


def from_a_neighbour(source: np.ndarray) -> np.ndarray:
    """Where step 2 filled from one neighbour (``filled_by`` holds its offset there): any of NEIGHBOUR_SOURCES."""
    return np.isin(source, NEIGHBOUR_SOURCES)
# Distances in pixels of the local flow's working resolution (see CompletionConfig.flow_max_side).
NEAR_MISSING_PX = 12  # motion inpainting works within this distance of the missing area (> flow's erosion)
RESCUE_NEAR_MISSING_PX = 40  # large motions the flow missed are searched for this close to the missing area
# ECC's iterations per neighbour: it starts from the global warp, a pixel or two off; 30 (OpenCV's usual count) made
# ECC 60 % of full mode's time on selh_asb_1, and 10 recover the ground truth's corrections as well (docs/completion.md).
_ECC_ITERATIONS = 10
_MIN_REGISTER_PIXELS = 200  # fewer band pixels than this (at the working resolution): the warp is left as it is


@dataclass(frozen=True)
class CompletionConfig:
    neighbour_frames: int = 6  # neighbours t-r..t+r take part (mosaic and local warp)
    max_warp_neighbours: int = 4  # local flow is computed for this many neighbours, nearest in time first
    residual_radius: int = 4  # local alignment error: mean over the (2r+1)^2 known pixels around the nearest one
    check_mosaic: bool = True  # let clearly moving local-warp candidates replace mosaic pixels
    moving_px: float = 2.0  # a candidate whose inpainted flow is longer than this shows moving content
    # A moving candidate replaces a mosaic pixel when its local alignment error is lower than that of the
    # static scene (no local motion) by more than this (intensity, 0..255) and at most this share of it. The
    # share: on a motion-blurred frame every sharp sample's error grows with the blur, and the margin alone let a
    # moving object's flow, carried into the strip by motion inpainting, replace the background the mosaic had
    # right (benchmarks/dynamic_scene.py's person clips: +0.2 to +0.7 dB over the synthesized pixels on four of
    # five, docs/decisions.md 2026-11-26). 1: the margin alone.
    mosaic_check_margin: float = 5.0
    mosaic_check_ratio: float = 0.5
    # Flows are computed in boxes around the clusters of pixels needing a local warp, grown by this margin (px
    # of the flow's working resolution); None: over the whole frame. The margin is DIS's context: with 64 px
    # its coarsest pyramid level lost an object's 20-50 px motion (synthetic rocket scene -3.5 dB against
    # whole-frame flows); 96 px is within 0.4 dB of them on that scene and equal or better on three others,
    # at a third of the area.
    flow_margin_px: int | None = 96
    # Local flow and motion inpainting run on frames scaled down to this longest side (the flow is upsampled
    # after; the local warp samples full-resolution neighbours), as motion estimation does: at 1080p that is
    # a ninth of the pixels. None: full resolution.
    flow_max_side: int | None = 640
    confirm_difference: float | None = 20.0
    # Local registration before the mosaic (see register_neighbours): each neighbour's global warp refined by ECC
    # on frame t's known pixels within ``register_band_px`` of the missing area, with this motion model
    # ("translation", "affine", "homography"; None: off); a refinement that moves a frame corner further than
    # ``register_max_px`` or lowers the band's error by less than 5 % is refused. Working resolution: longest
    # side at most ``register_max_side`` (None: full).
    register_model: str | None = "homography"
    register_band_px: int = 24
    register_max_px: float = 12.0
    register_max_side: int | None = 320
    # Pixels the mosaic refused and no local warp reached, but some neighbour covers, take the covering
    # neighbour's sample (zero local motion) whose warp best explains the surroundings, instead of the smooth
    # fallback.
    static_fill: bool = True
    # With the static fill: where every local warp explains the surroundings worse than this (local alignment error,
    # intensity 0..255; their flows are guesses that failed, e.g. object flow carried into a border the object has
    # left), the best covering neighbour's sample as it is (zero local motion, as the static fill takes it) competes
    # with them, its error counted ``static_candidate_margin`` higher. None: off.
    static_candidate_error: float | None = 30.0
    static_candidate_margin: float = 3.0
    # Moving content carried on into frame t at constant velocity: where the two nearest neighbours on one side of t
    # (t+s and t+2s) both cover a pixel needing a local warp, the flow from t+s to t+2s there (about minus the
    # content's motion in a frame) moves t+s's sample on by one frame, a candidate wherever it moves by more than
    # ``moving_px`` (see _extrapolated_candidates).
    extrapolate_motion: bool = True
    # The median of the neighbours' strict majority as they are (mosaic.majority_median: eqs. 20-22 without the
    # samples an object passing in a few neighbours made disagree) as one more candidate, its error the median local
    # error of the majority's own samples. A local warp reaching such a pixel samples the nearest neighbours, which
    # are the ones still showing the object; person clips of benchmarks/dynamic_scene.py +0.5 to +1.9 dB over the
    # synthesized pixels (docs/decisions.md 2026-11-26).
    majority_candidate: bool = True
    mosaic: mosaic.MosaicConfig = field(default_factory=mosaic.MosaicConfig)
    flow: local_flow.LocalFlowConfig = field(default_factory=local_flow.LocalFlowConfig)
    inpaint: fmm.MotionInpaintConfig = field(default_factory=fmm.MotionInpaintConfig)
    # After every frame is completed: its synthesized pixels averaged with the completed frames next to it where they
    # agree (pipeline/stages/temporal.py; run over the stream of frames by pipeline/chain.py).
    temporal: temporal.TemporalConfig = field(default_factory=temporal.TemporalConfig)

    def __post_init__(self) -> None:
        if self.neighbour_frames < 0:
            raise ConfigError(f"completion radius must be >= 0, not {self.neighbour_frames}")
        if self.max_warp_neighbours < 0:
            raise ConfigError(f"max_warp_neighbours must be >= 0, not {self.max_warp_neighbours}")
        if self.flow_max_side is not None and self.flow_max_side < 32:
            raise ConfigError(f"flow_max_side must be at least 32 px, not {self.flow_max_side}")
        if self.residual_radius < 0:
            raise ConfigError(f"residual_radius must be >= 0, not {self.residual_radius}")
        if self.register_model is not None and self.register_model not in registration.MODEL_PARAMETERS:
            raise ConfigError(f"register_model must be one of {', '.join(registration.MODEL_PARAMETERS)} or None, "
                              f"not {self.register_model!r}")
        if not 0.0 < self.mosaic_check_ratio <= 1.0:
            raise ConfigError(f"mosaic_check_ratio must be in (0, 1], not {self.mosaic_check_ratio}")
        if self.static_candidate_error is not None and not self.static_candidate_error >= 0:
            raise ConfigError(f"static_candidate_error must be >= 0 or None, not {self.static_candidate_error}")
        if self.register_band_px < 1:
            raise ConfigError(f"register_band_px must be >= 1, not {self.register_band_px}")
        if not self.register_max_px > 0:
            raise ConfigError(f"register_max_px must be positive, not {self.register_max_px}")
        if self.register_max_side is not None and self.register_max_side < 32:
            raise ConfigError(f"register_max_side must be at least 32 px, not {self.register_max_side}")


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
    alignment_error: float  # eq. 23 over the common area (on a grid, see _priority)
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
        owner = _owners(self.pieces, ys, xs)
        for k, piece in enumerate(self.pieces):
            mine = owner == k
            if mine.any():
                out[mine] = piece.inpainted_flow_at(ys[mine], xs[mine])
        return out


def _claims(pieces: Sequence[FlowPiece]) -> list[tuple[int, tuple[slice, slice]]]:
    """(piece index, rectangle) in the order they claim pixels, a later claim winning: every box, then each
    piece's owned rectangles. So a pixel takes the flow of the piece owning it, else of the last box holding
    it (a pixel near, not among, the ones that needed the flow, e.g. on the local error's band)."""
    return ([(k, piece.box) for k, piece in enumerate(pieces)]
            + [(k, rect) for k, piece in enumerate(pieces) for rect in piece.owned])


def _owners(pieces: Sequence[FlowPiece], ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """Per pixel, the index of the piece whose flow it takes (``_claims``); -1: none."""
    claims = _claims(pieces)
    rects = np.array([(rows.start, rows.stop, cols.start, cols.stop) for _, (rows, cols) in claims],
                     np.int64).reshape(-1, 4)
    return _last_claim(np.array([k for k, _ in claims], np.int64), rects, np.asarray(ys), np.asarray(xs))


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


@dataclass(frozen=True)
class CompletionResult:
    frame: np.ndarray  # completed (H, W, 3) uint8
    missing: np.ndarray  # the stabilized frame's missing mask this started from
    mosaic: mosaic.MosaicResult
    neighbour_order: list[int]  # offsets by priority
    fills: list[NeighbourFill]
    source: np.ndarray  # (H, W) uint8: SOURCE_* per pixel
    filled_by: np.ndarray  # (H, W) int16: the neighbour's offset where step 2 filled (from_a_neighbour), 0 elsewhere
    fallback: np.ndarray  # (H, W) bool: pixels the last resort filled
    corrected: np.ndarray | None = None  # (H, W) bool: mosaic pixels the local warp replaced (moving content)
    registered: tuple[int, ...] = ()  # offsets of the neighbours whose warps local registration refined
    # A call returning the mosaic.MosaicResult of the unrefined global warps, made on request (what OpenCV's
    # chain, which has no local registration, would start from: the evaluation's baseline); None when no warp
    # was refined.
    unregistered_mosaic: Callable[[], object] | None = None


@dataclass
class _Candidate:
    """One neighbour's local warp, sampled at the pixels that need one (vectors over those pixels)."""

    colours: np.ndarray  # (m, 3) uint8: I_t'(p + F(p))
    reached: np.ndarray  # (m,) bool: the warp landed on neighbour content
    motion: np.ndarray  # (m,) float32: |F(p)|
    error: np.ndarray  # (m,) float32: local alignment error after the warp (see _LocalError)
    confirmed: np.ndarray  # (m,) bool: moves, or another neighbour shows the same there (not a passing occluder)


class _LocalError:
    """Eq. 23 made local: for a pixel to fill, the mean |I_t - warped neighbour| over the known pixels
    within ``radius`` of its nearest known pixel, so that each pixel can be judged by how well a warp
    explains the visible surroundings it continues.

    Only those windows are evaluated: ``band_y``, ``band_x`` are the known pixels they hold (a thin band
    around the missing area), and a call takes a warped neighbour's samples there."""

    def __init__(self, target: np.ndarray, known: np.ndarray, ys: np.ndarray, xs: np.ndarray, radius: int) -> None:
        width = known.shape[1]
        near = fallback.nearest_known(~known, ys, xs, mask_size=5)  # the L2 5x5 approximation
        self.point_of, self.window, band = _windows(np.ascontiguousarray(known), near, radius)
        self.band_y, self.band_x = band // width, band % width
        self.target = imaging.intensity(target[self.band_y, self.band_x])

    def __call__(self, colours: np.ndarray, landed: np.ndarray) -> np.ndarray:
        """(m,) errors from a warped neighbour's (colours, landed) on the band; NaN where the warp reached none of
        a pixel's window."""
        difference = np.abs(self.target - imaging.intensity(colours))
        per_point = np.empty(len(self.window), np.float32)
        _window_means(difference, np.ascontiguousarray(landed, dtype=np.bool_), self.window, per_point)
        return per_point[self.point_of]


def _nan_median_columns(values: np.ndarray) -> np.ndarray:
    """np.nanmedian(values, axis=0) for float columns with at least one number each: the same values, ~4x
    faster (numpy's NaN-aware median goes through masked arrays)."""
    ordered = np.sort(values, axis=0)  # NaN last
    count = np.count_nonzero(~np.isnan(values), axis=0)
    columns = np.arange(values.shape[1])
    return (ordered[(count - 1) // 2, columns] + ordered[count // 2, columns]) / values.dtype.type(2)


@njit(cache=True, nogil=True)
def _windows(known: np.ndarray, near: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The local error's bookkeeping, from each pixel's nearest known pixel (flat ``near``):
    ``point_of`` (m,), the row of each pixel's window (pixels sharing a nearest known pixel share one);
    ``window`` (points, (2r+1)^2), indices into the band, -1 where the offset is outside the frame or missing;
    ``band``, the flat indices of the known pixels the windows hold, each once, in first-seen order."""
    height, width = known.shape
    side = 2 * radius + 1
    index = np.full(height * width, -1, np.int32)  # per pixel: its point, then its place in the band
    point_of = np.empty(len(near), np.int64)
    points = np.empty(len(near), np.int64)
    n_points = 0
    for i in range(len(near)):
        if index[near[i]] < 0:
            index[near[i]] = n_points
            points[n_points] = near[i]
            n_points += 1
        point_of[i] = index[near[i]]
    for p in range(n_points):
        index[points[p]] = -1
    window = np.full((n_points, side * side), -1, np.int64)
    band = np.empty(n_points * side * side, np.int64)
    n_band = 0
    for p in range(n_points):
        y, x = points[p] // width, points[p] % width
        for k in range(side * side):
            wy, wx = y + k // side - radius, x + k % side - radius
            if wy < 0 or wy >= height or wx < 0 or wx >= width or not known[wy, wx]:
                continue
            flat = wy * width + wx
            if index[flat] < 0:
                index[flat] = n_band
                band[n_band] = flat
                n_band += 1
            window[p, k] = index[flat]
    return point_of, window, band[:n_band].copy()


@njit(cache=True, nogil=True)
def _window_means(difference: np.ndarray, landed: np.ndarray, window: np.ndarray, out: np.ndarray) -> None:
    """Per row of ``window`` (indices into the band, -1: none), the mean ``difference`` over its landed entries;
    NaN where none landed."""
    for i in range(window.shape[0]):
        total = 0.0
        count = 0
        for k in range(window.shape[1]):
            j = window[i, k]
            if j >= 0 and landed[j]:
                total += difference[j]
                count += 1
        out[i] = total / count if count > 0 else np.nan


def complete(target: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
             config: CompletionConfig = CompletionConfig(), *,
             target_original: WarpedNeighbour | None = None) -> CompletionResult:
    """Fill ``missing`` pixels of the stabilized ``target`` from its warped neighbours.

    ``target_original``: frame t itself as a lazy neighbour (offset 0, with its downscaled copy), so that the
    local flow's reduced-resolution crops of frame t are resampled as the neighbours' are (from the downscaled
    copy); without it they are shrunk from ``target``. Mixing the two (neighbours from the copy, frame t shrunk
    after warping) cost 1.2 dB on a 1080p scene: the neighbours came out slightly blurrier than frame t.
    """
    height, width = missing.shape
    registered: tuple[int, ...] = ()
    unregistered_mosaic = None
    if config.register_model is not None:
        as_given = neighbours
        neighbours = register_neighbours(target, missing, neighbours, config, target_original=target_original)
        registered = tuple(b.offset for a, b in zip(as_given, neighbours) if a is not b)
        if registered:
            unregistered_mosaic = functools.partial(_mosaic, target, missing, as_given, config.mosaic)
    source = np.where(missing, SOURCE_FALLBACK, SOURCE_ORIGINAL).astype(np.uint8)
    filled_by = np.zeros((height, width), np.int16)
    ys, xs = geometry.mask_pixels(missing)  # the pixels to fill
    # Each neighbour is looked at only where needed (pipeline/stages/neighbours.py): first at the missing pixels.
    at_missing = [n.at(ys, xs) for n in neighbours]
    mosaic_result = _mosaic(target, missing, neighbours, config.mosaic, at_missing)
    frame = mosaic_result.frame.copy()
    source[mosaic_result.accepted] = SOURCE_MOSAIC
    remaining = mosaic_result.remaining.copy()
    corrected = np.zeros((height, width), bool)

    known = ~missing
    order, errors = _by_distance(neighbours), [float("nan")] * len(neighbours)
    fills: list[NeighbourFill] = []
    local_error: _LocalError | None = None
    static_errors: list[np.ndarray] = []  # (neighbours, missing pixels): local error with zero local motion, once

    def errors_without_motion() -> np.ndarray:
        if not static_errors:
            static_errors.append(np.stack([local_error(*n.at(local_error.band_y, local_error.band_x))
                                           for n in neighbours]))
        return static_errors[0]

    if len(ys) and known.any() and neighbours and (config.max_warp_neighbours > 0 or config.static_fill):
        local_error = _LocalError(target, known, ys, xs, config.residual_radius)
    if local_error is not None and config.max_warp_neighbours > 0:
        accepted = mosaic_result.accepted[ys, xs]
        # Mosaic pixels can only be replaced where the static scene explains the surroundings worse than the
        # margin (a candidate's error is >= 0): elsewhere nothing needs a flow.
        static_error = np.full(len(ys), -np.inf, np.float32)
        if config.check_mosaic and accepted.any():
            per_neighbour = errors_without_motion()[:, accepted]
            covered = ~np.isnan(per_neighbour).all(axis=0)  # no neighbour sees the surroundings: no evidence
            static_error[np.flatnonzero(accepted)[covered]] = _nan_median_columns(per_neighbour[:, covered])
        checked = accepted & (static_error > config.mosaic_check_margin)
        needing = np.flatnonzero(remaining[ys, xs] | checked)  # indices (into ys, xs) of the pixels to warp
        if len(needing):
            # Every neighbour's samples at those pixels, and their intensities for the confirmation test, once for
            # the local warps, the static candidate and the carried-on content.
            at_needing = [(colours[needing], valid[needing]) for colours, valid in at_missing]
            shown = _intensities(at_needing, config.confirm_difference)
            order, errors = _priority(target, known, neighbours, config.max_warp_neighbours)
            fills, candidates = _local_warps(target, known, missing, neighbours, order, errors, ys, xs, needing,
                                             shown, local_error, config, target_original)
        if fills:
            # Candidates are over the ``needing`` pixels only.
            static_from = None
            if config.static_fill and config.static_candidate_error is not None:
                static, static_from = _static_candidate(candidates, errors_without_motion()[:, needing], at_needing,
                                                        shown, config)
                candidates.append(static)
            majority_index = None
            if config.majority_candidate:
                majority_index = len(candidates)
                candidates.append(_majority_candidate(errors_without_motion()[:, needing], at_needing, shown, config))
            carried_from: list[tuple[int, int]] = []  # (candidate index, the neighbour's offset it samples)
            if config.extrapolate_motion:
                for offset, carried in _extrapolated_candidates(neighbours, at_needing, ys, xs, needing, local_error,
                                                                config):
                    carried_from.append((len(candidates), offset))
                    candidates.append(carried)
            chosen = _best_candidate(candidates)
            take = chosen >= 0
            take &= ~checked[needing] | _moving_and_better(candidates, chosen, static_error[needing], config)
            among = np.flatnonzero(take)
            which = chosen[among]
            pick = needing[among]
            py, px = ys[pick], xs[pick]
            frame[py, px] = np.stack([c.colours for c in candidates])[which, among]
            source[py, px] = SOURCE_LOCAL_WARP
            corrected[py, px] = accepted[pick]
            remaining[py, px] = False
            for k, fill in enumerate(fills):
                fill.filled[py[which == k], px[which == k]] = True
                filled_by[py[which == k], px[which == k]] = fill.offset
            for index, offset in carried_from:
                mine = which == index
                filled_by[py[mine], px[mine]] = offset
                source[py[mine], px[mine]] = SOURCE_CARRIED_ON
            if static_from is not None:  # the candidate after the local warps: a neighbour's sample as it is
                mine = which == len(fills)
                filled_by[py[mine], px[mine]] = np.array([n.offset for n in neighbours], np.int16)[
                    static_from[among[mine]]]
                source[py[mine], px[mine]] = SOURCE_AS_IS
            if majority_index is not None:
                source[py[which == majority_index], px[which == majority_index]] = SOURCE_MAJORITY

    if config.static_fill and local_error is not None and remaining.any():
        rest = np.flatnonzero(remaining[ys, xs])
        which, rank = _best_static(errors_without_motion()[:, rest], [(c[rest], v[rest]) for c, v in at_missing],
                                   config.confirm_difference)
        ok = np.isfinite(rank)
        pick, which = rest[ok], which[ok]
        py, px = ys[pick], xs[pick]
        frame[py, px] = np.stack([c[pick] for c, _ in at_missing])[which, np.arange(len(pick))]
        source[py, px] = SOURCE_AS_IS  # eq. 25 with zero local motion
        filled_by[py, px] = np.array([n.offset for n in neighbours], np.int16)[which]
        remaining[py, px] = False

    if remaining.any():
        frame = fallback.smooth_fill(frame, remaining)
    return CompletionResult(frame=frame, missing=missing, mosaic=mosaic_result,
                            neighbour_order=[neighbours[i].offset for i in order], fills=fills, source=source,
                            filled_by=filled_by, fallback=remaining, corrected=corrected,
                            registered=registered, unregistered_mosaic=unregistered_mosaic)


def _mosaic(target: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
            config: mosaic.MosaicConfig, at_missing: list[tuple[np.ndarray, np.ndarray]] | None = None
            ) -> mosaic.MosaicResult:
    """Eqs. 20-22 from the neighbours' samples at the missing pixels (``at_missing``, taken here when not given)."""
    if at_missing is None:
        at_missing = [n.at(*geometry.mask_pixels(missing)) for n in neighbours]
    return mosaic.mosaic_from_samples(
        target, missing, np.stack([c for c, _ in at_missing]) if neighbours else None,
        np.stack([v for _, v in at_missing]) if neighbours else None, config)


def flow_scale(shape: tuple[int, int], config: CompletionConfig) -> float:
    """Local flow's working resolution as a fraction of the frame's (``flow_max_side``)."""
    return 1.0 if config.flow_max_side is None else min(1.0, config.flow_max_side / max(shape))


def _by_distance(neighbours: Sequence[WarpedNeighbour]) -> list[int]:
    return sorted(range(len(neighbours)), key=lambda i: (abs(neighbours[i].offset), neighbours[i].offset))


def _priority(target: np.ndarray, known: np.ndarray, neighbours: Sequence[WarpedNeighbour], needed: int,
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
    for _, group in itertools.groupby(_by_distance(neighbours), key=lambda i: abs(neighbours[i].offset)):
        group = list(group)
        if usable < needed:
            for i in group:
                colours, valid = neighbours[i].sample(grid_x, grid_y)
                errors[i] = local_flow.mean_abs_difference(target_grid, known_grid, colours, valid)
            group.sort(key=lambda i: errors[i])  # stable: t-k before t+k on equal errors
            usable += sum(np.isfinite(errors[i]) for i in group)
        order += group
    return order, errors


def _local_warps(target: np.ndarray, known: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
                 order: list[int], errors: list[float], ys: np.ndarray, xs: np.ndarray, needing: np.ndarray,
                 shown: list[tuple[np.ndarray, np.ndarray]] | None, local_error: _LocalError, config: CompletionConfig,
                 target_original: WarpedNeighbour | None = None) -> tuple[list[NeighbourFill], list[_Candidate]]:
    """Steps 2-4 for the nearest ``max_warp_neighbours`` neighbours: local flow, motion inpainting, local warp.

    ``needing``: indices of the pixels to fill (ys, xs) that need it. Flow and motion inpainting run inside boxes
    around them only (``_work_boxes``), at the flow's working resolution; the local warp is sampled at those
    pixels and on the local error's band (the mosaic filled the others). The candidates returned are over the
    ``needing`` pixels only. ``shown``: every neighbour's (intensity, valid) at them (``_intensities``).
    """
    height, width = missing.shape
    scale = flow_scale((height, width), config)
    near_missing, rescue_focus = _dilate(missing, round(NEAR_MISSING_PX / scale),
                                         round(RESCUE_NEAR_MISSING_PX / scale))
    wanted = np.zeros((height, width), bool)
    wanted[ys[needing], xs[needing]] = True
    works = _work_boxes(wanted, None if config.flow_margin_px is None else round(config.flow_margin_px / scale))
    views = [_BoxView.of(work.box, target, known, rescue_focus, near_missing, scale, target_original)
             for work in works]
    points_y = np.concatenate([ys[needing], local_error.band_y])
    points_x = np.concatenate([xs[needing], local_error.band_x])
    m = len(needing)
    fills: list[NeighbourFill] = []
    candidates: list[_Candidate] = []
    for i in order:
        if len(fills) >= config.max_warp_neighbours:
            break
        neighbour = neighbours[i]
        if not np.isfinite(errors[i]):
            continue  # no overlap to measure flow on
        pieces = [_flow_in_box(view, *neighbour.crop(view.box, view.size), config, work.owned)
                  for view, work in zip(views, works)]
        fill = NeighbourFill(neighbour.offset, errors[i], pieces, (height, width), np.zeros((height, width), bool))
        colours, landed, motion = _local_warp(fill.inpainted_flow_at(points_y, points_x), neighbour, points_y,
                                              points_x)
        # A warp whose surroundings cannot be checked ranks after every checked one.
        error = np.nan_to_num(local_error(colours[m:], landed[m:])[needing], nan=255.0)
        sample, moving = colours[:m], motion[:m] > config.moving_px
        confirmed = moving | _seen_by_another(sample, i, shown, config.confirm_difference)
        candidates.append(_Candidate(sample, landed[:m], motion[:m], error, confirmed))
        fill.reached = np.zeros((height, width), bool)
        fill.reached[ys[needing], xs[needing]] = landed[:m]
        fills.append(fill)
    return fills, candidates


@dataclass(frozen=True)
class _BoxView:
    """Frame t's side of one work box at the flow's working resolution: made once, used for every neighbour."""

    box: tuple[slice, slice]  # full-resolution frame coordinates
    size: tuple[int, int] | None  # (width, height) at the working resolution; None: full resolution
    scale: float  # working / full resolution (exact along x)
    target: np.ndarray
    known: np.ndarray
    focus: np.ndarray  # where large motions are searched for (local_flow's rescue)
    near_missing: np.ndarray  # where motion inpainting may fill

    @staticmethod
    def of(box: tuple[slice, slice], target: np.ndarray, known: np.ndarray, focus: np.ndarray,
           near_missing: np.ndarray, scale: float, target_original: WarpedNeighbour | None = None) -> _BoxView:
        size = _working_size(box, scale)
        if size is None:
            return _BoxView(box, None, 1.0, target[box], known[box], focus[box], near_missing[box])
        width = box[1].stop - box[1].start
        if target_original is not None:
            small_target, small_known = target_original.crop(box, size)  # resampled as the neighbours are
        else:
            small_target, small_known = shrink(target[box], size), shrink_all(known[box], size)
        return _BoxView(box, size, size[0] / width, small_target, small_known, shrink_any(focus[box], size),
                        shrink_any(near_missing[box], size))


def _working_size(box: tuple[slice, slice], scale: float) -> tuple[int, int] | None:
    """(width, height) of ``box`` at the flow's working resolution (``scale`` of the frame's, at least 8 px a side);
    None where that would not shrink it (work at full resolution)."""
    height, width = box[0].stop - box[0].start, box[1].stop - box[1].start
    size = (max(round(width * scale), 8), max(round(height * scale), 8))
    return size if size[0] < width and size[1] < height else None


def _flow_in_box(view: _BoxView, neighbour_rgb: np.ndarray, neighbour_valid: np.ndarray,
                 config: CompletionConfig, owned: tuple[tuple[slice, slice], ...]) -> FlowPiece:
    """Local flow and its motion inpainting in one box, from the neighbour's crop of it at the box view's
    working resolution."""
    flow = local_flow.local_flow(view.target, view.known, neighbour_rgb, neighbour_valid, config.flow,
                                 focus=view.focus)
    trusted = flow.common if flow.reliable is None else flow.reliable
    # Propagate over everything untrusted near the hole: the common area is eroded, so the band between
    # it and the missing area must be crossed too.
    inpainted = fmm.inpaint_motion(flow.flow, trusted, neighbour_rgb, neighbour_valid=neighbour_valid,
                                   region=~trusted & view.near_missing, config=config.inpaint)
    return FlowPiece(view.box, view.scale, flow, inpainted, owned)


@dataclass(frozen=True)
class _WorkBox:
    box: tuple[slice, slice]  # where the flow is computed
    owned: tuple[tuple[slice, slice], ...]  # the pixels needing it that take it from here (disjoint across boxes)


def _work_boxes(wanted: np.ndarray, margin: int | None, max_cells: int = 16) -> list[_WorkBox]:
    """Where flows are computed: boxes around the pixels that need a local warp, grown by ``margin`` (their
    flow's context); ``margin`` None: the whole frame.

    The pixels needing a local warp are what the mosaic left (it fills ~93% of the missing area), mostly along
    the borders. One box per connected cluster was 82-86% of the frame on real clips with wide borders
    (vplab_C, linyihaolyh): a border on two sides joined along a third is one cluster, and its box is the
    frame. Instead the pixels are taken by cells (half a margin wide, at most ``max_cells`` along a side),
    each cell's pixels in a grown box of their own, and boxes are merged, the largest saving first, while one
    box around two costs no more area than both: a compact cluster ends in one box, the strips of a U-shaped
    border in three (0.47-0.55 of the frame on those clips). Boxes may overlap; each pixel needing a flow is
    owned by exactly one box, which holds it with its full margin."""
    height, width = wanted.shape
    if margin is None:
        whole = (slice(0, height), slice(0, width))
        return [_WorkBox(whole, (whole,))] if wanted.any() else []
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

    def rect(y0: int, x0: int, y1: int, x1: int) -> tuple[slice, slice]:
        return slice(int(y0), int(y1)), slice(int(x0), int(x1))

    return [_WorkBox(rect(*boxes[k]), tuple(rect(*owned[m]) for m in members[k])) for k in alive]


def _full_frame(pieces: list[FlowPiece], shape: tuple[int, int],
                ) -> tuple[local_flow.LocalFlowResult, fmm.MotionInpaintResult]:
    """Flow pieces as full-frame, full-resolution arrays (no flow outside them). Where boxes overlap, each
    pixel shows the piece whose flow it takes (``_claims``)."""
    owner = np.full(shape, -1, np.int64)
    for k, (rows, cols) in _claims(pieces):
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


def _dilate(mask: np.ndarray, *radii: int) -> list[np.ndarray]:
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


def _intensities(samples: list[tuple[np.ndarray, np.ndarray]], threshold: float | None
                 ) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """(intensity, valid) of each neighbour's samples, for ``_seen_by_another``: made once for all the neighbours'
    tests (each compares with every other); None when the test is off (``threshold`` None)."""
    return None if threshold is None else [(imaging.intensity(colours), valid) for colours, valid in samples]


def _seen_by_another(sample: np.ndarray, source: int, shown: list[tuple[np.ndarray, np.ndarray]] | None,
                     threshold: float | None, value: np.ndarray | None = None) -> np.ndarray:
    """Whether some other neighbour than ``source`` shows (as it is, no local motion) the sample's intensity at each
    pixel; ``shown``: every neighbour's (intensity, valid) there (``_intensities``), ``value``: the sample's
    intensity when at hand (else taken here)."""
    if threshold is None or shown is None:
        return np.ones(len(sample), bool)
    if value is None:
        value = imaging.intensity(sample)
    seen = np.zeros(len(sample), bool)
    for n, (intensity, valid) in enumerate(shown):
        if n != source:
            seen |= valid & (np.abs(intensity - value) < threshold)
    return seen


def _best_candidate(candidates: list[_Candidate]) -> np.ndarray:
    """Per pixel, the index of the reached candidate with the lowest local alignment error; -1 where none.

    Unconfirmed static samples (an object that only passed there in that neighbour) rank after all others.
    """
    error = np.stack([np.where(c.reached, c.error + np.where(c.confirmed, 0, np.float32(1e4)), np.inf)
                      for c in candidates])
    best = np.argmin(error, axis=0)
    return np.where(np.isfinite(np.min(error, axis=0)), best, -1)


def _best_static(errors: np.ndarray, samples: list[tuple[np.ndarray, np.ndarray]],
                 confirm_difference: float | None, shown: list[tuple[np.ndarray, np.ndarray]] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the neighbour whose sample (zero local motion) to take: covering the pixel, with the lowest local
    alignment error (``errors``, (neighbours, m), NaN where unmeasured); a sample no other neighbour shows ranks
    after the confirmed ones, as in _best_candidate. Returns (index (m,), its rank (m,): the error, + 1e4 when
    unconfirmed, inf where no neighbour has one). ``shown``: the samples' ``_intensities`` when at hand."""
    ranked = np.full(errors.shape, np.inf, np.float32)
    if shown is None:
        shown = _intensities(samples, confirm_difference)
    for i, (colours, valid) in enumerate(samples):
        confirmed = _seen_by_another(colours, i, shown, confirm_difference,
                                     value=None if shown is None else shown[i][0])
        ranked[i] = np.where(valid & ~np.isnan(errors[i]),
                             errors[i] + np.where(confirmed, np.float32(0), np.float32(1e4)), np.inf)
    which = np.argmin(ranked, axis=0)
    return which, ranked[which, np.arange(ranked.shape[1])]


def _static_candidate(candidates: list[_Candidate], errors: np.ndarray, samples: list[tuple[np.ndarray, np.ndarray]],
                      shown: list[tuple[np.ndarray, np.ndarray]] | None, config: CompletionConfig
                      ) -> tuple[_Candidate, np.ndarray]:
    """The best covering neighbour's sample as it is (``_best_static`` over all neighbours, not only the local-warp
    ones) as one more candidate, at the pixels where no local warp explains the surroundings within
    ``static_candidate_error``; its error counts ``static_candidate_margin`` higher, so a local warp that explains
    them about as well keeps them. Returns the candidate and, per pixel, the index of the neighbour it comes from.

    Why: a moving object's flow carried by motion inpainting into a border strip the object has already left pastes
    a stale copy of it there, and with few local-warp neighbours reaching the strip nothing better competes; the
    background those frames hide is often shown as it is by farther neighbours (docs/completion.md)."""
    which, rank = _best_static(errors, samples, config.confirm_difference, shown)
    warped = np.min(np.stack([np.where(c.reached, c.error, np.inf) for c in candidates]), axis=0)
    reached = np.isfinite(rank) & (warped > config.static_candidate_error)
    colours = np.stack([c for c, _ in samples])[which, np.arange(len(which))]
    error = np.where(reached, rank + np.float32(config.static_candidate_margin), np.inf).astype(np.float32)
    # The confirmation is already in the rank (+1e4 when unconfirmed).
    return (_Candidate(colours, reached, np.zeros(len(which), np.float32), error, np.ones(len(which), bool)),
            which)


def _majority_candidate(errors: np.ndarray, samples: list[tuple[np.ndarray, np.ndarray]],
                        shown: list[tuple[np.ndarray, np.ndarray]] | None, config: CompletionConfig) -> _Candidate:
    """The median of the covering neighbours' strict majority (``mosaic.majority_median``, as they are) where they
    have one; its error is the median of the majority's own local errors without motion (``errors``, (neighbours, m),
    NaN where unmeasured), so it competes with the local warps on how well those neighbours explain the
    surroundings. Several neighbours agreeing is its confirmation."""
    colours = np.stack([c for c, _ in samples])
    valid = np.stack([v for _, v in samples])
    values = (np.stack([i for i, _ in shown]) if shown is not None
              else np.stack([imaging.intensity(c) for c, _ in samples]))
    ok, median, member = mosaic.majority_median(colours, values, valid, config.mosaic.variance_threshold)
    own = np.where(member, errors, np.nan)
    measured = ok & ~np.isnan(own).all(axis=0)
    error = np.full(len(ok), np.inf, np.float32)
    error[measured] = _nan_median_columns(own[:, measured])
    return _Candidate(median, measured, np.zeros(len(ok), np.float32), error, np.ones(len(ok), bool))


def register_neighbours(target: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
                        config: CompletionConfig = CompletionConfig(), *,
                        target_original: WarpedNeighbour | None = None) -> list[WarpedNeighbour]:
    """The neighbours with their global warps refined where frame t's border shows them misregistered.

    The global warp of a neighbour k frames away is a chain of k inter-frame motions of a global model; near
    the frame's border, where the missing area is, the chain's error reaches pixels on far neighbours, and on
    fine texture that fails eq. 20's variance test (and makes a mosaic that changes from frame to frame).
    For each neighbour, ECC (Evangelidis & Psarakis 2008; ``config.register_model``; pipeline/stages/
    registration.py) fits the correction ``other_from_here`` that best aligns it with frame t over frame t's
    known pixels within ``register_band_px`` of the missing area, at most ``register_max_side`` px wide. A lazy
    neighbour is looked at in its own frame (shrunk and differentiated once for all the frames it is a neighbour
    of) through its global warp. A correction is kept only when it moves no frame corner further than
    ``register_max_px`` and lowers the mean intensity difference on the band by 5 % or more; otherwise the
    neighbour is returned as it was. Frame t itself (offset 0) is kept.
    """
    if not neighbours or not missing.any() or missing.all():
        return list(neighbours)
    height, width = missing.shape
    scale = 1.0 if config.register_max_side is None else min(1.0, config.register_max_side / max(height, width))
    size = (max(round(width * scale), 8), max(round(height * scale), 8))
    reduced = size != (width, height)
    small_from_full = _small_from_full(size, (width, height))
    full_from_small = np.linalg.inv(small_from_full)
    band = _dilate(missing, config.register_band_px)[0] & ~missing
    whole = (slice(0, height), slice(0, width))
    if reduced and target_original is not None:
        small_target, small_known = target_original.crop(whole, size)
        band = shrink_all(band, size) & small_known
    elif reduced:
        small_target, band, small_known = shrink(target, size), shrink_all(band, size), shrink_all(~missing, size)
    else:
        small_target, small_known = target, ~missing
    # ECC compares blurred images: the band's pixels whose blur reaches a missing (black) pixel are left out (kept,
    # they pulled the ground truth's corrections 0.3-0.5 px off; without them they are within 0.03 px).
    band &= cv2.GaussianBlur(small_known.astype(np.float32), (3, 3), 0, 0) >= 0.95
    if np.count_nonzero(band) < _MIN_REGISTER_PIXELS:
        return list(neighbours)
    target_grey = imaging.intensity(small_target)
    band_y, band_x = np.nonzero(band)
    template = cv2.GaussianBlur(target_grey, (3, 3), 0, 0)[band_y, band_x]
    target_values = target_grey[band_y, band_x]
    corners = np.array([[0.0, width - 1.0, 0.0, width - 1.0], [0.0, 0.0, height - 1.0, height - 1.0],
                        [1.0, 1.0, 1.0, 1.0]])
    out = []
    for neighbour in neighbours:
        out.append(neighbour)
        if neighbour.offset == 0:
            continue
        if neighbour.original is not None:
            original_height, original_width = neighbour.original.shape[:2]
            source_size = (max(round(original_width * size[0] / width), 8),
                           max(round(original_height * size[1] / height), 8))
            image = registration.source_image(neighbour.original, source_size)
            image_from_small = (_small_from_full(source_size, (original_width, original_height))
                                @ neighbour.other_from_stab @ full_from_small)
        else:
            rgb, valid = neighbour.crop(whole, size if reduced else None)
            image, image_from_small = registration.prepare(imaging.intensity(rgb), valid), np.eye(3)
        before, covered = _sample_intensity(image, image_from_small, band_x, band_y)
        if np.count_nonzero(covered) < _MIN_REGISTER_PIXELS:
            continue
        # Over every band pixel: taking every other or third (selh_asb_1's band has 5-10 thousand at 320 px) made
        # the corrections vary more from frame to frame (flicker 1.03 -> 1.10 on its first 120 frames).
        small_correction = registration.ecc_on_points(template[covered], band_x[covered], band_y[covered], image,
                                                      image_from_small, config.register_model, _ECC_ITERATIONS)
        if small_correction is None:  # did not converge, or a degenerate update
            continue
        correction = full_from_small @ small_correction @ small_from_full
        moved = correction @ corners
        with np.errstate(divide="ignore", invalid="ignore"):
            moved = moved[:2] / moved[2]
        if not np.isfinite(moved).all() or np.abs(moved - corners[:2]).max() > config.register_max_px:
            continue
        after, still = _sample_intensity(image, image_from_small @ small_correction, band_x, band_y)
        both = covered & still
        if not both.any():
            continue
        if np.abs(target_values - after)[both].mean() < 0.95 * np.abs(target_values - before)[both].mean():
            out[-1] = neighbour.refined(correction)
    return out


def _small_from_full(small: tuple[int, int], full: tuple[int, int]) -> np.ndarray:
    """Pixel centres of an image of size ``full`` (width, height) shrunk to ``small``: full (x + 0.5) is
    small (x + 0.5) * scale."""
    scale_x, scale_y = small[0] / full[0], small[1] / full[1]
    return np.array([[scale_x, 0.0, 0.5 * scale_x - 0.5], [0.0, scale_y, 0.5 * scale_y - 0.5], [0.0, 0.0, 1.0]])


def _sample_intensity(image: registration.SourceImage, image_from_work: np.ndarray, xs: np.ndarray, ys: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The unblurred intensity of ``image`` at working points (xs, ys) through ``image_from_work`` (bilinear) and
    whether each lands on its usable area."""
    mapped = image_from_work @ np.stack([xs, ys, np.ones(len(xs))])
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = mapped[0] / mapped[2], mapped[1] / mapped[2]
    height, width = image.usable.shape
    inside = (u >= 0) & (v >= 0) & (u <= width - 1) & (v <= height - 1)
    landed = np.zeros(len(xs), bool)
    landed[inside] = image.usable[np.rint(v[inside]).astype(np.intp), np.rint(u[inside]).astype(np.intp)]
    values = remap_points(image.intensity, np.where(landed, u, -2.0), np.where(landed, v, -2.0))[:, 0]
    return values, landed


def _moving_and_better(candidates: list[_Candidate], chosen: np.ndarray, static_error: np.ndarray,
                       config: CompletionConfig) -> np.ndarray:
    """Pixels whose chosen candidate moves and explains the surroundings clearly better than the static scene: its
    error under the static scene's by ``mosaic_check_margin`` and under ``mosaic_check_ratio`` of it."""
    pick = np.maximum(chosen, 0)[None]
    motion = np.take_along_axis(np.stack([c.motion for c in candidates]), pick, 0)[0]
    error = np.take_along_axis(np.stack([c.error for c in candidates]), pick, 0)[0]
    return ((chosen >= 0) & (motion > config.moving_px) & (error + config.mosaic_check_margin < static_error)
            & (error < config.mosaic_check_ratio * static_error))


def _extrapolated_candidates(neighbours: Sequence[WarpedNeighbour], at_needing: list[tuple[np.ndarray, np.ndarray]],
                             ys: np.ndarray, xs: np.ndarray, needing: np.ndarray, local_error: _LocalError,
                             config: CompletionConfig) -> list[tuple[int, _Candidate]]:
    """Moving content carried on into frame t from either side: (offset s of the neighbour sampled, candidate over
    the ``needing`` pixels) for s = -1 and +1 where neighbours s and 2s are both given (``at_needing``: every
    neighbour's samples at those pixels).

    Frame t's content at p moved by v a frame was at p - v in frame t+s (s = -1; p + v for s = +1); the flow H from
    the warped neighbour t+s to t+2s is about -v (+v) on it, so the candidate is I_{t+s}(p + H(p)). H is taken at p
    of frame t+s, where the content was v earlier: exact inside an object that moves less than its own size a
    frame, off by up to v at its edges. A sample counts where both neighbours cover p (H was measured there, not
    invented), it lands on frame t+s's content, and it moves by more than ``moving_px`` (elsewhere it is the static
    scene, the mosaic's and the static fill's); its local alignment error on the band ranks it as any local warp.

    Why: a local warp's flow is frame t's own, measured on its known surroundings and inpainted outwards; an object
    that has left those surroundings (crossing the border, or a near object under parallax) is then pasted where
    the neighbour saw it, a frame or more stale, while the two neighbours on one side still see it move
    (docs/completion.md)."""
    index_of = {neighbour.offset: i for i, neighbour in enumerate(neighbours)}
    # No pixel both neighbours cover: no sample to take, no flow to measure. (Skipping frames whose two neighbours also
    # look alike there halved the cost but switched the candidate on and off from frame to frame: selh_tasc's
    # synthesized-pixel flicker 1.29 -> 1.41.)
    sides = [side for side in (-1, 1) if side in index_of and 2 * side in index_of
             and (at_needing[index_of[side]][1] & at_needing[index_of[2 * side]][1]).any()]
    if not sides:
        return []
    m = len(needing)
    points_y = np.concatenate([ys[needing], local_error.band_y])
    points_x = np.concatenate([xs[needing], local_error.band_x])
    # Both sides' flows over one box: every pixel needing a local warp with the local flows' margin of context, at
    # their working resolution. On a box around the covered pixels alone, or at half that resolution, DIS lost the
    # objects' motion (synthetic rocket seed 13: +5.67 dB over mosaic + Telea against +3.55 and +2.76).
    height, width = neighbours[index_of[sides[0]]].shape
    scale = flow_scale((height, width), config)
    margin = round((config.flow_margin_px if config.flow_margin_px is not None else max(height, width)) / scale)
    rows = slice(max(int(ys[needing].min()) - margin, 0), min(int(ys[needing].max()) + 1 + margin, height))
    cols = slice(max(int(xs[needing].min()) - margin, 0), min(int(xs[needing].max()) + 1 + margin, width))
    size = _working_size((rows, cols), scale)
    step_x, step_y = ((1.0, 1.0) if size is None
                      else (size[0] / (cols.stop - cols.start), size[1] / (rows.stop - rows.start)))
    # Working-resolution coordinates of the points (pixel centres map to pixel centres); outside the box a point is
    # not measured.
    u = ((points_x - cols.start + 0.5) * step_x - 0.5).astype(np.float32)
    v = ((points_y - rows.start + 0.5) * step_y - 0.5).astype(np.float32)
    out = []
    for side in sides:
        near, far = neighbours[index_of[side]], neighbours[index_of[2 * side]]
        near_rgb, near_valid = near.crop((rows, cols), size)
        far_rgb, far_valid = far.crop((rows, cols), size)
        flow = local_flow.local_flow(near_rgb, near_valid, far_rgb, far_valid, config.flow)
        h = remap_points(flow.flow, u, v, cv2.BORDER_REPLICATE)
        hx, hy = h[:, 0] / np.float32(step_x), h[:, 1] / np.float32(step_y)
        measured = remap_points(flow.common.astype(np.uint8) * 255, u, v)[:, 0] == 255  # every tap measured
        colours, landed = near.sample(points_x + hx, points_y + hy)
        motion = np.hypot(hx, hy).astype(np.float32)
        landed &= measured & (motion > config.moving_px)
        error = np.nan_to_num(local_error(colours[m:], landed[m:])[needing], nan=255.0).astype(np.float32)
        out.append((side, _Candidate(colours[:m], landed[:m], motion[:m], error, np.ones(m, bool))))
    return out


def _local_warp(flow: np.ndarray, neighbour: WarpedNeighbour, ys: np.ndarray, xs: np.ndarray,
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
