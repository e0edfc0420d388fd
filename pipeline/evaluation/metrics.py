"""Objective stabilization measures: Liu et al. 2013 as the common evaluation script computes them, plus ours.

Liu, Yuan, Tan, Sun, "Bundled camera paths for video stabilization" (SIGGRAPH 2013) defined cropping ratio,
distortion and stability; this module follows the script published with DIFRINT (github.com/jinsc37/DIFRINT,
``metrics.py``), written from the definitions (no code copied) and without its known bugs, and adds two measures
of ours: residual jitter in pixels (one video) and the flicker of synthesized pixels (input against output).

* Matching: SIFT once per frame on a copy whose longer side is ``max_side``, Lowe's ratio test, a RANSAC
  homography; a pair fails on too few matches or inliers, a degenerate fit, or (consecutive frames of one
  video) a step implausible as camera motion (``_plausible_step``).
* ``compare``, input frame i against output frame i (``H_i``: input -> output pixels, ``A = H_i[:2, :2]``):
  cropping ``min(1, 1 / sqrt|det A|)``, distortion ``sigma_min(A) / sigma_max(A)``, black border fraction.
* Stability (``stability_score``): the share of the accumulated path's spectral energy (translation magnitude,
  rotation angle) in frequencies 1-5, DC excluded.
* Residual jitter (``residual_jitter``): RMS of the frame-centre trajectory minus its Gaussian low-pass
  (sigma = half a second; each end padded by point reflection about a line fitted to it).
* Synthesized-pixel flicker (``synthesized_change``): mean |O_t - warp(O_{t-1})| over output pixels outside
  the input frame's mapped outline (a seam band excluded), divided by the same mean over real pixels.

Invariants: both videos are read only through ``video_reader.VideoReader`` (upright, rotation tags applied; an
undecodable frame stood in for by the previous one, so frame counts agree with the stabilizer's); a failed
pair is left out of every mean, never counted as a value (NaN when all fail; ``to_dict`` writes None).
Every definition in full, with where and why it departs from the script: docs/metrics.md.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import asdict, dataclass
from typing import Callable, Iterator

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter1d

from pipeline.runtime.video_info import VideoInfo
from pipeline.runtime import video_reader
from pipeline.errors import ConfigError, InputError

_MIN_INLIERS = 8
# a step between neighbouring frames beyond these is a scene cut or a bogus fit, not camera motion
_MAX_STEP_ROTATION_DEG = 30.0
_MAX_STEP_SCALE = 1.5
_MIN_STEP_ANISOTROPY = 0.7
_LOW_BINS = 5


@dataclass(frozen=True)
class MetricsConfig:
    """How frames are matched and pixels classed (docs/metrics.md)."""

    max_side: int = 320  # px: longer side of the image given to SIFT (which doubles it internally)
    ratio: float = 0.75  # Lowe's ratio test: best match distance over the second best's, at most this
    ransac_px: float = 3.0  # px of the downscaled image: RANSAC's reprojection threshold
    n_features: int = 1000  # keypoints SIFT keeps a frame, the strongest
    min_matches: int = 10  # matches: a pair needs more good ones than this
    black_level: int = 7  # 0..255: a pixel is black when R, G and B are all <= this ("< 8")
    seam_px: int = 2  # px: band on either side of the input's outline that is neither real nor synthesized
    min_synth_fraction: float = 0.005  # share of the frame: a pair synthesizing less is left out of the flicker

    def __post_init__(self) -> None:
        if self.max_side < 16:
            raise ConfigError(f"max_side must be at least 16, not {self.max_side}")


def _clean(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    return value


@dataclass
class VideoMotionStats:
    residual_jitter_px: float
    residual_jitter_deg: float
    stability_translation: float
    stability_rotation: float
    n_frames: int
    failed_pairs: int

    def to_dict(self) -> dict:
        return _clean(asdict(self))


@dataclass
class StabilizationMetrics:
    """Comparison of an input video and its stabilized output (definitions: docs/metrics.md)."""

    cropping_ratio: float
    distortion: float
    distortion_mean: float
    black_fraction: float
    stability_translation: float
    stability_rotation: float
    residual_jitter_px: float
    residual_jitter_deg: float
    input: VideoMotionStats
    n_frames: int
    failed_pairs: int
    synth_flicker_ratio: float = float("nan")  # synth_change_mean / real_change_mean
    synth_change_mean: float = float("nan")  # mean |O_t - warp(O_{t-1})| over synthesized pixels, 0-255
    real_change_mean: float = float("nan")  # the same over real pixels
    synth_flicker_pairs: int = 0  # consecutive output pairs that entered the three above

    def to_dict(self) -> dict:
        """JSON-serialisable (NaN becomes None), with the input's stats nested under "input"."""
        return _clean(asdict(self))


