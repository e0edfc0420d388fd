"""Rolling-shutter correction: undo the wobble of cameras that expose their rows one after another.

A rolling shutter reads row y of frame t at time t + r y / H (r: the readout time as a fraction of the frame
interval), so a camera that shakes while the rows are read bends straight lines and makes the picture wobble
like jelly. The camera's image motion between rows is taken from the global motion estimates (thesis 3.2):
around frame t, the view at time ``mid + s`` (``mid``: the middle row's time, ``s`` in frames) is, to second
order in s,

    view(mid + s)_from_view(mid) = I + s (a_t + a_{t+1}) / 2 + s^2 (a_{t+1} - a_t) / 2,   a_t = curr_from_prev_t - I,

the parabola through the neighbouring frames' views (exact at s = -1, 0, 1 to first order in the motion).
Correction maps every frame to the global-shutter view of its middle row: an input pixel p of row y shows the
point ``q = view(mid + s(y))_from_view(mid)^-1 p``; the warp samples, for each output pixel, the input point
found by a fixed-point iteration on its row. The inter-frame motions are then refitted on tracks moved into
those views (a second round repeats it), so path planning sees the camera without the wobble.

The readout time is given (``--rolling-shutter 0.9``) or fitted (``auto``): the one, on a grid of 0..1 in
steps of 0.05 refined by a parabola, whose corrected tracks a similarity (the global-shutter camera's motion)
fits best. Per-band views (``RowMotion.bands``) are what the debugger shows.
Invariants: readout 0 is the identity map; corrections are affine in each row; missing pixels as in warping.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pipeline import geometry
from pipeline.errors import ConfigError
from pipeline.stages import warping
from pipeline.stages.motion import MotionEstimate

READOUT_GRID = np.round(np.linspace(0.0, 1.0, 21), 2)
REFIT_ROUNDS = 2  # motion refits on corrected tracks: a third hardly lowers the wobble (docs/decisions.md D17)
FIXED_POINT_ITERATIONS = 3  # input row of an output pixel: the motion in one row's time is far below a pixel
MIN_FIT_TRACKS = 12  # a pair's motion is refitted only on at least this many inlier tracks
DEFAULT_BANDS = 8


def parse_readout(text: str | float | None) -> float | str | None:
    """``--rolling-shutter`` value: None (off), "auto", or a readout time in 0..1 (fraction of the frame interval)."""
    if text is None or text == "auto":
        return text
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ConfigError(f"--rolling-shutter {text!r}: expected auto or a readout time in 0..1 "
                          f"(a fraction of the frame interval)") from None
    if not 0.0 <= value <= 1.0:
        raise ConfigError(f"--rolling-shutter {text}: the readout time is a fraction of the frame interval, 0..1")
    return value


@dataclass(frozen=True)
class RowMotion:
    """Frame t's rows against its middle row: view(mid + s)_from_view(mid) = I + s velocity + s^2 acceleration,
    with s = readout (y / height - 1/2) in frames; full-resolution px."""

    readout: float
    height: int
    velocity: np.ndarray  # 3x3, last row zero: (a_t + a_{t+1}) / 2
    acceleration: np.ndarray  # 3x3, last row zero: (a_{t+1} - a_t) / 2

    def row_times(self, rows) -> np.ndarray:
        """s of each (fractional) row, frames after the middle row's time."""
        return self.readout * (np.asarray(rows, np.float64) / self.height - 0.5)

    def row_from_mid(self, rows) -> np.ndarray:
        """(n, 3, 3): the view that exposed each row, from the middle row's view."""
        s = self.row_times(np.atleast_1d(rows))[:, None, None]
        return np.eye(3) + s * self.velocity + s * s * self.acceleration

    def bands(self, n_bands: int = DEFAULT_BANDS) -> tuple[np.ndarray, np.ndarray]:
        """(centre rows (n,), row_from_mid at them (n, 3, 3)): the correction as horizontal bands."""
        centres = (np.arange(n_bands) + 0.5) * self.height / n_bands - 0.5
        return centres, self.row_from_mid(centres)

    def mid_points(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) input pixels moved into the middle row's view (each by the inverse of its row's view)."""
        points = np.asarray(points, np.float64).reshape(-1, 2)
        m = self.row_from_mid(points[:, 1])  # affine: p = L q + b, so q = L^-1 (p - b), L^-1 in closed form
        dx, dy = points[:, 0] - m[:, 0, 2], points[:, 1] - m[:, 1, 2]
        det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
        return np.stack([(m[:, 1, 1] * dx - m[:, 0, 1] * dy) / det, (m[:, 0, 0] * dy - m[:, 1, 0] * dx) / det], axis=1)

    def valid_box(self, width: int, samples: int = 9) -> np.ndarray:
        """(4, 2) corners of an axis-aligned box, in the middle row's view, that the input frame covers (its
        border, moved row by row into that view, sampled at ``samples`` points a side, lies outside the box)."""
        ramp_x, ramp_y = np.linspace(0.0, width - 1.0, samples), np.linspace(0.0, self.height - 1.0, samples)
        left = self.mid_points(np.stack([np.zeros(samples), ramp_y], axis=1))[:, 0].max()
        right = self.mid_points(np.stack([np.full(samples, width - 1.0), ramp_y], axis=1))[:, 0].min()
        top = self.mid_points(np.stack([ramp_x, np.zeros(samples)], axis=1))[:, 1].max()
        bottom = self.mid_points(np.stack([ramp_x, np.full(samples, self.height - 1.0)], axis=1))[:, 1].min()
        return np.array([[left, top], [right, top], [right, bottom], [left, bottom]])

    def input_points(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Input coordinates showing the middle-row-view points (x, y) (arrays of one shape): p = row_from_mid(p_y) q,
        solved for p_y by fixed-point iteration."""
        v, a = self.velocity, self.acceleration
        vx, vy = v[0, 0] * x + v[0, 1] * y + v[0, 2], v[1, 0] * x + v[1, 1] * y + v[1, 2]
        ax, ay = a[0, 0] * x + a[0, 1] * y + a[0, 2], a[1, 0] * x + a[1, 1] * y + a[1, 2]
        row = y
        for _ in range(FIXED_POINT_ITERATIONS):
            s = self.row_times(row)
            row = y + s * vy + s * s * ay
        s = self.row_times(row)
        return x + s * vx + s * s * ax, row


