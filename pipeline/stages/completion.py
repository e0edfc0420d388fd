"""Full-frame video completion (thesis chapter 4): the ordered chain that fills a stabilized frame's missing area,
each step filling what the ones before it left.

0. local registration (``register_neighbours``): each neighbour's global warp refined on the band next to the
   missing area, where a chain of global motions has drifted by pixels on far neighbours;
1. consistent mosaicing (eqs. 20-22, pipeline/stages/mosaic.py): static areas, median of neighbours that agree;
2. the contest of candidate sources (pipeline/stages/candidates.py), run in the order ``CompletionConfig.candidates``
   lists: each proposes values and a local alignment error (eq. 23 made local) for the pixels it can fill, the
   lowest error wins per pixel (``choose``), and the winners are written back (``_write_back``). The default chain
   is the mosaic's doubtful pixels, local warps through inpainted local flow (eqs. 23-25, pipeline/stages/
   local_warp.py), a neighbour's sample as it is, the neighbours' majority, and moving content carried on;
3. a smooth last-resort fill (pipeline/stages/fallback.py) for what no neighbour covers.

Invariants: every neighbour arrives already warped into the target's stabilized coordinates, with its valid
mask; pixels outside ``missing`` are never changed; every missing pixel leaves filled, and ``source`` says by
which step or candidate. Why each choice, with the measurements: docs/completion.md.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Callable, Sequence

import cv2
import numpy as np

from pipeline import geometry, imaging
from pipeline.errors import ConfigError
from pipeline.stages import fallback, fmm, local_flow, local_warp, mosaic, registration, temporal
from pipeline.stages.candidates import (AsIs, Candidate, CandidateSource, CarriedOn, Contest, Evidence, LocalWarps,
                                        Majority, Mosaic, UNCONFIRMED_PENALTY, nan_median_columns)
from pipeline.stages.local_warp import FlowPiece, FlowSettings, NeighbourFill  # noqa: F401 (results name them here)
from pipeline.stages.neighbours import WarpedNeighbour, remap_points, shrink, shrink_all

# What filled each pixel (CompletionResult.source): "original" (not missing), "mosaic" (step 1), "fallback" (step 3),
# and the kinds of candidate that win step 2's contest, by the names CompletionConfig.candidates lists. Three kinds
# take a pixel's value from one neighbour (CompletionResult.filled_by names it): its local warp (eq. 25), its moving
# content carried on by a frame, its sample as it is (no local motion); the majority is several neighbours' median.
SOURCE_ORIGINAL, SOURCE_MOSAIC, SOURCE_LOCAL_WARP, SOURCE_FALLBACK, SOURCE_CARRIED_ON, SOURCE_AS_IS = 0, 1, 2, 3, 4, 5
SOURCE_MAJORITY = 6
SOURCE_NAMES = ("original", "mosaic", "local warp", "fallback", "carried on", "neighbour as is", "majority")
NEIGHBOUR_SOURCES = (SOURCE_LOCAL_WARP, SOURCE_CARRIED_ON, SOURCE_AS_IS)  # filled_by names the neighbour


def from_a_neighbour(source: np.ndarray) -> np.ndarray:
    """Where one neighbour's sample filled (``filled_by`` holds its offset there): any of NEIGHBOUR_SOURCES."""
    return np.isin(source, NEIGHBOUR_SOURCES)


# ECC's iterations per neighbour: it starts from the global warp, a pixel or two off, and more iterations give the
# same corrections on the ground truth at several times the cost (docs/completion.md).
_ECC_ITERATIONS = 10
_MIN_REGISTER_PIXELS = 200  # fewer band pixels than this (at the working resolution): the warp is left as it is