# ----------------------------------------------------------------------------------------------
# Reading: only through pipeline.runtime.video_reader, so both videos are seen upright (the container's rotation
# tag applied) exactly as the stabilizer saw its input and wrote its output, and a frame that does not
# decode is stood in for as in the stabilizer (frame count and timing kept). Read raw, a phone clip
# tagged "rotate 90" is landscape while its upright output is portrait: the output was squeezed onto
# the input's size and the distortion read about 0.56 instead of 0.99.


def _fps(info: VideoInfo) -> float:
    """Frame rate for the jitter low-pass (sigma = fps / 2 frames)."""
    fps = float(info.fps)
    return fps if math.isfinite(fps) and fps > 0 else 30.0


def _pictures(reader: video_reader.VideoReader) -> Iterator[np.ndarray]:
    """The reader's upright RGB frames, (H, W, 3) uint8, one at a time."""
    for frame in reader:
        yield frame.rgb


# ----------------------------------------------------------------------------------------------
# Features and pairwise homographies


@dataclass
class _Features:
    points: np.ndarray  # (N, 2) float32, full-resolution pixels
    descriptors: np.ndarray | None
    scale: float  # detection image / full resolution
    shape: tuple[int, int]  # full-resolution (height, width)


def _detector(config: MetricsConfig):
    return cv2.SIFT_create(config.n_features), cv2.NORM_L2


def _detect(rgb: np.ndarray, detector, config: MetricsConfig) -> _Features:
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    h, w = grey.shape
    scale = min(1.0, config.max_side / max(h, w))
    if scale < 1.0:
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        small = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        per_axis = np.array([size[0] / w, size[1] / h])  # exact, after rounding the small size
    else:
        small, per_axis = grey, np.ones(2)
    keypoints, descriptors = detector.detectAndCompute(small, None)
    if keypoints:
        # keypoint coordinates refer to pixel centres: map centre-to-centre back to full resolution
        pts = (np.array([kp.pt for kp in keypoints], dtype=np.float64) + 0.5) / per_axis - 0.5
    else:
        pts = np.zeros((0, 2))
    return _Features(pts.astype(np.float32), descriptors, float(per_axis.min()), (h, w))


def _plausible_step(H: np.ndarray) -> bool:
    """Whether a consecutive-frame homography can be camera motion rather than a bogus fit (a cut)."""
    A = H[:2, :2]
    sv = np.linalg.svd(A, compute_uv=False)
    scale = math.sqrt(sv[0] * sv[1])
    angle = abs(math.degrees(math.atan2(H[1, 0], H[0, 0])))
    return angle <= _MAX_STEP_ROTATION_DEG and 1 / _MAX_STEP_SCALE <= scale <= _MAX_STEP_SCALE and sv[1] >= _MIN_STEP_ANISOTROPY * sv[0]


def _match(a: _Features, b: _Features, norm: int, config: MetricsConfig, consecutive: bool = False) -> np.ndarray | None:
    """Homography H with b ~ H a in full-resolution pixels, or None when the pair fails.

    ``consecutive``: the frames are neighbours in one video, so an implausible step fails too.
    """
    if a.descriptors is None or b.descriptors is None or len(a.descriptors) < 2 or len(b.descriptors) < 2:
        return None
    matcher = cv2.BFMatcher(norm)
    knn = matcher.knnMatch(a.descriptors, b.descriptors, k=2)
    pairs = [m for m in knn if len(m) == 2]
    if len(pairs) <= config.min_matches:
        return None
    dist = np.array([(m[0].distance, m[1].distance) for m in pairs])
    good = dist[:, 0] < config.ratio * dist[:, 1]
    if int(good.sum()) <= config.min_matches:
        return None
    query = np.array([m[0].queryIdx for m in pairs])[good]
    train = np.array([m[0].trainIdx for m in pairs])[good]
    src = a.points[query]
    dst = b.points[train]
    threshold = config.ransac_px / min(a.scale, b.scale)
    H, mask = cv2.findHomography(src, dst, cv2.RANSAC, threshold, maxIters=2000, confidence=0.995)
    if H is None or mask is None or int(mask.sum()) < _MIN_INLIERS:
        return None
    if not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
        return None
    H = H / H[2, 2]
    if np.linalg.det(H[:2, :2]) <= 0:
        return None
    if consecutive and not _plausible_step(H):
        return None
    return H