def row_motions(curr_from_prev: np.ndarray, usable: np.ndarray, readout: float, height: int) -> list[RowMotion]:
    """Every frame's RowMotion from the inter-frame motions (N, 3, 3; [t] maps frame t-1 to t) of the pairs that
    are ``usable`` (N bools; a cut or a failed pair is not: its side borrows the other's motion, and with
    neither the frame is left as it is)."""
    n = len(curr_from_prev)
    deviation = np.asarray(curr_from_prev, np.float64) - np.eye(3)
    deviation[:, 2, :] = 0.0  # first order: perspective rows are not extrapolated
    ok = np.asarray(usable, bool).copy()
    if n:
        ok[0] = False
    motions = []
    for t in range(n):
        before = deviation[t] if ok[t] else None
        after = deviation[t + 1] if t + 1 < n and ok[t + 1] else None
        before = after if before is None else before
        after = before if after is None else after
        if before is None:
            before = after = np.zeros((3, 3))
        # The outer pairs, where there are any, make the derivatives fourth-order (five-point stencils).
        earlier = deviation[t - 1] if t >= 2 and ok[t - 1] and ok[t] else before
        later = deviation[t + 2] if t + 2 < n and ok[t + 2] and t + 1 < n and ok[t + 1] else after
        velocity = (7.0 * (before + after) - (earlier + later)) / 12.0
        acceleration = (15.0 * (after - before) - (later - earlier)) / 24.0
        motions.append(RowMotion(float(readout), int(height), velocity, acceleration))
    return motions


