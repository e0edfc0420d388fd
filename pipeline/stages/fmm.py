"""Motion inpainting by Fast Marching (thesis 4.2.3 and 4.3, eqs. 24, 26-27; Telea 2004).

A dense flow F is known on part of the frame (``known``); the missing area is filled pixel by pixel in
increasing distance T from the known area, each new pixel taking the weighted mean (eq. 24) of the flow of
pixels that already have one. Flow layout: (H, W, 2) float32, [..., 0] = x (right), [..., 1] = y (down); the
neighbour frame's pixel at p + F(p) corresponds to frame t's pixel p.

Fast Marching (eqs. 26-27): pixels are KNOWN (T fixed), BAND (min-heap on T, lazy deletion) or INSIDE. The
band's head is frozen and its 4-neighbours get T from the upwind solution of |grad T| = 1 over frozen
neighbours only: with a <= b the smaller frozen T along x and along y,
    T = (a + b + sqrt(2 - (a - b)^2)) / 2   if b - a < 1,   else a + 1.
Invariants: each missing pixel is frozen once, in non-decreasing T, and filled in that order; pixels neither
known nor in the region are walls (never entered, never used); only the region's bounding box grown by
radius + 1 is processed, and that crop is exact.

Eq. 24: F(p) = sum_q w(p, q) F(q) / sum_q w(p, q) over q with 0 < |p - q| <= radius that have a flow, and
    w(p, q) = 1 / |p - q|  *  1 / (||I'(p + F(q)) - I'(q + F(q))||_2 + eps),
I' the neighbour frame (RGB 0..255, bilinear). p + F(q) is where p's match would be if p moved like q, so the
colour factor favours the q whose motion the neighbour's colours confirm for p. A pair whose 2x2 bilinear
footprint leaves the image or the neighbour's valid area keeps the distance factor alone (``use_colour=False``:
everywhere). Telea's direction and level-set terms are left out: they favour q straight upstream of p, which for
flow only strengthens extrusion across object boundaries. Without a gradient term the fill is a zero-order
extension. Accuracy of T, limits and the radius: docs/completion.md.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.errors import ConfigError

# Pixel states during marching.
_KNOWN = np.int8(0)
_BAND = np.int8(1)
_INSIDE = np.int8(2)
_WALL = np.int8(3)


@dataclass(frozen=True)
class MotionInpaintConfig:
    radius_px: int = 4  # H(p): known pixels within this distance contribute (see "Radius" above)
    colour_epsilon: float = 1.0  # eps in w = 1/(colour distance + eps), RGB 0..255 units
    use_colour: bool = True  # False: eq. 24's distance factor alone, everywhere

    def __post_init__(self) -> None:
        if self.radius_px < 1:
            raise ConfigError(f"motion inpainting radius must be >= 1 px, got {self.radius_px}")
        if not self.colour_epsilon > 0:
            raise ConfigError(f"colour epsilon must be > 0, got {self.colour_epsilon}")


@dataclass(frozen=True)
class MotionInpaintResult:
    flow: np.ndarray  # (H, W, 2) float32: input flow on known pixels, inpainted on the filled ones, NaN where never reached
    order: np.ndarray  # (H, W) int32: visiting order of filled pixels 0,1,2,...; -1 for known or unreached pixels
    arrival: np.ndarray  # (H, W) float32: T; 0 on known pixels, +inf where unreached
    filled: np.ndarray  # (H, W) bool: pixels that received a flow value


# ----------------------------------------------------------------------------------------------------
# Compiled kernels


@njit(cache=True, nogil=True)
def _heap_push(keys: np.ndarray, items: np.ndarray, size: int, key: float, item: int) -> int:
    i = size
    while i > 0:
        parent = (i - 1) >> 1
        if keys[parent] <= key:
            break
        keys[i] = keys[parent]
        items[i] = items[parent]
        i = parent
    keys[i] = key
    items[i] = item
    return size + 1


@njit(cache=True, nogil=True)
def _heap_pop(keys: np.ndarray, items: np.ndarray, size: int) -> tuple[float, int, int]:
    """Remove the smallest entry: (key, item, new size)."""
    top_key = keys[0]
    top_item = items[0]
    size -= 1
    last_key = keys[size]
    last_item = items[size]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and keys[child + 1] < keys[child]:
            child += 1
        if keys[child] >= last_key:
            break
        keys[i] = keys[child]
        items[i] = items[child]
        i = child
    keys[i] = last_key
    items[i] = last_item
    return top_key, top_item, size


@njit(cache=True, nogil=True)
def _eikonal(state: np.ndarray, arrival: np.ndarray, y: int, x: int) -> float:
    """Upwind solution of |grad T| = 1 at (y, x) from its frozen 4-neighbours (eq. 27)."""
    h, w = state.shape
    a = np.inf
    if x > 0 and state[y, x - 1] == _KNOWN:
        a = arrival[y, x - 1]
    if x < w - 1 and state[y, x + 1] == _KNOWN:
        a = min(a, arrival[y, x + 1])
    b = np.inf
    if y > 0 and state[y - 1, x] == _KNOWN:
        b = arrival[y - 1, x]
    if y < h - 1 and state[y + 1, x] == _KNOWN:
        b = min(b, arrival[y + 1, x])
    if a > b:
        a, b = b, a
    if b - a >= 1.0:  # also when b is inf: a one-sided update
        return a + 1.0
    return 0.5 * (a + b + np.sqrt(2.0 - (a - b) * (a - b)))


@njit(cache=True, nogil=True)
def _march(state: np.ndarray, arrival: np.ndarray) -> np.ndarray:
    """Fast Marching in place on state/arrival; returns the flat indices of the INSIDE pixels in visiting order.

    On entry: KNOWN pixels with arrival 0, INSIDE pixels (to reach) with arrival inf, WALL pixels.
    """
    h, w = state.shape
    dys = (0, 0, -1, 1)
    dxs = (-1, 1, 0, 0)
    n_inside = 0
    for y in range(h):
        for x in range(w):
            if state[y, x] == _INSIDE:
                n_inside += 1
    # Each pixel is pushed at most once per frozen 4-neighbour.
    capacity = 4 * n_inside + 1
    keys = np.empty(capacity, np.float64)
    items = np.empty(capacity, np.int64)
    size = 0
    for y in range(h):
        for x in range(w):
            if state[y, x] != _INSIDE:
                continue
            for k in range(4):
                ny, nx = y + dys[k], x + dxs[k]
                if 0 <= ny < h and 0 <= nx < w and state[ny, nx] == _KNOWN:
                    arrival[y, x] = _eikonal(state, arrival, y, x)
                    state[y, x] = _BAND
                    size = _heap_push(keys, items, size, arrival[y, x], y * w + x)
                    break
    visits = np.empty(n_inside, np.int64)
    n_visited = 0
    while size > 0:
        _, flat, size = _heap_pop(keys, items, size)
        y, x = flat // w, flat % w
        if state[y, x] == _KNOWN:
            continue  # stale entry: T dropped and the pixel was pushed again, then frozen at the smaller T
        state[y, x] = _KNOWN
        visits[n_visited] = flat
        n_visited += 1
        for k in range(4):
            ny, nx = y + dys[k], x + dxs[k]
            if not (0 <= ny < h and 0 <= nx < w):
                continue
            s = state[ny, nx]
            if s != _INSIDE and s != _BAND:
                continue
            t_new = _eikonal(state, arrival, ny, nx)
            if t_new < arrival[ny, nx]:
                arrival[ny, nx] = t_new
                state[ny, nx] = _BAND
                size = _heap_push(keys, items, size, t_new, ny * w + nx)
    return visits[:n_visited]


@njit(cache=True, nogil=True)
def _colour_image(rgb: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The neighbour as float32 RGB with NaN where it has no content, so a bilinear sample touching it is NaN."""
    h, w = valid.shape
    out = np.empty((h, w, 3), np.float32)
    for y in range(h):
        for x in range(w):
            for c in range(3):
                out[y, x, c] = rgb[y, x, c] if valid[y, x] else np.nan
    return out


