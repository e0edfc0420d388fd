"""ECC image alignment (Evangelidis & Psarakis 2008) over a set of points, for completion's local registration.

``ecc_on_points`` maximizes the enhanced correlation coefficient between a template (frame t's intensities at
the points of the band next to the missing area) and an image warped by a correction (translation, affine or
homography), with OpenCV's forward-additive update (findTransformECC's lambda for photometric change), but sums
over the given points only, in one pass per iteration: OpenCV's version works on whole images (every pixel,
every iteration, masked afterwards), which made registration half of full mode's CPU time.

The image is given in its own coordinates with ``image_from_work``, the map from the working coordinates to it
(the neighbour's global warp): each neighbour's blurred intensity and gradients (``SourceImage``) are then made
once per source frame (``source_image``, cached while the frame lives) and shared by every target frame it is a
neighbour of, instead of warping and differentiating the neighbour again for each. Gradients are carried to the
working coordinates by the chain rule through ``image_from_work``.

Invariants: the correction starts at the identity; points whose sample leaves the image's eroded valid area do
not count; fewer than MIN_POINTS usable points, a singular system or a correlation going negative stops it
with a non-zero status and the correction is not to be used.
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from pipeline import imaging
from pipeline.stages.neighbours import shrink

MODEL_PARAMETERS = {"translation": 2, "affine": 6, "homography": 8}
MIN_POINTS = 16
_GRADIENT = np.array([[-0.5, 0.0, 0.5]], np.float32)  # OpenCV's ECC: central differences
# the warp's (row, column) each parameter moves, in the Jacobian's order (as OpenCV's ECC orders them)
_HOMOGRAPHY_CELLS = np.array([[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1], [0, 2], [1, 2]])
_AFFINE_CELLS = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0, 2], [1, 2]])
_TRANSLATION_CELLS = np.array([[0, 2], [1, 2]])


@dataclass(frozen=True)
class SourceImage:
    """One image prepared for ECC: ``stack`` (h, w, 3) float32 of the intensity blurred 3x3 (as ECC smooths both
    images) and its x and y gradients, zero outside ``usable``; ``usable`` (h, w) bool: valid pixels away from
    the invalid ones by the blur's reach; ``intensity`` (h, w) float32, not blurred (for the error test)."""
    stack: np.ndarray
    usable: np.ndarray
    intensity: np.ndarray


def prepare(grey: np.ndarray, valid: np.ndarray | None = None) -> SourceImage:
    """A SourceImage of intensity ``grey`` (float32); ``valid``: its covered pixels (None: all but a 1 px rim)."""
    blurred = cv2.GaussianBlur(grey, (3, 3), 0, 0)
    if valid is None:
        usable = np.zeros(grey.shape, bool)
        usable[1:-1, 1:-1] = True
    else:  # as OpenCV's ECC: the mask blurred the same way, kept where it stays >= 0.95
        usable = cv2.GaussianBlur(valid.astype(np.float32), (3, 3), 0, 0) >= 0.95
    weight = usable.astype(np.float32)
    gx = cv2.filter2D(blurred, -1, _GRADIENT) * weight
    gy = cv2.filter2D(blurred, -1, _GRADIENT.T) * weight
    return SourceImage(cv2.merge([blurred, gx, gy]), usable, grey)


class _SourceCache:
    """SourceImages of original frames by (frame, size), each made once while its frame is alive: an entry goes
    when its frame array is freed (a weak reference), so memory follows the frames the caller keeps."""

    def __init__(self) -> None:
        self._entries: dict[tuple[int, tuple[int, int]], tuple[weakref.ref, SourceImage]] = {}
        # Re-entrant: a weak reference's callback (_forget) runs wherever the garbage collector happens to run,
        # which can be inside this lock on the same thread (an allocation under it); a plain lock deadlocks there.
        self._lock = threading.RLock()

    def get(self, original: np.ndarray, size: tuple[int, int]) -> SourceImage:
        key = (id(original), size)
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None and entry[0]() is original:
                return entry[1]
        image = prepare(imaging.intensity(shrink(original, size)))
        with self._lock:
            self._entries[key] = (weakref.ref(original, lambda _, key=key: self._forget(key)), image)
        return image

    def _forget(self, key: tuple[int, tuple[int, int]]) -> None:
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None and entry[0]() is None:
                del self._entries[key]

    def __len__(self) -> int:
        return len(self._entries)


