"""Global motion between consecutive frames (thesis 3.2).

Robust feature-based estimation: Shi-Tomasi corners tracked by pyramidal Lucas-Kanade with a
forward-backward check, then a RANSAC fit of the chosen model (affine by default, similarity or
homography), seeded by a similarity so that one fit covers one layer, and further motions among the
outliers where large figures move, each one step on top of the first (which one is the camera's:
pipeline/stages/background.py).
Optionally a hierarchical direct refinement in the spirit of Bergen et al.: ECC (enhanced correlation
coefficient) maximisation coarse-to-fine on an image pyramid.

Frames that cannot be aligned (featureless, black, a scene cut) fall back to the identity and say why,
so the camera path is never flung by one bad pair.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np

from pipeline import geometry
from pipeline.errors import ConfigError
from pipeline.stages.background import (SHARPNESS_RATIO, CameraChoice, at_one_sharpness, away_from, gradient_energy,
                                       motions_of, track_ends)

MotionModel = Literal["affine", "similarity", "homography"]
Refinement = Literal["none", "ecc"]
RANSAC_SEED = 0x5EED
# A second motion among RANSAC's outliers needs this share of the tracks: beside one large layer a few tracks moving
# their own way are a small or near object's (cars behind a railing, a cushion near the lens), not the camera's ...
ALTERNATIVE_MIN_SHARE = 0.10
ALTERNATIVE_MIN_TRACKS = 6  # ... and every motion at least this many (a third, beside two large layers, no more)
LAYER_MODEL_MIN_TRACKS = 40  # a layer fitted on fewer tracks (first-pass ones: LK's loose pass, drift across a blur)
# keeps its similarity: an affine's two more parameters follow those tracks' errors, and from the part of the frame
# the tracks cover they carry the frame's far corners px off the camera's motion (docs/decisions.md D46)
MAX_OTHER_MOTIONS = 2  # motions looked for beside RANSAC's winner (the background and two figures, or three figures)
ALTERNATIVE_MIN_SHIFT_PX = 6.0  # ... and kept when it moves the frame this much differently (working px): less is
# depth (parallax between near and far layers of a walk), which the camera path must not jump between
CARRIED_PAIRS = 10  # pairs in a row a layer no motion of the pair is goes on being tracked (``continued``): a third
# of a second at 30 fps, longer than a sky behind figures goes without corners enough for a motion of its own
MOTION_MODELS: tuple[str, ...] = ("affine", "similarity", "homography")
REFINEMENTS: tuple[str, ...] = ("none", "ecc")


@dataclass(frozen=True)
class IgnoreRegion:
    """A box (full-resolution px, top-left x, y, width, height) whose features motion estimation ignores (a logo,
    a dashboard, a person), from ``start_s`` to ``end_s`` (seconds of the input; None: from the start / to the
    end)."""

    x: int
    y: int
    width: int
    height: int
    start_s: float | None = None
    end_s: float | None = None

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0 or self.x < 0 or self.y < 0:
            raise ConfigError(f"ignore box {self.x},{self.y},{self.width},{self.height}: x and y must be >= 0, "
                              f"width and height > 0")
        if self.start_s is not None and self.end_s is not None and not self.start_s <= self.end_s:
            raise ConfigError(f"ignore box time range {self.start_s:g}-{self.end_s:g}: the start must not be after "
                              f"the end")

    def active(self, time_s: float) -> bool:
        return (self.start_s is None or time_s >= self.start_s) and (self.end_s is None or time_s <= self.end_s)


@dataclass(frozen=True)
class MotionConfig:
    """Pass 1's settings. "Working px" are pixels of the frame downscaled to ``max_side`` (full resolution for
    frames no larger), where corners are found, tracked and fitted; "full px" are the input's."""

    model: MotionModel = "affine"  # the inter-frame transform fitted: affine, similarity or homography
    refine: Refinement = "none"  # "ecc": the feature estimate refined by direct alignment (_refine_ecc)
    max_side: int = 960  # full px: frames are downscaled to this longest side for estimation (never enlarged)
    max_corners: int = 300  # corners per frame, over the whole grid (600 cost more CPU for no steadier output,
    # 200 shook more: docs/decisions.md D18)
    # Shi-Tomasi quality: a cell keeps corners whose response reaches ten times this fraction of its best one's
    corner_quality: float = 0.003
    corner_min_distance: int = 8  # working px between two corners
    corner_grid: tuple[int, int] = (8, 5)  # cells (columns, rows), each with its share of max_corners (_detect_corners)
    lk_window: int = 15  # working px: the Lucas-Kanade window's side
    lk_levels: int = 3  # pyramid levels above the working size for the first tracking pass
    lk_passes: int = 2  # tracking passes; later ones track against curr warped back by the estimate so far
    # (removes LK's bias)
    fb_max_error_px: float = 1.0  # working px: forward-backward tracking error beyond which a track is dropped
    ransac_threshold_px: float = 1.5  # working px: RANSAC's inlier distance (half of it in the refining passes)
    min_inliers: int = 12  # tracks: fewer inliers and the pair falls back to the identity
    min_inlier_ratio: float = 0.25  # fraction of the tracked corners the inliers must reach, or the pair falls back
    max_rotation_deg: float = 25.0  # degrees between two frames: larger is not hand shake, treated as a failure
    max_scale_change: float = 0.25  # fraction: a larger zoom change between two frames is treated as a failure
    max_shift_fraction: float = 0.35  # fraction of the frame's diagonal: a larger shift is treated as a failure
    cut_hist_distance: float = 0.45  # Bhattacharyya distance (0..1) of HSV histograms that marks a scene cut
    hist_step: int = 4  # working px: the histograms take every hist_step-th pixel in each direction
    ecc_levels: int = 3  # refine "ecc": pyramid levels, halving the size each
    ecc_iterations: int = 50  # refine "ecc": iterations per level at most
    ecc_epsilon: float = 1e-5  # refine "ecc": change of the correlation coefficient (0..1) at which a level stops
    ignore: tuple[IgnoreRegion, ...] = ()  # boxes (full px, seconds) whose features are not used (--ignore)
    ignore_mask: str | None = None  # image or video, white = ignore (--ignore-mask); pipeline.stabilize reads it

    def __post_init__(self) -> None:
        if not all(isinstance(region, IgnoreRegion) for region in self.ignore):
            raise ConfigError("motion ignore regions must be IgnoreRegion boxes")
        if self.model not in MOTION_MODELS:
            raise ConfigError(f"motion model must be one of {', '.join(MOTION_MODELS)}, not {self.model!r}")
        if self.hist_step < 1:
            raise ConfigError(f"hist_step must be at least 1, not {self.hist_step}")
        if self.refine not in REFINEMENTS:
            raise ConfigError(f"refinement must be one of {', '.join(REFINEMENTS)}, not {self.refine!r}")