@njit(cache=True, nogil=True, inline="always")
def _bilinear(image: np.ndarray, y0: int, x0: int, fy: float, fx: float) -> tuple[float, float, float]:
    """RGB at (y0 + fy, x0 + fx) from the 2x2 footprint at (y0, x0); NaN when it leaves the image or touches NaN."""
    h, w = image.shape[0], image.shape[1]
    if y0 < 0 or x0 < 0 or y0 + 1 >= h or x0 + 1 >= w:
        return np.nan, np.nan, np.nan
    w11 = fy * fx
    w10 = fy - w11
    w01 = fx - w11
    w00 = 1.0 - fy - w01
    r = w00 * image[y0, x0, 0] + w01 * image[y0, x0 + 1, 0] + w10 * image[y0 + 1, x0, 0] + w11 * image[y0 + 1, x0 + 1, 0]
    g = w00 * image[y0, x0, 1] + w01 * image[y0, x0 + 1, 1] + w10 * image[y0 + 1, x0, 1] + w11 * image[y0 + 1, x0 + 1, 1]
    b = w00 * image[y0, x0, 2] + w01 * image[y0, x0 + 1, 2] + w10 * image[y0 + 1, x0, 2] + w11 * image[y0 + 1, x0 + 1, 2]
    return r, g, b