_SOURCES = _SourceCache()


def source_image(original: np.ndarray, size: tuple[int, int]) -> SourceImage:
    """``original`` (H, W, 3) shrunk to ``size`` (width, height) and prepared for ECC, made once per frame."""
    return _SOURCES.get(original, size)


@njit(cache=True, nogil=True)
def _ecc(template: np.ndarray, xs: np.ndarray, ys: np.ndarray, stack: np.ndarray, usable: np.ndarray,
         image_from_work: np.ndarray, warp: np.ndarray, n_params: int, iterations: int, eps: float) -> int:
    """ECC's iterations on the points, updating ``warp`` in place; 0, or the status that stopped it (module
    docstring). Called through ``_ECC_KERNELS`` with ``n_params`` a constant, so the Jacobian's loops compile to
    fixed lengths."""
    jac = np.zeros(8)
    hessian = np.zeros((8, 8))
    j_one, j_image, j_template = np.zeros(8), np.zeros(8), np.zeros(8)  # sums of the Jacobian, x image, x template
    rho, last_rho = -1.0, -1.0 - 2.0 * eps
    for _ in range(iterations):
        if abs(rho - last_rho) < eps:
            break
        sums = _accumulate(template, xs, ys, stack, usable, image_from_work, warp, n_params, jac, hessian,
                           j_one, j_image, j_template)
        if sums[0] < MIN_POINTS:
            return 1
        status, correlation_coefficient = _update(warp, n_params, sums, hessian, j_one, j_image, j_template)
        if status != 0:
            return status
        last_rho, rho = rho, correlation_coefficient
    return 0


@njit(cache=True, nogil=True)
def _accumulate(template: np.ndarray, xs: np.ndarray, ys: np.ndarray, stack: np.ndarray, usable: np.ndarray,
                g: np.ndarray, warp: np.ndarray, n_params: int, jac: np.ndarray, hessian: np.ndarray,
                j_one: np.ndarray, j_image: np.ndarray,
                j_template: np.ndarray) -> tuple[int, float, float, float, float, float]:
    """One pass over the points at the current ``warp``: the sums ECC's update needs over the points whose sample
    lies in the image's usable area. Returned: their count and the sums of image, template, image^2, template^2
    and template x image values; the Jacobian's go into ``hessian``'s upper triangle, ``j_one``, ``j_image`` and
    ``j_template`` (sums of the Jacobian, of it x image, of it x template), all reset first. ``g``: image_from_work. Where it is affine (bottom row exactly 0, 0, 1: the usual global warp) the projective
    terms are left out: dividing by exactly 1 and subtracting exactly 0 change no value, so both forms give the
    same bits."""
    affine = g[2, 0] == 0.0 and g[2, 1] == 0.0 and g[2, 2] == 1.0
    height, width = usable.shape
    hessian[:] = 0.0
    j_one[:] = 0.0
    j_image[:] = 0.0
    j_template[:] = 0.0
    count = 0
    s_i = s_t = s_ii = s_tt = s_ti = 0.0
    for k in range(len(xs)):
        x, y = xs[k], ys[k]
        den = warp[2, 0] * x + warp[2, 1] * y + warp[2, 2]
        wx = (warp[0, 0] * x + warp[0, 1] * y + warp[0, 2]) / den
        wy = (warp[1, 0] * x + warp[1, 1] * y + warp[1, 2]) / den
        if affine:
            gw = 1.0
            u = g[0, 0] * wx + g[0, 1] * wy + g[0, 2]
            v = g[1, 0] * wx + g[1, 1] * wy + g[1, 2]
        else:
            gw = g[2, 0] * wx + g[2, 1] * wy + g[2, 2]
            u = (g[0, 0] * wx + g[0, 1] * wy + g[0, 2]) / gw
            v = (g[1, 0] * wx + g[1, 1] * wy + g[1, 2]) / gw
        if not (u >= 0.0 and v >= 0.0 and u < width - 1.0 and v < height - 1.0):
            continue
        if not usable[int(v + 0.5), int(u + 0.5)]:
            continue
        value, ix, iy = _bilinear(stack, u, v)
        # d(image)/d(wx, wy) through image_from_work, then over the correction's denominator
        if affine:
            gx = (ix * g[0, 0] + iy * g[1, 0]) / den
            gy = (ix * g[0, 1] + iy * g[1, 1]) / den
        else:
            gx = (ix * (g[0, 0] - g[2, 0] * u) + iy * (g[1, 0] - g[2, 0] * v)) / gw / den
            gy = (ix * (g[0, 1] - g[2, 1] * u) + iy * (g[1, 1] - g[2, 1] * v)) / gw / den
        _jacobian(jac, n_params, gx, gy, x, y, wx, wy)
        t = template[k]
        _add_jacobian(t, value, jac, n_params, hessian, j_one, j_image, j_template)
        count += 1
        s_i += value
        s_t += t
        s_ii += value * value
        s_tt += t * t
        s_ti += t * value
    return count, s_i, s_t, s_ii, s_tt, s_ti