def pair_homography(a_rgb: np.ndarray, b_rgb: np.ndarray, config: MetricsConfig = MetricsConfig()) -> np.ndarray | None:
    """Homography H (3x3, H[2,2] = 1) with ``b ~ H a`` in full-resolution pixels, or None on failure."""
    detector, norm = _detector(config)
    return _match(_detect(a_rgb, detector, config), _detect(b_rgb, detector, config), norm, config)


# ----------------------------------------------------------------------------------------------
# Array-level measures


def frame_cropping(H: np.ndarray) -> float:
    """min(1, 1 / sqrt(|det H[:2,:2]|)) for a homography mapping input to output."""
    s = math.sqrt(abs(float(np.linalg.det(H[:2, :2]))))
    return min(1.0, 1.0 / s) if s > 0 else float("nan")


def frame_distortion(H: np.ndarray) -> float:
    """Ratio of the smaller to the larger singular value of H[:2,:2]."""
    sv = np.linalg.svd(H[:2, :2], compute_uv=False)
    return float(sv[-1] / sv[0]) if sv[0] > 0 else float("nan")


def black_fraction(rgb: np.ndarray, level: int = 7) -> float:
    """Fraction of pixels with every channel <= level that are 4-connected to the image border."""
    img = np.ascontiguousarray(rgb)
    lo = (0,) * (img.shape[2] if img.ndim == 3 else 1)
    dark = cv2.inRange(img, lo, tuple(int(level) for _ in lo))  # 255 where every channel <= level
    if not (dark[0].any() or dark[-1].any() or dark[:, 0].any() or dark[:, -1].any()):
        return 0.0
    n, labels = cv2.connectedComponents(dark, connectivity=4)
    border = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    keep = np.zeros(n, dtype=bool)
    keep[border] = True
    keep[0] = False  # label 0 is the non-dark background
    counts = np.bincount(labels.ravel(), minlength=n)
    return float(counts[keep].sum()) / dark.size


# labels of synthesized_labels: 0 is reserved for "outside the frame" once a label image is warped
LABEL_REAL, LABEL_SEAM, LABEL_SYNTH = 1, 2, 3


def synthesized_labels(H: np.ndarray, shape: tuple[int, int], seam_px: int = 2) -> np.ndarray:
    """uint8 (height, width) labels of an output frame: LABEL_REAL inside the input frame mapped by H
    (``x_out ~ H x_in``; the input has the output's size), LABEL_SYNTH outside, LABEL_SEAM within
    ``seam_px`` pixels of the outline on either side."""
    h, w = shape
    corners = np.float64([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    mapped = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), np.asarray(H, np.float64)).reshape(-1, 2)
    inside = np.zeros((h, w), np.uint8)
    if np.all(np.isfinite(mapped)):
        pts = np.round(np.clip(mapped, -1e5, 1e5) * 16).astype(np.int32)  # 4 fractional bits
        cv2.fillPoly(inside, [pts], 1, lineType=cv2.LINE_8, shift=4)
    inner = outer = inside
    if seam_px > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * seam_px + 1, 2 * seam_px + 1))
        inner, outer = cv2.erode(inside, kernel), cv2.dilate(inside, kernel)
    # 3 - 1 - 1 = LABEL_REAL inside the eroded outline, 3 - 0 - 1 = LABEL_SEAM in the band, 3 outside
    return (LABEL_SYNTH - inner - outer).astype(np.uint8)


