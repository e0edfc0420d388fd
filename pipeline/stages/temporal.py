"""Temporal consistency of the synthesized pixels: each one averaged with the same scene point in the completed
frames next to it, weighted by how well they agree.

Completion (chapter 4) fills every frame on its own. Deep in a wide missing area several neighbours offer samples
that explain the surroundings about equally well but show the scene from slightly different places (parallax, a
near object leaving through the border), and which one wins changes from frame to frame: the synthesized area
flickers, the more so the larger the smoothing radius (eq. 18) makes it. Each synthesized pixel p of frame t
becomes

    O_t(p) = (C_t(p) + sum_j w_j C_j(q_j)) / (1 + sum_j w_j),   w_j = exp(-(d_j / sigma)^2),   0 < |j - t| <= r,

with C_j frame j's completed frame, q_j = S_j^-1 M_(j<-t) S_t p the same scene point in frame j's output (the
stabilized paths S and the global motion M: no estimation here), and d_j the largest channel difference between
C_j(q_j) and C_t(p). Only points frame j synthesized too are averaged in: where q_j is one of j's real pixels,
completion has already drawn on that frame, and taking its pixel as it is would bring its motion blur and the
resampling's softness into the strip (docs/decisions.md D40). Samples that disagree by much more than sigma (a moving
object, a step that is not flicker) leave frame t's own value. Real pixels are never changed; only frames of the
same shot take part.

Invariants: pure function of the completed frames and transforms given; the result is the same whatever order
frames are rendered in (each frame depends only on its neighbours' completion, never on their smoothed output),
so a segment rendered with r frames of margin is identical to the same frames of a whole-video run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from pipeline.errors import ConfigError
from pipeline.stages.neighbours import remap_points


@dataclass(frozen=True)
class TemporalConfig:
    radius: int = 1  # frames r on each side of t whose completed frames are averaged in; 0: off
    # Agreement scale (grey levels 0..255, largest channel difference): a neighbour's sample this far from frame t's
    # own counts e^-1 as much, at twice this 2 %. Wide enough to average out the flicker between near-equal samples,
    # narrow enough to leave a moving object's step alone (docs/decisions.md D40).
    sigma: float = 50.0

    def __post_init__(self) -> None:
        if self.radius < 0:
            raise ConfigError(f"temporal radius must be >= 0, not {self.radius}")
        if not self.sigma > 0:
            raise ConfigError(f"temporal sigma must be positive, not {self.sigma}")


@dataclass(frozen=True)
class CompletedFrame:
    """What temporal consistency needs of one completed frame: the frame and which of its pixels were synthesized."""

    frame: np.ndarray  # (H, W, 3) uint8
    synthesized: np.ndarray  # (H, W) bool


@dataclass
class TemporalResult:
    frame: np.ndarray  # the completed frame with its synthesized pixels averaged over time (H, W, 3) uint8
    share: np.ndarray  # (H, W) float32: the share of each pixel's value that came from other frames (0 on real ones)
    neighbours: tuple[int, ...]  # offsets j - t of the frames averaged in


@dataclass(frozen=True)
class CompletedNeighbour:
    """Frame j's completed frame, its synthesized pixels, and where frame t's output pixels are in it (3x3, t's
    output -> j's output)."""

    offset: int  # j - t
    frame: np.ndarray
    other_from_t: np.ndarray
    synthesized: np.ndarray  # (H, W) bool: frame j's own synthesized pixels (only those are averaged in)


def smooth(frame: np.ndarray, synthesized: np.ndarray, neighbours: Sequence[CompletedNeighbour],
           config: TemporalConfig) -> TemporalResult:
    """Frame t's completed ``frame`` with its ``synthesized`` pixels averaged with ``neighbours`` (see the module)."""
    share = np.zeros(synthesized.shape, np.float32)
    if not neighbours or not synthesized.any():
        return TemporalResult(frame, share, ())
    height, width = synthesized.shape
    flat = np.flatnonzero(synthesized)  # the synthesized pixels in row-major order, as np.nonzero gives them
    ys, xs = np.divmod(flat, width)
    own = frame.reshape(-1, 3)[flat].astype(np.float32)
    total = own.copy()
    weight = np.ones(len(ys), np.float32)
    points = np.stack([xs, ys, np.ones_like(xs)]).astype(np.float64)
    for neighbour in neighbours:
        mapped = neighbour.other_from_t @ points
        map_x, map_y = mapped[0] / mapped[2], mapped[1] / mapped[2]
        inside = (map_x >= 0) & (map_x <= width - 1) & (map_y >= 0) & (map_y <= height - 1)
        # Bicubic: a bilinear sample is a little blurred, and averaging it in would soften a textured strip; a
        # bicubic one keeps it as sharp as frame t's own (docs/decisions.md D40).
        sample = remap_points(neighbour.frame, map_x, map_y, cv2.BORDER_REPLICATE,
                              interpolation=cv2.INTER_CUBIC).astype(np.float32)
        difference = np.abs(sample - own).max(axis=1)
        rows = np.clip(np.rint(map_y), 0, height - 1).astype(np.intp)
        columns = np.clip(np.rint(map_x), 0, width - 1).astype(np.intp)
        also_synthesized = inside & neighbour.synthesized[rows, columns]
        w = np.exp(-np.square(difference / config.sigma)).astype(np.float32) * also_synthesized
        total += sample * w[:, None]
        weight += w
    out = frame.copy()
    out.reshape(-1, 3)[flat] = np.clip(total / weight[:, None] + 0.5, 0, 255).astype(np.uint8)
    share.reshape(-1)[flat] = 1.0 - 1.0 / weight
    return TemporalResult(out, share, tuple(n.offset for n in neighbours))