@njit(cache=True, nogil=True)
def _bilinear(stack: np.ndarray, u: float, v: float) -> tuple[float, float, float]:
    """The blurred intensity and its x and y gradients at (u, v), bilinearly (u, v inside the image but for its
    last row and column)."""
    x0, y0 = int(u), int(v)
    fx, fy = u - x0, v - y0
    w00, w01, w10, w11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
    value = (w00 * stack[y0, x0, 0] + w01 * stack[y0, x0 + 1, 0] + w10 * stack[y0 + 1, x0, 0]
             + w11 * stack[y0 + 1, x0 + 1, 0])
    ix = (w00 * stack[y0, x0, 1] + w01 * stack[y0, x0 + 1, 1] + w10 * stack[y0 + 1, x0, 1]
          + w11 * stack[y0 + 1, x0 + 1, 1])
    iy = (w00 * stack[y0, x0, 2] + w01 * stack[y0, x0 + 1, 2] + w10 * stack[y0 + 1, x0, 2]
          + w11 * stack[y0 + 1, x0 + 1, 2])
    return value, ix, iy


@njit(cache=True, nogil=True)
def _jacobian(jac: np.ndarray, n_params: int, gx: float, gy: float, x: float, y: float, wx: float,
              wy: float) -> None:
    """The image's derivative by each of the correction's parameters at one point, into ``jac[:n_params]`` (in
    the order of the model's cells); (gx, gy): its gradient at the corrected point (wx, wy) of (x, y)."""
    if n_params == 8:
        c = -(gx * wx + gy * wy)
        jac[0], jac[1], jac[2], jac[3] = gx * x, gy * x, c * x, gx * y
        jac[4], jac[5], jac[6], jac[7] = gy * y, c * y, gx, gy
    elif n_params == 6:
        jac[0], jac[1], jac[2], jac[3], jac[4], jac[5] = gx * x, gy * x, gx * y, gy * y, gx, gy
    else:
        jac[0], jac[1] = gx, gy


@njit(cache=True, nogil=True)
def _add_jacobian(t: float, value: float, jac: np.ndarray, n_params: int, hessian: np.ndarray, j_one: np.ndarray,
                  j_image: np.ndarray, j_template: np.ndarray) -> None:
    """One point's share of the Jacobian's sums: template value ``t``, image value ``value``, Jacobian ``jac``."""
    for a in range(n_params):
        ja = jac[a]
        j_one[a] += ja
        j_image[a] += ja * value
        j_template[a] += ja * t
        for b in range(a, n_params):
            hessian[a, b] += ja * jac[b]


