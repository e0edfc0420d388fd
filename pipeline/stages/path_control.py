"""What a user says about the camera path, beside the planner's own parameters (issue 25).

Smoothness: one strength 0-100 per axis (translation, rotation, zoom), as Warp Stabilizer's "Smoothness %" and
Gyroflow's per-axis smoothness. 50 is the default path; 0 follows the input. On eq. 18's path it sets the radius
k (sigma = sqrt(k)) of each axis, k = K (s / 50)^2 with K the run's k (the mode's default); on the L1 path the
margin each axis may depart from its input, default (s / 50). A larger strength is a larger kernel or a larger feasible set: a smoother path.

Departure bound: no output frame's centre moves more than ``max_shift`` px (x and y each) from its input's, nor
turns more than ``max_angle`` degrees (vid.stab maxshift / maxangle); applied last, on every path.

Segments: time ranges with their own path and smoothness (Gyroflow keyframes), e.g. ``0-5:tripod`` and
``5-:gaussian:80``. Each range is planned alone; at a switch the new range's correction starts where the old one
ends and the difference fades out over ``BLEND_S`` seconds (raised cosine): the path has no jump, and frames
before the switch follow the old setting exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline import geometry
from pipeline.errors import ConfigError

DEFAULT_STRENGTH = 50.0  # the strength of the default path (eq. 18 at the mode's k; the L1 path's default margins)
BLEND_S = 1.0  # seconds over which a segment's correction eases into the next one's
AXES = ("translation", "rotation", "zoom")
_AXIS_KEYS = {"t": "translation", "r": "rotation", "z": "zoom"}


@dataclass(frozen=True)
class Smoothness:
    """Strength 0-100 per axis: 0 follows the input, 50 is the default path, 100 the smoothest offered."""

    translation: float = DEFAULT_STRENGTH
    rotation: float = DEFAULT_STRENGTH
    zoom: float = DEFAULT_STRENGTH

    def __post_init__(self) -> None:
        for axis in AXES:
            value = getattr(self, axis)
            if not 0.0 <= value <= 100.0:  # False for nan
                raise ConfigError(f"smoothness {axis} must be between 0 and 100, not {value}")

    @classmethod
    def parse(cls, text: str) -> Smoothness:
        """``S`` (every axis) or ``t=S,r=S,z=S`` (axes left out keep 50)."""
        text = text.strip()
        try:
            if "=" not in text:
                values = dict.fromkeys(AXES, float(text))
            else:
                values = {}
                for part in text.split(","):
                    key, _, value = part.partition("=")
                    values[_AXIS_KEYS[key.strip().lower()]] = float(value)
        except (KeyError, ValueError):
            raise ConfigError(f"smoothness {text!r}: expected a number 0-100 or t=S,r=S,z=S") from None
        return cls(**values)

    def radius(self, axis: str, default: int) -> int:
        """Eq. 18's k for an axis: ``default`` (the run's k without --smoothness) at strength 50, 0 at 0, four times
        ``default`` at 100 (quadratic: fine control where it is light)."""
        return int(round(default * (getattr(self, axis) / DEFAULT_STRENGTH) ** 2))

    def margin_factor(self, axis: str) -> float:
        """The L1 path's margin for an axis, as a multiple of its default: 1 at strength 50, 0 at 0, 2 at 100."""
        return getattr(self, axis) / DEFAULT_STRENGTH

    @property
    def uniform(self) -> bool:
        return self.translation == self.rotation == self.zoom

    def label(self) -> str:
        if self.uniform:
            return f"{self.translation:g}"
        return f"t={self.translation:g},r={self.rotation:g},z={self.zoom:g}"


