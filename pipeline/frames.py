"""A decoded video frame: its place in the stream and its pixels. The type every layer passes frames in (the
reader makes them, sources hand them out, the chain and the results carry them), so it sits below all of them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frame:
    index: int  # 0-based decode order after dropping undecodable frames
    pts: int | None  # presentation timestamp in the stream's time_base
    time_s: float  # seconds since the stream's start_time (absolute time is pts * time_base)
    rgb: np.ndarray  # (H, W, 3) uint8 (float32 0..255: deeper video read with keep_depth), rotation applied