def synthesized_change(prev_grey: np.ndarray, prev_labels: np.ndarray, grey: np.ndarray, labels: np.ndarray,
                       M: np.ndarray) -> tuple[float, int, float, int]:
    """(sum, count) of |grey - warp(prev_grey)| over synthesized pixels, then over real ones.

    ``M`` maps the previous output frame to this one (``x_t ~ M x_{t-1}``). Real: real in both frames;
    synthesized: synthesized in either, in neither's seam band; both inside the warped previous frame.
    """
    h, w = grey.shape
    M = np.asarray(M, np.float64)
    warped = cv2.warpPerspective(prev_grey, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    prev = cv2.warpPerspective(prev_labels, M, (w, h), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=0)
    code = labels * np.uint8(4) + prev  # 4 x current label + previous label, 0..15
    diff = cv2.absdiff(grey, warped)
    out = []
    for lut in (_SYNTH_LUT, _REAL_LUT):
        mask = cv2.LUT(code, lut)  # 255 where the pixel is in the class
        out += [cv2.sumElems(cv2.bitwise_and(diff, mask))[0], cv2.countNonZero(mask)]
    return float(out[0]), int(out[1]), float(out[2]), int(out[3])


def _code_lut(codes) -> np.ndarray:
    lut = np.zeros(256, np.uint8)
    lut[list(codes)] = 255
    return lut


_REAL_LUT = _code_lut([LABEL_REAL * 4 + LABEL_REAL])
_SYNTH_LUT = _code_lut([LABEL_REAL * 4 + LABEL_SYNTH, LABEL_SYNTH * 4 + LABEL_REAL, LABEL_SYNTH * 4 + LABEL_SYNTH])


class _FlickerTally:
    """Streaming pooled sums of synthesized_change over consecutive output frames (keeps one frame)."""

    def __init__(self, config: MetricsConfig) -> None:
        self.config = config
        self.prev: tuple[np.ndarray, np.ndarray] | None = None  # grey and labels of the previous frame
        self.synth_sum = self.real_sum = 0.0
        self.synth_n = self.real_n = 0
        self.pairs = 0

    def add(self, grey: np.ndarray, H: np.ndarray | None, M: np.ndarray | None) -> None:
        """Frame t: its grey output, H_t (input -> output, None if failed), M_t (output t-1 -> t, None if failed or t = 0).

        A frame whose synthesized area is only a sliver along the outline, no deeper than H's fitting tolerance
        (``ransac_px`` at the detection scale), counts as having none: a crop's window touches the warped input at
        its tightest frame, where an H off by a few pixels would otherwise read as a strip of synthesized pixels."""
        labels = None if H is None else synthesized_labels(H, grey.shape, self.config.seam_px)
        if labels is not None and not self._synthesizes(H, grey.shape):
            labels = np.where(labels == LABEL_SYNTH, LABEL_SEAM, labels).astype(np.uint8)
        if labels is not None and self.prev is not None and M is not None:
            ss, sn, rs, rn = synthesized_change(self.prev[0], self.prev[1], grey, labels, M)
            if sn >= self.config.min_synth_fraction * grey.size and rn > 0:
                self.synth_sum += ss
                self.synth_n += sn
                self.real_sum += rs
                self.real_n += rn
                self.pairs += 1
        self.prev = None if labels is None else (grey, labels)

    def _synthesizes(self, H: np.ndarray, shape: tuple[int, int]) -> bool:
        """Whether at least min_synth_fraction of the frame lies outside H's outline by more than its tolerance."""
        tolerance = self.config.ransac_px * max(1.0, max(shape) / self.config.max_side)  # full-resolution px
        deep = synthesized_labels(H, shape, max(self.config.seam_px, math.ceil(tolerance)))
        return int(np.count_nonzero(deep == LABEL_SYNTH)) >= self.config.min_synth_fraction * deep.size

    def result(self) -> tuple[float, float, float]:
        """(synth_flicker_ratio, synth_change_mean, real_change_mean); NaN without a counted pair."""
        nan = float("nan")
        if self.pairs == 0:
            return nan, nan, nan
        synth, real = self.synth_sum / self.synth_n, self.real_sum / self.real_n
        return (synth / real if real > 0 else nan), synth, real


def _low_frequency_share(signal: np.ndarray) -> float:
    x = np.asarray(signal, dtype=np.float64)
    if x.size < 3:
        return float("nan")
    energy = np.abs(np.fft.fft(x)) ** 2
    energy = energy[1:]
    energy = energy[: energy.size // 2]
    total = float(energy.sum())
    scale = float(np.max(np.abs(x))) ** 2 * x.size ** 2
    if total <= 1e-20 * max(scale, 1e-300):
        return 1.0
    return float(energy[:_LOW_BINS].sum()) / total


def stability_score(path_matrices) -> tuple[float, float]:
    """(translation, rotation) stability of an accumulated path P_1..P_{N-1}, shape (K, 3, 3).

    Translation signal: |(P[0,2], P[1,2])|; rotation: unwrapped atan2(P[1,0], P[0,0]) in degrees.
    Each score is the energy of frequencies 1..5 over the energy of frequencies 1..(K-1)//2.
    NaN when K < 3.
    """
    P = np.asarray(path_matrices, dtype=np.float64).reshape(-1, 3, 3)
    if len(P) < 3:
        return float("nan"), float("nan")
    P = P / P[:, 2:3, 2:3]
    translation = np.hypot(P[:, 0, 2], P[:, 1, 2])
    rotation = np.degrees(np.unwrap(np.arctan2(P[:, 1, 0], P[:, 0, 0])))
    return _low_frequency_share(translation), _low_frequency_share(rotation)


def accumulate_path(pair_matrices) -> np.ndarray:
    """P_t = M_t @ P_{t-1} with P_0 = I, for M_1..M_K (None = identity); returns P_1..P_K, (K, 3, 3)."""
    P = np.eye(3)
    out = []
    for M in pair_matrices:
        if M is not None:
            P = np.asarray(M, dtype=np.float64) @ P
            P = P / P[2, 2]
        out.append(P.copy())
    return np.array(out).reshape(-1, 3, 3)


def pair_increment(M: np.ndarray | None, width: int, height: int) -> tuple[float, float, float]:
    """(dx, dy, dangle_rad) of one pairwise homography: how it moves the frame centre and turns it."""
    if M is None:
        return 0.0, 0.0, 0.0
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    p = M @ np.array([cx, cy, 1.0])
    return float(p[0] / p[2] - cx), float(p[1] / p[2] - cy), float(math.atan2(M[1, 0], M[0, 0]))


def trajectory(pair_matrices, width: int, height: int) -> np.ndarray:
    """(N, 3) trajectory x px, y px, angle rad: the running sum of pair increments, starting at 0."""
    inc = np.array([pair_increment(M, width, height) for M in pair_matrices]).reshape(-1, 3)
    return np.vstack([np.zeros((1, 3)), np.cumsum(inc, axis=0)])


def _end_anchor(T: np.ndarray, span: int, at_start: bool) -> np.ndarray:
    """Value at the first (or last) sample of a least-squares line through the first (last) span samples."""
    seg = T[:span] if at_start else T[-span:]
    if len(seg) < 2:
        return seg[0] if at_start else seg[-1]
    t = np.arange(len(seg), dtype=np.float64)
    t_end = 0.0 if at_start else t[-1]
    tc = t - t.mean()
    slope = (tc @ (seg - seg.mean(axis=0))) / float(tc @ tc)
    return seg.mean(axis=0) + slope * (t_end - t.mean())


def residual_jitter(trajectory_xy_angle, fps: float) -> tuple[float, float]:
    """(RMS px, RMS degrees) of a trajectory's high-pass residual (Gaussian sigma = fps/2 frames).

    ``trajectory_xy_angle``: (N, 3) array of x, y in pixels and angle in radians. The ends are padded
    by point reflection about a line fitted to the last half second, so constant-velocity motion
    stays out of the residual and one noisy end frame does not anchor the padding.
    """
    T = np.asarray(trajectory_xy_angle, dtype=np.float64).reshape(-1, 3)
    n = len(T)
    if n < 2:
        return 0.0, 0.0
    sigma = max(float(fps), 1e-6) / 2.0
    radius = max(1, int(4.0 * sigma + 0.5))
    span = min(n, max(2, int(round(sigma))))
    padded = np.pad(T, ((radius, radius), (0, 0)), mode="reflect", reflect_type="odd")  # 2 x_0 - x_k
    padded[:radius] += 2.0 * (_end_anchor(T, span, True) - T[0])  # -> 2 a_0 - x_k
    padded[radius + n :] += 2.0 * (_end_anchor(T, span, False) - T[-1])
    low = gaussian_filter1d(padded, sigma, axis=0, mode="nearest", truncate=4.0)[radius : radius + n]
    high = T - low
    px = math.sqrt(float(np.mean(high[:, 0] ** 2 + high[:, 1] ** 2)))
    deg = math.degrees(math.sqrt(float(np.mean(high[:, 2] ** 2))))
    return px, deg


def _motion_stats(pair_matrices: list, width: int, height: int, fps: float, n_frames: int) -> VideoMotionStats:
    st, sr = stability_score(accumulate_path(pair_matrices))
    jp, jd = residual_jitter(trajectory(pair_matrices, width, height), fps)
    return VideoMotionStats(
        residual_jitter_px=jp,
        residual_jitter_deg=jd,
        stability_translation=st,
        stability_rotation=sr,
        n_frames=n_frames,
        failed_pairs=sum(1 for M in pair_matrices if M is None),
    )


# ----------------------------------------------------------------------------------------------
# Videos


def video_motion_stats(path, config: MetricsConfig = MetricsConfig()) -> VideoMotionStats:
    """Stability scores and residual jitter of one video (one streaming pass).

    Detection of frame t runs in a worker thread while frames t-2 and t-1 are matched in the other.
    """
    detectors = [_detector(config) for _ in range(2)]  # one per thread: a detector is not shared
    norm = detectors[0][1]
    pair_futures = []
    n = 0
    width = height = 0
    with video_reader.VideoReader(path) as reader, ThreadPoolExecutor(max_workers=2) as pool:
        fps = _fps(reader.info)
        pending = None  # detection of the previous frame
        last: _Features | None = None  # features of the frame before it
        for rgb in _pictures(reader):
            if n == 0:
                height, width = rgb.shape[:2]
            future = pool.submit(_detect, rgb, detectors[n % 2][0], config)
            if pending is not None:
                feats = pending.result()
                if last is not None:
                    pair_futures.append(pool.submit(_match, last, feats, norm, config, True))
                last = feats
            pending = future
            n += 1
        if pending is not None:
            feats = pending.result()
            if last is not None:
                pair_futures.append(pool.submit(_match, last, feats, norm, config, True))
        pairs = [f.result() for f in pair_futures]
    if n == 0:
        raise InputError(f"video {path} has no frames")
    return _motion_stats(pairs, width, height, fps, n)


def compare(
    input_path,
    output_path,
    config: MetricsConfig = MetricsConfig(),
    progress: Callable[[int, int], None] | None = None,
) -> StabilizationMetrics:
    """Measures of an output video against its input, in one streaming pass over both.

    Per frame t: the input and output frames are detected once each (two worker threads), then
    three pairs are matched: input t -> output t, output t-1 -> output t, input t-1 -> input t. The
    matches of frame t run while frame t+1 is decoded and detected; of the previous frame only its
    features and, for the flicker figure, its grey output frame and its labels are kept.
    ``progress(done, total)`` is called once per frame; total is the input's frame count from its
    container (VideoInfo.frame_count: an estimate for MKV). Both videos are read upright
    through video_reader (see Reading). Raises InputError when a video cannot be read or the frame
    counts differ.
    """
    with ExitStack() as stack:
        in_reader = stack.enter_context(video_reader.VideoReader(input_path))
        out_reader = stack.enter_context(video_reader.VideoReader(output_path))
        return _compare(in_reader, out_reader, config, progress)


def _compare(in_reader: video_reader.VideoReader, out_reader: video_reader.VideoReader, config: MetricsConfig,
             progress: Callable[[int, int], None] | None) -> StabilizationMetrics:
    """compare's streaming pass: frame t's detections run while frame t - 1's matches are collected."""
    detectors = [_detector(config) for _ in range(2)]  # one per thread: a detector is not shared
    norm = detectors[0][1]
    # the input's count from its container (an estimate for MKV): for progress only
    tally = _Tally(config, in_reader.info.frame_count, progress)
    prev_in: _Features | None = None
    prev_out: _Features | None = None
    n = 0
    width = height = 0
    with ThreadPoolExecutor(max_workers=2) as pool:
        pending = None  # match jobs of the previous frame
        for a, b in _frame_pairs(in_reader, out_reader):
            if n == 0:
                height, width = a.shape[:2]
            tally.blacks.append(black_fraction(b, config.black_level))
            if b.shape[:2] != a.shape[:2]:
                b = cv2.resize(b, (a.shape[1], a.shape[0]), interpolation=cv2.INTER_AREA)
            fut_a = pool.submit(_detect, a, detectors[0][0], config)
            fut_b = pool.submit(_detect, b, detectors[1][0], config)
            if pending is not None:
                tally.collect(*pending)
            grey = cv2.cvtColor(b, cv2.COLOR_RGB2GRAY)
            fa, fb = fut_a.result(), fut_b.result()
            jobs = [pool.submit(_match, fa, fb, norm, config)]
            if prev_in is not None:
                jobs.append(pool.submit(_match, prev_out, fb, norm, config, True))
                jobs.append(pool.submit(_match, prev_in, fa, norm, config, True))
            pending = (jobs, grey)
            prev_in, prev_out = fa, fb
            n += 1
        if pending is not None:
            tally.collect(*pending)
    if n == 0:
        raise InputError(f"video {in_reader.info.path} has no frames")
    return tally.metrics(n, width, height, _fps(in_reader.info), _fps(out_reader.info))


def _frame_pairs(in_reader: video_reader.VideoReader,
                 out_reader: video_reader.VideoReader) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(input frame, output frame) in step; InputError, with both counts, when one video ends before the other."""
    in_iter = _pictures(in_reader)
    out_iter = _pictures(out_reader)
    n = 0
    while True:
        a = next(in_iter, None)
        b = next(out_iter, None)
        if a is None or b is None:
            if a is None and b is None:
                return
            n_in = n + (a is not None) + sum(1 for _ in in_iter)
            n_out = n + (b is not None) + sum(1 for _ in out_iter)
            raise InputError(f"frame counts differ: input has {n_in} frames, output has {n_out}")
        yield a, b
        n += 1


class _Tally:
    """What compare keeps of each frame once its matches are in: the pair transforms of both videos, the
    per-frame cropping, distortion and black share, the synthesized-pixel flicker; ``progress`` is told each."""

    def __init__(self, config: MetricsConfig, total: int, progress: Callable[[int, int], None] | None) -> None:
        self.in_pairs: list = []
        self.out_pairs: list = []
        self.crops: list[float] = []
        self.dists: list[float] = []
        self.blacks: list[float] = []
        self.failed_io = 0  # frames whose input -> output match failed
        self.flicker = _FlickerTally(config)
        self.done = 0
        self._total, self._progress = total, progress

    def collect(self, jobs: list, grey: np.ndarray) -> None:
        """One frame's match jobs (input -> output, then output t-1 -> t and input t-1 -> t after the first frame)
        and its grey output frame."""
        results = [j.result() for j in jobs]
        H = results[0]
        self.flicker.add(grey, H, results[1] if len(results) == 3 else None)
        if H is None:
            self.failed_io += 1
        else:
            self.crops.append(frame_cropping(H))
            self.dists.append(frame_distortion(H))
        if len(results) == 3:
            self.out_pairs.append(results[1])
            self.in_pairs.append(results[2])
        self.done += 1
        if self._progress is not None:
            self._progress(self.done, self._total)

    def metrics(self, n: int, width: int, height: int, fps_in: float, fps_out: float) -> StabilizationMetrics:
        """The measures over the ``n`` frames collected (of ``width`` x ``height``)."""
        out_stats = _motion_stats(self.out_pairs, width, height, fps_out, n)
        in_stats = _motion_stats(self.in_pairs, width, height, fps_in, n)
        nan = float("nan")
        ratio, synth_change, real_change = self.flicker.result()
        return StabilizationMetrics(
            cropping_ratio=float(np.mean(self.crops)) if self.crops else nan,
            distortion=float(np.min(self.dists)) if self.dists else nan,
            distortion_mean=float(np.mean(self.dists)) if self.dists else nan,
            black_fraction=float(np.mean(self.blacks)),
            stability_translation=out_stats.stability_translation,
            stability_rotation=out_stats.stability_rotation,
            residual_jitter_px=out_stats.residual_jitter_px,
            residual_jitter_deg=out_stats.residual_jitter_deg,
            input=in_stats,
            n_frames=n,
            failed_pairs=self.failed_io + out_stats.failed_pairs,
            synth_flicker_ratio=ratio,
            synth_change_mean=synth_change,
            real_change_mean=real_change,
            synth_flicker_pairs=self.flicker.pairs,
        )
