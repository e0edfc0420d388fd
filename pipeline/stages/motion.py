"""Global motion between consecutive frames (thesis 3.2).

Robust feature-based estimation: Shi-Tomasi corners tracked by pyramidal Lucas-Kanade with a
forward-backward check, then a RANSAC fit of the chosen model (affine by default, similarity or
homography). Optionally a hierarchical direct refinement in the spirit of Bergen et al.: ECC
(enhanced correlation coefficient) maximisation coarse-to-fine on an image pyramid.

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

MotionModel = Literal["affine", "similarity", "homography"]
Refinement = Literal["none", "ecc"]
RANSAC_SEED = 0x5EED
# A second motion is looked for among RANSAC's outliers when they are at least this share of the tracks ...
ALTERNATIVE_MIN_SHARE = 0.15
ALTERNATIVE_MIN_SHIFT_PX = 6.0  # ... and kept when it moves the frame this much differently (working px): less is
# depth (parallax between near and far layers of a walk), which the camera path must not jump between
ALTERNATIVE_PRIOR_PX = 2.0  # the alternative must continue the camera path this much better to be taken
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
    # The second motion the tracks hold (a large moving object, or the background when the object won RANSAC),
    # full-resolution 3x3, and the tracks that support it; None when there is none. ``choose_background``
    # decides which is the camera's.
    alternative: np.ndarray | None = None
    alternative_prev_points: np.ndarray | None = None  # (M, 2) its supporting tracks, full-resolution px
    alternative_curr_points: np.ndarray | None = None
    chose_alternative: bool = False  # the RANSAC winner was a moving object: the alternative was taken
    ignored: np.ndarray | None = None  # bool, working size: where prev's features were not used (--ignore*)

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
    return PreparedFrame(gray=gray, hist=hist, scale=scale, width=width, height=height, ignore=ignore)


def estimate(prev: PreparedFrame, curr: PreparedFrame, config: MotionConfig) -> MotionEstimate:
    """curr_from_prev between two prepared frames, or the identity with a reason.

    Deterministic: RANSAC draws from OpenCV's global RNG, reseeded here so that an estimate does not
    depend on what ran before it in the process (a segment run must equal a whole-video run).
    """
    cv2.setRNGSeed(RANSAC_SEED)
    hist_distance = float(cv2.compareHist(prev.hist, curr.hist, cv2.HISTCMP_BHATTACHARYYA))
    work = _track_and_fit(prev.gray, curr.gray, config, prev.ignore)
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
        alternative=None if work.alternative is None else geometry.rescale_transform(work.alternative, curr.scale),
        alternative_prev_points=None if work.alternative is None else work.alternative_points[0] * to_full,
        alternative_curr_points=None if work.alternative is None else work.alternative_points[1] * to_full,
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
    alternative: np.ndarray | None = None
    alternative_points: tuple[np.ndarray, np.ndarray] | None = None  # (prev, curr) tracks supporting it


def _track_and_fit(prev_gray: np.ndarray, curr_gray: np.ndarray, config: MotionConfig,
                   ignore: np.ndarray | None = None) -> _WorkEstimate:
    corners = _detect_corners(prev_gray, config)
    if ignore is not None and len(corners):
        x = np.clip(np.round(corners[:, 0]).astype(int), 0, ignore.shape[1] - 1)
        y = np.clip(np.round(corners[:, 1]).astype(int), 0, ignore.shape[0] - 1)
        corners = corners[~ignore[y, x]]
    if len(corners) < config.min_inliers:
        return _WorkEstimate(geometry.IDENTITY.copy(), f"featureless frame ({len(corners)} corners)")

    # Pass 1 only needs to land within a pixel (RANSAC and pass 2 do the rest): loose, cheap termination.
    lk = dict(winSize=(config.lk_window, config.lk_window), maxLevel=config.lk_levels,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
    corners = corners.reshape(-1, 2)
    curr_from_prev = geometry.IDENTITY.copy()
    result = _WorkEstimate(curr_from_prev, "no tracking pass ran")
    for lk_pass in range(max(1, config.lk_passes)):
        if lk_pass == 0:
            prev_pts, curr_pts = _track(prev_gray, curr_gray, corners, lk, config.fb_max_error_px)
        else:
            # Track again against curr brought back into prev's frame: what LK sees is only the residual
            # motion (a pixel or so), so no pyramid, ten iterations and no backward check suffice (as accurate
            # on synthetic truth as two levels and 30 iterations, at half the cost). All tracks take part, and
            # RANSAC runs tighter, so a compromise fit of pass 1 is not locked in.
            target = _warp_gray(curr_gray, curr_from_prev)
            refine_lk = dict(winSize=(21, 21), maxLevel=0,
                             criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.01))
            prev_pts, target_pts = _track(prev_gray, target, result.prev_points, refine_lk, None)
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
            candidate.alternative, candidate.alternative_points = _second_motion(prev_pts, curr_pts, inliers,
                                                                               candidate.curr_from_prev, config)
        else:  # the refining pass tracks against the first motion: the second keeps its first-pass tracks
            candidate.alternative, candidate.alternative_points = result.alternative, result.alternative_points
        result = candidate
        curr_from_prev = result.curr_from_prev
    inl = result.inliers
    projected = geometry.apply(result.curr_from_prev, result.prev_points[inl])
    result.residual_px = float(np.sqrt(np.mean(np.sum((projected - result.curr_points[inl]) ** 2, axis=1))))
    return result


def _second_motion(prev_pts: np.ndarray, curr_pts: np.ndarray, inliers: np.ndarray, first: np.ndarray,
                   config: MotionConfig) -> tuple[np.ndarray | None, tuple[np.ndarray, np.ndarray] | None]:
    """A second consistent motion among the first fit's outliers: RANSAC keeps the motion most tracks agree on,
    which is a large textured object's once it holds more tracks than the background. None when the outliers
    are too few (under ALTERNATIVE_MIN_SHARE of the tracks) or agree with nothing, or the motion is the first's."""
    outliers = ~inliers
    needed = max(config.min_inliers, int(ALTERNATIVE_MIN_SHARE * len(inliers)))
    if outliers.sum() < needed:
        return None, None
    matrix, mask = _fit_model(prev_pts[outliers], curr_pts[outliers], config)
    if matrix is None or mask is None or not np.all(np.isfinite(matrix)) or int(mask.sum()) < needed:
        return None, None
    second = geometry.to_3x3(matrix)
    if corner_shift(second, first, prev_pts) < ALTERNATIVE_MIN_SHIFT_PX:
        return None, None
    support = mask.ravel().astype(bool)
    return second, (prev_pts[outliers][support], curr_pts[outliers][support])