@dataclass(frozen=True)
class CompletionConfig:
    """Chapter 4's settings. Lengths are in pixels of the full-resolution frame unless a field says otherwise;
    errors and differences are intensities (0..255, pipeline.imaging.intensity)."""

    neighbour_frames: int = 6  # frames: neighbours t-r..t+r take part (mosaic and candidates)
    # The candidate sources of step 2, in order (pipeline/stages/candidates.py; names from SOURCE_NAMES): an earlier
    # one wins a tie, and each sees those before it. "mosaic": the mosaic's pixels whose static scene explains their
    # surroundings worse than mosaic_check_margin are contested too (without it, the mosaic's pixels are final).
    # "majority" and "carried on" take part only where some local warp does (see _propose). --quality fast drops
    # "mosaic" and "carried on" (pipeline/presets.py).
    candidates: tuple[str, ...] = ("mosaic", "local warp", "neighbour as is", "majority", "carried on")
    max_warp_neighbours: int = 4  # neighbours: local flows are computed for this many, by priority
    residual_radius: int = 4  # px: a local alignment error averages the known pixels within r of the nearest one
    moving_px: float = 2.0  # px: a candidate sampled through a longer flow shows moving content
    # A moving candidate replaces a doubtful mosaic pixel when its error is under the static scene's by more than
    # mosaic_check_margin (intensity) and under mosaic_check_ratio (a share, in (0, 1]; 1: the margin alone) of it:
    # on a motion-blurred frame every sharp sample's error grows with the blur, and the margin alone let a moving
    # object's flow, carried into the strip by motion inpainting, replace background the mosaic had right.
    mosaic_check_margin: float = 5.0
    mosaic_check_ratio: float = 0.5
    # px of the flow's working resolution: local flows run in boxes around the pixels needing a local warp, grown by
    # this much context (DIS's coarsest pyramid level loses a fast object's motion in a smaller box); None: the whole
    # frame.
    flow_margin_px: int | None = 96
    # px: local flows and motion inpainting run on frames scaled down to this longest side, as motion estimation does
    # (the flow is upsampled after; the local warp samples full-resolution neighbours); None: full resolution.
    flow_max_side: int | None = 640
    confirm_difference: float = 20.0  # intensity: another neighbour as it is within this confirms a sample
    # Local registration (register_neighbours) with this motion model: "translation", "affine", "homography"; None:
    # off. It fits on frame t's known pixels within register_band_px (px) of the missing area, refuses a correction
    # moving a frame corner by more than register_max_px (px), and works at a longest side of register_max_side px
    # (None: full resolution).
    register_model: str | None = "homography"
    register_band_px: int = 24
    register_max_px: float = 12.0
    register_max_side: int | None = 320
    # "neighbour as is" competes where every candidate before it explains the surroundings worse than
    # static_candidate_error (intensity), its own error counted static_candidate_margin (intensity) higher.
    static_candidate_error: float = 30.0
    static_candidate_margin: float = 3.0
    mosaic: mosaic.MosaicConfig = field(default_factory=mosaic.MosaicConfig)  # eqs. 20-22
    flow: local_flow.LocalFlowConfig = field(default_factory=local_flow.LocalFlowConfig)  # local flow (eq. 23)
    inpaint: fmm.MotionInpaintConfig = field(default_factory=fmm.MotionInpaintConfig)  # motion inpainting (eq. 24)
    # After every frame is completed: its synthesized pixels averaged with the completed frames next to it where they
    # agree (pipeline/stages/temporal.py; run over the stream of frames by pipeline/chain.py).
    temporal: temporal.TemporalConfig = field(default_factory=temporal.TemporalConfig)

    def __post_init__(self) -> None:
        unknown = [name for name in self.candidates if name not in _SOURCES]
        if unknown or len(set(self.candidates)) != len(self.candidates):
            raise ConfigError(f"candidates must be distinct names among {', '.join(_SOURCES)}, "
                              f"not {', '.join(self.candidates)}")
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
        if not self.static_candidate_error >= 0:
            raise ConfigError(f"static_candidate_error must be >= 0, not {self.static_candidate_error}")
        if self.register_band_px < 1:
            raise ConfigError(f"register_band_px must be >= 1, not {self.register_band_px}")
        if not self.register_max_px > 0:
            raise ConfigError(f"register_max_px must be positive, not {self.register_max_px}")
        if self.register_max_side is not None and self.register_max_side < 32:
            raise ConfigError(f"register_max_side must be at least 32 px, not {self.register_max_side}")


def _flow_settings(config: CompletionConfig) -> FlowSettings:
    return FlowSettings(config.flow_max_side, config.flow_margin_px, config.flow, config.inpaint)


