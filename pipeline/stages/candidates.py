"""Completion's candidate sources (thesis chapter 4, step 2): each proposes, for the contested pixels it can fill,
values and a local alignment error; pipeline/stages/completion.py runs them in the order its configuration lists
and lets the lowest error win per pixel.

The interface is ``CandidateSource.propose(contest, proposed) -> list[Candidate]``: a ``Contest`` holds the pixels
(what the mosaic left, and the mosaic's own pixels in doubt) and the evidence every candidate is judged by; a
``Candidate`` is one proposal over them. The sources, by the names ``CompletionConfig.candidates`` lists:

- ``Mosaic`` ("mosaic"): eqs. 20-22's median where the static scene explains the surroundings badly, the value
  to beat (a moving candidate clearly better replaces it);
- ``LocalWarps`` ("local warp"): eq. 25 through each near neighbour's inpainted local flow (eqs. 23-24);
- ``AsIs`` ("neighbour as is"): the best covering neighbour's sample with no local motion, where the candidates
  before it failed;
- ``Majority`` ("majority"): the median of the covering neighbours' strict majority;
- ``CarriedOn`` ("carried on"): moving content carried on by a frame from the two neighbours on one side.

Eq. 23 made local (``LocalError``): the thesis fills a pixel from the first neighbour whose warp reaches it, but
one neighbour's inpainted flow is a guess (object flow bleeds into background, an occluder hides the pixel). So a
candidate is judged by how well it explains the known surroundings it continues: the mean intensity difference
after its warp around the pixel's nearest known pixel. A static sample no other neighbour confirms ranks after
every confirmed one. Why each source, with the measurements: docs/completion.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar, Protocol, Sequence

import cv2
import numpy as np
from numba import njit

from pipeline import geometry, imaging
from pipeline.stages import fallback, local_flow, local_warp, mosaic
from pipeline.stages.local_warp import FlowSettings, NeighbourFill
from pipeline.stages.neighbours import WarpedNeighbour, remap_points

UNCONFIRMED_PENALTY = np.float32(1e4)  # added to an unconfirmed sample's error: it ranks after every confirmed one


@dataclass
class Candidate:
    """What one source proposes for the contested pixels (vectors over them, m long)."""

    kind: str  # the source's name (CompletionConfig.candidates, completion.SOURCE_NAMES)
    colours: np.ndarray  # (m, 3) uint8: the values proposed
    reached: np.ndarray  # (m,) bool: where it has a value
    motion: np.ndarray  # (m,) float32: px, the local motion its sample was taken through (0: as it is)
    error: np.ndarray  # (m,) float32: local alignment error (LocalError), intensity 0..255
    confirmed: np.ndarray  # (m,) bool: moves, or another neighbour shows the same there (not a passing occluder)
    sampled_from: np.ndarray  # (m,) int16: the offset of the neighbour each value comes from; 0: none (several)
    fill: NeighbourFill | None = None  # a local warp's flows and what it filled


class CandidateSource(Protocol):
    """One link of completion's chain."""

    kind: ClassVar[str]  # its name in CompletionConfig.candidates and completion.SOURCE_NAMES

    def propose(self, contest: Contest, proposed: Sequence[Candidate]) -> list[Candidate]:
        """Candidates over ``contest``'s pixels (none, one, or one per neighbour); ``proposed``: those of the
        sources before it in the chain."""
        ...