@njit(cache=True, nogil=True)
def _inpaint_in_order(flow: np.ndarray, has_flow: np.ndarray, visits: np.ndarray, origin_y: int, origin_x: int,
                      colour: np.ndarray, off_y: np.ndarray, off_x: np.ndarray, off_weight: np.ndarray,
                      eps: float, use_colour: bool) -> None:
    """Eq. 24 at each visited pixel in turn; flow/has_flow are a crop whose (0, 0) is (origin_y, origin_x) of colour."""
    h, w = has_flow.shape
    # Per q, computed once when first needed: its match q + F(q) in the neighbour as integer base + fraction,
    # and the colour there. p + F(q) = match + (p - q) has the same fraction, so only the base moves.
    q_state = np.zeros((h, w), np.int8)  # 0 not yet, 1 colour valid, 2 colour unusable
    q_base = np.empty((h, w, 2), np.int32)
    q_data = np.empty((h, w, 5), np.float32)  # fraction y, x; colour r, g, b
    for n in range(visits.shape[0]):
        py = visits[n] // w
        px = visits[n] % w
        sum_w = 0.0
        sum_fx = 0.0
        sum_fy = 0.0
        for k in range(off_y.shape[0]):
            qy = py + off_y[k]
            qx = px + off_x[k]
            if qy < 0 or qy >= h or qx < 0 or qx >= w or not has_flow[qy, qx]:
                continue
            fx = flow[qy, qx, 0]
            fy = flow[qy, qx, 1]
            wt = off_weight[k]
            if use_colour:
                state = q_state[qy, qx]
                if state == 0:
                    my = origin_y + qy + fy
                    mx = origin_x + qx + fx
                    by = np.floor(my)
                    bx = np.floor(mx)
                    r, g, b = _bilinear(colour, int(by), int(bx), my - by, mx - bx)
                    state = 1 if r == r else 2  # r != r: NaN
                    q_state[qy, qx] = state
                    q_base[qy, qx, 0] = int(by)
                    q_base[qy, qx, 1] = int(bx)
                    q_data[qy, qx, 0] = my - by
                    q_data[qy, qx, 1] = mx - bx
                    q_data[qy, qx, 2] = r
                    q_data[qy, qx, 3] = g
                    q_data[qy, qx, 4] = b
                if state == 1:
                    r, g, b = _bilinear(colour, q_base[qy, qx, 0] - off_y[k], q_base[qy, qx, 1] - off_x[k],
                                        q_data[qy, qx, 0], q_data[qy, qx, 1])
                    if r == r:
                        dr = r - q_data[qy, qx, 2]
                        dg = g - q_data[qy, qx, 3]
                        db = b - q_data[qy, qx, 4]
                        wt /= np.sqrt(dr * dr + dg * dg + db * db) + eps
            sum_w += wt
            sum_fx += wt * fx
            sum_fy += wt * fy
        # A visited pixel always has a frozen 4-neighbour with a flow, so sum_w > 0.
        flow[py, px, 0] = sum_fx / sum_w
        flow[py, px, 1] = sum_fy / sum_w
        has_flow[py, px] = True