def corner_shift(a: np.ndarray, b: np.ndarray, points: np.ndarray) -> float:
    """Mean distance (px) between where two transforms take the bounding box corners of ``points`` (N, 2)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]], np.float64)
    return float(np.mean(np.linalg.norm(geometry.apply(a, corners) - geometry.apply(b, corners), axis=1)))


def choose_background(estimate: MotionEstimate, previous: MotionEstimate | None, width: int,
                      height: int) -> MotionEstimate:
    """The camera's motion between the two motions a pair holds (RANSAC keeps the one most tracks agree on,
    which is a large textured object's once it holds more tracks than the background).

    With no pair before (the first pair, or after a failed one), by spread: the background surrounds what moves
    in front of it, so its tracks spread wider. Where the pair before also held two motions, by place: this pair's tracks start in the frame the pair before
    ended in, so each of its tracks is labelled by the nearest track end of the pair before (background or
    object); the motion whose tracks lie mostly in the background's places is the camera's. An object moves
    10-25 px a frame, far less than its own size, so the places carry over. Otherwise the motion RANSAC kept stays
    when it holds the most tracks and they spread wider (both cues say background), and else the camera's is the
    motion that continues the previous pair's camera motion better by ALTERNATIVE_PRIOR_PX. Continuity alone is
    weak: a hand's shake can change the camera's motion by 10-15 px from one pair to the next, so a small object
    moving like the last pair's camera once took the camera's place (the demo's frames 42, 49 and 52)."""
    if estimate.alternative is None or estimate.status != "ok":
        return estimate
    swap = False
    kept_points = estimate.prev_points[estimate.inliers]
    if previous is None or previous.status != "ok":
        # A robust bounding box: wider for the background unless the object fills the frame edge to edge.
        swap = _spread(estimate.alternative_prev_points) > _spread(kept_points)
    elif previous.alternative is not None and len(kept_points):
        background_ends = previous.curr_points[previous.inliers]  # in this pair's first frame
        object_ends = previous.alternative_curr_points
        ends = np.concatenate([background_ends, object_ends])
        is_background = np.r_[np.ones(len(background_ends), bool), np.zeros(len(object_ends), bool)]
        import scipy.spatial  # here: only pairs holding two motions need it

        tree = scipy.spatial.cKDTree(ends)
        kept = is_background[tree.query(kept_points, k=1)[1]].mean()
        other = is_background[tree.query(estimate.alternative_prev_points, k=1)[1]].mean()
        swap = other > kept
    elif not (len(kept_points) >= len(estimate.alternative_prev_points)
              and _spread(kept_points) > _spread(estimate.alternative_prev_points)):
        corners = geometry.frame_corners(width, height)
        kept = corner_shift(estimate.curr_from_prev, previous.curr_from_prev, corners)
        other = corner_shift(estimate.alternative, previous.curr_from_prev, corners)
        swap = other + ALTERNATIVE_PRIOR_PX < kept
    if not swap:
        return estimate
    return dataclasses.replace(
        estimate, curr_from_prev=estimate.alternative, alternative=estimate.curr_from_prev,
        prev_points=estimate.alternative_prev_points, curr_points=estimate.alternative_curr_points,
        inliers=np.ones(len(estimate.alternative_prev_points), bool), n_inliers=len(estimate.alternative_prev_points),
        alternative_prev_points=kept_points, alternative_curr_points=estimate.curr_points[estimate.inliers],
        chose_alternative=True)


def _spread(points: np.ndarray) -> float:
    """Area of the 2nd-98th percentile box of (N, 2) points."""
    if len(points) < 2:
        return 0.0
    lo, hi = np.percentile(points, 2, axis=0), np.percentile(points, 98, axis=0)
    return float(np.prod(hi - lo))


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
    threshold = config.ransac_threshold_px * (0.5 if tight else 1.0)
    if config.model == "homography":
        return cv2.findHomography(prev_pts, curr_pts, cv2.RANSAC, threshold, maxIters=2000, confidence=0.995)
    fit = cv2.estimateAffine2D if config.model == "affine" else cv2.estimateAffinePartial2D
    return fit(prev_pts, curr_pts, method=cv2.RANSAC, ransacReprojThreshold=threshold,
               maxIters=2000, confidence=0.995, refineIters=20)


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
