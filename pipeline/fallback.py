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
    """``image`` with ``missing`` pixels replaced by a smooth extension of the known ones."""
    if not missing.any():
        return image.copy()
    if missing.all():
        return np.zeros_like(image)
    ys, xs = geometry.mask_pixels(missing)
    pad = int(3 * blur_sigma) + 2
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, missing.shape[0])
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, missing.shape[1])
    box_missing = missing[y0:y1, x0:x1]
    box = image[y0:y1, x0:x1]
    if box_missing.all():  # the hole fills its whole neighbourhood: look at the full frame instead
        box_missing, box, (y0, x0) = missing, image, (0, 0)
    extended = box.astype(np.float32)
    hole_y, hole_x = geometry.mask_pixels(box_missing)
    near = nearest_known(box_missing, hole_y, hole_x)
    extended[hole_y, hole_x] = extended.reshape(-1, *box.shape[2:])[near]
    smoothed = cv2.GaussianBlur(extended, (0, 0), blur_sigma, borderType=cv2.BORDER_REPLICATE)
    out = image.copy()
    region = out[y0:y0 + box.shape[0], x0:x0 + box.shape[1]]
    region[box_missing] = np.clip(smoothed[box_missing] + 0.5, 0, 255).astype(image.dtype)
    return out


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
