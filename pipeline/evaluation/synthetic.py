"""Synthetic hand-held video with exact ground truth: the built-in demo input and the basis of truth tests.

A "world" canvas (a photograph from ``skimage.data``, upscaled so every camera view plus a margin lies inside it)
is filmed by a virtual camera: a smooth intentional path (slow pan, drift and roll) plus band-limited hand-held
jitter (translation, roll, zoom). A foreground object is composited into the world before the camera warp: a
textured disc, or (``object_kind="person"``) a person-sized figure dressed in the world photograph's own colours,
walking 10-25 px a frame; the background it hides is kept. A few frames are motion-blurred with a known linear
kernel; their sharp versions are kept.

Coordinate convention (whole project): ``a_from_b`` is a 3x3 homogeneous matrix mapping pixel coordinates in
``b`` to pixel coordinates in ``a``, acting on column vectors ``(x, y, 1)``; x right, y down, the centre of
pixel (0, 0) is the coordinate (0, 0) (as ``cv2.warpAffine`` uses). Hence (readout 0: a global shutter)::

    frame_t == cv2.warpAffine(world_with_object_at_t, frame_from_world[t][:2], (W, H), flags=cv2.INTER_CUBIC)

Camera model: the frame of time t shows the world point ``c_t`` at the frame centre, with the camera rolled by
``theta_t`` (radians, positive = clockwise on screen, i.e. the usual rotation matrix acting on y-down
coordinates) and zoomed by ``s_t`` (frame pixels per world pixel)::

    world_from_frame = T(c) @ R(theta) @ S(1 / s) @ T(-frame_centre)

The jitter is added to these parameters: ``c = c_int + dc``, ``theta = theta_int + dtheta``,
``s = s_int * (1 + ds)``, each a zero-mean band-limited Gaussian process (default band 1.5-6 Hz, 4th order
Butterworth-shaped amplitude spectrum) normalised to the configured standard deviation over the clip.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterable, Iterator

import cv2
import numpy as np

from pipeline.errors import ConfigError

__all__ = [
    "SyntheticConfig",
    "SyntheticVideo",
    "generate",
    "stream_frames",
    "write_video",
    "make_two_frames",
    "motion_blur_kernel",
    "apply_blur",
    "load_image",
    "default_blurred_frames",
    "warp",
    "psnr",
]

# The textured disc that moves through the world: the round mission patch on the astronaut's sleeve.
_PATCH_CENTRE_XY = (172, 385)  # in skimage.data.astronaut() pixel coordinates
_PATCH_RADIUS = 37.0  # source pixels
_RIM_COLOUR = (40, 220, 90)  # saturated green rim, absent from the default photographs
_RIM_WIDTH = 3.0  # source pixels

# Pixels kept between any rendered pixel's footprint and the world canvas edge (cubic support is 2 px).
_INTERP_PAD = 3.0


@dataclass(frozen=True)
class SyntheticConfig:
    """Everything that defines a synthetic clip; the clip is a deterministic function of this."""

    width: int = 640  # px
    height: int = 360  # px
    n_frames: int = 90
    fps: float = 30.0  # frames a second
    image: str = "coffee"  # skimage.data name of the world photograph (coffee, astronaut, rocket, chelsea, ...)
    seed: int = 0  # of every random draw: the shake, the object's path, the noise
    # Hand-held jitter (standard deviations over the clip).
    jitter_px: float = 6.0  # translation, per axis, pixels
    jitter_deg: float = 1.0  # roll, degrees
    jitter_scale: float = 0.01  # relative zoom
    jitter_band_hz: tuple[float, float] = (1.5, 6.0)  # Hz: pass band of the jitter spectrum
    # Gain of the jitter over time: equal stretches of the clip, eased between by a raised cosine over a tenth of
    # the clip (e.g. (0.1, 1.0): a calm first half, a shaky second). () -> 1 throughout (the stds above hold).
    jitter_envelope: tuple[float, ...] = ()
    # Intentional (smooth) motion.
    pan_px_per_frame: float = 1.5  # px a frame: steady horizontal pan
    drift_px: float = 8.0  # px: amplitude of the slow sinusoidal drift (x; y gets 0.6x this)
    drift_deg: float = 0.5  # degrees: amplitude of the slow intentional roll
    drift_hz: float = 0.25  # Hz: frequency of the slow drift (well below the jitter band)
    # Moving foreground object.
    moving_object: bool = True  # False: a static scene
    # "disc": the mission patch (below); "person": a person-sized figure wearing a texture cut from the world
    # photograph itself (same colour statistics as the background), walking irregularly across the view.
    object_kind: str = "disc"
    object_radius_px: float = 40.0  # px: "disc": its radius
    object_sweep: float = 0.6  # fraction of the frame width its path spans (centred); > 1: enters/leaves through the borders
    person_size: tuple[float, float] = (0.22, 0.6)  # "person": width, height as fractions of the frame's
    person_speed_px: tuple[float, float] = (10.0, 25.0)  # "person": per-frame speed range, frame pixels
    people: int = 1  # "person": how many figures, each on its own path in its own cut of the photograph; the k-th
    # (from 0) at 0.8**k of person_size, behind the ones before it
    # Motion blur.
    blurred_frames: tuple[int, ...] | None = None  # None -> default_blurred_frames(n_frames); () -> none
    blur_length_px: float = 12.0  # px: length of the linear motion-blur kernel
    blur_angle_deg: float = 20.0  # direction (cos a, sin a) in y-down pixel coordinates (clockwise on screen)
    # Rolling shutter: row y of frame t is exposed with the camera of time t + readout * y / height (frames; the
    # camera between frames is the cubic spline through its per-frame parameters). 0: a global shutter.
    readout: float = 0.0
    # World canvas.
    world_margin: float = 0.12  # extra world around every (actual and intended) view, as a fraction of W and H
    min_world_scale: float = 1.0  # the photograph is upscaled by at least this factor

    def __post_init__(self) -> None:
        w, h, n, fps = int(self.width), int(self.height), int(self.n_frames), float(self.fps)
        if w < 8 or h < 8 or n < 1 or not fps > 0:  # "not >" also refuses NaN
            raise ConfigError(f"bad synthetic config: {w}x{h}, {n} frames at {fps} fps (needs >= 8x8, >= 1 frame, "
                              f"fps > 0)")
        if not 0.0 <= float(self.readout) <= 1.0:
            raise ConfigError(f"readout must be a fraction of the frame interval in 0..1, not {self.readout}")
        if self.object_kind not in ("disc", "person"):
            raise ConfigError(f"object_kind must be 'disc' or 'person', not {self.object_kind!r}")
        if int(self.people) < 1 or (self.people > 1 and self.object_kind != "person"):
            raise ConfigError(f"people must be at least 1, and above 1 only for object_kind 'person', not "
                              f"{self.people}")
        for i in self.blurred_frames or ():
            if not 0 <= int(i) < n:
                raise ConfigError(f"blurred frame index {i} outside 0..{n - 1}")


@dataclass
class SyntheticVideo:
    """A rendered clip and its exact truth. Transforms follow the ``a_from_b`` convention of the module."""

    frames: list[np.ndarray]  # rendered input frames, RGB uint8 (H, W, 3), blur applied where chosen
    sharp_frames: list[np.ndarray]  # the same without blur
    frame_from_world: np.ndarray  # (N, 3, 3) float64
    intended_frame_from_world: np.ndarray  # (N, 3, 3) the smooth intentional path, no jitter
    curr_from_prev: np.ndarray  # (N, 3, 3) background motion frame t-1 -> frame t; [0] = identity
    object_mask: list[np.ndarray]  # bool (H, W): the object's footprint (coverage >= 0.5) in the sharp frame
    blurred: tuple[int, ...]
    blur_kernel: np.ndarray  # float32 (odd kh, odd kw), centre (kh//2, kw//2), sums to 1, point-symmetric (so correlation == convolution)
    config: SyntheticConfig
    world: np.ndarray  # the world canvas, RGB uint8, without the object
    # Extras (not needed to construct by hand).
    intended_params: np.ndarray | None = None  # (N, 4): cx, cy (world px), theta (rad), zoom
    jitter_params: np.ndarray | None = None  # (N, 4): dcx, dcy (world px), dtheta (rad), dzoom (relative)
    object_world_from_patch: np.ndarray | None = None  # (N, 3, 3) pose of the object patch in the world
    object_patch: np.ndarray | None = None  # RGB uint8 (P, P, 3): the object texture
    object_alpha: np.ndarray | None = None  # float32 (P, P): its coverage (disc, anti-aliased edge)
    # The other figures (SyntheticConfig.people > 1), behind the first, each (patch, alpha, (N, 3, 3) world_from_patch).
    other_objects: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...] = ()

    # ------------------------------------------------------------------ derived truth
    @property
    def n_frames(self) -> int:
        return len(self.frames)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the frames."""
        return self.config.width, self.config.height

    @property
    def intended_from_frame(self) -> np.ndarray:
        """(N, 3, 3) the ideal stabilising warp: maps frame t pixels to the intended (jitter-free) view t."""
        return self.intended_frame_from_world @ np.linalg.inv(self.frame_from_world)

    @property
    def intended_curr_from_prev(self) -> np.ndarray:
        """(N, 3, 3) inter-frame motion of the intended path alone; [0] = identity."""
        return _curr_from_prev(self.intended_frame_from_world)

    @property
    def object_center_world(self) -> np.ndarray:
        """(N, 2) world coordinates of the object's centre (NaN rows when there is no object)."""
        if self.object_world_from_patch is None or self.object_patch is None:
            return np.full((self.n_frames, 2), np.nan)
        cx, cy = (self.object_patch.shape[1] - 1) / 2.0, (self.object_patch.shape[0] - 1) / 2.0
        p = self.object_world_from_patch @ np.array([cx, cy, 1.0])
        return p[:, :2] / p[:, 2:3]

    @property
    def object_center_frame(self) -> np.ndarray:
        """(N, 2) frame coordinates of the object's centre (may lie outside the frame)."""
        cw = self.object_center_world
        h = np.concatenate([cw, np.ones((len(cw), 1))], axis=1)
        p = np.einsum("nij,nj->ni", self.frame_from_world, h)
        return p[:, :2] / p[:, 2:3]

    def is_blurred(self, t: int) -> bool:
        return t in self.blurred

    def row_frame_from_world(self, t: int, rows) -> np.ndarray:
        """(len(rows), 3, 3): the camera that exposed each (possibly fractional) row of frame t, that of time
        ``t + readout * row / height``; all ``frame_from_world[t]`` under a global shutter (readout 0)."""
        rows = np.atleast_1d(np.asarray(rows, np.float64))
        if self.config.readout == 0 or self.intended_params is None or self.jitter_params is None:
            return np.repeat(self.frame_from_world[t][None], len(rows), axis=0)
        times = t + self.config.readout * rows / self.config.height
        return _frames_from_world_at(self.intended_params, self.jitter_params, times, self.config)

    # ------------------------------------------------------------------ rendering truth
    def world_at(self, t: int) -> np.ndarray:
        """The world canvas with the object composited at its pose of time t (a new array)."""
        canvas = self.world.copy()
        for patch, alpha, pose in reversed(self._objects()):  # the first figure in front
            _composite(canvas, patch, alpha, pose[t])
        return canvas

    def _objects(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Every moving object (patch, alpha, world_from_patch per frame), the one in front first."""
        if self.object_world_from_patch is None or self.object_patch is None:
            return []
        return [(self.object_patch, self.object_alpha, self.object_world_from_patch), *self.other_objects]

    def render_view(self, t: int, view_from_frame: np.ndarray, *, sharp: bool = True) -> np.ndarray:
        """Truth for any virtual camera: the world (with the object at time t) seen through
        ``view_from_world = view_from_frame @ frame_from_world[t]``; same size as the frames.

        With ``sharp=False`` and t a blurred frame, the frame's blur kernel is applied to the rendered view
        (exact for the identity view; an approximation for views that rotate/zoom relative to frame t).
        Parts of the view outside the world canvas (see ``view_coverage``) are reflected, not truth.
        """
        view_from_world = _as3x3(view_from_frame) @ self.frame_from_world[t]
        img = warp(self.world_at(t), view_from_world, self.size, interpolation=cv2.INTER_CUBIC)
        if not sharp and t in self.blurred:
            img = apply_blur(img, self.blur_kernel)
        return img

    def hidden_background(self, t: int, view_from_frame: np.ndarray) -> np.ndarray:
        """What ``render_view(t, view_from_frame)`` would show without the object: the background it hides."""
        view_from_world = _as3x3(view_from_frame) @ self.frame_from_world[t]
        return warp(self.world, view_from_world, self.size, interpolation=cv2.INTER_CUBIC)

    def object_view_mask(self, t: int, view_from_frame: np.ndarray) -> np.ndarray:
        """bool (H, W): the object's footprint (coverage >= 0.5) in the view ``view_from_frame`` of frame t."""
        mask = np.zeros((self.config.height, self.config.width), bool)
        for _, alpha, pose in self._objects():
            view_from_patch = _as3x3(view_from_frame) @ self.frame_from_world[t] @ pose[t]
            mask |= _object_mask(alpha, view_from_patch, self.config.width, self.config.height)
        return mask

    def view_coverage(self, t: int, view_from_frame: np.ndarray) -> np.ndarray:
        """bool (H, W): where ``render_view(t, view_from_frame)`` samples inside the world canvas (true truth)."""
        view_from_world = _as3x3(view_from_frame) @ self.frame_from_world[t]
        ones = np.ones(self.world.shape[:2], np.uint8)
        cov = warp(ones, view_from_world, self.size, interpolation=cv2.INTER_NEAREST, border_value=0)
        return cov > 0

    def view_path(self, orig_from_out: np.ndarray) -> np.ndarray:
        """(N, 3): where the outputs of ``orig_from_out`` (one transform a frame: output pixel -> input pixel) look at
        in the world: their centre's x and y (world px) and their roll (radians), for metrics.residual_jitter."""
        centre = np.array([(self.config.width - 1) / 2.0, (self.config.height - 1) / 2.0, 1.0])
        path = []
        for frame_from_world, m in zip(self.frame_from_world, orig_from_out):
            world_from_out = np.linalg.inv(frame_from_world) @ m
            x, y, w = world_from_out @ centre
            path.append((x / w, y / w, math.atan2(world_from_out[1, 0], world_from_out[0, 0])))
        return np.array(path)

    def frame_coverage(self, t: int, view_from_frame: np.ndarray) -> np.ndarray:
        """bool (H, W): where a view ``view_from_frame`` of frame t sees pixels inside input frame t
        (False = region a full-frame method must complete from other frames)."""
        ones = np.ones((self.config.height, self.config.width), np.uint8)
        cov = warp(ones, _as3x3(view_from_frame), self.size, interpolation=cv2.INTER_NEAREST, border_value=0)
        return cov > 0


# ---------------------------------------------------------------------- small public helpers


def load_image(name: str) -> np.ndarray:
    """An RGB uint8 photograph from ``skimage.data`` by name (grey images are stacked, alpha dropped)."""
    import skimage.data

    loader = getattr(skimage.data, name, None)
    if loader is None or not callable(loader):
        raise ValueError(f"unknown skimage.data image {name!r}")
    img = np.asarray(loader())
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    img = img[:, :, :3]
    if img.dtype != np.uint8:
        f = img.astype(np.float64)
        f = (f - f.min()) / max(f.max() - f.min(), 1e-12)
        img = np.round(f * 255).astype(np.uint8)
    return np.ascontiguousarray(img)


def default_blurred_frames(n_frames: int) -> tuple[int, ...]:
    """Three of every ten frames, each isolated between sharp neighbours: t % 10 in {2, 5, 8},
    never the first or the last frame."""
    return tuple(t for t in range(1, n_frames - 1) if t % 10 in (2, 5, 8))


def motion_blur_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """Linear motion-blur kernel: a uniform line segment of ``length_px`` centred on the kernel centre, in the
    direction (cos a, sin a) of y-down pixel coordinates, anti-aliased by bilinear splatting. float32, odd
    (rows, cols) cropped to its support, centre at (rows // 2, cols // 2), sums to 1, point-symmetric (so ``cv2.filter2D`` correlation equals convolution)."""
    length = float(length_px)
    if length <= 1e-6:
        return np.ones((1, 1), np.float32)
    half = int(math.ceil(length / 2.0)) + 1
    size = 2 * half + 1
    k = np.zeros((size, size), np.float64)
    a = math.radians(angle_deg)
    dx, dy = math.cos(a), math.sin(a)
    n = max(16, int(math.ceil(length * 16)))
    # Symmetric sample positions along the segment -> a point-symmetric kernel.
    u = (np.arange(n) + 0.5) / n * length - length / 2.0
    xs, ys = half + u * dx, half + u * dy
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    for ox, oy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(k, (y0 + oy, x0 + ox), w)
    k[k < 1e-6 * k.max()] = 0.0  # drop float dust from splats landing exactly on pixel centres
    k = 0.5 * (k + k[::-1, ::-1])  # exact point symmetry despite float round-off
    # Crop all-zero border rows/columns symmetrically (keeps the centre; a smaller kernel filters faster).
    rows, cols = np.nonzero(k.sum(axis=1))[0], np.nonzero(k.sum(axis=0))[0]
    ry = max(half - rows.min(), rows.max() - half)
    rx = max(half - cols.min(), cols.max() - half)
    k = k[half - ry : half + ry + 1, half - rx : half + rx + 1]
    return (k / k.sum()).astype(np.float32)


def apply_blur(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Blur an image (uint8 or float) with a kernel, reflecting at the borders; same dtype out."""
    return cv2.filter2D(image, -1, np.asarray(kernel, np.float32), borderType=cv2.BORDER_REFLECT)


def warp(
    image: np.ndarray,
    dst_from_src: np.ndarray,
    size: tuple[int, int],
    *,
    interpolation: int = cv2.INTER_CUBIC,
    border_value: float | None = None,
) -> np.ndarray:
    """Render ``image`` through ``dst_from_src`` (3x3 or 2x3) into a ``size`` = (width, height) image, with
    warpAffine when the last row is (0, 0, 1), else warpPerspective. Outside the source: reflected, or the
    constant ``border_value`` when one is given."""
    m = _as3x3(dst_from_src)
    m = m / m[2, 2]
    if border_value is None:
        mode, value = cv2.BORDER_REFLECT, 0
    else:
        mode, value = cv2.BORDER_CONSTANT, border_value
    w, h = int(size[0]), int(size[1])
    if abs(m[2, 0]) < 1e-12 and abs(m[2, 1]) < 1e-12:
        return cv2.warpAffine(image, m[:2], (w, h), flags=interpolation, borderMode=mode, borderValue=value)
    return cv2.warpPerspective(image, m, (w, h), flags=interpolation, borderMode=mode, borderValue=value)


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR in dB for 8-bit images over ``mask`` (bool (H, W)) or everything."""
    d = a.astype(np.float64) - b.astype(np.float64)
    if mask is not None:
        d = d[mask]
    mse = float(np.mean(d * d)) if d.size else 0.0
    return float("inf") if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


# ---------------------------------------------------------------------- internals


def _as3x3(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, np.float64)
    if m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])
    if m.shape != (3, 3):
        raise ValueError(f"expected a 3x3 (or 2x3) transform, got shape {m.shape}")
    return m


