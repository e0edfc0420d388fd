"""Turning intermediates into pictures for the viewer: flow colour wheel, sparse arrows, scalar maps."""

from __future__ import annotations

import functools

import cv2
import numpy as np


def flow_to_rgb(flow: np.ndarray, max_magnitude: float | None = None) -> np.ndarray:
    """Middlebury-style colour coding: hue = direction, saturation = magnitude; NaN flow (none computed there) in
    NO_VALUE_COLOUR, the grey of every map's "no value" (no flow colour is grey: their value is always full)."""
    fx, fy = cv2.split(np.ascontiguousarray(flow, np.float32))  # contiguous copies, changed in place below
    valid = np.isfinite(fx + fy)  # both components finite
    invalid = ~valid
    fx[invalid] = 0
    fy[invalid] = 0
    magnitude, angle = cv2.cartToPolar(fx, fy, angleInDegrees=True)
    scale = max_magnitude or max(_percentile_99(magnitude[valid]) if valid.any() else 1.0, 1e-3)
    saturation = np.clip(magnitude / scale * 255, 0, 255).astype(np.uint8)
    saturation[invalid] = 0  # no value: no saturation at the grey's value, which HSV -> RGB turns into that grey
    value = np.full(valid.shape, 255, np.uint8)
    value[invalid] = NO_VALUE_COLOUR[0]
    return cv2.cvtColor(cv2.merge([(angle / 2).astype(np.uint8), saturation, value]), cv2.COLOR_HSV2RGB)