# Each candidate source by its name in CompletionConfig.candidates, made with its settings.
_SOURCES: dict[str, Callable[[CompletionConfig], CandidateSource]] = {
    Mosaic.kind: lambda config: Mosaic(),
    LocalWarps.kind: lambda config: LocalWarps(config.max_warp_neighbours, _flow_settings(config), config.moving_px),
    AsIs.kind: lambda config: AsIs(config.static_candidate_error, config.static_candidate_margin),
    Majority.kind: lambda config: Majority(config.mosaic.variance_threshold),
    CarriedOn.kind: lambda config: CarriedOn(_flow_settings(config), config.moving_px),
}


@dataclass(frozen=True)
class CompletionResult:
    """One frame's completion: the completed frame and what each step made of it (ffviz/recorder.py records them)."""

    frame: np.ndarray  # completed (H, W, 3) uint8
    missing: np.ndarray  # the stabilized frame's missing mask this started from
    mosaic: mosaic.MosaicResult
    neighbour_order: list[int]  # offsets by priority
    fills: list[NeighbourFill]  # the local warps', by priority
    source: np.ndarray  # (H, W) uint8: SOURCE_* per pixel
    filled_by: np.ndarray  # (H, W) int16: the neighbour's offset where one neighbour filled (from_a_neighbour), else 0
    fallback: np.ndarray  # (H, W) bool: pixels the last resort filled
    corrected: np.ndarray | None = None  # (H, W) bool: mosaic pixels a moving candidate replaced
    registered: tuple[int, ...] = ()  # offsets of the neighbours whose warps local registration refined
    # A call returning the mosaic.MosaicResult of the unrefined global warps, made on request (what OpenCV's
    # chain, which has no local registration, would start from: the evaluation's baseline); None when no warp
    # was refined.
    unregistered_mosaic: Callable[[], object] | None = None


def complete(target: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
             config: CompletionConfig = CompletionConfig(), *,
             target_original: WarpedNeighbour | None = None) -> CompletionResult:
    """Fill ``missing`` pixels of the stabilized ``target`` from its warped neighbours, by the chain of the module
    docstring: local registration, the mosaic, the contest of ``config.candidates``, the smooth fallback.

    ``target_original``: frame t itself as a lazy neighbour (offset 0, with its downscaled copy), so that the
    local flow's reduced-resolution crops of frame t are resampled as the neighbours' are (from the downscaled
    copy); without it they are shrunk from ``target``, and the neighbours come out slightly blurrier than frame t.
    """
    given = neighbours
    if config.register_model is not None:
        neighbours = register_neighbours(target, missing, neighbours, config, target_original=target_original)
    registered = tuple(b.offset for a, b in zip(given, neighbours) if a is not b)
    evidence = Evidence(target, missing, neighbours, config.residual_radius, target_original)
    mosaic_result = _mosaic(target, missing, neighbours, config.mosaic, evidence.samples)
    filled = _Filled.by_mosaic(mosaic_result, missing)
    contest = _contest(evidence, mosaic_result, config)
    proposed = [] if contest is None else _propose([_SOURCES[name](config) for name in config.candidates], contest)
    if proposed:
        _write_back(filled, contest, proposed, choose(proposed, config))
    order = local_warp.by_distance(neighbours) if contest is None else contest.order
    return CompletionResult(
        frame=fallback.smooth_fill(filled.frame, filled.remaining) if filled.remaining.any() else filled.frame,
        missing=missing, mosaic=mosaic_result, neighbour_order=[neighbours[i].offset for i in order],
        fills=[c.fill for c in proposed if c.fill is not None], source=filled.source, filled_by=filled.filled_by,
        fallback=filled.remaining, corrected=filled.corrected, registered=registered,
        unregistered_mosaic=functools.partial(_mosaic, target, missing, given, config.mosaic) if registered else None)


def _mosaic(target: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
            config: mosaic.MosaicConfig, at_missing: list[tuple[np.ndarray, np.ndarray]] | None = None
            ) -> mosaic.MosaicResult:
    """Eqs. 20-22 from the neighbours' samples at the missing pixels (``at_missing``, taken here when not given)."""
    if at_missing is None:
        ys, xs = geometry.mask_pixels(missing)
        at_missing = [n.at(ys, xs) for n in neighbours]
    return mosaic.mosaic_from_samples(
        target, missing, np.stack([c for c, _ in at_missing]) if neighbours else None,
        np.stack([v for _, v in at_missing]) if neighbours else None, config)


