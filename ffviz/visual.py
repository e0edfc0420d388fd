"""Turning intermediates into pictures for the viewer: flow colour wheel, sparse arrows, scalar maps."""

from __future__ import annotations

import cv2
import numpy as np


def flow_to_rgb(flow: np.ndarray, max_magnitude: float | None = None) -> np.ndarray:
    """Middlebury-style colour coding: hue = direction, saturation = magnitude; NaN flow is black."""
    valid = np.isfinite(flow).all(axis=-1)
    fx = np.where(valid, flow[..., 0], 0.0).astype(np.float32)
    fy = np.where(valid, flow[..., 1], 0.0).astype(np.float32)
    magnitude, angle = cv2.cartToPolar(fx, fy, angleInDegrees=True)
    scale = max_magnitude or max(float(np.percentile(magnitude[valid], 99)) if valid.any() else 1.0, 1e-3)
    hsv = np.zeros((*flow.shape[:2], 3), np.uint8)
    hsv[..., 0] = (angle / 2).astype(np.uint8)
    hsv[..., 1] = np.clip(magnitude / scale * 255, 0, 255).astype(np.uint8)
    hsv[..., 2] = np.where(valid, 255, 0).astype(np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def sparse_arrows(flow: np.ndarray, step: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """(origins, vectors) of the flow sampled on a grid, NaN samples dropped."""
    ys, xs = np.mgrid[step // 2: flow.shape[0]: step, step // 2: flow.shape[1]: step]
    vectors = flow[ys, xs].reshape(-1, 2)
    origins = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float32)
    keep = np.isfinite(vectors).all(axis=1)
    return origins[keep], vectors[keep]


def finite_or_nan(values: np.ndarray) -> np.ndarray:
    """Float32 map with non-finite values as NaN (the viewer leaves NaN transparent)."""
    out = np.asarray(values, dtype=np.float32).copy()
    out[~np.isfinite(out)] = np.nan
    return out