def fit_pair(prev_points: np.ndarray, curr_points: np.ndarray, model: str) -> np.ndarray:
    """Least-squares curr_from_prev of a model (similarity, affine, homography) on matched points."""
    p, c = np.asarray(prev_points, np.float64), np.asarray(curr_points, np.float64)
    if model == "homography":
        import cv2

        matrix, _ = cv2.findHomography(p, c, 0)
        return geometry.to_3x3(matrix) if matrix is not None else _affine_fit(p, c)
    return _similarity_fit(p, c) if model == "similarity" else _affine_fit(p, c)


def _affine_fit(p: np.ndarray, c: np.ndarray) -> np.ndarray:
    design = np.concatenate([p, np.ones((len(p), 1))], axis=1)
    solution, *_ = np.linalg.lstsq(design, c, rcond=None)
    return np.vstack([solution.T, [0.0, 0.0, 1.0]])


def _similarity_fit(p: np.ndarray, c: np.ndarray) -> np.ndarray:
    """[[a, -b, tx], [b, a, ty]] by linear least squares, on centred points for conditioning."""
    pm, cm = p.mean(axis=0), c.mean(axis=0)
    pc, cc = p - pm, c - cm
    norm = float(np.sum(pc * pc)) or 1.0
    a = float(np.sum(pc[:, 0] * cc[:, 0] + pc[:, 1] * cc[:, 1])) / norm
    b = float(np.sum(pc[:, 0] * cc[:, 1] - pc[:, 1] * cc[:, 0])) / norm
    linear = np.array([[a, -b], [b, a]])
    t = cm - linear @ pm
    return np.array([[a, -b, t[0]], [b, a, t[1]], [0.0, 0.0, 1.0]])


Tracks = tuple[np.ndarray, np.ndarray]  # (prev, curr) inlier track ends of a pair, (M, 2) each, full-resolution px


def inlier_tracks(estimate: MotionEstimate) -> Tracks | None:
    """What the correction keeps of a pair: its inlier tracks (None: a pair it cannot use)."""
    if estimate.status != "ok" or len(estimate.inliers) != len(estimate.prev_points):
        return None
    inl = estimate.inliers
    if int(inl.sum()) < MIN_FIT_TRACKS:
        return None
    return estimate.prev_points[inl].astype(np.float32), estimate.curr_points[inl].astype(np.float32)


@dataclass(frozen=True)
class Correction:
    """The clip's rolling-shutter correction: the readout time, every frame's RowMotion, and the inter-frame
    motions between the corrected (middle-row) views, for path planning."""

    readout: float
    rows: list[RowMotion]
    curr_from_prev: np.ndarray  # (N, 3, 3)


def correct(curr_from_prev: np.ndarray, tracks: Sequence[Tracks | None], readout: float, height: int,
            model: str = "affine") -> Correction:
    """RowMotions for a known readout time, with the inter-frame motions (N, 3, 3; [t] maps frame t-1 to t)
    refitted between corrected views on each pair's inlier ``tracks`` (None: a pair that failed, a cut)."""
    curr_from_prev = np.asarray(curr_from_prev, np.float64)
    usable = np.array([pair is not None for pair in tracks])
    rows = row_motions(curr_from_prev, usable, readout, height)
    if readout == 0:
        return Correction(0.0, rows, curr_from_prev)
    for _ in range(REFIT_ROUNDS):
        refitted = curr_from_prev.copy()
        for t, pair in enumerate(tracks):
            if pair is not None and t > 0:
                refitted[t] = fit_pair(rows[t - 1].mid_points(pair[0]), rows[t].mid_points(pair[1]), model)
        curr_from_prev = refitted
        rows = row_motions(curr_from_prev, usable, readout, height)
    return Correction(float(readout), rows, curr_from_prev)