def _contest(evidence: Evidence, mosaic_result: mosaic.MosaicResult, config: CompletionConfig) -> Contest | None:
    """The pixels the candidates compete for: what the mosaic left, and, with "mosaic" among the candidates, its
    pixels whose static scene explains the surroundings worse than ``mosaic_check_margin`` (elsewhere no candidate
    could replace it: ``_moving_and_better``). The static scene's error is the median of the covering neighbours'
    errors as they are. None when there is no such pixel or nothing to judge candidates by."""
    if not evidence.judged:
        return None
    ys, xs = evidence.ys, evidence.xs
    accepted = mosaic_result.accepted[ys, xs]
    static_error = np.full(len(ys), -np.inf, np.float32)
    if Mosaic.kind in config.candidates and accepted.any():
        per_neighbour = evidence.errors_as_is[:, accepted]
        covered = ~np.isnan(per_neighbour).all(axis=0)  # no neighbour sees the surroundings: no evidence
        static_error[np.flatnonzero(accepted)[covered]] = nan_median_columns(per_neighbour[:, covered])
    doubted = accepted & (static_error > config.mosaic_check_margin)
    pixels = np.flatnonzero(mosaic_result.remaining[ys, xs] | doubted)
    if not len(pixels):
        return None
    order, errors = local_warp.priority(evidence.target, evidence.known, evidence.neighbours,
                                        config.max_warp_neighbours)
    return Contest(evidence, pixels, mosaic_result.frame[ys[pixels], xs[pixels]], static_error[pixels],
                   doubted[pixels], order, errors, config.confirm_difference)


def _propose(chain: Sequence[CandidateSource], contest: Contest) -> list[Candidate]:
    """Every source's candidates over the contest, in the chain's order, each source seeing those before it.

    The majority and the carried-on content refine local-warp mosaicing: where no neighbour could be warped
    locally (none overlaps frame t's known area, or ``max_warp_neighbours`` is 0) they stand aside, and the
    neighbours' samples as they are fill what the mosaic left."""
    proposed: list[Candidate] = []
    for source in chain:
        proposed += source.propose(contest, tuple(proposed))
    if not any(c.kind == LocalWarps.kind for c in proposed):
        proposed = [c for c in proposed if c.kind in (Mosaic.kind, AsIs.kind)]
    return proposed


def choose(candidates: Sequence[Candidate], config: CompletionConfig) -> np.ndarray:
    """Per contested pixel, the index of the candidate to write there; -1: none (the pixel stays as it was).

    The reached candidate with the lowest local alignment error wins, an unconfirmed one (a static sample no other
    neighbour shows: an object that passed there in that frame only) after every confirmed one, the earlier in the
    chain on a tie. The mosaic's candidate is not in that race: it keeps its pixels unless the winner moves and
    explains the surroundings clearly better (``_moving_and_better``): eqs. 20-22 assume a static scene, and only
    moving content shows where that assumption failed.
    """
    error = np.stack([np.where(c.reached & (c.kind != Mosaic.kind),
                               c.error + np.where(c.confirmed, 0, UNCONFIRMED_PENALTY), np.inf) for c in candidates])
    chosen = np.where(np.isfinite(np.min(error, axis=0)), np.argmin(error, axis=0), -1)
    for held in (c for c in candidates if c.kind == Mosaic.kind):
        chosen[held.reached & ~_moving_and_better(candidates, chosen, held.error, config)] = -1
    return chosen


def _moving_and_better(candidates: Sequence[Candidate], chosen: np.ndarray, static_error: np.ndarray,
                       config: CompletionConfig) -> np.ndarray:
    """Pixels whose chosen candidate moves and explains the surroundings clearly better than the static scene: its
    error under the static scene's by ``mosaic_check_margin`` and under ``mosaic_check_ratio`` of it."""
    pick = np.maximum(chosen, 0)[None]
    motion = np.take_along_axis(np.stack([c.motion for c in candidates]), pick, 0)[0]
    error = np.take_along_axis(np.stack([c.error for c in candidates]), pick, 0)[0]
    return ((chosen >= 0) & (motion > config.moving_px) & (error + config.mosaic_check_margin < static_error)
            & (error < config.mosaic_check_ratio * static_error))