class Evidence:
    """What candidates are judged by, over frame t's missing pixels (``ys``, ``xs``): the neighbours' samples there
    (``samples``), and eq. 23 made local (``local_error``) with each neighbour's error as it is, made on first use.

    ``target``: the stabilized frame t; ``neighbours``: warped into its coordinates; ``target_original``: frame t
    as a lazy neighbour (see completion.complete)."""

    def __init__(self, target: np.ndarray, missing: np.ndarray, neighbours: Sequence[WarpedNeighbour],
                 residual_radius: int, target_original: WarpedNeighbour | None = None) -> None:
        self.target, self.missing, self.known = target, missing, ~missing
        self.neighbours, self.target_original = list(neighbours), target_original
        self.residual_radius = residual_radius
        self.ys, self.xs = geometry.mask_pixels(missing)
        # Each neighbour is looked at only where needed (pipeline/stages/neighbours.py): first at the missing pixels.
        self.samples = [n.at(self.ys, self.xs) for n in self.neighbours]

    @property
    def judged(self) -> bool:
        """Whether there are pixels to fill, and known surroundings and neighbours to judge candidates by."""
        return bool(len(self.ys)) and bool(self.known.any()) and bool(self.neighbours)

    @cached_property
    def local_error(self) -> LocalError:
        return LocalError(self.target, self.known, self.ys, self.xs, self.residual_radius)

    @cached_property
    def errors_as_is(self) -> np.ndarray:
        """(neighbours, missing pixels) float32: each neighbour's local error with no local motion; NaN where its
        sample reached none of a pixel's window."""
        band = (self.local_error.band_y, self.local_error.band_x)
        return np.stack([self.local_error(*n.at(*band)) for n in self.neighbours])