def readout_misfit(curr_from_prev: np.ndarray, tracks: Sequence[Tracks | None], readout: float,
                   height: int) -> float:
    """Mean squared residual (px^2) of a similarity fitted to each pair's inlier tracks in the views corrected
    for ``readout``: how far the corrected frames are from a global-shutter camera's."""
    correction = correct(curr_from_prev, tracks, readout, height, "affine")
    total, count = 0.0, 0
    for t, pair in enumerate(tracks):
        if pair is None or t == 0:
            continue
        prev_mid, curr_mid = correction.rows[t - 1].mid_points(pair[0]), correction.rows[t].mid_points(pair[1])
        residual = geometry.apply(_similarity_fit(prev_mid, curr_mid), prev_mid) - curr_mid
        total += float(np.mean(np.sum(residual * residual, axis=1)))
        count += 1
    return total / count if count else 0.0


def fit_readout(curr_from_prev: np.ndarray, tracks: Sequence[Tracks | None], height: int) -> float:
    """The readout time in 0..1 whose correction leaves the tracks closest to a global-shutter camera's motion."""
    misfit = np.array([readout_misfit(curr_from_prev, tracks, r, height) for r in READOUT_GRID])
    best = int(np.argmin(misfit))
    if 0 < best < len(READOUT_GRID) - 1:  # parabola through the minimum and its neighbours
        lo, mid, hi = misfit[best - 1:best + 2]
        curvature = lo - 2 * mid + hi
        if curvature > 0:
            step = READOUT_GRID[1] - READOUT_GRID[0]
            return float(np.clip(READOUT_GRID[best] + 0.5 * step * (lo - hi) / curvature, 0.0, 1.0))
    return float(READOUT_GRID[best])


def estimate(curr_from_prev: np.ndarray, tracks: Sequence[Tracks | None], readout: float | str, height: int,
             model: str = "affine") -> Correction:
    """The correction for a given readout time, or for the fitted one with ``readout="auto"``."""
    value = fit_readout(curr_from_prev, tracks, height) if readout == "auto" else float(readout)
    return correct(curr_from_prev, tracks, value, height, model)


def orig_maps(orig_from_out: np.ndarray, rows: RowMotion, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """float32 (H, W) maps of the input coordinates each output pixel samples: the output pixel mapped by
    ``orig_from_out`` into frame t's middle-row view, then to the input row that shows it."""
    width, height = size
    xs, ys = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    m = np.asarray(orig_from_out, np.float64)
    w = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
    qx = (m[0, 0] * xs + m[0, 1] * ys + m[0, 2]) / w
    qy = (m[1, 0] * xs + m[1, 1] * ys + m[1, 2]) / w
    px, py = rows.input_points(qx, qy)
    return px.astype(np.float32), py.astype(np.float32)


def middle_row_view(rgb: np.ndarray, rows: RowMotion) -> np.ndarray:
    """The frame seen from its middle row's view (bilinear; the few border pixels no row covers repeat the edge):
    what the neighbours of a frame are for completion and deblurring, which align whole frames."""
    import cv2

    height, width = rgb.shape[:2]
    map_x, map_y = orig_maps(np.eye(3), rows, (width, height))
    return cv2.remap(rgb, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def warp_frame(rgb: np.ndarray, orig_from_out: np.ndarray, rows: RowMotion | None,
               size: tuple[int, int] | None = None) -> warping.WarpResult:
    """``warping.warp_frame`` with each row's view undone first (bilinear; missing: pixels not fully covered)."""
    if rows is None or rows.readout == 0:
        return warping.warp_frame(rgb, orig_from_out, size)
    import cv2

    height, width = rgb.shape[:2]
    out_size = size or (width, height)
    map_x, map_y = orig_maps(orig_from_out, rows, out_size)
    frame = cv2.remap(rgb, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    coverage = cv2.remap(np.full((height, width), 255, np.uint8), map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    missing = coverage < 255
    warping.blacken(frame, missing)
    return warping.WarpResult(frame=frame, missing=missing, orig_from_out=np.asarray(orig_from_out, np.float64))