@njit(cache=True, nogil=True)
def _update(warp: np.ndarray, n_params: int, sums: tuple[int, float, float, float, float, float],
            hessian: np.ndarray, j_one: np.ndarray, j_image: np.ndarray, j_template: np.ndarray) -> tuple[int, float]:
    """findTransformECC's forward-additive step from one pass's sums, added to ``warp``: (0, the correlation
    coefficient before the step), or (the status that stops ECC, nan)."""
    count, s_i, s_t, s_ii, s_tt, s_ti = sums
    for a in range(n_params):
        for b in range(a):
            hessian[a, b] = hessian[b, a]
    mean_i, mean_t = s_i / count, s_t / count
    image_norm2, template_norm2 = s_ii - s_i * mean_i, s_tt - s_t * mean_t
    correlation = s_ti - s_t * mean_i
    if image_norm2 <= 0.0 or template_norm2 <= 0.0:
        return 2, np.nan
    rho = correlation / np.sqrt(image_norm2 * template_norm2)
    h = hessian[:n_params, :n_params]
    det = np.linalg.det(h)
    if not np.isfinite(det) or det == 0.0:
        return 3, np.nan
    h_inv = np.linalg.inv(h)
    # the zero-mean projections onto the Jacobian
    image_projection = j_image[:n_params] - j_one[:n_params] * mean_i
    template_projection = j_template[:n_params] - j_one[:n_params] * mean_t
    image_projection_h = h_inv @ image_projection
    lambda_d = correlation - template_projection @ image_projection_h
    if lambda_d <= 0.0:
        return 4, np.nan
    lam = (image_norm2 - image_projection @ image_projection_h) / lambda_d
    delta = h_inv @ (lam * template_projection - image_projection)
    cells = _HOMOGRAPHY_CELLS if n_params == 8 else _AFFINE_CELLS if n_params == 6 else _TRANSLATION_CELLS
    for a in range(n_params):
        warp[cells[a, 0], cells[a, 1]] += delta[a]
    return 0, rho


@njit(cache=True, nogil=True)
def _ecc_translation(template, xs, ys, stack, usable, image_from_work, warp, iterations, eps):
    return _ecc(template, xs, ys, stack, usable, image_from_work, warp, 2, iterations, eps)


@njit(cache=True, nogil=True)
def _ecc_affine(template, xs, ys, stack, usable, image_from_work, warp, iterations, eps):
    return _ecc(template, xs, ys, stack, usable, image_from_work, warp, 6, iterations, eps)


@njit(cache=True, nogil=True)
def _ecc_homography(template, xs, ys, stack, usable, image_from_work, warp, iterations, eps):
    return _ecc(template, xs, ys, stack, usable, image_from_work, warp, 8, iterations, eps)


# _ecc for each model, its number of parameters a compile-time constant (about a fifth less CPU than passing it)
_ECC_KERNELS = {"translation": _ecc_translation, "affine": _ecc_affine, "homography": _ecc_homography}


def ecc_on_points(template: np.ndarray, xs: np.ndarray, ys: np.ndarray, image: SourceImage,
                  image_from_work: np.ndarray, model: str, iterations: int, eps: float = 1e-4) -> np.ndarray | None:
    """The 3x3 correction W (working coordinates -> working coordinates) for which ``image`` sampled at
    image_from_work @ W @ (x, y) best matches ``template`` (values at the points xs, ys; blurred as ``prepare``
    blurs) in the ECC sense; None where ECC stopped without a usable answer (see the module docstring)."""
    warp = np.eye(3)
    status = _ECC_KERNELS[model](np.asarray(template, np.float64), np.asarray(xs, np.float64),
                                 np.asarray(ys, np.float64), image.stack, image.usable,
                                 np.asarray(image_from_work, np.float64), warp, iterations, eps)
    return warp if status == 0 and np.isfinite(warp).all() else None