@dataclass(frozen=True)
class OtherMotion:
    """A motion of the pair other than the camera's: a moving figure's, full-resolution curr_from_prev and the
    tracks that follow it (full-resolution px, (M, 2) each). ``carried``: 0 for a motion of the pair's own tracks,
    k for a layer of an earlier pair that no motion of the last k pairs was, tracked on (``continued``)."""

    curr_from_prev: np.ndarray
    prev_points: np.ndarray
    curr_points: np.ndarray
    carried: int = 0


@dataclass(frozen=True)
class MotionEstimate:
    """Motion of one frame relative to the previous one, with what the estimate rests on."""

    curr_from_prev: np.ndarray  # 3x3, full-resolution pixels
    status: Literal["ok", "fallback", "cut", "first"]
    n_tracked: int = 0
    n_inliers: int = 0
    residual_px: float = 0.0  # RMS reprojection error of the inliers, full-resolution px
    hist_distance: float = 0.0
    warning: str | None = None
    # Tracks for the debugger, full-resolution px: (K, 2) each, inlier flags (K,).
    prev_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    curr_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    inliers: np.ndarray = field(default_factory=lambda: np.zeros((0,), bool))
    # The other motions the tracks hold (large moving figures, or the background when a figure won RANSAC), with
    # their tracks; pipeline/stages/background.py decides which motion is the camera's (``with_camera``).
    others: tuple[OtherMotion, ...] = ()
    chose_other: bool = False  # RANSAC's winner moved with a figure: the camera took one of the others
    ignored: np.ndarray | None = None  # bool, working size: where prev's features were not used (--ignore*)
    camera: CameraChoice | None = None  # how the camera's motion was chosen (pipeline/stages/background.py)

    @property
    def inlier_ratio(self) -> float:
        return self.n_inliers / self.n_tracked if self.n_tracked else 0.0


@dataclass(frozen=True)
class PreparedFrame:
    """What motion estimation keeps of a frame: downscaled grey image and colour histogram."""

    gray: np.ndarray
    hist: np.ndarray
    scale: float  # working size / full size
    width: int
    height: int
    ignore: np.ndarray | None = None  # bool, working size: features here are not used (IgnoreRegion, --ignore-mask)
    sharpness: float = 0.0  # mean squared gradient of gray (0: unknown, never matched)


def prepare(rgb: np.ndarray, config: MotionConfig, ignore: np.ndarray | None = None) -> PreparedFrame:
    """``ignore``: bool (H, W) at full resolution, where features are not used (None: none)."""
    height, width = rgb.shape[:2]
    scale = min(1.0, config.max_side / max(width, height))
    small = rgb if scale == 1.0 else cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    if small.dtype != np.uint8:  # deeper video (float32, 0..255): tracking works on 8-bit grey all the same
        small = np.clip(small + np.float32(0.5), 0, 255).astype(np.uint8)
    gray = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
    hsv = cv2.cvtColor(np.ascontiguousarray(small[::config.hist_step, ::config.hist_step]), cv2.COLOR_RGB2HSV)
    hist = cv2.calcHist([hsv], [0, 1], None, [30, 32], [0, 180, 0, 256])
    cv2.normalize(hist, hist, alpha=1.0, norm_type=cv2.NORM_L1)
    if ignore is not None:
        ignore = ignore if scale == 1.0 else cv2.resize(ignore.view(np.uint8), (gray.shape[1], gray.shape[0]),
                                                           interpolation=cv2.INTER_NEAREST).view(bool)
    return PreparedFrame(gray=gray, hist=hist, scale=scale, width=width, height=height, ignore=ignore,
                         sharpness=gradient_energy(gray))