@dataclass
class _Filled:
    """The frame as the chain fills it, and what filled each pixel so far (CompletionResult's fields)."""

    frame: np.ndarray
    source: np.ndarray
    filled_by: np.ndarray
    remaining: np.ndarray  # missing pixels nothing has filled yet
    corrected: np.ndarray

    @staticmethod
    def by_mosaic(result: mosaic.MosaicResult, missing: np.ndarray) -> _Filled:
        source = np.where(missing, SOURCE_FALLBACK, SOURCE_ORIGINAL).astype(np.uint8)
        source[result.accepted] = SOURCE_MOSAIC
        return _Filled(result.frame.copy(), source, np.zeros(missing.shape, np.int16), result.remaining.copy(),
                       np.zeros(missing.shape, bool))


def _write_back(filled: _Filled, contest: Contest, candidates: Sequence[Candidate], chosen: np.ndarray) -> None:
    """Each contested pixel's chosen candidate (``choose``) into the frame, with its kind (``source``), the neighbour
    it was sampled from (``filled_by``), whether it replaced a mosaic pixel (``corrected``), and, for a local warp,
    into its NeighbourFill's ``filled``."""
    among = np.flatnonzero(chosen >= 0)
    which = chosen[among]
    ys, xs = contest.ys[among], contest.xs[among]
    filled.frame[ys, xs] = np.stack([c.colours for c in candidates])[which, among]
    filled.source[ys, xs] = np.array([SOURCE_NAMES.index(c.kind) for c in candidates], np.uint8)[which]
    filled.filled_by[ys, xs] = np.stack([c.sampled_from for c in candidates])[which, among]
    filled.corrected[ys, xs] = contest.doubted[among]
    filled.remaining[ys, xs] = False
    for k, candidate in enumerate(candidates):
        if candidate.fill is not None:
            candidate.fill.filled[ys[which == k], xs[which == k]] = True


def flow_scale(shape: tuple[int, int], config: CompletionConfig) -> float:
    """Local flow's working resolution as a fraction of the frame's (``flow_max_side``)."""
    return local_warp.working_scale(shape, config.flow_max_side)


def register_neighbours(target: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
                        config: CompletionConfig = CompletionConfig(), *,
                        target_original: WarpedNeighbour | None = None) -> list[WarpedNeighbour]:
    """The neighbours with their global warps refined where frame t's border shows them misregistered.

    The global warp of a neighbour k frames away is a chain of k inter-frame motions of a global model; near
    the frame's border, where the missing area is, the chain's error reaches pixels on far neighbours, and on
    fine texture that fails eq. 20's variance test (and makes a mosaic that changes from frame to frame).
    For each neighbour, ECC (Evangelidis & Psarakis 2008; ``config.register_model``; pipeline/stages/
    registration.py) fits the correction ``other_from_here`` that best aligns it with frame t over frame t's
    known pixels within ``register_band_px`` of the missing area, at most ``register_max_side`` px wide
    (``_RegistrationBand``). A correction is kept only when it moves no frame corner further than
    ``register_max_px`` and lowers the mean intensity difference on the band by 5 % or more; otherwise the
    neighbour is returned as it was. Frame t itself (offset 0) is kept.
    """
    if not neighbours or not missing.any() or missing.all():
        return list(neighbours)
    band = _RegistrationBand.of(target, missing, config, target_original)
    if band is None:
        return list(neighbours)
    return [neighbour if neighbour.offset == 0 else _registered(neighbour, band, config) for neighbour in neighbours]


