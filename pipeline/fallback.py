"""The last resort for pixels no neighbour covers (thesis 4.2.4, last paragraph: "a blurring filter").

Each missing pixel first takes the value of its nearest known pixel (flat extension, so a wide border
strip continues the border instead of drifting to some average), then the filled area is smoothed by
a blur that only spreads known-or-extended values, so the streaks of nearest extension disappear and
no seam or hole is visible. Known pixels are never changed.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage


def smooth_fill(image: np.ndarray, missing: np.ndarray, *, blur_sigma: float = 4.0) -> np.ndarray:
    """``image`` with ``missing`` pixels replaced by a smooth extension of the known ones."""
    if not missing.any():
        return image.copy()
    if missing.all():
        return np.zeros_like(image)
    ys, xs = np.nonzero(missing)
    pad = int(3 * blur_sigma) + 2
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, missing.shape[0])
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, missing.shape[1])
    box_missing = missing[y0:y1, x0:x1]
    box = image[y0:y1, x0:x1]
    if box_missing.all():  # the hole fills its whole neighbourhood: look at the full frame instead
        box_missing, box, (y0, x0) = missing, image, (0, 0)
    # Nearest known pixel for every pixel (indices of the closest False in box_missing).
    _, (near_y, near_x) = ndimage.distance_transform_edt(box_missing, return_indices=True)
    extended = box[near_y, near_x].astype(np.float32)
    smoothed = cv2.GaussianBlur(extended, (0, 0), blur_sigma, borderType=cv2.BORDER_REPLICATE)
    out = image.copy()
    region = out[y0:y0 + box.shape[0], x0:x0 + box.shape[1]]
    region[box_missing] = np.clip(smoothed[box_missing] + 0.5, 0, 255).astype(image.dtype)
    return out