def estimate(prev: PreparedFrame, curr: PreparedFrame, config: MotionConfig) -> MotionEstimate:
    """curr_from_prev between two prepared frames, or the identity with a reason.

    Deterministic: RANSAC draws from OpenCV's global RNG, reseeded here so that an estimate does not
    depend on what ran before it in the process (a segment run must equal a whole-video run).
    """
    cv2.setRNGSeed(RANSAC_SEED)
    hist_distance = float(cv2.compareHist(prev.hist, curr.hist, cv2.HISTCMP_BHATTACHARYYA))
    work = _with_matched_sharpness(_track_and_fit(prev.gray, curr.gray, config, prev.ignore), prev, curr, config)
    if config.refine == "ecc":
        work = _refine_ecc(prev.gray, curr.gray, work, config)

    failure = work.failure or _implausible(work.curr_from_prev, curr.gray.shape, config)
    full_transform = geometry.rescale_transform(work.curr_from_prev, curr.scale)
    to_full = 1.0 / curr.scale
    tracks = dict(
        n_tracked=work.n_tracked,
        n_inliers=work.n_inliers,
        residual_px=work.residual_px * to_full,
        hist_distance=hist_distance,
        prev_points=work.prev_points * to_full,
        curr_points=work.curr_points * to_full,
        inliers=work.inliers,
        others=tuple(OtherMotion(geometry.rescale_transform(matrix, curr.scale), starts * to_full, ends * to_full)
                     for matrix, starts, ends in work.others),
        ignored=prev.ignore,
    )
    if failure is None:
        return MotionEstimate(curr_from_prev=full_transform, status="ok", **tracks)
    # A failed alignment with a different colour distribution is a cut; otherwise a bad pair.
    if hist_distance > config.cut_hist_distance:
        return MotionEstimate(
            curr_from_prev=geometry.IDENTITY.copy(), status="cut",
            warning=f"scene cut ({failure}; histogram distance {hist_distance:.2f}): smoothing restarts here",
            **tracks,
        )
    return MotionEstimate(
        curr_from_prev=geometry.IDENTITY.copy(), status="fallback",
        warning=f"motion fallback to identity: {failure}", **tracks,
    )


def continued(before: MotionEstimate | None, estimate: MotionEstimate, previous: PreparedFrame | None,
              prepared: PreparedFrame, config: MotionConfig) -> MotionEstimate:
    """``estimate`` with the layers of the pair before (``before``, as this function returned it) tracked on, so that
    a layer keeps its tracks from pair to pair for as long as they track. Each layer's track ends are tracked into
    this frame and fitted as one motion (``_carried``). Where a motion of the pair is that layer (the two move the
    layer's tracks within ALTERNATIVE_MIN_SHIFT_PX of each other), the carried tracks join that motion's
    (``_with_tracks_of``); where none is, the layer is added as another motion (at most MAX_OTHER_MOTIONS of them,
    each for at most CARRIED_PAIRS pairs in a row). A layer that leaves few corners in each frame (a sky behind three
    figures, a motion-blurred frame) has too few tracks in some pairs for the search among RANSAC's outliers, and its
    motion is then missing there (the chooser must follow a figure across); kept, its tracks add up over the frames
    it is seen in. Layers are only carried from a pair with several motions. A pair's motions so depend on the pairs
    before it: pass 1 runs over the clip in order (pipeline/segments.py too)."""
    if before is None or previous is None or before.status != "ok" or estimate.status != "ok" or not before.others:
        return estimate
    added: list[OtherMotion] = []
    for ends, carried in zip(track_ends(before), (0, *(other.carried for other in before.others))):
        if len(ends) < ALTERNATIVE_MIN_TRACKS or carried >= CARRIED_PAIRS:
            continue
        layer = _carried(ends, previous, prepared, config)
        if layer is None:
            continue
        known = [*motions_of(estimate), *(other.curr_from_prev for other in added)]
        shifts = [corner_shift(layer.curr_from_prev, matrix, layer.prev_points) for matrix in known]
        same = int(np.argmin(shifts))
        if shifts[same] >= ALTERNATIVE_MIN_SHIFT_PX / prepared.scale:
            if len(added) < MAX_OTHER_MOTIONS:
                added.append(dataclasses.replace(layer, carried=carried + 1))
        elif same <= len(estimate.others):
            estimate = _with_tracks_of(estimate, same, layer, prepared, config)
    return dataclasses.replace(estimate, others=estimate.others + tuple(added)) if added else estimate


def _with_tracks_of(estimate: MotionEstimate, index: int, layer: OtherMotion, prepared: PreparedFrame,
                    config: MotionConfig) -> MotionEstimate:
    """``estimate`` with the carried ``layer``'s tracks added to its motion ``index`` (0: RANSAC's winner), leaving
    out those that start within corner_min_distance of one of the motion's own (the same corner). The winner keeps
    its motion (its tracks were refined in a second pass) and takes the carried tracks it moves within RANSAC's
    threshold; another motion (first-pass tracks only) is refitted to its tracks and the carried ones."""
    own = estimate.prev_points[estimate.inliers] if index == 0 else estimate.others[index - 1].prev_points
    new = away_from(layer.prev_points, own, config.corner_min_distance / prepared.scale)
    if not new.any():
        return estimate
    starts, ends = layer.prev_points[new], layer.curr_points[new]
    if index == 0:
        held = np.linalg.norm(geometry.apply(estimate.curr_from_prev, starts) - ends, axis=1) \
            < config.ransac_threshold_px / prepared.scale
        return dataclasses.replace(
            estimate, prev_points=np.concatenate([estimate.prev_points, starts[held]]).astype(np.float32),
            curr_points=np.concatenate([estimate.curr_points, ends[held]]).astype(np.float32),
            inliers=np.concatenate([estimate.inliers, np.ones(int(held.sum()), bool)]),
            n_tracked=estimate.n_tracked + int(held.sum()), n_inliers=estimate.n_inliers + int(held.sum()))
    refitted = _refitted(estimate.others[index - 1], starts, ends, prepared.scale, config)
    if refitted is None:
        return estimate
    others = list(estimate.others)
    others[index - 1] = refitted
    return dataclasses.replace(estimate, others=tuple(others))