@dataclass(frozen=True)
class _RegistrationBand:
    """Frame t's known pixels next to the missing area at registration's working resolution: what ECC aligns each
    neighbour with."""

    shape: tuple[int, int]  # (height, width) of the full-resolution frame
    size: tuple[int, int]  # (width, height) at the working resolution
    small_from_full: np.ndarray  # 3x3: full-resolution pixel centres to working ones
    x: np.ndarray  # the band's pixels at the working resolution
    y: np.ndarray
    template: np.ndarray  # frame t's intensity there, blurred as ECC compares it
    values: np.ndarray  # frame t's intensity there, unblurred: the band's error before and after

    @staticmethod
    def of(target: np.ndarray, missing: np.ndarray, config: CompletionConfig,
           target_original: WarpedNeighbour | None) -> _RegistrationBand | None:
        """None where the band has fewer than ``_MIN_REGISTER_PIXELS`` pixels."""
        height, width = missing.shape
        scale = 1.0 if config.register_max_side is None else min(1.0, config.register_max_side / max(height, width))
        size = (max(round(width * scale), 8), max(round(height * scale), 8))
        reduced = size != (width, height)
        band = local_warp.dilate(missing, config.register_band_px)[0] & ~missing
        if reduced and target_original is not None:
            small_target, small_known = target_original.crop((slice(0, height), slice(0, width)), size)
            band = shrink_all(band, size) & small_known
        elif reduced:
            small_target, band, small_known = shrink(target, size), shrink_all(band, size), shrink_all(~missing, size)
        else:
            small_target, small_known = target, ~missing
        # ECC compares blurred images: the band's pixels whose blur reaches a missing (black) pixel are left out (kept,
        # they pull the corrections off by a fraction of a pixel: docs/completion.md).
        band &= cv2.GaussianBlur(small_known.astype(np.float32), (3, 3), 0, 0) >= 0.95
        if np.count_nonzero(band) < _MIN_REGISTER_PIXELS:
            return None
        target_grey = imaging.intensity(small_target)
        band_y, band_x = np.nonzero(band)
        template = cv2.GaussianBlur(target_grey, (3, 3), 0, 0)[band_y, band_x]
        return _RegistrationBand((height, width), size, _small_from_full(size, (width, height)), band_x, band_y,
                                 template, target_grey[band_y, band_x])

    @property
    def reduced(self) -> bool:
        return self.size != (self.shape[1], self.shape[0])

    def image_of(self, neighbour: WarpedNeighbour) -> tuple[registration.SourceImage, np.ndarray]:
        """The neighbour as ECC samples it, and image_from_small: a lazy neighbour in its own frame (shrunk and
        differentiated once for all the frames it is a neighbour of) through its global warp, else its warp."""
        height, width = self.shape
        if neighbour.original is None:
            rgb, valid = neighbour.crop((slice(0, height), slice(0, width)), self.size if self.reduced else None)
            return registration.prepare(imaging.intensity(rgb), valid), np.eye(3)
        original_height, original_width = neighbour.original.shape[:2]
        source_size = (max(round(original_width * self.size[0] / width), 8),
                       max(round(original_height * self.size[1] / height), 8))
        image_from_small = (_small_from_full(source_size, (original_width, original_height))
                            @ neighbour.other_from_stab @ np.linalg.inv(self.small_from_full))
        return registration.source_image(neighbour.original, source_size), image_from_small


def _registered(neighbour: WarpedNeighbour, band: _RegistrationBand, config: CompletionConfig) -> WarpedNeighbour:
    """``neighbour`` with its warp refined by ECC on ``band``, or as it is where the correction is refused."""
    image, image_from_small = band.image_of(neighbour)
    before, covered = _sample_intensity(image, image_from_small, band.x, band.y)
    if np.count_nonzero(covered) < _MIN_REGISTER_PIXELS:
        return neighbour
    # Over every band pixel: a regular subsample shifts with the band from frame to frame, and the corrections
    # varied more (docs/completion.md).
    small_correction = registration.ecc_on_points(band.template[covered], band.x[covered], band.y[covered], image,
                                                  image_from_small, config.register_model, _ECC_ITERATIONS)
    if small_correction is None:  # did not converge, or a degenerate update
        return neighbour
    correction = np.linalg.inv(band.small_from_full) @ small_correction @ band.small_from_full
    height, width = band.shape
    corners = np.array([[0.0, width - 1.0, 0.0, width - 1.0], [0.0, 0.0, height - 1.0, height - 1.0],
                        [1.0, 1.0, 1.0, 1.0]])
    moved = correction @ corners
    with np.errstate(divide="ignore", invalid="ignore"):
        moved = moved[:2] / moved[2]
    if not np.isfinite(moved).all() or np.abs(moved - corners[:2]).max() > config.register_max_px:
        return neighbour
    after, still = _sample_intensity(image, image_from_small @ small_correction, band.x, band.y)
    both = covered & still
    if both.any() and (np.abs(band.values - after)[both].mean()
                       < 0.95 * np.abs(band.values - before)[both].mean()):
        return neighbour.refined(correction)
    return neighbour


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
