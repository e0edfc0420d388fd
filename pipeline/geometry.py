"""3x3 homogeneous transforms: naming convention and small helpers shared by the stages.

A matrix named ``a_from_b`` maps pixel coordinates of image b to pixel coordinates of image a,
acting on column vectors (x, y, 1); x right, y down, (0, 0) is the centre of the top-left pixel
(OpenCV's convention for warpAffine/warpPerspective).
"""

from __future__ import annotations

import math

import numpy as np

IDENTITY = np.eye(3)


def mask_pixels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.nonzero`` of a 2-D mask, (rows, columns) in raster order: ~4x faster on a large frame (numpy's
    2-D nonzero is much slower than its flat one)."""
    flat = np.flatnonzero(mask)
    return np.divmod(flat, mask.shape[1])


def is_affine(transform: np.ndarray) -> bool:
    """Whether a 3x3 transform's last row is (0, 0, 1) within ``np.allclose``'s default tolerances (the same
    test, in scalars: np.allclose on a 3-vector costs ~0.15 ms, called for every warp)."""
    m = transform
    return abs(m[2, 0]) <= 1e-8 and abs(m[2, 1]) <= 1e-8 and abs(m[2, 2] - 1.0) <= 1e-8 + 1e-5


def to_3x3(matrix: np.ndarray) -> np.ndarray:
    """A 2x3 affine or a 3x3 matrix as a float64 3x3 homogeneous matrix (normalised so [2, 2] == 1)."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])
    if m.shape != (3, 3):
        raise ValueError(f"expected a 2x3 or 3x3 matrix, got shape {m.shape}")
    return m / m[2, 2]


def apply(transform: np.ndarray, points_xy: np.ndarray) -> np.ndarray:
    """Map (N, 2) points through a 3x3 transform."""
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    homog = np.hstack([pts, np.ones((len(pts), 1))]) @ np.asarray(transform, dtype=np.float64).T
    return homog[:, :2] / homog[:, 2:3]


def frame_corners(width: int, height: int) -> np.ndarray:
    """The four corner pixel centres of a width x height image, clockwise from the top-left."""
    return np.array([[0, 0], [width - 1, 0], [width - 1, height - 1], [0, height - 1]], dtype=np.float64)


def corner_error(estimate: np.ndarray, truth: np.ndarray, width: int, height: int) -> float:
    """Largest distance (px) between the frame corners mapped by two transforms: a model-independent error."""
    corners = frame_corners(width, height)
    return float(np.max(np.linalg.norm(apply(estimate, corners) - apply(truth, corners), axis=1)))


def resize_from_full(scale: float) -> np.ndarray:
    """Maps full-resolution pixel coordinates to those of the image resized by ``scale`` (cv2.resize centres)."""
    offset = 0.5 * scale - 0.5
    return np.array([[scale, 0.0, offset], [0.0, scale, offset], [0.0, 0.0, 1.0]])


def rescale_transform(work_transform: np.ndarray, scale: float) -> np.ndarray:
    """A transform estimated between images resized by ``scale``, expressed in full-resolution pixels."""
    work_from_full = resize_from_full(scale)
    return to_3x3(np.linalg.inv(work_from_full) @ work_transform @ work_from_full)


def neighbour_transforms(curr_from_prev: np.ndarray, t: int, first: int, last: int,
                         prev_from_curr: np.ndarray | None = None) -> dict[int, np.ndarray]:
    """t_from_i for every i in [first, last]: chains of inter-frame transforms outward from t."""
    if prev_from_curr is None:
        prev_from_curr = np.linalg.inv(curr_from_prev)
    t_from = {t: IDENTITY.copy()}
    for i in range(t - 1, first - 1, -1):  # t_from_i = t_from_(i+1) @ (i+1)_from_i
        t_from[i] = t_from[i + 1] @ curr_from_prev[i + 1]
    for i in range(t + 1, last + 1):  # t_from_i = t_from_(i-1) @ (i-1)_from_i
        t_from[i] = t_from[i - 1] @ prev_from_curr[i]
    return {i: m / m[2, 2] for i, m in t_from.items()}


def decompose(transform: np.ndarray, width: int, height: int) -> tuple[float, float, float, float]:
    """Displacement of the frame centre (dx, dy in px), rotation (degrees) and mean scale of a transform.

    Using the centre, not the origin, keeps x/y free of the lever arm a rotation has at the corner.
    """
    centre = np.array([[(width - 1) / 2.0, (height - 1) / 2.0]])
    dx, dy = (apply(transform, centre) - centre)[0]
    a, b, c, d = transform[0, 0], transform[0, 1], transform[1, 0], transform[1, 1]
    angle = math.degrees(math.atan2(c - b, a + d))
    scale = math.sqrt(abs(a * d - b * c))
    return float(dx), float(dy), angle, scale