def _refitted(other: OtherMotion, starts: np.ndarray, ends: np.ndarray, scale: float,
              config: MotionConfig) -> OtherMotion | None:
    """``other`` refitted (``_refit``, at working size) to its tracks and the tracks ``starts`` -> ``ends`` (full px);
    None where too few hold."""
    prev_pts = (np.concatenate([other.prev_points, starts]) * scale).astype(np.float32)
    curr_pts = (np.concatenate([other.curr_points, ends]) * scale).astype(np.float32)
    seed = geometry.rescale_transform(other.curr_from_prev, 1.0 / scale)
    model = _layer_model(config.model, len(prev_pts))
    matrix, mask = _refit(prev_pts, curr_pts, np.ones(len(prev_pts), bool),
                          seed if config.model == "homography" else seed[:2], model, config.ransac_threshold_px)
    if not _holds(matrix, mask, ALTERNATIVE_MIN_TRACKS):
        return None
    held = mask.ravel().astype(bool)
    return OtherMotion(geometry.rescale_transform(geometry.to_3x3(matrix), scale), prev_pts[held] / scale,
                       curr_pts[held] / scale)


def _carried(ends: np.ndarray, previous: PreparedFrame, prepared: PreparedFrame,
             config: MotionConfig) -> OtherMotion | None:
    """A layer's track ends (full px, in previous) tracked into prepared and fitted as one layer; None where too few
    of them track or agree."""
    cv2.setRNGSeed(RANSAC_SEED)  # as ``estimate``: the same fit whatever ran before
    starts = _outside((ends * prepared.scale).astype(np.float32), previous.ignore)
    if len(starts) < ALTERNATIVE_MIN_TRACKS:
        return None
    prev_pts, curr_pts = _track(previous.gray, prepared.gray, starts, _first_pass_lk(config), config.fb_max_error_px)
    if len(prev_pts) < ALTERNATIVE_MIN_TRACKS:
        return None
    matrix, mask = _fit_model(prev_pts, curr_pts, config)
    if not _holds(matrix, mask, ALTERNATIVE_MIN_TRACKS):
        return None
    held = mask.ravel().astype(bool)
    to_full = 1.0 / prepared.scale
    return OtherMotion(geometry.rescale_transform(geometry.to_3x3(matrix), prepared.scale), prev_pts[held] * to_full,
                       curr_pts[held] * to_full)


def _with_matched_sharpness(work: _WorkEstimate, prev: PreparedFrame, curr: PreparedFrame,
                            config: MotionConfig) -> _WorkEstimate:
    """Where one frame of the pair is much blurrier (gradient energy beyond background.SHARPNESS_RATIO), the pair is
    tracked again with the sharper frame blurred to match, and that fit's motion joins the others (or stands in
    where the first fit failed): LK between a motion-blurred frame and a sharp one drifts, most where a large figure
    leaves few background corners, and the camera's motion can then be missing from the first fit's. Where prev is
    the blurrier, the pair is also tracked from corners found on curr (a motion-blurred frame's corners are fewer and
    smeared), and that fit, turned round, joins too. The chooser (background.py) decides among them as among the
    others; the first fit stays RANSAC's winner."""
    matched = _at_one_sharpness(prev, curr)
    if matched is None:
        return work
    for again in _matched_fits(matched, prev, curr, config):
        work = _joined(work, again)
    return work


def _matched_fits(matched: tuple[np.ndarray, np.ndarray], prev: PreparedFrame, curr: PreparedFrame,
                  config: MotionConfig) -> list[_WorkEstimate]:
    """The fits of the pair at one sharpness (``matched``) that did not fail: from prev's corners, and where prev is
    the blurrier, from curr's too (turned round)."""
    fits = [_track_and_fit(*matched, config, prev.ignore)]
    if prev.sharpness < curr.sharpness:
        fits.append(_reversed(_track_and_fit(matched[1], matched[0], config, curr.ignore)))
    return [fit for fit in fits if fit.failure is None]


def _joined(work: _WorkEstimate, again: _WorkEstimate) -> _WorkEstimate:
    """``work`` with ``again``'s motion among its others where it moves the frame differently from each of them
    (the others with the most tracks keep their places); ``again`` where ``work`` failed."""
    if work.failure is not None:
        return again
    known = [work.curr_from_prev] + [matrix for matrix, _, _ in work.others]
    if any(corner_shift(again.curr_from_prev, matrix, work.prev_points) < ALTERNATIVE_MIN_SHIFT_PX for matrix in known):
        return work
    others = work.others
    if len(others) >= MAX_OTHER_MOTIONS:
        others = sorted(others, key=lambda other: -len(other[1]))[:MAX_OTHER_MOTIONS - 1]
    inliers = again.inliers
    work.others = others + [(again.curr_from_prev, again.prev_points[inliers], again.curr_points[inliers])]
    return work


def _reversed(work: _WorkEstimate) -> _WorkEstimate:
    """A fit of curr_from_prev from one of prev_from_curr: each motion inverted, each track's ends swapped."""
    if work.failure is not None:
        return work
    turned = dataclasses.replace(work, curr_from_prev=np.linalg.inv(work.curr_from_prev),
                                 prev_points=work.curr_points, curr_points=work.prev_points)
    turned.others = [(np.linalg.inv(geometry.to_3x3(matrix)), ends, starts) for matrix, starts, ends in work.others]
    return turned


def _at_one_sharpness(prev: PreparedFrame, curr: PreparedFrame) -> tuple[np.ndarray, np.ndarray] | None:
    """The pair's grey images with the sharper blurred to the other's sharpness (background.at_one_sharpness);
    None where the two are within SHARPNESS_RATIO already, or cannot be matched."""
    energy = (prev.sharpness, curr.sharpness)
    if min(energy) <= 0 or max(energy) <= SHARPNESS_RATIO * min(energy):
        return None
    matched = at_one_sharpness((prev.gray, curr.gray), energy)
    return None if matched is None else (matched[0], matched[1])