def _percentile_99(values: np.ndarray, most: int = 65536) -> float:
    """The 99th percentile of ``values``, of an even sample of at most ``most`` of them: a colour scale's top, where
    sorting a million values would cost more than the colours."""
    step = max(len(values) // most, 1)
    return float(np.percentile(values[::step], 99))


def sparse_arrows(flow: np.ndarray, step: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """(origins, vectors) of the flow sampled on a grid, NaN samples dropped."""
    ys, xs = np.mgrid[step // 2: flow.shape[0]: step, step // 2: flow.shape[1]: step]
    vectors = flow[ys, xs].reshape(-1, 2)
    origins = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float32)
    keep = np.isfinite(vectors).all(axis=1)
    return origins[keep], vectors[keep]


def finite_or_nan(values: np.ndarray) -> np.ndarray:
    """Float32 map with non-finite values as NaN (the viewer shows NaN in a depth image as the colour map's lowest
    colour, like 0: colour_mapped makes them transparent)."""
    out = np.asarray(values, dtype=np.float32).copy()
    out[~np.isfinite(out)] = np.nan
    return out


# -- colours shared by the viewer (recorder) and the figures ---------------------------------------------------

# Camera path: original in warm colours, smoothed in cool ones; x and y told apart within each.
TRAJECTORY_COLOURS = {("original", "x"): (235, 80, 60), ("original", "y"): (245, 175, 40),
                      ("original", "angle"): (235, 80, 60), ("smoothed", "x"): (50, 130, 245),
                      ("smoothed", "y"): (60, 210, 200), ("smoothed", "angle"): (50, 130, 245),
                      ("original", "zoom"): (235, 80, 60), ("smoothed", "zoom"): (50, 130, 245)}
# The two planners on the same motion (PathComparison), thin: eq. 18 in greens, L1 in magentas, y darker than x
# (x and y share one chart in the viewer).
for _axis in ("x", "angle", "zoom"):
    TRAJECTORY_COLOURS["gaussian", _axis], TRAJECTORY_COLOURS["l1", _axis] = (120, 220, 120), (230, 110, 230)
TRAJECTORY_COLOURS["gaussian", "y"], TRAJECTORY_COLOURS["l1", "y"] = (30, 150, 80), (150, 70, 210)
VARIANCE_RANGE = (0.0, 400.0)  # intensity^2: the variance map's colour range (4x the default threshold)
ARRIVAL_RANGE = (0.0, 60.0)  # px


def hex_colour(rgb: tuple[int, ...]) -> str:
    return "#" + "".join(f"{int(c):02x}" for c in rgb[:3])


# -- colour keys (the viewer's colour maps, drawn as small images logged beside the views) -----------------

_CV2_COLORMAPS = {"turbo": cv2.COLORMAP_TURBO, "viridis": cv2.COLORMAP_VIRIDIS, "magma": cv2.COLORMAP_MAGMA,
                  "inferno": cv2.COLORMAP_INFERNO, "plasma": cv2.COLORMAP_PLASMA}
KEY_BACKGROUND = (250, 250, 250)
KEY_TEXT = (20, 20, 20)
# The background of the views that show colour-mapped maps: a map's pixels without a value are transparent, so
# they show this grey, which none of the colour maps here (turbo, viridis, magma) contains.
NO_VALUE_COLOUR = (128, 128, 128)
MAP_LEVELS = 255  # colours a shown map uses: palette entries 1-255 of an 8-bit paletted PNG (0: no value)


def map_indices(values: np.ndarray, value_range: tuple[float, float], shown: np.ndarray | None = None,
                *, levels: int = MAP_LEVELS) -> np.ndarray:
    """uint8 palette index per pixel of a float map: 1 + the value's step of ``levels`` over ``value_range``
    (clipped to it) where ``shown`` (default: where finite) and finite; 0 elsewhere (no value)."""
    values = np.asarray(values, np.float32)
    finite = np.isfinite(values)
    shown = finite if shown is None else (np.asarray(shown, bool) & finite)
    low, high = float(value_range[0]), float(value_range[1])
    steps = np.where(finite, values - np.float32(low), 0).astype(np.float32)
    steps *= np.float32((levels - 1) / max(high - low, 1e-12))
    np.clip(steps, 0, levels - 1, out=steps)
    steps += np.float32(1.5)  # round, and 1 past the no-value index
    indices = steps.astype(np.uint8)
    indices[~shown] = 0
    return indices


@functools.lru_cache(maxsize=16)
def map_palette(colormap: str, *, levels: int = MAP_LEVELS) -> np.ndarray:
    """(256, 4) uint8 RGBA palette for map_indices: 0 transparent, 1..levels ``colormap`` (the colour keys'
    own, OpenCV's tables) from its lowest to its highest colour."""
    ramp = np.rint(np.arange(levels) * (255.0 / max(levels - 1, 1))).astype(np.uint8)[:, None]
    palette = np.zeros((256, 4), np.uint8)
    palette[1:levels + 1, :3] = cv2.applyColorMap(ramp, _CV2_COLORMAPS[colormap])[:, 0, ::-1]
    palette[1:levels + 1, 3] = 255
    return palette


def colour_mapped(values: np.ndarray, colormap: str, value_range: tuple[float, float],
                  shown: np.ndarray | None = None) -> np.ndarray:
    """RGBA uint8 picture of a float map as the viewer shows it: ``colormap`` over ``value_range``, opaque where
    ``shown`` (default: where finite), (0, 0, 0, 0) elsewhere, so that no value does not read as the lowest."""
    return map_palette(colormap)[map_indices(values, value_range, shown)]


def _text(image: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.5) -> None:
    cv2.putText(image, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, KEY_TEXT, 1, cv2.LINE_AA)


def colour_bar(colormap: str, low: float, high: float, unit: str, title: str, *, width: int = 360,
               ticks: int = 5, fmt: str = "{:g}", no_value: str | None = None) -> np.ndarray:
    """RGB image: ``title``, a horizontal bar of ``colormap`` from ``low`` to ``high``, tick labels in ``unit``;
    with ``no_value``, a NO_VALUE_COLOUR swatch saying which pixels have none.

    Dark text on white, so it reads on any viewer theme."""
    height, margin, bar_h = 90 + (20 if no_value else 0), 14, 22
    image = np.full((height, width, 3), KEY_BACKGROUND, np.uint8)
    ramp = np.linspace(0, 255, width - 2 * margin).astype(np.uint8)[None, :]
    bar = cv2.cvtColor(cv2.applyColorMap(np.repeat(ramp, bar_h, axis=0), _CV2_COLORMAPS[colormap]), cv2.COLOR_BGR2RGB)
    image[26:26 + bar_h, margin:width - margin] = bar
    _text(image, title, (margin, 18))
    for i in range(ticks):
        x = margin + round(i * (width - 2 * margin - 1) / (ticks - 1))
        cv2.line(image, (x, 26 + bar_h), (x, 26 + bar_h + 5), KEY_TEXT, 1)
        label = fmt.format(low + (high - low) * i / (ticks - 1))
        size = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.42, 1)[0][0]
        _text(image, label, (int(np.clip(x - size // 2, 0, width - size)), 26 + bar_h + 20), 0.42)
    _text(image, unit, (margin, 86), 0.42)
    if no_value:
        cv2.rectangle(image, (margin, 92), (margin + 22, 104), NO_VALUE_COLOUR, -1)
        cv2.rectangle(image, (margin, 92), (margin + 22, 104), KEY_TEXT, 1)
        _text(image, f"no value: {no_value}", (margin + 30, 103), 0.42)
    return image


def flow_wheel(size: int = 200) -> np.ndarray:
    """The flow colour key: hue = direction, saturation = magnitude (rim: the frame's flow scale), and the
    "no value" swatch (where no flow was computed)."""
    height = size + 62
    image = np.full((height, size, 3), KEY_BACKGROUND, np.uint8)
    radius = size // 2 - 20
    ys, xs = np.mgrid[-radius:radius + 1, -radius:radius + 1].astype(np.float32)
    flow = np.stack([xs, ys], axis=-1) / radius
    inside = np.hypot(xs, ys) <= radius
    wheel = flow_to_rgb(flow, max_magnitude=1.0)
    top, left = 20, size // 2 - radius
    region = image[top:top + 2 * radius + 1, left:left + 2 * radius + 1]
    region[inside] = wheel[inside]
    centre = (size // 2, top + radius)
    _text(image, "flow direction = hue", (6, 14), 0.42)
    _text(image, "+x", (centre[0] + radius - 14, centre[1] + 5), 0.4)
    _text(image, "+y (down)", (centre[0] - 30, top + 2 * radius + 14), 0.4)
    _text(image, "rim: 99th pct magnitude", (6, size + 34), 0.4)
    cv2.rectangle(image, (6, size + 44), (28, size + 56), NO_VALUE_COLOUR, -1)
    cv2.rectangle(image, (6, size + 44), (28, size + 56), KEY_TEXT, 1)
    _text(image, "no value: not computed", (34, size + 55), 0.4)
    return image


def palette_key(entries: list[tuple[str, tuple[int, ...]]], title: str, *, width: int = 360) -> np.ndarray:
    """RGB image: one swatch and name per class (alpha shown against white)."""
    row = 20
    image = np.full((26 + row * len(entries), width, 3), KEY_BACKGROUND, np.uint8)
    _text(image, title, (8, 16))
    for i, (name, colour) in enumerate(entries):
        y = 24 + i * row
        rgb = np.array(colour[:3], float)
        alpha = (colour[3] / 255.0) if len(colour) > 3 else 1.0
        swatch = (alpha * rgb + (1 - alpha) * np.array(KEY_BACKGROUND)).astype(int)
        cv2.rectangle(image, (8, y + 2), (30, y + row - 4), tuple(int(c) for c in swatch), -1)
        cv2.rectangle(image, (8, y + 2), (30, y + row - 4), KEY_TEXT, 1)
        _text(image, name, (38, y + row - 6), 0.42)
    return image
