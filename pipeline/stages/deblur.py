"""Deblurring by transferring sharper pixels from neighbouring frames (thesis chapter 5, eqs. 28-31).

No point spread function is estimated. Relative blurriness (eq. 28): b_t = 1 / mean_p |grad I_t(p)|^2 (Sobel,
intensity), each frame of the window measured on its original pixels over the part of the scene all of them see,
so that b_t / b_t' compares the same content. Interpolation (eqs. 30-31):
    I^_t(p) = (I_t(p) + sum_t' w_t'(p) I_t'(T p)) / (1 + sum_t' w_t'(p)),
    w_t'(p) = b_t / b_t' * alpha / (E_t'(p) + alpha) where b_t / b_t' > ``min_ratio`` (eq. 31: 1), else 0.
Alignment error E (eq. 29 made blur-tolerant): the max over R, G, B of the low-passed *signed* difference,
|G_sigma * (I_t' - I_t)|; blur by a kernel that sums to 1 leaves low frequencies unchanged, a moving object or a
misregistration does not. Rejection (beyond eq. 31, whose weight decays only as 1 / E): a neighbour's pixel with
E above ``reject_error``, or where ``StructureGuard`` finds other structure (a person dressed like the
background), gets no weight, nor does anything within ``reject_grow_px`` of one.

Invariants: only sharper neighbours contribute; pixels no sharper neighbour covers keep their value (a missing
pixel of ``--mode none`` stays missing); lengths (sigma, growth, windows) are for 360 rows and scale with the
frame height. It runs last, on the frame about to be written (pipeline/stabilize.py), reusing completion's
neighbours, so transferred pixels are resampled once and completed pixels are sharpened like the rest.

``deblur`` equals whole-frame warps and full-resolution maps within float32 rounding, except on a neighbour's
1-px coverage boundary (tests/test_deblur.py): coverage is solved per row from the transform, E stays at low
resolution and is upsampled only where it can cross the threshold, and one pass over the rows blends every
neighbour (pipeline/stages/deblur_kernels.py). Choices and measurements: docs/deblurring.md.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import cv2
import numpy as np

from pipeline.stages import deblur_kernels as kernels
from pipeline import geometry
from pipeline.stages import warping
from pipeline.errors import ConfigError
from pipeline.stages.neighbours import TAP_SLACK, WarpedNeighbour, warp_neighbours
from pipeline.imaging import INTENSITY_WEIGHTS, intensity
from pipeline.stages.per_frame import PerFrame

# Defaults chosen with benchmarks/quality/deblur_psnr.py (see the module docstring). Lengths are for 360 frame rows
# and scale with the frame height (blur, in pixels, grows with the resolution).
REFERENCE_HEIGHT = 360
DEBLUR_ALPHA = 8.0
ERROR_SIGMA_PX = 4.0
REJECT_ERROR = 32.0
REJECT_GROW_PX = 8
MIN_RATIO = 1.2
# Structure guard (see ``StructureGuard``): a neighbour's pixel is refused where the local structure of the
# low-passed images disagrees, whatever the colours.
STRUCTURE_MIN = 0.75
STRUCTURE_WINDOW_PX = 8  # half-width of the square window the local statistics are taken over (360 rows)
STRUCTURE_C = 1.0  # the contrast-structure term's stabiliser: windows flatter than ~1 level of std count as agreeing
# (a ghost of flat content on flat content is invisible)
STRUCTURE_SHIFT_MARGIN = 0.05  # refuse where moving the neighbour by one cell agrees better by this much ...
STRUCTURE_SHIFT_MIN_VAR = np.float32(9.0)  # ... in windows with structure in both images (std >= 3 levels)
STRUCTURE_FLAT_VAR = np.float32(9.0)  # windows whose variances are both below this are flat (std < 3 levels) ...
STRUCTURE_FLAT_DIFFERENCE = np.float32(2.0)  # ... and refused when their mean levels differ by more than this
REFUSED_ERROR = np.float32(1e4)  # what a refused low-res cell's alignment error is set to: far above any threshold
# Energy maps are kept at this fraction of the frame size: means over large polygons barely change, and
# masking 16x fewer pixels keeps the per-frame cost of the window's blurriness small.
ENERGY_SCALE = 0.25
# Below this share of the frame, the window's common coverage is too small to compare sharpness on: each
# neighbour is then compared with frame t over their pairwise overlap instead.
MIN_COMMON_FRACTION = 0.2


@dataclass(frozen=True)
class DeblurConfig:
    enabled: bool = True  # False: no deblurring (--no-deblur)
    alpha: float = DEBLUR_ALPHA  # eq. 31, in intensity units (0..255) of the alignment error E
    neighbour_frames: int = 6  # neighbours t-r..t+r are compared (<= the completion radius: their warps are reused)
    min_ratio: float = MIN_RATIO  # a neighbour contributes only where b_t / b_t' exceeds this (eq. 31: 1)
    # px at 360 rows (Gaussian sigma): low-pass of the signed difference before E is taken (0: eq. 29 as written)
    error_sigma_px: float = ERROR_SIGMA_PX
    reject_error: float = REJECT_ERROR  # intensity 0..255: E above this marks another scene (moving object, ...)
    reject_grow_px: int = REJECT_GROW_PX  # px at 360 rows: ... and so does everything this close to such a pixel
    # Correlation-like score in [-1, 1] (``StructureGuard``): refuse where the local structure agreement is below this
    # (None: off, the colour test alone).
    structure_min: float | None = STRUCTURE_MIN
    structure_window_px: int = STRUCTURE_WINDOW_PX  # px at 360 rows: half-width of its window

    def __post_init__(self) -> None:
        if not (self.alpha > 0 and math.isfinite(self.alpha)):
            raise ConfigError(f"deblur alpha must be a positive number, not {self.alpha}")
        if self.neighbour_frames < 0:
            raise ConfigError(f"deblur radius must be >= 0, not {self.neighbour_frames}")
        if not self.min_ratio >= 1.0:
            raise ConfigError(f"deblur min_ratio must be >= 1 (only sharper neighbours may contribute), "
                             f"not {self.min_ratio}")
        if not self.error_sigma_px >= 0 or self.reject_grow_px < 0:
            raise ConfigError("deblur error_sigma_px and reject_grow_px must be >= 0")
        if not self.reject_error > 0:
            raise ConfigError(f"deblur reject_error must be positive, not {self.reject_error}")
        if self.structure_min is not None and not -1.0 <= self.structure_min <= 1.0:
            raise ConfigError(f"deblur structure_min must lie in [-1, 1] or be None, not {self.structure_min}")
        if self.structure_window_px < 1:
            raise ConfigError(f"deblur structure_window_px must be >= 1, not {self.structure_window_px}")


@dataclass(frozen=True)
class DeblurResult:
    frame: np.ndarray  # (H, W, 3) uint8, after
    before: np.ndarray  # (H, W, 3) uint8, the frame handed in
    blurriness: float  # b_t (eq. 28) of this frame over its own whole area (for the series; NaN if unknown)
    neighbours: tuple[int, ...]  # offsets t'-t of the sharper neighbours that contributed
    weights: np.ndarray  # (H, W) float32 in [0, 1]: share of the output pixel that came from neighbours
    ratios: dict[int, float] = field(default_factory=dict)  # b_t / b_t' of every neighbour compared, by offset
    provenance: Provenance | None = field(default=None, repr=False, compare=False)

    @property
    def main_source(self) -> np.ndarray | None:
        """(H, W) int8: offset of the neighbour that gave the pixel the most weight, 0 where neighbours gave
        under 5 %; None when no neighbour contributed."""
        return None if self.provenance is None else self.provenance.main_source

    @property
    def refused(self) -> np.ndarray | None:
        """(H, W) bool: pixels where a sharper neighbour was refused (other content after alignment: a moving
        object, parallax, misregistration); None when no neighbour was sharper."""
        return None if self.provenance is None else self.provenance.refused


class Provenance:
    """Where a deblurred frame's pixels came from, worked out when first asked for (by the recording; a run
    that records nothing never pays for it) from the arrays eq. 30 was computed with."""

    def __init__(self, taken: kernels.Contributions, alpha: np.float32, weights: np.ndarray | None,
                 target_valid: np.ndarray) -> None:
        count = taken.count
        self._offsets = tuple(taken.offsets)
        self._ratios, self._errors = taken.ratios[:count], taken.errors[:count]
        self._rejected = None if taken.rejected is None else \
            taken.rejected[:count][taken.has_rejected[:count].any(axis=1)]
        self._alpha, self._weights, self._target_valid = alpha, weights, target_valid

    @functools.cached_property
    def main_source(self) -> np.ndarray | None:
        """The neighbour with the largest eq. 31 weight, judged on the alignment error's grid (where a neighbour
        was refused its error is REFUSED_ERROR, so it loses)."""
        if self._weights is None:
            return None
        small = self._ratios[:, None, None] / (self._errors + self._alpha)  # eq. 31 up to the common alpha
        offsets = np.asarray(self._offsets, np.int8)[np.argmax(small, axis=0)]
        height, width = self._weights.shape
        source = cv2.resize(offsets, (width, height), interpolation=cv2.INTER_NEAREST)
        source[self._weights < 0.05] = 0
        return source

    @functools.cached_property
    def refused(self) -> np.ndarray:
        if self._rejected is None or len(self._rejected) == 0:
            return np.zeros(self._target_valid.shape, bool)
        return np.bitwise_or.reduce(self._rejected, axis=0).view(bool) & self._target_valid


@dataclass(frozen=True)
class WindowBlurriness:
    """Eq. 28 for frame t and its neighbours, measured where all of them see the same scene."""

    own: float  # b_t over frame t's whole area (the series)
    ratios: dict[int, float]  # b_t / b_t' by offset t' - t, each pair measured on the same scene (> 1: sharper)
    common_fraction: float  # area of the window's common coverage / frame area (0: pairwise overlaps used)


def gradient_energy(gray_or_rgb: np.ndarray) -> np.ndarray:
    """(H, W) float32: (f_x * I)^2 + (f_y * I)^2, the summand of eq. 28 (Sobel filters, intensity 0..255)."""
    image = np.asarray(gray_or_rgb)
    gray = intensity(image) if image.ndim == 3 else image.astype(np.float32)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, borderType=cv2.BORDER_REFLECT)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, borderType=cv2.BORDER_REFLECT)
    return gx * gx + gy * gy


def blurriness(gray_or_rgb: np.ndarray, valid_mask: np.ndarray | None = None) -> float:
    """Eq. 28 over ``valid_mask`` (bool (H, W); None: everywhere), as 1 / mean squared gradient.

    inf for a flat image (no gradient at all); NaN when the mask is empty.
    """
    energy = gradient_energy(gray_or_rgb)
    if valid_mask is not None:
        if valid_mask.shape != energy.shape:
            raise ValueError(f"valid mask {valid_mask.shape} does not match the image {energy.shape}")
        energy = energy[valid_mask]
    if energy.size == 0:
        return math.nan
    return _inverse(float(np.mean(energy, dtype=np.float64)))


class EnergyCache(PerFrame[np.ndarray, np.ndarray]):
    """Gradient-energy maps of frames by index, so that each frame of a streaming window is filtered once."""

    def __init__(self) -> None:
        super().__init__(_downscaled_energy)


def window_blurriness(frames: Mapping[int, np.ndarray], t: int, curr_from_prev: np.ndarray, *,
                      cache: EnergyCache | None = None) -> WindowBlurriness:
    """b of frame t and of every neighbour in ``frames`` ({frame index: original RGB}, t included) over the
    area all of them see; the overlap of each pair instead when that common area is below MIN_COMMON_FRACTION.

    ``curr_from_prev`` are the inter-frame transforms (N, 3, 3) that chain the frames to t.
    """
    if t not in frames:
        raise ValueError(f"frame {t} must be among the frames compared")
    cache = EnergyCache() if cache is None else cache
    height, width = frames[t].shape[:2]
    t_from = geometry.neighbour_transforms(curr_from_prev, t, min(frames), max(frames))
    energy = {i: cache.get(i, rgb) for i, rgb in frames.items()}
    own = _inverse(float(np.mean(energy[t], dtype=np.float64)))
    rect = geometry.frame_corners(width, height)
    # Each neighbour's frame outline in t's coordinates.
    outlines = {i: geometry.apply(t_from[i], rect) for i in frames if i != t}
    common = rect
    for outline in outlines.values():
        common = _intersect(common, outline)
        if common is None:
            break
    frame_area = float((width - 1) * (height - 1))
    fraction = 0.0 if common is None else _area(common) / frame_area
    if fraction >= MIN_COMMON_FRACTION:
        b_t = _mean_inverse(energy[t], common, width, height)
        ratios = {i - t: _ratio(b_t, _mean_inverse(energy[i], geometry.apply(np.linalg.inv(t_from[i]), common),
                                                   width, height)) for i in outlines}
        return WindowBlurriness(own, ratios, fraction)
    # Pairwise: t and each neighbour over their own overlap (none below 5% of the frame: not the same scene).
    ratios = {}
    for i, outline in outlines.items():
        overlap = _intersect(rect, outline)
        if overlap is not None and _area(overlap) / frame_area >= 0.05:
            b_t = _mean_inverse(energy[t], overlap, width, height)
            b_i = _mean_inverse(energy[i], geometry.apply(np.linalg.inv(t_from[i]), overlap), width, height)
            ratios[i - t] = _ratio(b_t, b_i)
    return WindowBlurriness(own, ratios, 0.0)


def alignment_error(target: np.ndarray, neighbour: np.ndarray, valid: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W) float32: eq. 29 on low-passed images, max over R, G, B of |G_sigma * (I_t' - I_t)| over ``valid``
    (normalised convolution: pixels outside ``valid`` do not leak in). sigma 0: eq. 29 per channel as written.

    With sigma >= 2 px the low-pass runs at 1/f of the resolution, f the largest power of two <= sigma / 2
    but at least 2 (the default sigma: f = 2 at 360p, 4 at 1080p): what that loses, the low-pass removes anyway.
    """
    height, width = valid.shape
    factor = kernels.error_factor(sigma)
    size = (max(width // factor, 1), max(height // factor, 1))
    weight = valid.astype(np.float32)
    if factor > 1:
        target, neighbour = (cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in (target, neighbour))
        weight = cv2.resize(weight, size, interpolation=cv2.INTER_AREA)
    error = kernels.low_res_error(target, neighbour, weight, sigma / factor)
    if error.shape != (height, width):
        error = cv2.resize(error, (width, height), interpolation=cv2.INTER_LINEAR)
    return error


class StructureGuard:
    """Whether a neighbour shows the same content as frame t after alignment, judged by structure.

    The alignment error E compares low-passed colours, so content of similar colour passes it: a dark coat moving
    over a dark hedge, or a figure dressed in the background's own colours, would be blended into frame t as a
    see-through ghost. Here both images are low-passed as for E (intensity, Gaussian of E's sigma: blur by a kernel
    that sums to 1 leaves what remains nearly unchanged) and compared by the contrast-structure term of SSIM over
    a square window, (2 cov + C) / (var_t + var_t' + C): near 1 where the same structure shows (sharper or not),
    near 0 for other content, and 1 where both are flat. Cells below ``minimum`` are refused, and so are cells where
    the neighbour moved by one cell agrees better (a same-looking object a few px off, which the smooth windows
    cannot tell from aligned), and flat windows whose mean levels differ by over 2 (another flat surface: a
    transfer could not sharpen anything there, only shift its colour). Specks of one cell are then dropped (a 3x3
    opening), so that isolated edge cells of a sharp neighbour do not punch holes in the transfer once dilated.
    Only windows wholly inside the neighbour's coverage are judged. Thresholds: benchmarks/quality/dynamic_scene.py.

    Works at the alignment error's resolution (ErrorGrid); the target's statistics are made once per frame.
    """

    def __init__(self, target_small: np.ndarray, sigma: float, window: float, minimum: float) -> None:
        self.sigma = sigma
        window = max(round(window), 1)
        self.size = (2 * window + 1, 2 * window + 1)
        self.minimum = np.float32(minimum)
        self.target = self._low_passed(target_small)
        # Both images are centred on the target's mean: the same covariances, with float32 sums of smaller products.
        self._products: np.ndarray | None = None
        self._means: np.ndarray | None = None
        self.offset = np.float32(self.target.mean())
        self.target -= self.offset
        moments = self._box(np.stack([self.target, self.target * self.target]))
        self.target_mean = moments[0]
        self.target_var = moments[1] - self.target_mean * self.target_mean

    def _low_passed(self, rgb: np.ndarray) -> np.ndarray:
        grey = intensity(rgb)
        return cv2.GaussianBlur(grey, (0, 0), self.sigma) if self.sigma > 0 else grey

    def _box(self, planes: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Window means of each image of float32 ``planes``, (c, h, w) or (c, h, w, channels) (edges reflected)."""
        out = np.empty_like(planes) if out is None else out
        for plane, mean in zip(planes, out):
            cv2.boxFilter(plane, cv2.CV_32F, self.size, dst=mean, borderType=cv2.BORDER_REFLECT)
        return out

    def agreement(self, neighbour_small: np.ndarray) -> np.ndarray:
        """(h, w) float32: the contrast-structure term at each low-res cell."""
        agreement = np.empty_like(self.target)
        self._decide(neighbour_small, np.ones(self.target.shape, np.float32), agreement)
        return agreement

    def _decide(self, neighbour_small: np.ndarray, weight: np.ndarray, agreement: np.ndarray) -> np.ndarray:
        """uint8 (h, w): 1 where refused, before the opening (kernels.structure_refusal)."""
        other = self._low_passed(neighbour_small)
        other -= self.offset
        # Scratch planes kept for every neighbour of this target (fresh megabytes would cost page faults each time).
        if self._products is None:
            self._products = np.empty((2, *other.shape, 4), np.float32)
            self._means = np.empty_like(self._products)
        kernels.structure_products(self.target, other, np.ascontiguousarray(weight, np.float32), self._products)
        means = self._box(self._products, self._means)
        return kernels.structure_refusal(means, self.target_mean, self.target_var, np.float32(STRUCTURE_C),
                                         self.minimum, np.float32(STRUCTURE_SHIFT_MARGIN), STRUCTURE_SHIFT_MIN_VAR,
                                         self.size[0] // 2 + 1, agreement, STRUCTURE_FLAT_VAR,
                                         STRUCTURE_FLAT_DIFFERENCE)

    def refused(self, neighbour_small: np.ndarray, weight: np.ndarray) -> np.ndarray | None:
        """bool (h, w) of the refused cells, None when there are none. ``weight``: the neighbour's coverage
        share of each cell (the alignment error's)."""
        refused = self._decide(neighbour_small, weight, np.empty_like(self.target))
        if not refused.any():
            return None
        refused = cv2.morphologyEx(refused, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).view(bool)
        return refused if refused.any() else None


def deblur(target: np.ndarray, target_valid: np.ndarray, neighbours: Sequence[WarpedNeighbour],
           config: DeblurConfig = DeblurConfig(), *, ratios: Mapping[int, float],
           blurriness_t: float = math.nan) -> DeblurResult:
    """Eqs. 30-31 for one frame, with the blur-tolerant alignment error and the rejection (module docstring).

    ``target``: frame t (H, W, 3) uint8; ``target_valid``: its pixels that have content (only those change);
    ``neighbours``: frames in the target's coordinates, lazy (original frame and transform) or already warped
    with their valid masks; ``ratios``: b_t / b_t' by offset (``window_blurriness`` on the original frames);
    ``blurriness_t``: b_t, for the record.
    """
    target = np.asarray(target)
    if target.ndim != 3 or target.shape[2] != 3 or target.dtype not in (np.uint8, np.float32):
        raise ValueError(f"deblur needs an (H, W, 3) uint8 or float32 frame, not {target.shape} {target.dtype}")
    if target_valid.shape != target.shape[:2]:
        raise ValueError(f"valid mask {target_valid.shape} does not match the frame {target.shape[:2]}")
    height, width = target_valid.shape
    scale = height / REFERENCE_HEIGHT
    grow = round(config.reject_grow_px * scale)
    alpha = np.float32(config.alpha)
    neighbours = list(neighbours)
    for n in neighbours:
        image = n.rgb if n.original is None else n.original
        if image.shape != target.shape or (n.original is None and n.valid.shape != target_valid.shape):
            raise ValueError(f"neighbour {n.offset:+d} has shape {image.shape}, the frame {target.shape}")
    # Eq. 31: blurrier (or unmeasured) neighbours get no weight.
    sharper = [n for n in neighbours if float(ratios.get(n.offset, math.nan)) > config.min_ratio]
    used: tuple[int, ...] = ()
    if sharper:
        grid = kernels.ErrorGrid(target, target_valid, config.error_sigma_px * scale, grow)
        taken = kernels.Contributions(len(sharper), grid, target_valid, target.dtype)
        guard = None if config.structure_min is None else StructureGuard(
            grid.target_small, grid.sigma_small, config.structure_window_px * scale / grid.factor,
            config.structure_min)
        for n in sharper:
            rgb = taken.next_rgb()
            if not n.warped_whole:
                # Lazy: warp the colours only; which pixels the neighbour covers is worked out row by row from
                # the transform (WarpedNeighbour.sample's rule), instead of warping a coverage mask. (Whole-frame
                # warps already at hand are used as they are, below.)
                warping.warp(n.original, n.other_from_stab, out=rgb)
                first, last = kernels.covered_spans(n.other_from_stab, n.original.shape[0], n.original.shape[1],
                                                     height, width, TAP_SLACK)
                kernels.zero_outside_spans(rgb, first, last)  # the whole-frame warp's black enters the low-res copy
                mask = None
                np.maximum(first, grid.target_first, out=first)
                np.minimum(last, grid.target_last, out=last)
                exact = grid.target_exact
            else:
                rgb[...] = n.rgb
                mask = n.valid & target_valid
                first, last, exact = kernels.row_runs(mask)
            weight = kernels.area_coverage(first, last, exact, target_valid if mask is None else mask,
                                           *grid.area_tables)  # INTER_AREA of the valid pixels
            if not weight.any():
                continue
            small = rgb if grid.factor == 1 else cv2.resize(rgb, grid.small_size, interpolation=cv2.INTER_AREA)
            error = kernels.low_res_error(grid.target_small, small, weight, grid.sigma_small)
            refused = None if guard is None else guard.refused(small, weight)
            if refused is not None:
                error[refused] = REFUSED_ERROR
            bands = kernels.hot_bands(error, config.reject_error, grid)
            if bands:
                kernels.fill_rejected(error, config.reject_error, grow, grid, bands, taken.next_rejected())
            taken.add(n.offset, first, last, exact, mask, bool(bands), error, float(ratios[n.offset]))
        if taken.count:
            half = np.float32(0.5 if target.dtype == np.uint8 else 0.0)  # rounds into uint8; float32 as it is
            frame, weights, counts = kernels.blend(target, *taken.arrays(), *grid.up_tables, alpha, half)  # eq. 30
            used = tuple(offset for offset, count in zip(taken.offsets, counts) if count > 0)
    if not used:
        provenance = Provenance(taken, alpha, None, target_valid) if sharper else None
        return DeblurResult(target, target, blurriness_t, (), np.zeros((height, width), np.float32), dict(ratios),
                            provenance)
    return DeblurResult(frame, target, blurriness_t, used, weights, dict(ratios),
                        Provenance(taken, alpha, weights, target_valid))


def deblur_frame(output: np.ndarray, output_valid: np.ndarray | None, t: int, frames: Mapping[int, np.ndarray],
                 curr_from_prev: np.ndarray, orig_from_view: np.ndarray, config: DeblurConfig = DeblurConfig(), *,
                 warped: Sequence[WarpedNeighbour] = (), cache: EnergyCache | None = None) -> DeblurResult:
    """Deblur frame t of a stream as it is about to be written.

    ``output``: frame t in the output's view (``orig_from_view`` maps it to frame t's original pixels);
    ``output_valid``: its pixels with content (None: all); ``frames``: original frames by index, t included
    (those beyond ``config.neighbour_frames`` are ignored); ``warped``: neighbours in that view the caller already has
    (completion's; reused, not made again); ``cache``: gradient-energy maps the caller keeps across frames (it
    forgets those no later frame needs). Blurriness is measured on the original frames; only the sharper
    neighbours are warped.
    """
    frames = {i: rgb for i, rgb in frames.items() if abs(i - t) <= config.neighbour_frames}
    measured = window_blurriness(frames, t, curr_from_prev, cache=cache)
    sharper = {o for o, ratio in measured.ratios.items() if ratio > config.min_ratio}
    neighbours = [n for n in warped if n.offset in sharper]
    to_warp = {t + o: frames[t + o] for o in sharper - {n.offset for n in neighbours}}
    neighbours += warp_neighbours(to_warp, t, curr_from_prev, orig_from_view)
    valid = np.ones(output.shape[:2], bool) if output_valid is None else output_valid
    return deblur(output, valid, neighbours, config, ratios=measured.ratios, blurriness_t=measured.own)


# ---------------------------------------------------------------------------------------------- internals

def _downscaled_energy(image: np.ndarray) -> np.ndarray:
    """cv2.resize(gradient_energy(image), ENERGY_SCALE of its size, INTER_AREA), for RGB frames in one pass
    that never holds the full-resolution maps (within float32 rounding of the two-step result)."""
    height, width = image.shape[:2]
    size = (max(round(width * ENERGY_SCALE), 1), max(round(height * ENERGY_SCALE), 1))
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype not in (np.uint8, np.float32):
        return cv2.resize(gradient_energy(image), size, interpolation=cv2.INTER_AREA)
    row_index, row_weight, row_count, _ = kernels.area_table(height, size[1])
    col_index, col_weight, col_count, _ = kernels.area_table(width, size[0])
    block = col_index.shape[1]  # an integer factor's cells: runs of `block` consecutive columns
    if not np.array_equal(col_index.ravel(), np.arange(col_index.size)) or not np.all(col_count == block):
        block = 0
    return kernels.energy_area(np.ascontiguousarray(image), INTENSITY_WEIGHTS, row_index, row_weight, row_count,
                        col_index, col_weight, col_count, block)


def _inverse(mean_energy: float) -> float:
    return 1.0 / mean_energy if mean_energy > 0 else math.inf


def _ratio(b_t: float, b_other: float) -> float:
    if not (math.isfinite(b_t) and math.isfinite(b_other)) or b_other <= 0:
        return math.nan
    return b_t / b_other


def _intersect(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """Intersection of two convex polygons ((n, 2) points), None when they do not overlap."""
    area, points = cv2.intersectConvexConvex(np.asarray(a, np.float32), np.asarray(b, np.float32))
    if points is None or area <= 0:
        return None
    return points.reshape(-1, 2).astype(np.float64)


def _area(polygon: np.ndarray) -> float:
    return float(cv2.contourArea(np.asarray(polygon, np.float32)))


def _mean_inverse(energy: np.ndarray, polygon: np.ndarray, width: int, height: int) -> float:
    """1 / mean of a (downscaled) energy map over a polygon given in full-resolution pixel coordinates."""
    small_h, small_w = energy.shape
    sx, sy = small_w / width, small_h / height
    # cv2.resize's pixel-centre mapping: x_small = (x + 0.5) * sx - 0.5.
    pts = np.column_stack([(polygon[:, 0] + 0.5) * sx - 0.5, (polygon[:, 1] + 0.5) * sy - 0.5])
    mask = np.zeros(energy.shape, np.uint8)
    cv2.fillConvexPoly(mask, np.round(pts * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4)
    if not mask.any():
        return math.nan
    return _inverse(float(cv2.mean(energy, mask)[0]))