@dataclass
class Contest:
    """The pixels the candidates compete for, as indices into the evidence's missing pixels (``pixels``, m of them),
    and what the sources share about them."""

    evidence: Evidence
    pixels: np.ndarray  # (m,) intp
    mosaic_colours: np.ndarray  # (m, 3): the frame as the mosaic left it
    mosaic_error: np.ndarray  # (m,) float32: the static scene's local error where the mosaic is in doubt
    doubted: np.ndarray  # (m,) bool: the mosaic's own pixels in the contest
    order: list[int]  # neighbour indices by priority (local_warp.priority: nearest first, eq. 23 breaking ties)
    alignment_errors: list[float]  # eq. 23 per neighbour, NaN where unmeasured
    confirm_difference: float  # intensity 0..255: another neighbour within this of a sample confirms it

    @cached_property
    def ys(self) -> np.ndarray:
        return self.evidence.ys[self.pixels]

    @cached_property
    def xs(self) -> np.ndarray:
        return self.evidence.xs[self.pixels]

    @cached_property
    def samples(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Every neighbour's (colours, valid) at the contested pixels."""
        return [(colours[self.pixels], valid[self.pixels]) for colours, valid in self.evidence.samples]

    @cached_property
    def shown(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Every neighbour's (intensity, valid) at the contested pixels: made once for all confirmation tests."""
        return [(imaging.intensity(colours), valid) for colours, valid in self.samples]

    @cached_property
    def errors_as_is(self) -> np.ndarray:
        """(neighbours, m): Evidence.errors_as_is at the contested pixels."""
        return self.evidence.errors_as_is[:, self.pixels]

    @cached_property
    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """(ys, xs): the contested pixels, then the local error's band (a warp is sampled at both)."""
        band = self.evidence.local_error
        return np.concatenate([self.ys, band.band_y]), np.concatenate([self.xs, band.band_x])

    def error_of(self, colours: np.ndarray, landed: np.ndarray) -> np.ndarray:
        """(m,) float32 local errors at the contested pixels of a warp's samples at ``points`` (on their band part);
        255 where the warp reached none of a pixel's window, so it ranks after every checked one."""
        m = len(self.pixels)
        return np.nan_to_num(self.evidence.local_error(colours[m:], landed[m:])[self.pixels], nan=255.0)

    def seen_by_another(self, sample: np.ndarray, source: int, value: np.ndarray | None = None) -> np.ndarray:
        """Whether some other neighbour than ``source`` (an index) shows, as it is, the sample's intensity at each
        contested pixel, within ``confirm_difference``; ``value``: the sample's intensity when at hand."""
        if value is None:
            value = imaging.intensity(sample)
        seen = np.zeros(len(sample), bool)
        for n, (intensity, valid) in enumerate(self.shown):
            if n != source:
                seen |= valid & (np.abs(intensity - value) < self.confirm_difference)
        return seen


@dataclass(frozen=True)
class Mosaic:
    """The mosaic's pixels in doubt (``Contest.doubted``: the static scene explains their surroundings badly), as
    the candidate to beat: eqs. 20-22's median, its error the static scene's. completion.choose keeps it unless the
    best other candidate moves and is clearly better; a moving object inside the missing area is shown as
    background by every neighbour it has left, so eq. 20's variance test passes and paints background there."""

    kind: ClassVar[str] = "mosaic"

    def propose(self, contest: Contest, proposed: Sequence[Candidate]) -> list[Candidate]:
        m = len(contest.pixels)
        return [Candidate(self.kind, contest.mosaic_colours, contest.doubted, np.zeros(m, np.float32),
                          contest.mosaic_error, np.ones(m, bool), np.zeros(m, np.int16))]


@dataclass(frozen=True)
class LocalWarps:
    """Eq. 25 from each of the first ``max_neighbours`` neighbours by priority with a measured eq. 23 error: local
    flow over the common area in work boxes around the contested pixels, its motion inpainting by Fast Marching
    (eq. 24), the neighbour sampled through it (pipeline/stages/local_warp.py). One candidate per neighbour, with
    its ``NeighbourFill``; a sample moving by at most ``moving_px`` that no other neighbour shows is unconfirmed."""

    kind: ClassVar[str] = "local warp"
    max_neighbours: int
    flows: FlowSettings
    moving_px: float  # px: a sample through a longer flow shows moving content

    def propose(self, contest: Contest, proposed: Sequence[Candidate]) -> list[Candidate]:
        usable = [i for i in contest.order if np.isfinite(contest.alignment_errors[i])][:self.max_neighbours]
        if not usable:  # no neighbour overlaps frame t's known area: no flow to measure
            return []
        evidence = contest.evidence
        views = local_warp.box_views(contest.ys, contest.xs, evidence.target, evidence.missing, self.flows,
                                     evidence.target_original)
        return [self._candidate(contest, i, views) for i in usable]

    def _candidate(self, contest: Contest, i: int, views: Sequence[local_warp.BoxView]) -> Candidate:
        neighbour, m, shape = contest.evidence.neighbours[i], len(contest.pixels), contest.evidence.missing.shape
        fill = local_warp.neighbour_fill(neighbour, contest.alignment_errors[i], views, self.flows, shape)
        points_y, points_x = contest.points
        colours, landed, motion = local_warp.samples_through(fill.inpainted_flow_at(points_y, points_x), neighbour,
                                                             points_y, points_x)
        fill.reached = np.zeros(shape, bool)
        fill.reached[contest.ys, contest.xs] = landed[:m]
        sample = colours[:m]
        confirmed = (motion[:m] > self.moving_px) | contest.seen_by_another(sample, i)
        return Candidate(self.kind, sample, landed[:m], motion[:m], contest.error_of(colours, landed), confirmed,
                         np.full(m, neighbour.offset, np.int16), fill)


@dataclass(frozen=True)
class AsIs:
    """The best covering neighbour's sample as it is (zero local motion; ``best_as_is`` over all neighbours, not
    only the local-warp ones) at the pixels where every candidate before it in the chain (the mosaic's aside)
    explains the surroundings worse than ``error_above``, or reaches none; its error counted ``margin`` higher,
    so that one explaining them about as well keeps the pixel. It is also what fills the pixels no local warp
    reaches, the smooth fallback being for those no neighbour covers.

    Why: a moving object's flow carried by motion inpainting into a border strip the object has already left pastes
    a stale copy of it there, and with few local-warp neighbours reaching the strip nothing better competes; the
    background those frames hide is often shown as it is by farther neighbours (docs/completion.md)."""

    kind: ClassVar[str] = "neighbour as is"
    error_above: float  # intensity 0..255 (CompletionConfig.static_candidate_error)
    margin: float  # intensity 0..255 (CompletionConfig.static_candidate_margin)

    def propose(self, contest: Contest, proposed: Sequence[Candidate]) -> list[Candidate]:
        which, rank = best_as_is(contest)
        m = len(which)
        rivals = [np.where(c.reached, c.error, np.inf) for c in proposed if c.kind != Mosaic.kind]
        rival_error = np.min(np.stack(rivals), axis=0) if rivals else np.full(m, np.inf, np.float32)
        reached = np.isfinite(rank) & (rival_error > self.error_above)
        colours = np.stack([c for c, _ in contest.samples])[which, np.arange(m)]
        # The confirmation is already in the rank (+UNCONFIRMED_PENALTY when unconfirmed).
        error = np.where(reached, rank + np.float32(self.margin), np.inf).astype(np.float32)
        offsets = np.array([n.offset for n in contest.evidence.neighbours], np.int16)[which]
        return [Candidate(self.kind, colours, reached, np.zeros(m, np.float32), error, np.ones(m, bool), offsets)]


def best_as_is(contest: Contest) -> tuple[np.ndarray, np.ndarray]:
    """Per contested pixel, the neighbour whose sample (zero local motion) to take: covering the pixel, with the
    lowest local alignment error (``Contest.errors_as_is``); a sample no other neighbour shows ranks after the
    confirmed ones, as in completion.choose. Returns (index (m,), its rank (m,): the error, +UNCONFIRMED_PENALTY
    when unconfirmed, inf where no neighbour has one)."""
    errors = contest.errors_as_is
    ranked = np.full(errors.shape, np.inf, np.float32)
    for i, (colours, valid) in enumerate(contest.samples):
        confirmed = contest.seen_by_another(colours, i, value=contest.shown[i][0])
        ranked[i] = np.where(valid & ~np.isnan(errors[i]),
                             errors[i] + np.where(confirmed, np.float32(0), UNCONFIRMED_PENALTY), np.inf)
    which = np.argmin(ranked, axis=0)
    return which, ranked[which, np.arange(ranked.shape[1])]


@dataclass(frozen=True)
class Majority:
    """The median of the covering neighbours' strict majority, as they are (``mosaic.majority_median``: eqs. 20-22
    without the samples an object passing in a few neighbours made disagree), where they have one; its error is
    the median of the majority's own local errors as they are, so it competes with the local warps on how well
    those neighbours explain the surroundings. Several neighbours agreeing is its confirmation.

    Why: a local warp reaching such a pixel samples the nearest neighbours, which are the ones still showing the
    object (docs/completion.md)."""

    kind: ClassVar[str] = "majority"
    variance_threshold: float  # intensity^2: eq. 20's, the mosaic's (MosaicConfig.variance_threshold)

    def propose(self, contest: Contest, proposed: Sequence[Candidate]) -> list[Candidate]:
        colours = np.stack([c for c, _ in contest.samples])
        valid = np.stack([v for _, v in contest.samples])
        values = np.stack([i for i, _ in contest.shown])
        ok, median, member = mosaic.majority_median(colours, values, valid, self.variance_threshold)
        own = np.where(member, contest.errors_as_is, np.nan)
        measured = ok & ~np.isnan(own).all(axis=0)
        error = np.full(len(ok), np.inf, np.float32)
        error[measured] = nan_median_columns(own[:, measured])
        m = len(ok)
        return [Candidate(self.kind, median, measured, np.zeros(m, np.float32), error, np.ones(m, bool),
                          np.zeros(m, np.int16))]


@dataclass(frozen=True)
class CarriedOn:
    """Moving content carried on into frame t at constant velocity from either side: for s = -1 and +1, where
    neighbours t+s and t+2s both cover a contested pixel, one candidate sampled from t+s.

    Frame t's content at p moved by v a frame was at p - v in frame t+s (s = -1; p + v for s = +1); the flow H from
    the warped neighbour t+s to t+2s is about -v (+v) on it, so the candidate is I_{t+s}(p + H(p)). H is taken at p
    of frame t+s, where the content was v earlier: exact inside an object that moves less than its own size a
    frame, off by up to v at its edges. A sample counts where both neighbours cover p (H was measured there, not
    invented), it lands on frame t+s's content, and it moves by more than ``moving_px`` (elsewhere it is the static
    scene, the mosaic's and the samples' as they are); its local alignment error ranks it as any local warp.

    Why: a local warp's flow is frame t's own, measured on its known surroundings and inpainted outwards; an object
    that has left those surroundings (crossing the border, or a near object under parallax) is then pasted where
    the neighbour saw it, a frame or more stale, while the two neighbours on one side still see it move
    (docs/completion.md)."""

    kind: ClassVar[str] = "carried on"
    flows: FlowSettings
    moving_px: float  # px

    def propose(self, contest: Contest, proposed: Sequence[Candidate]) -> list[Candidate]:
        index_of = {neighbour.offset: i for i, neighbour in enumerate(contest.evidence.neighbours)}
        # No pixel both neighbours cover: no sample to take, no flow to measure. It runs wherever there is one: a
        # candidate switched on and off from frame to frame makes the synthesized pixels flicker (docs/completion.md).
        sides = [side for side in (-1, 1) if side in index_of and 2 * side in index_of
                 and (contest.samples[index_of[side]][1] & contest.samples[index_of[2 * side]][1]).any()]
        if not sides:
            return []
        near_and_far = [(contest.evidence.neighbours[index_of[s]], contest.evidence.neighbours[index_of[2 * s]])
                        for s in sides]
        box, size = self._box(contest, near_and_far[0][0].shape)
        return [self._candidate(contest, near, far, box, size) for near, far in near_and_far]

    def _box(self, contest: Contest, shape: tuple[int, int]) -> tuple[tuple[slice, slice], tuple[int, int] | None]:
        """Both sides' flows run over one box, at its working size: every contested pixel with the local flows'
        margin of context, at their working resolution. On a box around the covered pixels alone, or at half that
        resolution, the flow lost the objects' motion (docs/completion.md)."""
        height, width = shape
        scale = self.flows.scale((height, width))
        margin = self.flows.margin(scale)
        margin = round(max(height, width) / scale) if margin is None else margin
        ys, xs = contest.ys, contest.xs
        rows = slice(max(int(ys.min()) - margin, 0), min(int(ys.max()) + 1 + margin, height))
        cols = slice(max(int(xs.min()) - margin, 0), min(int(xs.max()) + 1 + margin, width))
        return (rows, cols), local_warp.working_size((rows, cols), scale)

    def _candidate(self, contest: Contest, near: WarpedNeighbour, far: WarpedNeighbour, box: tuple[slice, slice],
                   size: tuple[int, int] | None) -> Candidate:
        rows, cols = box
        step_x, step_y = ((1.0, 1.0) if size is None
                          else (size[0] / (cols.stop - cols.start), size[1] / (rows.stop - rows.start)))
        points_y, points_x = contest.points
        # Working-resolution coordinates of the points (pixel centres map to pixel centres); outside the box a point
        # is not measured.
        u = ((points_x - cols.start + 0.5) * step_x - 0.5).astype(np.float32)
        v = ((points_y - rows.start + 0.5) * step_y - 0.5).astype(np.float32)
        near_rgb, near_valid = near.crop(box, size)
        far_rgb, far_valid = far.crop(box, size)
        flow = local_flow.local_flow(near_rgb, near_valid, far_rgb, far_valid, self.flows.flow)
        h = remap_points(flow.flow, u, v, cv2.BORDER_REPLICATE)
        hx, hy = h[:, 0] / np.float32(step_x), h[:, 1] / np.float32(step_y)
        measured = remap_points(flow.common.astype(np.uint8) * 255, u, v)[:, 0] == 255  # every tap measured
        colours, landed = near.sample(points_x + hx, points_y + hy)
        motion = np.hypot(hx, hy).astype(np.float32)
        landed &= measured & (motion > self.moving_px)
        m = len(contest.pixels)
        return Candidate(self.kind, colours[:m], landed[:m], motion[:m],
                         contest.error_of(colours, landed).astype(np.float32), np.ones(m, bool),
                         np.full(m, near.offset, np.int16))


class LocalError:
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


def nan_median_columns(values: np.ndarray) -> np.ndarray:
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