@dataclass(frozen=True)
class PathSegment:
    """A time range (seconds, end exclusive; None: to the end) planned with its own path and smoothness."""

    start_s: float
    end_s: float | None
    path: str
    smoothness: Smoothness | None = None

    def __post_init__(self) -> None:
        if not self.start_s >= 0 or (self.end_s is not None and not self.end_s > self.start_s):
            raise ConfigError(f"path segment {self.start_s:g}-{'' if self.end_s is None else f'{self.end_s:g}'}: "
                              f"needs 0 <= start < end (seconds)")
        if self.path == "tripod" and self.smoothness is not None:
            raise ConfigError("a tripod segment holds the camera still: it takes no smoothness")

    @classmethod
    def parse(cls, text: str) -> PathSegment:
        """``T0-T1:PATH[:SMOOTHNESS]`` in seconds, either end may be left out (``5-:l1``, ``-2.5:tripod``);
        SMOOTHNESS as ``Smoothness.parse``."""
        times, _, rest = text.partition(":")
        path, _, strength = rest.partition(":")
        first, dash, last = times.partition("-")
        try:
            if not dash or not path:
                raise ValueError
            start = float(first) if first.strip() else 0.0
            end = float(last) if last.strip() else None
        except ValueError:
            raise ConfigError(f"path segment {text!r}: expected T0-T1:PATH or T0-T1:PATH:SMOOTHNESS (seconds; "
                              f"either end may be left out), e.g. 0-5:tripod or 5-:gaussian:80") from None
        return cls(start, end, path.strip(), Smoothness.parse(strength) if strength else None)

    def label(self) -> str:
        end = "" if self.end_s is None else f"{self.end_s:g}"
        return f"{self.start_s:g}-{end}:{self.path}" + (f":{self.smoothness.label()}" if self.smoothness else "")


def check_segments(segments: tuple[PathSegment, ...]) -> None:
    """Segments may leave gaps (the main setting plans those) but must not overlap."""
    ordered = sorted(segments, key=lambda s: s.start_s)
    for before, after in zip(ordered, ordered[1:]):
        if before.end_s is None or before.end_s > after.start_s:
            raise ConfigError(f"path segments {before.label()} and {after.label()} overlap")


def setting_of_frames(segments: tuple[PathSegment, ...], times_s: np.ndarray) -> np.ndarray:
    """(N,) index per frame: 0 for the main setting, k + 1 for ``segments[k]``; a frame belongs to a range when
    its time is in [start, end)."""
    setting = np.zeros(len(times_s), dtype=np.int64)
    for k, segment in enumerate(segments):
        inside = times_s >= segment.start_s - 1e-9
        if segment.end_s is not None:
            inside &= times_s < segment.end_s - 1e-9
        setting[inside] = k + 1
    return setting


def blend_frames(times_s: np.ndarray) -> int:
    """``BLEND_S`` in frames at the clip's median frame interval."""
    if len(times_s) < 2:
        return 1
    interval = float(np.median(np.diff(times_s)))
    return max(int(round(BLEND_S / interval)), 1) if interval > 0 else 1


def ease_out(offset: np.ndarray, frames: int) -> np.ndarray:
    """Weight of the previous setting's correction ``offset`` frames after a switch: 1 at the switch, a raised
    cosine down to 0 at ``frames`` (zero slope at both ends)."""
    u = np.clip(np.asarray(offset, np.float64) / max(frames, 1), 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(math.pi * u))


def eased(start_offset: np.ndarray, weight: float) -> np.ndarray:
    """The 3x3 transform ``weight`` of the way from the identity to ``start_offset`` (exact at 0 and 1; the
    offsets are small, so the linear blend of matrices is a near-similarity throughout)."""
    m = np.eye(3) + weight * (start_offset - np.eye(3))
    return m / m[2, 2]


def bound_departure(orig_from_stab: np.ndarray, width: int, height: int, max_shift: float | None,
                    max_angle: float | None) -> np.ndarray:
    """Each S_t limited so that the output frame's centre lies within ``max_shift`` px (x and y each) of the
    input frame's and turns at most ``max_angle`` degrees from it: a rotation about the centre, then a shift,
    applied only where the bound is exceeded (the frames within it are unchanged)."""
    out = np.array(orig_from_stab, dtype=np.float64, copy=True)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    for t, s in enumerate(out):
        dx, dy, angle, _ = geometry.decompose(s, width, height)
        if max_angle is not None and abs(angle) > max_angle:
            turn = math.radians(math.copysign(max_angle, angle) - angle)
            c, n = math.cos(turn), math.sin(turn)
            about_centre = np.array([[c, -n, cx - c * cx + n * cy], [n, c, cy - n * cx - c * cy], [0, 0, 1.0]])
            s = s @ about_centre  # turns the output about its centre, which S_t still sends to the same place
        if max_shift is not None and (abs(dx) > max_shift or abs(dy) > max_shift):
            shift = np.eye(3)
            shift[0, 2] = float(np.clip(dx, -max_shift, max_shift)) - dx
            shift[1, 2] = float(np.clip(dy, -max_shift, max_shift)) - dy
            s = shift @ s
        out[t] = s / s[2, 2]
    return out
