"""The last resort for pixels no neighbour covers (thesis 4.2.4, last paragraph: "a blurring filter").

Each missing pixel first takes the value of its nearest known pixel (flat extension, so a wide border
strip continues the border instead of drifting to some average), then the filled area is smoothed by
a blur that only spreads known-or-extended values, so the streaks of nearest extension disappear and
no seam or hole is visible. Known pixels are never changed.
"""

from __future__ import annotations

import cv2
import numpy as np

from pipeline import geometry


def smooth_fill(image: np.ndarray, missing: np.ndarray, *, blur_sigma: float = 4.0) -> np.ndarray:
    """``image`` with ``missing`` pixels replaced by a smooth extension of the known ones.

    Each group of nearby missing pixels is filled in a box around it (grown by the blur's reach), so a hole's
    fill does not depend on holes elsewhere in the frame, and a few stray pixels in opposite corners of a
    1080p frame cost two small boxes rather than the frame."""
    if not missing.any():
        return image.copy()
    if missing.all():
        return np.zeros_like(image)
    pad = int(3 * blur_sigma) + 2
    out = image.copy()
    whole: np.ndarray | None = None  # the full frame's fill, made at most once
    ys, xs = geometry.mask_pixels(missing)
    for group_y, group_x in _groups(ys, xs, missing.shape, pad):
        y0, y1 = max(group_y.min() - pad, 0), min(group_y.max() + pad + 1, missing.shape[0])
        x0, x1 = max(group_x.min() - pad, 0), min(group_x.max() + pad + 1, missing.shape[1])
        if missing[y0:y1, x0:x1].all():  # the hole fills its whole neighbourhood: look at the full frame instead
            if whole is None:
                whole = _fill_box(image, missing, blur_sigma)
            smoothed, (y0, x0) = whole, (0, 0)
        else:
            smoothed = _fill_box(image[y0:y1, x0:x1], missing[y0:y1, x0:x1], blur_sigma)
        values = smoothed[group_y - y0, group_x - x0]
        half = 0.5 if image.dtype == np.uint8 else 0.0  # rounds into uint8; float32 (deeper video) as it is
        out[group_y, group_x] = np.clip(values + half, 0, 255).astype(image.dtype)
    return out


def _groups(ys: np.ndarray, xs: np.ndarray, shape: tuple[int, int], gap: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The pixels (ys, xs) in groups: cells of ``gap`` pixels holding some, joined when fewer than three empty
    cells apart (so pixels of different groups are more than 2 * gap apart)."""
    cell_y, cell_x = ys // gap, xs // gap
    occupied = np.zeros((shape[0] // gap + 1, shape[1] // gap + 1), np.uint8)
    occupied[cell_y, cell_x] = 1
    _, labels = cv2.connectedComponents(cv2.dilate(occupied, np.ones((3, 3), np.uint8)), connectivity=8)
    label = labels[cell_y, cell_x]
    order = np.argsort(label, kind="stable")
    splits = np.flatnonzero(np.diff(label[order])) + 1
    return [(ys[part], xs[part]) for part in np.split(order, splits)]


def _fill_box(box: np.ndarray, box_missing: np.ndarray, blur_sigma: float) -> np.ndarray:
    """The box with its missing pixels extended from the nearest known ones, then blurred (float32)."""
    extended = box.astype(np.float32)
    hole_y, hole_x = geometry.mask_pixels(box_missing)
    near = nearest_known(box_missing, hole_y, hole_x)
    extended[hole_y, hole_x] = extended.reshape(-1, *box.shape[2:])[near]
    return cv2.GaussianBlur(extended, (0, 0), blur_sigma, borderType=cv2.BORDER_REPLICATE)


def nearest_known(missing: np.ndarray, ys: np.ndarray, xs: np.ndarray,
                  mask_size: int = cv2.DIST_MASK_PRECISE) -> np.ndarray:
    """Flat index of the nearest known (not missing) pixel of each pixel (ys, xs): by exact Euclidean distance
    (OpenCV's precise distance transform; ties may go either way), or its 3x3/5x5 approximation
    (``mask_size`` 3 or 5)."""
    _, labels = cv2.distanceTransformWithLabels(missing.astype(np.uint8), cv2.DIST_L2, mask_size,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    known = np.flatnonzero(~missing)
    flat_labels = labels.reshape(-1)
    if flat_labels[known[0]] == 1 and flat_labels[known[-1]] == len(known):
        return known[labels[ys, xs] - 1]  # labels number the known pixels in raster order (OpenCV 4.x)
    pixel_of_label = np.zeros(int(labels.max()) + 1, np.int64)
    pixel_of_label[flat_labels[known]] = known
    return pixel_of_label[labels[ys, xs]]