# A refining pass tracks against curr brought back by an estimate: what LK sees is only the residual motion (a pixel or
# so), so no pyramid, ten iterations and no backward check suffice (as accurate on synthetic truth as two levels and
# 30 iterations, at half the cost).
_REFINE_LK = dict(winSize=(21, 21), maxLevel=0, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.01))


@dataclass
class _WorkEstimate:
    curr_from_prev: np.ndarray
    failure: str | None
    n_tracked: int = 0
    n_inliers: int = 0
    residual_px: float = 0.0
    prev_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    curr_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    inliers: np.ndarray = field(default_factory=lambda: np.zeros((0,), bool))
    others: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)  # (matrix, prev, curr)


def _outside(points: np.ndarray, ignore: np.ndarray | None) -> np.ndarray:
    """``points`` (working px) outside ``ignore`` (bool, working size; None: all)."""
    if ignore is None or not len(points):
        return points
    x = np.clip(np.round(points[:, 0]).astype(int), 0, ignore.shape[1] - 1)
    y = np.clip(np.round(points[:, 1]).astype(int), 0, ignore.shape[0] - 1)
    return points[~ignore[y, x]]


def _first_pass_lk(config: MotionConfig) -> dict:
    """LK's settings for a first tracking pass, which only needs to land within a pixel (RANSAC and the refining pass
    do the rest): loose, cheap termination."""
    return dict(winSize=(config.lk_window, config.lk_window), maxLevel=config.lk_levels,
                criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))


def _track_and_fit(prev_gray: np.ndarray, curr_gray: np.ndarray, config: MotionConfig,
                   ignore: np.ndarray | None = None) -> _WorkEstimate:
    corners = _outside(_detect_corners(prev_gray, config), ignore)
    if len(corners) < config.min_inliers:
        return _WorkEstimate(geometry.IDENTITY.copy(), f"featureless frame ({len(corners)} corners)")

    lk = _first_pass_lk(config)
    corners = corners.reshape(-1, 2)
    curr_from_prev = geometry.IDENTITY.copy()
    result = _WorkEstimate(curr_from_prev, "no tracking pass ran")
    for lk_pass in range(max(1, config.lk_passes)):
        if lk_pass == 0:
            prev_pts, curr_pts = _track(prev_gray, curr_gray, corners, lk, config.fb_max_error_px)
        else:
            # Track again against curr brought back into prev's frame (_REFINE_LK). All tracks take part, and
            # RANSAC runs tighter, so a compromise fit of pass 1 is not locked in.
            target = _warp_gray(curr_gray, curr_from_prev)
            prev_pts, target_pts = _track(prev_gray, target, result.prev_points, _REFINE_LK, None)
            curr_pts = geometry.apply(curr_from_prev, target_pts).astype(np.float32)
        if len(prev_pts) < config.min_inliers:
            if lk_pass > 0:
                break  # keep the previous pass's estimate
            return _WorkEstimate(geometry.IDENTITY.copy(), f"too few tracked features ({len(prev_pts)})",
                                 n_tracked=len(prev_pts), prev_points=prev_pts, curr_points=curr_pts,
                                 inliers=np.zeros(len(prev_pts), bool))
        matrix, inlier_mask = _fit_model(prev_pts, curr_pts, config, tight=lk_pass > 0)
        inliers = np.zeros(len(prev_pts), bool) if inlier_mask is None else inlier_mask.ravel().astype(bool)
        n_tracked = len(prev_pts) if lk_pass == 0 else result.n_tracked
        candidate = _WorkEstimate(curr_from_prev, None, n_tracked=n_tracked, n_inliers=int(inliers.sum()),
                                  prev_points=prev_pts, curr_points=curr_pts, inliers=inliers)
        if matrix is None or not np.all(np.isfinite(matrix)):
            candidate.failure = "model fit failed"
        elif candidate.n_inliers < config.min_inliers or candidate.n_inliers < config.min_inlier_ratio * n_tracked:
            candidate.failure = f"too few inliers ({candidate.n_inliers} of {n_tracked})"
        else:
            candidate.curr_from_prev = geometry.to_3x3(matrix)
        if candidate.failure is not None:
            if lk_pass > 0:
                break  # refinement only ever improves an accepted estimate: keep pass 1's
            return candidate
        if lk_pass == 0:
            candidate, others = _largest_first(candidate, _other_motions(prev_pts, curr_pts, inliers,
                                                                         candidate.curr_from_prev, config))
            candidate.others = [(matrix, prev_pts[index], curr_pts[index]) for matrix, index in others]
        else:  # the refining pass tracks against the first motion: the others keep their first-pass tracks
            candidate.others = result.others
        result = candidate
        curr_from_prev = result.curr_from_prev
    inl = result.inliers
    projected = geometry.apply(result.curr_from_prev, result.prev_points[inl])
    result.residual_px = float(np.sqrt(np.mean(np.sum((projected - result.curr_points[inl]) ** 2, axis=1))))
    return result


def _largest_first(first: _WorkEstimate, others: list[tuple[np.ndarray, np.ndarray]]
                   ) -> tuple[_WorkEstimate, list[tuple[np.ndarray, np.ndarray]]]:
    """RANSAC's winner is the motion most tracks follow. A similarity-seeded fit can win on fewer tracks than
    another motion takes once fitted in full (a blurred frame's noisy tracks fit a similarity less well), so the
    motion with the most tracks goes first; the camera chooser keeps the first where nothing says otherwise."""
    if not others:
        return first, others
    k = max(range(len(others)), key=lambda i: len(others[i][1]))
    if len(others[k][1]) <= first.n_inliers:
        return first, others
    matrix, index = others[k]
    inliers = np.zeros(len(first.inliers), bool)
    inliers[index] = True
    swapped = dataclasses.replace(first, curr_from_prev=matrix, inliers=inliers, n_inliers=int(inliers.sum()))
    return swapped, [(first.curr_from_prev, np.flatnonzero(first.inliers))] + others[:k] + others[k + 1:]


