"""Stage stepping: which frames to trace, and the pictures a traced frame shows on the `stage` and
`fmm_step` timelines (pure numpy/OpenCV; the recorder logs them)."""

from __future__ import annotations

from typing import Iterator

import cv2
import numpy as np

from ffviz import visual
from ffviz.entities import TRACE_STAGES

DEFAULT_TRACED = 3  # frames traced when none are chosen
FMM_STEPS = 30  # pictures of the Fast Marching band per traced frame
FMM_BACKGROUND_GAIN = 0.45  # the stabilized frame, dimmed, around the area being filled
MIN_FLOW_SCALE_PX = 0.5  # flow colour saturates at max(99th percentile of the filled flow, this)
# Flow colours always have a channel at 255 and the dimmed frame none above 115, so these two colours
# never occur otherwise (zero flow is white: a white band would vanish into it).
PENDING_RGB = (20, 20, 70)  # pixels Fast Marching has yet to reach: dark blue
BAND_RGB = (240, 200, 0)  # the narrow band, next to a frozen pixel and not frozen yet: amber


def missing_fractions(orig_from_stab: np.ndarray, width: int, height: int) -> np.ndarray:
    """Per frame, the fraction of the stabilized frame no original pixel covers (exact for the frame's
    quadrilateral: area of its intersection with the frame rectangle)."""
    corners = np.array([[-0.5, -0.5, 1], [width - 0.5, -0.5, 1], [width - 0.5, height - 0.5, 1],
                        [-0.5, height - 0.5, 1]], np.float64).T
    frame = corners[:2].T.astype(np.float32)
    out = np.empty(len(orig_from_stab))
    for t, orig_from_stab_t in enumerate(orig_from_stab):
        mapped = np.linalg.inv(orig_from_stab_t) @ corners  # stab_from_orig: where the input's corners land
        quad = (mapped[:2] / mapped[2]).T.astype(np.float32)
        area, _ = cv2.intersectConvexConvex(quad, frame)
        out[t] = 1.0 - max(float(area), 0.0) / (width * height)
    return np.clip(out, 0.0, 1.0)


def default_trace_frames(orig_from_stab: np.ndarray, width: int, height: int, count: int = DEFAULT_TRACED) -> list[int]:
    """``count`` frames spread over the clip: in each of ``count`` equal parts, the frame with the most missing
    area (parts without any missing area are skipped); the parts' middle frames if no frame has any."""
    n = len(orig_from_stab)
    if n == 0 or count <= 0:
        return []
    missing = missing_fractions(orig_from_stab, width, height)
    parts = [p for p in np.array_split(np.arange(n), min(count, n)) if len(p)]
    chosen = [int(p[np.argmax(missing[p])]) for p in parts if missing[p].max() > 1e-4]
    return chosen or [int(p[len(p) // 2]) for p in parts]


def parse_frame_list(text: str) -> tuple[int, ...] | None:
    """'10,40' -> (10, 40); 'none' or '' -> () (trace nothing); 'auto' -> None (the default choice).

    Raises ValueError with a readable message on anything else.
    """
    text = text.strip().lower()
    if text == "auto":
        return None
    if text in ("", "none"):
        return ()
    try:
        frames = tuple(sorted({int(part) for part in text.split(",") if part.strip()}))
    except ValueError:
        raise ValueError(f"expected frame numbers separated by commas (e.g. 10,40), 'auto' or 'none', not {text!r}") from None
    if any(t < 0 for t in frames):
        raise ValueError(f"frame numbers must be >= 0, not {text!r}")
    return frames


def local_warp_frame(mosaic_frame: np.ndarray, completed: np.ndarray, local_warp: np.ndarray) -> np.ndarray:
    """The frame after the local-warp stage: the mosaic's frame with the local-warp pixels of the completed
    frame; what only the fallback filled is still black."""
    frame = mosaic_frame.copy()
    frame[local_warp] = completed[local_warp]
    return frame


def fmm_thresholds(n_filled: int, steps: int = FMM_STEPS) -> np.ndarray:
    """Visiting-order thresholds of the pictures: at step s the pixels with order < thresholds[s] are filled."""
    steps = max(1, min(steps, n_filled))
    return np.round(np.linspace(0, n_filled, steps + 1)).astype(np.int64)


def fmm_band_images(stabilized: np.ndarray, flow: np.ndarray, order: np.ndarray, steps: int = FMM_STEPS,
                    ) -> Iterator[tuple[int, int, int, np.ndarray]]:
    """(step, pixels filled, pixels to fill, RGB picture) as Fast Marching fills the flow into the missing area.

    ``flow``/``order`` are a motion inpainting result's (order >= 0 on the pixels it filled, in visiting
    order). The picture: the dimmed stabilized frame for context; the filled pixels' flow colour-coded
    (scaled to the filled flow, so small motions still show hue); pixels still to fill dark blue; the
    band (not frozen yet, next to a frozen pixel) amber. Nothing is yielded when nothing was filled.
    """
    n_filled = int(order.max()) + 1 if order.size else 0
    if n_filled <= 0:
        return
    to_fill = order >= 0
    magnitude = np.hypot(flow[to_fill, 0], flow[to_fill, 1])
    magnitude = magnitude[np.isfinite(magnitude)]
    scale = max(float(np.percentile(magnitude, 99)) if magnitude.size else 0.0, MIN_FLOW_SCALE_PX)
    colours = visual.flow_to_rgb(flow, max_magnitude=scale)  # one colour scale for every step
    base = (stabilized.astype(np.float32) * FMM_BACKGROUND_GAIN).astype(np.uint8)
    frozen_before = (order < 0) & np.isfinite(flow).all(axis=-1)  # the flow Fast Marching starts from
    kernel = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)  # 4-neighbours, as the marching uses
    for step, threshold in enumerate(fmm_thresholds(n_filled, steps)):
        pending = to_fill & (order >= threshold)
        done = to_fill & ~pending
        band = pending & (cv2.dilate((frozen_before | done).astype(np.uint8), kernel) > 0)
        image = base.copy()
        image[done] = colours[done]
        image[pending] = PENDING_RGB
        image[band] = BAND_RGB
        yield step, int(threshold), n_filled, image


def stage_label(frame: int, step: int) -> str:
    """What the ``stage`` timeline's picture at ``step`` shows, e.g. 'frame 10, stage 2/5: mosaic'."""
    return f"frame {frame}, stage {step}/{len(TRACE_STAGES) - 1}: {TRACE_STAGES[step]}"