def _translation(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def _rotation(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _scaling(s: float) -> np.ndarray:
    return np.diag([s, s, 1.0])


def _frame_from_world(cx: float, cy: float, theta: float, zoom: float, fc: tuple[float, float]) -> np.ndarray:
    """Inverse of world_from_frame = T(c) R(theta) S(1/zoom) T(-fc)."""
    return _translation(*fc) @ _scaling(zoom) @ _rotation(-theta) @ _translation(-cx, -cy)


def _frames_from_world_at(intended: np.ndarray, jitter: np.ndarray, times: np.ndarray,
                          cfg: SyntheticConfig) -> np.ndarray:
    """(len(times), 3, 3) frame_from_world at fractional frame times: the camera's parameters (centre, roll,
    zoom) interpolated by a cubic spline through their per-frame values (extrapolated past the last frame)."""
    from scipy.interpolate import CubicSpline  # here: only rolling-shutter clips need it

    params = np.stack([intended[:, 0] + jitter[:, 0], intended[:, 1] + jitter[:, 1], intended[:, 2] + jitter[:, 2],
                       intended[:, 3] * (1.0 + jitter[:, 3])], axis=1)
    frames = np.arange(len(params), dtype=np.float64)
    at = CubicSpline(frames, params, axis=0)(times) if len(params) > 3 else np.repeat(params[:1], len(times), axis=0)
    # _frame_from_world, vectorised: zoom * R(-theta) on the linear part, the centre c landing on the frame's.
    cx, cy, theta, zoom = at.T
    cos, sin = zoom * np.cos(theta), zoom * np.sin(theta)
    out = np.zeros((len(at), 3, 3))
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1], out[:, 2, 2] = cos, sin, -sin, cos, 1.0
    out[:, 0, 2] = (cfg.width - 1) / 2.0 - (cos * cx + sin * cy)
    out[:, 1, 2] = (cfg.height - 1) / 2.0 - (-sin * cx + cos * cy)
    return out


def _render_rows(canvas: np.ndarray, row_frame_from_world: np.ndarray, w: int) -> np.ndarray:
    """A frame whose row y is the canvas seen by camera ``row_frame_from_world[y]`` (bicubic, reflected)."""
    world_from_row = np.linalg.inv(row_frame_from_world)  # (H, 3, 3), affine
    xs = np.arange(w, dtype=np.float64)[None, :]
    ys = np.arange(len(world_from_row), dtype=np.float64)[:, None]
    m = world_from_row
    map_x = m[:, 0, 0, None] * xs + m[:, 0, 1, None] * ys + m[:, 0, 2, None]
    map_y = m[:, 1, 0, None] * xs + m[:, 1, 1, None] * ys + m[:, 1, 2, None]
    return cv2.remap(canvas, map_x.astype(np.float32), map_y.astype(np.float32), cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_REFLECT)


def _curr_from_prev(frame_from_world: np.ndarray) -> np.ndarray:
    out = np.empty_like(frame_from_world)
    out[0] = np.eye(3)
    if len(frame_from_world) > 1:
        out[1:] = frame_from_world[1:] @ np.linalg.inv(frame_from_world[:-1])
    return out


def _apply(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply (..., 3, 3) transforms to (K, 2) points -> (..., K, 2)."""
    h = np.concatenate([pts, np.ones((len(pts), 1))], axis=1)
    p = np.einsum("...ij,kj->...ki", m, h)
    return p[..., :2] / p[..., 2:3]


def _corners(w: float, h: float, mx: float = 0.0, my: float = 0.0) -> np.ndarray:
    return np.array([[-mx, -my], [w - 1 + mx, -my], [w - 1 + mx, h - 1 + my], [-mx, h - 1 + my]], np.float64)


def _band_limited_noise(rng: np.random.Generator, n: int, fps: float, band: tuple[float, float], order: int = 4) -> np.ndarray:
    """Zero-mean, unit-std (over the n samples) Gaussian noise with a band-pass amplitude spectrum
    |H(f)| = 1/sqrt(1+(f_lo/f)^2k) * 1/sqrt(1+(f/f_hi)^2k). Generated on a long buffer so the band is
    resolved even for short clips, then truncated."""
    length = max(2 * n, int(math.ceil(8 * fps)), 64)
    white = rng.standard_normal(length)
    if n <= 1:
        return np.zeros(n)
    spec = np.fft.rfft(white)
    f = np.fft.rfftfreq(length, d=1.0 / fps)
    f_lo, f_hi = float(band[0]), float(band[1])
    with np.errstate(divide="ignore"):
        hp = 1.0 / np.sqrt(1.0 + (f_lo / np.maximum(f, 1e-12)) ** (2 * order)) if f_lo > 0 else np.ones_like(f)
    lp = 1.0 / np.sqrt(1.0 + (f / f_hi) ** (2 * order))
    gain = hp * lp
    gain[0] = 0.0
    x = np.fft.irfft(spec * gain, length)[:n]
    x = x - x.mean()
    sd = x.std()
    return x / sd if sd > 0 else x


def _object_texture(world_image: str = "") -> tuple[np.ndarray, np.ndarray]:
    """The mission patch cut out as an RGB square with an anti-aliased disc alpha and a green rim (colour
    negated when the world itself is the astronaut photograph, so the object never matches its background)."""
    import skimage.data

    src = np.asarray(skimage.data.astronaut())[:, :, :3]
    r = _PATCH_RADIUS
    half = int(math.ceil(r)) + 3
    cx, cy = _PATCH_CENTRE_XY
    rgb = src[cy - half : cy + half + 1, cx - half : cx + half + 1].astype(np.float32)
    yy, xx = np.mgrid[-half : half + 1, -half : half + 1].astype(np.float32)
    dist = np.sqrt(xx * xx + yy * yy)
    alpha = np.clip(r - dist + 0.5, 0.0, 1.0).astype(np.float32)
    rim = np.clip(dist - (r - _RIM_WIDTH) + 0.5, 0.0, 1.0)[:, :, None]
    if world_image == "astronaut":
        rgb = 255.0 - rgb
    rgb = rgb * (1.0 - rim) + np.asarray(_RIM_COLOUR, np.float32) * rim
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8), alpha


_PERSON_CUTS = ((1 / 3, 1 / 3), (2 / 3, 2 / 3), (1 / 2, 1 / 6))  # where the k-th figure's dress is cut (y, x share)


def _person_texture(cfg: SyntheticConfig, index: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A person-sized figure (head on a rounded body, anti-aliased alpha) dressed in a crop of the world
    photograph rotated half a turn: the background's own colours and texture statistics, other content. The
    ``index``-th figure is 0.8**index of the size and cut from another part of the photograph."""
    size = 0.8 ** index
    pw = max(int(round(cfg.person_size[0] * cfg.width * size)), 8)
    ph = max(int(round(cfg.person_size[1] * cfg.height * size)), 8)
    photo = load_image(cfg.image)[::-1, ::-1]
    # Scale the photograph as the world canvas does (about one photo pixel per frame pixel or more).
    scale = max(cfg.width / photo.shape[1], cfg.height / photo.shape[0], 1.0) * 1.3
    photo = cv2.resize(photo, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
    if index == 0:  # (the first figure's cut, exactly as it always was)
        y0, x0 = max((photo.shape[0] - ph) // 3, 0), max((photo.shape[1] - pw) // 3, 0)
    else:
        cut_y, cut_x = _PERSON_CUTS[index % len(_PERSON_CUTS)]
        y0, x0 = max(int((photo.shape[0] - ph) * cut_y), 0), max(int((photo.shape[1] - pw) * cut_x), 0)
    rgb = np.ascontiguousarray(photo[y0:y0 + ph, x0:x0 + pw])
    if rgb.shape[:2] != (ph, pw):
        rgb = cv2.resize(rgb, (pw, ph), interpolation=cv2.INTER_CUBIC)
    yy, xx = np.mgrid[0:ph, 0:pw].astype(np.float32)
    # Signed distance (px, positive inside) to a head circle over a rounded-rectangle body, then clipped.
    head_r = 0.28 * pw
    head = head_r - np.hypot(xx - (pw - 1) / 2.0, yy - head_r - 1.0)
    corner = 0.3 * pw
    top, bottom, left, right = 1.7 * head_r, ph - 1.5, 1.5, pw - 2.5
    qx = np.maximum(np.maximum(left + corner - xx, xx - (right - corner)), 0.0)
    qy = np.maximum(np.maximum(top + corner - yy, yy - (bottom - corner)), 0.0)
    inside = np.minimum(np.minimum(xx - left, right - xx), np.minimum(yy - top, bottom - yy))
    body = np.where((qx > 0) & (qy > 0), corner - np.hypot(qx, qy),
                    np.minimum(inside, corner - np.maximum(qx, qy)))
    alpha = np.clip(np.maximum(head, body) + 0.5, 0.0, 1.0).astype(np.float32)
    return rgb, alpha


def _person_path(cfg: SyntheticConfig, patch_shape: tuple[int, ...], view_centre_x: np.ndarray,
                 world_shift_y: float, index: int = 0) -> np.ndarray:
    """(N, 3, 3) world_from_patch: walking across the intended view at a speed drawn per frame from
    ``person_speed_px`` (changes of speed, and of direction near the view's sides or at random), with a small
    vertical bob. Drawn from its own generator (one a figure) so the camera's draws do not depend on it."""
    rng = np.random.default_rng((cfg.seed, 7919) if index == 0 else (cfg.seed, 7919, index))
    n, w, h = int(cfg.n_frames), int(cfg.width), int(cfg.height)
    ph, pw = patch_shape[:2]
    lo, hi = cfg.person_speed_px
    limit = max(0.5 * cfg.object_sweep * w, 1.0)  # turns back once its centre is this far from the view's
    # Steps are drawn in the world (speed relative to the background); the turns look at the offset from the view.
    x = view_centre_x[0] + rng.uniform(-0.5, 0.5) * limit
    direction = 1.0 if rng.random() < 0.5 else -1.0
    xs = np.empty(n)
    for i in range(n):
        xs[i] = x
        offset = x - view_centre_x[min(i + 1, n - 1)]
        if abs(offset) > limit and np.sign(offset) == direction or rng.random() < 0.08:
            direction = -direction
        x += direction * rng.uniform(lo, hi)
    bob = 0.02 * h * np.sin(np.arange(n) * 0.9 + rng.uniform(0, 2 * math.pi))
    # World coordinates of the intended view's centre are (view_centre_x, world_shift_y), drift aside; the
    # figure stands a little below it so that its feet reach the lower part of the frame.
    poses = [_translation(xs[i] - (pw - 1) / 2.0,
                          world_shift_y + 0.12 * h + bob[i] - (ph - 1) / 2.0) for i in range(n)]
    return np.stack(poses)


def _composite(canvas: np.ndarray, patch: np.ndarray, alpha: np.ndarray, world_from_patch: np.ndarray):
    """Alpha-composite the patch into the canvas in place at its pose; returns (y0, y1, x0, x1, saved region)
    so the caller can restore the canvas, or None when the patch misses the canvas."""
    ph, pw = alpha.shape
    hw, ww = canvas.shape[:2]
    pts = _apply(world_from_patch, _corners(pw, ph, 1.0, 1.0))
    x0 = max(int(math.floor(pts[:, 0].min())) - 2, 0)
    y0 = max(int(math.floor(pts[:, 1].min())) - 2, 0)
    x1 = min(int(math.ceil(pts[:, 0].max())) + 3, ww)
    y1 = min(int(math.ceil(pts[:, 1].max())) + 3, hw)
    if x1 <= x0 or y1 <= y0:
        return None
    local = _translation(-x0, -y0) @ world_from_patch
    size = (x1 - x0, y1 - y0)
    rgb = cv2.warpAffine(patch, local[:2], size, flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    a = cv2.warpAffine(alpha, local[:2], size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    region = canvas[y0:y1, x0:x1]
    saved = region.copy()
    a3 = a[:, :, None]
    blended = rgb.astype(np.float32) * a3 + region.astype(np.float32) * (1.0 - a3)
    region[...] = np.clip(np.round(blended), 0, 255).astype(np.uint8)
    return y0, y1, x0, x1, saved


def _object_mask(alpha: np.ndarray, frame_from_patch: np.ndarray, w: int, h: int) -> np.ndarray:
    """bool (h, w): where the patch's coverage (bilinear) is >= 0.5, warped only over its bounding box."""
    mask = np.zeros((h, w), bool)
    ph, pw = alpha.shape
    pts = _apply(frame_from_patch, _corners(pw, ph, 1.0, 1.0))
    x0 = max(int(math.floor(pts[:, 0].min())) - 1, 0)
    y0 = max(int(math.floor(pts[:, 1].min())) - 1, 0)
    x1 = min(int(math.ceil(pts[:, 0].max())) + 2, w)
    y1 = min(int(math.ceil(pts[:, 1].max())) + 2, h)
    if x1 > x0 and y1 > y0:
        local = _translation(-x0, -y0) @ frame_from_patch
        a = cv2.warpAffine(
            alpha, local[:2], (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        )
        mask[y0:y1, x0:x1] = a >= 0.5
    return mask


def _check_coverage(world_shape: tuple[int, ...], frame_from_world: np.ndarray, w: int, h: int, what: str) -> None:
    pts = _apply(np.linalg.inv(frame_from_world), _corners(w, h))  # (N, 4, 2) world coords of frame corners
    hw, ww = world_shape[:2]
    lo = _INTERP_PAD - 1.0
    bad = (pts[..., 0] < lo) | (pts[..., 0] > ww - 1 - lo) | (pts[..., 1] < lo) | (pts[..., 1] > hw - 1 - lo)
    if bad.any():
        t = int(np.argwhere(bad.any(axis=1))[0, 0])
        raise RuntimeError(f"synthetic {what} frame {t} is not covered by the {ww}x{hw} world canvas")


# ---------------------------------------------------------------------- generation


def generate(config: SyntheticConfig = SyntheticConfig()) -> SyntheticVideo:
    """Render a synthetic hand-held clip and its truth; deterministic given the config (seed included)."""
    cfg = config
    w, h, n, fps = int(cfg.width), int(cfg.height), int(cfg.n_frames), float(cfg.fps)  # checked by the config
    rng = np.random.default_rng(cfg.seed)
    fc = ((w - 1) / 2.0, (h - 1) / 2.0)
    t = np.arange(n, dtype=np.float64)

    # Intended path: steady pan + slow drift and roll; hand-held jitter on top.
    (drift_x, icy, ith), (jx, jy, jth, jzm) = _drift_and_jitter(cfg, rng, n, fps)
    icx = cfg.pan_px_per_frame * t + drift_x
    izm = np.ones(n)
    object_draws = _object_draws(rng, h)
    f_int = _frames_from_world(icx, icy, ith, izm, fc)
    f_act = _frames_from_world(icx + jx, icy + jy, ith + jth, izm * (1.0 + jzm), fc)

    # World canvas: cover every actual and intended view.
    world, shift_x, shift_y = _world_canvas(cfg, f_act, f_int)
    icx = icx + shift_x
    icy = icy + shift_y
    f_int = _frames_from_world(icx, icy, ith, izm, fc)
    f_act = _frames_from_world(icx + jx, icy + jy, ith + jth, izm * (1.0 + jzm), fc)
    _check_coverage(world.shape, f_act, w, h, "input")
    _check_coverage(world.shape, f_int, w, h, "intended")

    obj_patch, obj_alpha, obj_pose = _moving_object(cfg, object_draws, shift_x, shift_y)
    blurred = default_blurred_frames(n) if cfg.blurred_frames is None else tuple(sorted(set(int(i) for i in cfg.blurred_frames)))
    kernel = motion_blur_kernel(cfg.blur_length_px, cfg.blur_angle_deg)
    intended, jitter = np.stack([icx, icy, ith, izm], axis=1), np.stack([jx, jy, jth, jzm], axis=1)
    others = _other_people(cfg, shift_x, shift_y)
    objects = ([] if obj_pose is None else [(obj_patch, obj_alpha, obj_pose)]) + list(others)
    frames, sharp_frames, masks = _render(cfg, world, f_act, intended, jitter, objects,
                                          set(blurred), kernel)

    return SyntheticVideo(
        frames=frames,
        sharp_frames=sharp_frames,
        frame_from_world=f_act,
        intended_frame_from_world=f_int,
        curr_from_prev=_curr_from_prev(f_act),
        object_mask=masks,
        blurred=blurred,
        blur_kernel=kernel,
        config=cfg,
        world=world,
        intended_params=intended,
        jitter_params=jitter,
        object_world_from_patch=obj_pose,
        object_patch=obj_patch,
        object_alpha=obj_alpha,
        other_objects=others,
    )


def _frames_from_world(cx: np.ndarray, cy: np.ndarray, th: np.ndarray, zm: np.ndarray,
                       fc: tuple[float, float]) -> np.ndarray:
    """(N, 3, 3) frame_from_world of the views centred on (cx, cy), rolled by th, zoomed by zm, per frame."""
    return np.stack([_frame_from_world(cx[i], cy[i], th[i], zm[i], fc) for i in range(len(cx))])


def _object_draws(rng: np.random.Generator, h: int) -> tuple[float, np.ndarray, float, float]:
    """The disc's random path parameters, drawn from ``rng`` right after the camera's motion (so the random stream
    does not depend on later choices): direction across the view (+-1), its heights at the start and the end
    (px from the view's centre), its spin (radians a frame), its bob's phase."""
    direction = 1.0 if rng.random() < 0.5 else -1.0
    obj_y = rng.uniform(0.08, 0.2, size=2) * h * np.array([1.0, -1.0]) * (1 if rng.random() < 0.5 else -1)
    obj_spin = math.radians(rng.uniform(-1.0, 1.0))  # per frame
    obj_bob_phase = rng.uniform(0.0, 2.0 * math.pi)
    return direction, obj_y, obj_spin, obj_bob_phase


def _moving_object(cfg: SyntheticConfig, draws: tuple[float, np.ndarray, float, float], shift_x: float,
                   shift_y: float) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """The moving object's (patch, alpha, world_from_patch per frame), all None without one: the person walks its
    own path; the disc crosses the (linear part of the) intended view on a straight path, plus a bob and spin.
    ``shift_x``, ``shift_y``: where the world canvas put the intended path's origin."""
    if not cfg.moving_object:
        return None, None, None
    w, h, n, fps = int(cfg.width), int(cfg.height), int(cfg.n_frames), float(cfg.fps)
    t = np.arange(n, dtype=np.float64)
    if cfg.object_kind == "person":
        patch, alpha = _person_texture(cfg)
        return patch, alpha, _person_path(cfg, alpha.shape, cfg.pan_px_per_frame * t + shift_x, shift_y)
    direction, obj_y, obj_spin, obj_bob_phase = draws
    patch, alpha = _object_texture(cfg.image)
    half = (alpha.shape[0] - 1) / 2.0
    k = cfg.object_radius_px / _PATCH_RADIUS
    frac = t / max(n - 1, 1)
    base_x = cfg.pan_px_per_frame * t + shift_x
    ox = base_x + direction * (-0.5 + frac) * cfg.object_sweep * w
    oy = shift_y + obj_y[0] + (obj_y[1] - obj_y[0]) * frac + 0.04 * h * np.sin(2 * math.pi * 0.5 * (t / fps) + obj_bob_phase)
    pose = np.stack(
        [
            _translation(ox[i], oy[i]) @ _rotation(obj_spin * t[i]) @ _scaling(k) @ _translation(-half, -half)
            for i in range(n)
        ]
    )
    return patch, alpha, pose


def _other_people(cfg: SyntheticConfig, shift_x: float, shift_y: float
                  ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
    """The figures after the first (SyntheticConfig.people), each (patch, alpha, world_from_patch per frame)."""
    if not cfg.moving_object or cfg.object_kind != "person":
        return ()
    view_centre_x = cfg.pan_px_per_frame * np.arange(int(cfg.n_frames), dtype=np.float64) + shift_x
    others = []
    for index in range(1, int(cfg.people)):
        patch, alpha = _person_texture(cfg, index)
        others.append((patch, alpha, _person_path(cfg, alpha.shape, view_centre_x, shift_y, index)))
    return tuple(others)


def _render(cfg: SyntheticConfig, world: np.ndarray, f_act: np.ndarray, intended: np.ndarray, jitter: np.ndarray,
            objects: list[tuple[np.ndarray, np.ndarray, np.ndarray]], blurred: set[int],
            kernel: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """(frames, sharp frames, object masks): each frame of the world seen through ``f_act`` (row by row with a
    rolling shutter, from the camera's ``intended`` and ``jitter`` parameters), the moving ``objects`` (patch,
    alpha, world_from_patch per frame; the first in front) composited at their poses of the frame, frames in
    ``blurred`` blurred by ``kernel``."""
    w, h, n = int(cfg.width), int(cfg.height), int(cfg.n_frames)
    canvas = world.copy()
    frames, sharp_frames, masks = [], [], []
    for i in range(n):
        saved = [_composite(canvas, patch, alpha, pose[i]) for patch, alpha, pose in reversed(objects)]
        if cfg.readout > 0:  # rows exposed one after another (the objects stay at their poses of time i)
            times = i + cfg.readout * np.arange(h) / h
            sharp = _render_rows(canvas, _frames_from_world_at(intended, jitter, times, cfg), w)
        else:
            sharp = cv2.warpAffine(canvas, f_act[i][:2], (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        for region in reversed(saved):  # undone in the opposite order
            if region is not None:
                y0, y1, x0, x1, pixels = region
                canvas[y0:y1, x0:x1] = pixels
        sharp_frames.append(sharp)
        frames.append(apply_blur(sharp, kernel) if i in blurred else sharp.copy())
        mask = np.zeros((h, w), bool)
        for _, alpha, pose in objects:
            mask |= _object_mask(alpha, f_act[i] @ pose[i], w, h)
        masks.append(mask)
    return frames, sharp_frames, masks


def _drift_and_jitter(cfg: SyntheticConfig, rng: np.random.Generator, n: int, fps: float,
                      ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, ...]]:
    """The camera's random motion, drawn from ``rng`` in this order: the slow intentional drift and roll
    (well below the jitter band; no steady pan), then the hand-held jitter as independent band-limited
    processes normalised to the configured std. ((x, y, roll), (x, y, roll, relative zoom)) per frame."""
    sec = np.arange(n, dtype=np.float64) / fps
    ph = rng.uniform(0.0, 2.0 * math.pi, size=3)
    f0 = cfg.drift_hz
    drift = (cfg.drift_px * np.sin(2 * math.pi * f0 * sec + ph[0]),
             0.6 * cfg.drift_px * np.sin(2 * math.pi * 0.8 * f0 * sec + ph[1]),
             math.radians(cfg.drift_deg) * np.sin(2 * math.pi * 0.6 * f0 * sec + ph[2]))
    band = cfg.jitter_band_hz
    jitter = (cfg.jitter_px * _band_limited_noise(rng, n, fps, band),
              cfg.jitter_px * _band_limited_noise(rng, n, fps, band),
              math.radians(cfg.jitter_deg) * _band_limited_noise(rng, n, fps, band),
              cfg.jitter_scale * _band_limited_noise(rng, n, fps, band))
    if cfg.jitter_envelope:
        gain = jitter_gain(cfg.jitter_envelope, n)
        jitter = tuple(gain * j for j in jitter)
    return drift, jitter


def jitter_gain(envelope: tuple[float, ...], n: int) -> np.ndarray:
    """(n,) the jitter's gain per frame for ``SyntheticConfig.jitter_envelope``: each value holds over its
    stretch of the clip, the changes eased by a raised cosine over a tenth of the clip around each boundary."""
    levels = np.asarray(envelope, np.float64)
    t = (np.arange(n) + 0.5) / max(n, 1) * len(levels)  # position in stretches
    gain = np.full(n, levels[0])
    half = 0.05 * len(levels)  # half the ease, in stretches
    for k in range(1, len(levels)):
        u = np.clip((t - (k - half)) / (2 * half), 0.0, 1.0)
        gain += (levels[k] - levels[k - 1]) * 0.5 * (1.0 - np.cos(math.pi * u))
    return gain


def _world_canvas(cfg: SyntheticConfig, *views: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The world photograph scaled to cover every view (frame_from_world stacks) grown by the world margin,
    plus interpolation padding; and the (x, y) shift that centres the views on it."""
    w, h = int(cfg.width), int(cfg.height)
    grown = _corners(w, h, cfg.world_margin * w, cfg.world_margin * h)
    pts = np.concatenate([_apply(np.linalg.inv(view), grown).reshape(-1, 2) for view in views])
    xmin, ymin = pts.min(axis=0) - _INTERP_PAD
    xmax, ymax = pts.max(axis=0) + _INTERP_PAD
    photo = load_image(cfg.image)
    scale = max((xmax - xmin + 1) / photo.shape[1], (ymax - ymin + 1) / photo.shape[0], float(cfg.min_world_scale))
    ww, wh = int(math.ceil(scale * photo.shape[1])), int(math.ceil(scale * photo.shape[0]))
    world = cv2.resize(photo, (ww, wh), interpolation=cv2.INTER_CUBIC if scale >= 1 else cv2.INTER_AREA)
    return world, (ww - 1) / 2.0 - (xmin + xmax) / 2.0, (wh - 1) / 2.0 - (ymin + ymax) / 2.0


def stream_frames(config: SyntheticConfig) -> Iterator[np.ndarray]:
    """The frames of a clip rendered one at a time, for clips too long to hold (minutes of 1080p).

    The camera model of ``generate``: slow intentional drift and roll plus band-limited hand-held jitter
    (translation, roll, zoom) filming the world photograph. Memory holds the world canvas and the (N, 3, 3)
    path, never more than the frame being yielded. What needs more is not offered, and the config must turn
    it off: a steady pan (the world canvas would grow with the clip's length), the moving object and the
    blurred frames. The same config does not give ``generate``'s frames: the camera draws are the same, but
    ``generate``'s canvas also covers the intended views, and it renders bicubic.
    """
    cfg = config
    if cfg.pan_px_per_frame != 0 or cfg.moving_object or cfg.blurred_frames != ():
        raise ValueError("stream_frames needs pan_px_per_frame=0, moving_object=False and blurred_frames=()")
    w, h, n, fps = int(cfg.width), int(cfg.height), int(cfg.n_frames), float(cfg.fps)  # checked by the config
    rng = np.random.default_rng(cfg.seed)
    fc = ((w - 1) / 2.0, (h - 1) / 2.0)
    (drift_x, drift_y, roll), (jx, jy, jth, jzm) = _drift_and_jitter(cfg, rng, n, fps)
    cx, cy, theta, zoom = drift_x + jx, drift_y + jy, roll + jth, 1.0 + jzm
    frame_from_world = np.stack([_frame_from_world(cx[i], cy[i], theta[i], zoom[i], fc) for i in range(n)])

    world, shift_x, shift_y = _world_canvas(cfg, frame_from_world)
    # Centre the views on the canvas: moving the camera centres by +shift is frame_from_world @ T(-shift).
    frame_from_world = frame_from_world @ np.linalg.inv(_translation(shift_x, shift_y))
    _check_coverage(world.shape, frame_from_world, w, h, "streamed")
    # Bilinear, not generate's cubic: a third of the cost at 1080p, and the canvas is sampled near 1:1.
    for m in frame_from_world:
        yield cv2.warpAffine(world, m[:2], (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


# ---------------------------------------------------------------------- output


def write_video(
    video: SyntheticVideo | Iterable[np.ndarray],
    path,
    *,
    fps: float | None = None,
    crf: int = 12,
    preset: str | None = None,
    sharp: bool = False,
) -> None:
    """Write frames (``video.frames``, or ``video.sharp_frames`` with ``sharp=True``, or RGB uint8 frames from
    any iterable, encoded as they come: e.g. ``stream_frames``) to a video file with PyAV: libx264, yuv420p,
    ``crf`` (0 = lossless in YUV), x264's ``preset`` (None: its default), the config fps."""
    import av

    from pipeline.runtime.encoding import x264_options

    if isinstance(video, SyntheticVideo):
        frames: Iterable[np.ndarray] = video.sharp_frames if sharp else video.frames
        rate = video.config.fps if fps is None else fps
    else:
        frames = video
        rate = 30.0 if fps is None else fps
    remaining = iter(frames)
    first = next(remaining, None)
    if first is None:
        raise ValueError("no frames to write")
    h, w = first.shape[:2]
    if w % 2 or h % 2:
        raise ValueError(f"yuv420p needs even frame sizes, got {w}x{h}")
    container = av.open(str(Path(path)), mode="w")
    try:
        stream = container.add_stream("libx264", rate=Fraction(rate).limit_denominator(1001))
        stream.width, stream.height = w, h
        stream.pix_fmt = "yuv420p"
        options = {"qp": "0"} if crf <= 0 else {"crf": str(int(crf))}
        options.update(x264_options())  # the same bytes every run
        stream.options = options if preset is None else {**options, "preset": preset}
        for f in itertools.chain([first], remaining):
            arr = np.ascontiguousarray(f, dtype=np.uint8)
            for packet in stream.encode(av.VideoFrame.from_ndarray(arr, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    finally:
        container.close()


# ---------------------------------------------------------------------- two-frame helper


def make_two_frames(
    transform: np.ndarray,
    *,
    size: tuple[int, int] = (640, 360),
    image: str = "astronaut",
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Two views of a photograph related by a known motion, for motion-estimation tests.

    ``frame0`` is a view of ``image``; ``frame1`` is the same static scene under ``curr_from_prev = transform``
    (3x3 affine or homography, or 2x3), i.e. ``frame1(transform @ p) == frame0(p)``. Both are rendered directly
    from the photograph (one resampling each, INTER_CUBIC) and are fully covered: the photograph is scaled so
    that both views, plus a few pixels of interpolation padding, lie inside it. ``seed`` picks where in the
    slack the view sits. Returns (frame0, frame1), RGB uint8 (H, W, 3).
    """
    w, h = int(size[0]), int(size[1])
    m = _as3x3(transform)
    m = m / m[2, 2]
    photo = load_image(image)
    pw, phh = photo.shape[1], photo.shape[0]
    corners = _corners(w, h)
    # Frame-1 corners in frame-0 coordinates.
    inv = np.linalg.inv(m)
    hc = np.concatenate([corners, np.ones((4, 1))], axis=1) @ inv.T
    if np.any(hc[:, 2] <= 1e-9):
        raise ValueError("transform maps frame corners to infinity")
    c1 = hc[:, :2] / hc[:, 2:3]
    pts = np.concatenate([corners, c1])
    lo = pts.min(axis=0) - _INTERP_PAD
    hi = pts.max(axis=0) + _INTERP_PAD
    ext = hi - lo
    # photo px -> frame0 px is a zoom k >= 1; the photo must be at least ext in frame-0 pixels.
    k = max(ext[0] / (pw - 1), ext[1] / (phh - 1)) * 1.02
    slack = np.array([(pw - 1) * k - ext[0], (phh - 1) * k - ext[1]])  # frame-0 px of freedom
    rng = np.random.default_rng(seed)
    off = rng.uniform(0.0, 1.0, size=2) * np.maximum(slack, 0.0)
    # frame0_from_photo: photo (0,0) lands at lo - off in frame-0 coordinates.
    f0 = _translation(lo[0] - off[0], lo[1] - off[1]) @ _scaling(k)
    f1 = m @ f0
    frame0 = warp(photo, f0, (w, h), interpolation=cv2.INTER_CUBIC)
    frame1 = warp(photo, f1, (w, h), interpolation=cv2.INTER_CUBIC)
    return frame0, frame1