def _other_motions(prev_pts: np.ndarray, curr_pts: np.ndarray, inliers: np.ndarray, first: np.ndarray,
                   config: MotionConfig) -> list[tuple[np.ndarray, np.ndarray]]:
    """Up to MAX_OTHER_MOTIONS further motions among the first fit's outliers, one after another (each among what
    the ones before left; ``_next_motion``): RANSAC keeps the motion most tracks agree on, which is a large textured
    figure's once it holds more tracks than the background, and where several figures walk each moves its own way;
    a background of sky leaves the camera's motion few tracks. Each motion must move the frame at least
    ALTERNATIVE_MIN_SHIFT_PX differently from each found before. The first other needs ALTERNATIVE_MIN_SHARE of the
    tracks: beside one large layer, a few tracks of their own are a small or near object's. Once a second large layer
    shows that large figures move in the frame, and the winner may be one of them, a further motion needs only
    ALTERNATIVE_MIN_TRACKS: a background of sky behind them holds few. (matrix, its tracks' indices) each, working
    px."""
    share = max(ALTERNATIVE_MIN_TRACKS, int(ALTERNATIVE_MIN_SHARE * len(inliers)))
    left = ~inliers
    found: list[tuple[np.ndarray, np.ndarray]] = []
    while len(found) < MAX_OTHER_MOTIONS:
        needed = ALTERNATIVE_MIN_TRACKS if found else share
        if left.sum() < needed:
            break
        taken, aside = _next_motion(prev_pts, curr_pts, np.flatnonzero(left), [first, *(f[0] for f in found)],
                                    config, needed)
        if taken is not None:
            found.append(taken)
            left[taken[1]] = False
        elif aside is not None:
            left[aside] = False  # depth within one layer (parallax), not a motion of its own: set aside
        else:
            break
    return found


def _next_motion(prev_pts: np.ndarray, curr_pts: np.ndarray, index: np.ndarray, known: list[np.ndarray],
                 config: MotionConfig, needed: int) -> tuple[tuple[np.ndarray, np.ndarray] | None, np.ndarray | None]:
    """The next motion among the tracks ``index``: one step on top of the first motion (``_fit_beside``), else
    RANSAC's similarity-seeded fit (a figure nearer or farther than the first layer zooms differently, which no
    common step follows). Returns (motion, its tracks) or None, and the tracks of a fit too like a ``known`` motion
    (parallax) or None."""
    aside = None
    for fit in (lambda: _fit_beside(prev_pts[index], curr_pts[index], known[0], config),
                lambda: _fit_model(prev_pts[index], curr_pts[index], config)):
        matrix, mask = fit()
        if not _holds(matrix, mask, needed):
            continue
        motion = geometry.to_3x3(matrix)
        support = index[mask.ravel().astype(bool)]
        if min(corner_shift(motion, m, prev_pts) for m in known) >= ALTERNATIVE_MIN_SHIFT_PX:
            return (motion, support), None
        aside = support if aside is None else aside
    return None, aside


def _holds(matrix: np.ndarray | None, mask: np.ndarray | None, needed: int) -> bool:
    """A fit (as ``_fit_model`` returns it) that gave a finite motion on at least ``needed`` tracks."""
    return matrix is not None and mask is not None and bool(np.all(np.isfinite(matrix))) and int(mask.sum()) >= needed


def corner_shift(a: np.ndarray, b: np.ndarray, points: np.ndarray) -> float:
    """Mean distance (px) between where two transforms take the bounding box corners of ``points`` (N, 2)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]], np.float64)
    return float(np.mean(np.linalg.norm(geometry.apply(a, corners) - geometry.apply(b, corners), axis=1)))


def with_camera(estimate: MotionEstimate, choice: CameraChoice) -> MotionEstimate:
    """The estimate with the camera's motion the one ``choice`` took (pipeline/stages/background.py: 0 RANSAC's
    winner, k the k-th other motion): that motion and its tracks become the estimate's, RANSAC's winner one of the
    others."""
    if choice.taken == 0:
        return dataclasses.replace(estimate, camera=choice)
    taken = estimate.others[choice.taken - 1]
    winner = OtherMotion(estimate.curr_from_prev, estimate.prev_points[estimate.inliers],
                         estimate.curr_points[estimate.inliers])
    others = (winner, *(m for i, m in enumerate(estimate.others) if i != choice.taken - 1))
    return dataclasses.replace(
        estimate, curr_from_prev=taken.curr_from_prev, prev_points=taken.prev_points, curr_points=taken.curr_points,
        inliers=np.ones(len(taken.prev_points), bool), n_inliers=len(taken.prev_points), others=others,
        chose_other=True, camera=choice)


def _detect_corners(gray: np.ndarray, config: MotionConfig) -> np.ndarray:
    """Shi-Tomasi corners spread over a grid of cells, each cell with its own quota and quality scale.

    Detected globally, the strongest corners crowd onto the most textured thing in view, often a moving
    object, and RANSAC then fits a compromise. Per-cell quotas make the vote follow image area instead.
    """
    height, width = gray.shape
    cols, rows = config.corner_grid
    per_cell = max(4, config.max_corners // (cols * rows))
    found = []
    for r in range(rows):
        y0, y1 = r * height // rows, (r + 1) * height // rows
        for c in range(cols):
            x0, x1 = c * width // cols, (c + 1) * width // cols
            cell = gray[y0:y1, x0:x1]
            if cell.shape[0] < 8 or cell.shape[1] < 8 or int(cell.max()) - int(cell.min()) < 8:
                continue  # flat cell (sky, black border): nothing trackable
            corners = cv2.goodFeaturesToTrack(cell, maxCorners=per_cell, qualityLevel=config.corner_quality * 10,
                                              minDistance=config.corner_min_distance, blockSize=7)
            if corners is not None:
                found.append(corners.reshape(-1, 2) + (x0, y0))
    return np.concatenate(found).astype(np.float32) if found else np.zeros((0, 2), np.float32)


def _track(prev_gray: np.ndarray, curr_gray: np.ndarray, corners: np.ndarray, lk: dict,
           fb_max_error_px: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal LK from prev to curr; with ``fb_max_error_px``, keeps only tracks that come back to their start."""
    start = corners.reshape(-1, 1, 2).astype(np.float32)
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(prev_gray, curr_gray, start, None, **lk)
    good = status.ravel() == 1
    if fb_max_error_px is not None:
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(curr_gray, prev_gray, tracked, None, **lk)
        fb_error = np.linalg.norm((back - start).reshape(-1, 2), axis=1)
        good &= (status_back.ravel() == 1) & (fb_error < fb_max_error_px)
    return start.reshape(-1, 2)[good], tracked.reshape(-1, 2)[good]


