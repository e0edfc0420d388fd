"""Rolling-shutter wobble against a synthetic clip's true camera (pipeline.evaluation.synthetic, ``readout``).

An output frame is judged by where each of its pixels' content lies in the world: output pixel -> the input
coordinates it sampled (the warp's maps) -> the world, through the camera that exposed that input row. A
global-shutter camera sees the world through one similarity (centre, roll, zoom); whatever no similarity
explains is distortion. Per output row, the mean of that residual over the row is the row's displacement; the
wobble of a frame is the variance of the displacements over the rows (x and y summed, output px^2), and of a
clip the mean over its frames.
"""

from __future__ import annotations

import numpy as np

from pipeline.evaluation.synthetic import SyntheticVideo

GRID_STEP_PX = 8  # output pixels sampled every this many px in x and y


def world_points(video: SyntheticVideo, t: int, input_x: np.ndarray, input_y: np.ndarray) -> np.ndarray:
    """(n, 2) world coordinates shown by input pixels (n,) of frame t, each through its own row's camera."""
    world_from_row = np.linalg.inv(video.row_frame_from_world(t, input_y))
    homogeneous = np.stack([input_x, input_y, np.ones_like(input_x)], axis=1)
    return np.einsum("nij,nj->ni", world_from_row, homogeneous)[:, :2]


def frame_wobble(video: SyntheticVideo, t: int, map_x: np.ndarray, map_y: np.ndarray) -> float:
    """Per-row displacement variance (output px^2) of output frame t, whose pixel (x, y) sampled input frame t
    at (map_x[y, x], map_y[y, x]); pixels sampling outside the input are left out."""
    height, width = map_x.shape
    ys, xs = np.mgrid[0:height:GRID_STEP_PX, 0:width:GRID_STEP_PX]
    ix, iy = map_x[ys, xs].astype(np.float64), map_y[ys, xs].astype(np.float64)
    w, h = video.size
    inside = (ix >= 0) & (ix <= w - 1) & (iy >= 0) & (iy <= h - 1)
    out = np.stack([xs[inside], ys[inside]], axis=1).astype(np.float64)
    world = world_points(video, t, ix[inside], iy[inside])
    # Least-squares similarity world ~ S(out): [[a, -b, tx], [b, a, ty]], on centred points.
    om, wm = out.mean(axis=0), world.mean(axis=0)
    oc, wc = out - om, world - wm
    norm = float(np.sum(oc * oc))
    a = float(np.sum(oc[:, 0] * wc[:, 0] + oc[:, 1] * wc[:, 1])) / norm
    b = float(np.sum(oc[:, 0] * wc[:, 1] - oc[:, 1] * wc[:, 0])) / norm
    predicted = oc @ np.array([[a, b], [-b, a]]) + wm
    residual = (world - predicted) / np.hypot(a, b)  # world px -> output px
    rows = ys[inside]
    per_row = np.array([residual[rows == r].mean(axis=0) for r in np.unique(rows) if np.sum(rows == r) >= 4])
    return float(np.sum(per_row.var(axis=0)))


def clip_wobble(video: SyntheticVideo, maps) -> float:
    """Mean ``frame_wobble`` over frames; ``maps``: iterable of (t, map_x, map_y)."""
    values = [frame_wobble(video, t, mx, my) for t, mx, my in maps]
    return float(np.mean(values))
