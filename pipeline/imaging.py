"""Pixel helpers the stages share: the thesis's intensity (section 4.2.1, after its reference [17]), on which
the mosaic's consistency (eqs. 20-22), the neighbours' alignment error (eq. 23) and blurriness (eq. 28) are taken."""

from __future__ import annotations

import cv2
import numpy as np

INTENSITY_WEIGHTS = np.array([0.30, 0.59, 0.11], np.float32)  # R, G, B


def intensity(rgb: np.ndarray) -> np.ndarray:
    """0.30 R + 0.59 G + 0.11 B as float32, for (..., 3) arrays."""
    # cv2.transform: numpy's matmul with a length-3 vector is ~20x slower on large stacks.
    flat = np.ascontiguousarray(rgb, dtype=np.float32).reshape(-1, 1, 3)
    return cv2.transform(flat, INTENSITY_WEIGHTS.reshape(1, 3)).reshape(rgb.shape[:-1])