def _warp_gray(curr_gray: np.ndarray, curr_from_prev: np.ndarray) -> np.ndarray:
    """curr resampled into prev's pixel grid: out(p) = curr(curr_from_prev p)."""
    height, width = curr_gray.shape
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    if geometry.is_affine(curr_from_prev):
        return cv2.warpAffine(curr_gray, curr_from_prev[:2], (width, height), flags=flags, borderMode=cv2.BORDER_REPLICATE)
    return cv2.warpPerspective(curr_gray, curr_from_prev, (width, height), flags=flags, borderMode=cv2.BORDER_REPLICATE)


def _fit_model(prev_pts: np.ndarray, curr_pts: np.ndarray, config: MotionConfig, *, tight: bool = False):
    """RANSAC's fit of the configured model; the first (not ``tight``) fit of a layer seeds it with a similarity
    (``_fit_layer``). Returns (2x3 or 3x3 matrix or None, (N, 1) uint8 inlier mask or None), as OpenCV's fits."""
    threshold = config.ransac_threshold_px * (0.5 if tight else 1.0)
    if not tight and config.model != "similarity":
        return _fit_layer(prev_pts, curr_pts, config, threshold)
    if config.model == "homography":
        return cv2.findHomography(prev_pts, curr_pts, cv2.RANSAC, threshold, maxIters=2000, confidence=0.995)
    fit = cv2.estimateAffine2D if config.model == "affine" else cv2.estimateAffinePartial2D
    return fit(prev_pts, curr_pts, method=cv2.RANSAC, ransacReprojThreshold=threshold,
               maxIters=2000, confidence=0.995, refineIters=20)


def _fit_layer(prev_pts: np.ndarray, curr_pts: np.ndarray, config: MotionConfig, threshold: float):
    """One rigid layer's motion: RANSAC over a similarity (4 parameters) finds the layer's tracks, then the
    configured model is fitted to them (``_refit``). RANSAC over an affine or a homography directly can explain two
    layers at once (a stretch that moves the background on one side of a large figure and the figure on the other,
    each within the threshold); a similarity cannot."""
    seed, mask = cv2.estimateAffinePartial2D(prev_pts, curr_pts, method=cv2.RANSAC, ransacReprojThreshold=threshold,
                                             maxIters=2000, confidence=0.995, refineIters=20)
    if seed is None or mask is None or _layer_model(config.model, int(mask.sum())) == "similarity":
        return seed, mask
    return _refit(prev_pts, curr_pts, mask.ravel().astype(bool), seed, config.model, threshold)


def _fit_beside(prev_pts: np.ndarray, curr_pts: np.ndarray, first: np.ndarray, config: MotionConfig):
    """Another layer's motion among the tracks ``first`` left: the tracks that move by one common step on top of
    ``first`` (the layers of a frame share the camera's rotation and zoom, a figure adds its own step) make the
    layer, and the configured model is fitted to them (``_refit``; a similarity on fewer than
    LAYER_MODEL_MIN_TRACKS). RANSAC over a similarity here can join two far-apart groups of tracks of different
    layers (its rotation and zoom make up their different steps), which is no layer's motion. The step is the one
    most tracks share within twice RANSAC's threshold. Returns (matrix, (N, 1) uint8 inlier mask) as ``_fit_model``."""
    threshold = config.ransac_threshold_px
    steps = curr_pts - geometry.apply(first, prev_pts)
    near = np.linalg.norm(steps[:, None, :] - steps[None, :, :], axis=2) < 2.0 * threshold
    members = near[int(np.argmax(near.sum(axis=1)))]
    shifted = geometry.to_3x3(first).copy()
    shifted[:2] += np.outer(np.median(steps[members], axis=0), shifted[2])
    seed = shifted if config.model == "homography" else shifted[:2]
    model = _layer_model(config.model, int(members.sum()))
    return _refit(prev_pts, curr_pts, members, seed, model, threshold)


def _layer_model(model: str, n_tracks: int) -> str:
    """The model a layer on ``n_tracks`` first-pass tracks is fitted with: the configured one from
    LAYER_MODEL_MIN_TRACKS tracks on, a similarity below."""
    return model if n_tracks >= LAYER_MODEL_MIN_TRACKS else "similarity"