@njit(cache=True, nogil=True)
def _known_flow(flow: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Full-frame starting outputs: flow on known pixels (NaN elsewhere), arrival 0 / inf; False if a known flow is not finite."""
    h, w = known.shape
    out = np.empty((h, w, 2), np.float32)
    arrival = np.empty((h, w), np.float32)
    finite = True
    for y in range(h):
        for x in range(w):
            if known[y, x]:
                out[y, x, 0] = flow[y, x, 0]
                out[y, x, 1] = flow[y, x, 1]
                arrival[y, x] = 0.0
                finite &= np.isfinite(flow[y, x, 0]) and np.isfinite(flow[y, x, 1])
            else:
                out[y, x, 0] = np.nan
                out[y, x, 1] = np.nan
                arrival[y, x] = np.inf
    return out, arrival, finite


@njit(cache=True, nogil=True)
def _initial_state(known: np.ndarray, region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(state, arrival) for marching: KNOWN at 0, INSIDE (region minus known) at inf, WALL elsewhere."""
    h, w = known.shape
    state = np.empty((h, w), np.int8)
    arrival = np.empty((h, w), np.float64)
    for y in range(h):
        for x in range(w):
            if known[y, x]:
                state[y, x] = _KNOWN
                arrival[y, x] = 0.0
            else:
                state[y, x] = _INSIDE if region[y, x] else _WALL
                arrival[y, x] = np.inf
    return state, arrival


@njit(cache=True, nogil=True)
def _sample_defined(flow: np.ndarray, u: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """Bilinear flow at points (u, v) from the defined (finite) vectors only, edge pixels replicated; NaN where
    the defined taps weigh less than 1e-3."""
    h, w = flow.shape[0], flow.shape[1]
    for i in range(u.shape[0]):
        x0 = int(np.floor(u[i]))
        y0 = int(np.floor(v[i]))
        fx = u[i] - x0
        fy = v[i] - y0
        sum_w = 0.0
        sum_x = 0.0
        sum_y = 0.0
        for dy in range(2):
            yy = min(max(y0 + dy, 0), h - 1)
            wy = fy if dy else 1.0 - fy
            for dx in range(2):
                xx = min(max(x0 + dx, 0), w - 1)
                weight = wy * (fx if dx else 1.0 - fx)
                if weight > 0.0 and flow[yy, xx, 0] == flow[yy, xx, 0]:  # NaN: not defined
                    sum_w += weight
                    sum_x += weight * flow[yy, xx, 0]
                    sum_y += weight * flow[yy, xx, 1]
        if sum_w < 1e-3:
            out[i, 0] = np.nan
            out[i, 1] = np.nan
        else:
            out[i, 0] = sum_x / sum_w
            out[i, 1] = sum_y / sum_w


# ----------------------------------------------------------------------------------------------------
# Python API


def _as_mask(mask: np.ndarray, shape: tuple[int, int], name: str) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {mask.shape}")
    return np.ascontiguousarray(mask, dtype=bool)


def _region_box(known: np.ndarray, region: np.ndarray | None, margin: int) -> tuple[slice, slice] | None:
    """Bounding box of the pixels to fill (region minus known) grown by ``margin`` px; None when there are none."""
    to_fill = ~known if region is None else region & ~known
    rows = np.flatnonzero(to_fill.any(axis=1))
    if len(rows) == 0:
        return None
    cols = np.flatnonzero(to_fill.any(axis=0))
    h, w = known.shape
    return (slice(max(int(rows[0]) - margin, 0), min(int(rows[-1]) + margin + 1, h)),
            slice(max(int(cols[0]) - margin, 0), min(int(cols[-1]) + margin + 1, w)))


def _march_box(known: np.ndarray, region: np.ndarray | None, box: tuple[slice, slice]) -> tuple[np.ndarray, np.ndarray]:
    """FMM on the crop: (arrival float64, inf where unreached; flat crop indices in visiting order)."""
    crop_known = np.ascontiguousarray(known[box])  # one compiled signature whatever the box
    crop_region = ~crop_known if region is None else np.ascontiguousarray(region[box])
    state, arrival = _initial_state(crop_known, crop_region)
    return arrival, _march(state, arrival)


def _order_image(shape: tuple[int, int], visits: np.ndarray) -> np.ndarray:
    order = np.full(shape, -1, np.int32)
    order.ravel()[visits] = np.arange(len(visits), dtype=np.int32)
    return order


@functools.lru_cache(maxsize=8)
def _disc_offsets(radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets (dy, dx) with 0 < |d| <= radius and their distance weights 1/|d| (made once per radius, read-only)."""
    r = np.arange(-radius, radius + 1)
    dy, dx = (a.ravel() for a in np.meshgrid(r, r, indexing="ij"))
    dist = np.hypot(dy, dx)
    keep = (dist > 0) & (dist <= radius)
    offsets = dy[keep].astype(np.int64), dx[keep].astype(np.int64), 1.0 / dist[keep]
    for array in offsets:
        array.flags.writeable = False
    return offsets


def fast_marching(known: np.ndarray, region: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pure FMM distance: (order, arrival) for every pixel of `region` (default: ~known) reachable from `known`.

    order: (H, W) int32 visiting order 0, 1, 2, ... (-1 on known, wall and unreached pixels);
    arrival: (H, W) float32 T, 0 on known pixels, +inf elsewhere unreached. Region pixels reach each
    other through 4-neighbours only; pixels in neither mask are walls.
    """
    known = np.asarray(known)
    if known.ndim != 2:
        raise ValueError(f"known must be a 2-D mask, got shape {known.shape}")
    known = np.ascontiguousarray(known, dtype=bool)
    region = None if region is None else _as_mask(region, known.shape, "region")
    order = np.full(known.shape, -1, np.int32)
    arrival = np.where(known, np.float32(0), np.float32(np.inf))
    box = _region_box(known, region, 1)
    if box is None:
        return order, arrival
    crop_arrival, visits = _march_box(known, region, box)
    order[box] = _order_image(crop_arrival.shape, visits)
    arrival[box] = crop_arrival
    return order, arrival


def inpaint_motion(flow: np.ndarray, known: np.ndarray, neighbour_rgb: np.ndarray, *, neighbour_valid: np.ndarray | None = None,
                   region: np.ndarray | None = None, config: MotionInpaintConfig = MotionInpaintConfig()) -> MotionInpaintResult:
    """Propagate `flow` from `known` pixels into `region` (default ~known) in FMM order with eq. 24 weights.

    neighbour_rgb: (H, W, 3) uint8 (float32 0..255 for deeper video), the neighbour frame already warped into this
    frame's coordinates;
    neighbour_valid: where it has content (default: everywhere). Only the bounding box of the region
    grown by the radius is processed.
    """
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must have shape (H, W, 2), got {flow.shape}")
    shape = flow.shape[:2]
    known = _as_mask(known, shape, "known")
    region = None if region is None else _as_mask(region, shape, "region")
    neighbour_rgb = np.asarray(neighbour_rgb)
    if neighbour_rgb.shape != (*shape, 3) or neighbour_rgb.dtype not in (np.uint8, np.float32):
        raise ValueError(f"neighbour_rgb must be uint8 or float32 of shape {(*shape, 3)}, got {neighbour_rgb.dtype} "
                         f"{neighbour_rgb.shape}")
    valid = np.ones(shape, bool) if neighbour_valid is None else _as_mask(neighbour_valid, shape, "neighbour_valid")

    out_flow, arrival, finite = _known_flow(np.ascontiguousarray(flow, dtype=np.float32), known)
    if not finite:
        raise ValueError("flow must be finite on known pixels")
    order = np.full(shape, -1, np.int32)
    filled = np.zeros(shape, bool)
    box = _region_box(known, region, config.radius_px + 1)
    if box is None:
        return MotionInpaintResult(flow=out_flow, order=order, arrival=arrival, filled=filled)

    crop_arrival, visits = _march_box(known, region, box)
    crop_flow = out_flow[box].copy()
    colour = _colour_image(np.ascontiguousarray(neighbour_rgb), valid) if config.use_colour else np.zeros((1, 1, 3), np.float32)
    off_y, off_x, off_weight = _disc_offsets(config.radius_px)
    _inpaint_in_order(crop_flow, known[box].copy(), visits, box[0].start, box[1].start, colour,
                      off_y, off_x, off_weight, float(config.colour_epsilon), bool(config.use_colour))
    crop_order = _order_image(crop_arrival.shape, visits)
    order[box] = crop_order
    arrival[box] = crop_arrival
    filled[box] = crop_order >= 0
    out_flow[box] = crop_flow  # NaN stays NaN where nothing was filled
    return MotionInpaintResult(flow=out_flow, order=order, arrival=arrival, filled=filled)


def sample_flow(flow: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(m, 2) float32 bilinear samples of an inpainted flow (NaN where undefined) at points (x, y): each point
    interpolates between the defined vectors of its 2x2 footprint only (so an undefined neighbour does not
    poison it), edges replicated; NaN where the defined taps weigh almost nothing."""
    out = np.empty((len(x), 2), np.float32)
    _sample_defined(np.ascontiguousarray(flow, dtype=np.float32), np.ascontiguousarray(x, dtype=np.float64),
                    np.ascontiguousarray(y, dtype=np.float64), out)
    return out