def _refit(prev_pts: np.ndarray, curr_pts: np.ndarray, members: np.ndarray, seed: np.ndarray, model: str,
           threshold: float):
    """``model`` fitted by least squares to a layer's tracks (``members``), then to every track it explains within
    ``threshold``, twice; ``seed`` where a fit fails. Returns (matrix, (N, 1) uint8 inlier mask)."""
    matrix, inliers = seed, members
    for _ in range(2):
        fitted = _least_squares(prev_pts[inliers], curr_pts[inliers], model)
        if fitted is None:
            break
        error = np.linalg.norm(geometry.apply(geometry.to_3x3(fitted), prev_pts) - curr_pts, axis=1)
        matrix, inliers = fitted, error < threshold
    return matrix, inliers.astype(np.uint8).reshape(-1, 1)


def _least_squares(prev_pts: np.ndarray, curr_pts: np.ndarray, model: str) -> np.ndarray | None:
    """The similarity or affine (2x3) or homography (3x3) fitting the point pairs best, None with too few of them."""
    if model == "homography":
        if len(prev_pts) < 4:
            return None
        matrix, _ = cv2.findHomography(prev_pts, curr_pts, 0)
        return matrix
    if len(prev_pts) < 3:
        return None
    x, y = prev_pts[:, 0].astype(np.float64), prev_pts[:, 1].astype(np.float64)
    if model == "similarity":  # x' = a x - b y + tx, y' = b x + a y + ty
        ones, zeros = np.ones_like(x), np.zeros_like(x)
        design = np.vstack([np.column_stack([x, -y, ones, zeros]), np.column_stack([y, x, zeros, ones])])
        target = np.concatenate([curr_pts[:, 0], curr_pts[:, 1]]).astype(np.float64)
        (a, b, tx, ty), _, rank, _ = np.linalg.lstsq(design, target, rcond=None)
        return np.array([[a, -b, tx], [b, a, ty]]) if rank == 4 else None
    design = np.column_stack([x, y, np.ones_like(x)])
    solution, _, rank, _ = np.linalg.lstsq(design, curr_pts.astype(np.float64), rcond=None)
    return solution.T if rank == 3 else None


def _refine_ecc(prev_gray: np.ndarray, curr_gray: np.ndarray, start: _WorkEstimate,
                config: MotionConfig) -> _WorkEstimate:
    """Coarse-to-fine direct alignment (Bergen et al.'s hierarchical framework, ECC criterion).

    Starts from the feature estimate when there is one, else from the identity, so it can also rescue
    pairs with too few corners. Keeps the start when ECC does not converge.
    """
    homography = config.model == "homography"
    ecc_mode = cv2.MOTION_HOMOGRAPHY if homography else cv2.MOTION_AFFINE
    # ECC's warp maps template (curr) coordinates to input (prev) coordinates.
    prev_from_curr = np.linalg.inv(start.curr_from_prev)
    pyramid = [(prev_gray.astype(np.float32), curr_gray.astype(np.float32))]
    for _ in range(config.ecc_levels - 1):
        p, c = pyramid[-1]
        if min(p.shape) < 64:
            break
        pyramid.append((cv2.pyrDown(p), cv2.pyrDown(c)))
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, config.ecc_iterations, config.ecc_epsilon)
    try:
        for level in range(len(pyramid) - 1, -1, -1):
            scale = 0.5 ** level
            to_level = np.diag([scale, scale, 1.0])  # pyrDown halves coordinates (pixel-centre offset is negligible here)
            warp = to_level @ prev_from_curr @ np.linalg.inv(to_level)
            warp = (warp / warp[2, 2]).astype(np.float32)
            p, c = pyramid[level]
            _, warp = cv2.findTransformECC(c, p, warp if homography else warp[:2].copy(), ecc_mode, criteria, None, 5)
            prev_from_curr = np.linalg.inv(to_level) @ geometry.to_3x3(warp) @ to_level
    except cv2.error:
        return start
    curr_from_prev = geometry.to_3x3(np.linalg.inv(prev_from_curr))
    if config.model == "similarity":
        curr_from_prev = _nearest_similarity(curr_from_prev)
    return _WorkEstimate(curr_from_prev, None, start.n_tracked, start.n_inliers, start.residual_px,
                         start.prev_points, start.curr_points, start.inliers)


def _nearest_similarity(affine: np.ndarray) -> np.ndarray:
    """Closest rotation+uniform scale to the 2x2 part (polar decomposition), translation kept."""
    u, s, vt = np.linalg.svd(affine[:2, :2])
    rotation = u @ vt
    result = affine.copy()
    result[:2, :2] = rotation * s.mean()
    return result


def _implausible(curr_from_prev: np.ndarray, shape: tuple[int, int], config: MotionConfig) -> str | None:
    height, width = shape
    dx, dy, angle, scale = geometry.decompose(curr_from_prev, width, height)
    if abs(angle) > config.max_rotation_deg:
        return f"implausible rotation {angle:.1f} deg"
    if abs(scale - 1.0) > config.max_scale_change:
        return f"implausible scale change {scale:.2f}"
    if math.hypot(dx, dy) > config.max_shift_fraction * math.hypot(width, height):
        return f"implausible shift {math.hypot(dx, dy):.0f} px"
    if config.model == "homography" and np.abs(curr_from_prev[2, :2]).max() * max(width, height) > 0.5:
        return "implausible perspective"
    return None


def first_frame_estimate() -> MotionEstimate:
    """Frame 0 has no predecessor: identity by definition."""
    return MotionEstimate(curr_from_prev=geometry.IDENTITY.copy(), status="first")
