"""Fast Marching motion inpainting: arrival times against the exact distance transform, visiting order,
recovery of smooth flow, colour-steered propagation (eq. 24), and the degenerate inputs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from pipeline.errors import ConfigError
from pipeline.stages.fmm import MotionInpaintConfig, fast_marching, inpaint_motion, sample_flow

H, W = 200, 300
ROWS, COLS = np.mgrid[:H, :W]
# First-order FMM on a 4-neighbour grid, against the distance to the nearest known pixel centre:
# a pixel whose two upwind neighbours are both at T = 0 gets 1/sqrt(2) instead of 1 (-29.3 %), and one
# diagonal to a lone front pixel gets 1 + 1/sqrt(2) instead of sqrt(2) (+20.7 %). Nothing worse occurs.
MIN_REL, MAX_REL = 1 / np.sqrt(2) - 1, (1 + 1 / np.sqrt(2)) / np.sqrt(2) - 1


def hole(*boxes: tuple[int, int, int, int]) -> np.ndarray:
    """The known mask of a frame missing the given (y0, y1, x0, x1) boxes."""
    known = np.ones((H, W), bool)
    for y0, y1, x0, x1 in boxes:
        known[y0:y1, x0:x1] = False
    return known


def distance_errors(known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FMM arrival minus the exact Euclidean distance, absolute and relative, over the missing pixels."""
    _, arrival = fast_marching(known)
    exact = ndimage.distance_transform_edt(~known)
    missing = ~known
    error = arrival[missing].astype(np.float64) - exact[missing]
    return error, error / exact[missing]


# ---------------------------------------------------------------------------------------------------
# 1. Arrival times against the exact distance transform


def test_straight_border_is_exact():
    error, _ = distance_errors(hole((0, H, 180, W)))
    assert np.abs(error).max() < 1e-5


# Measured (mean |error| px, max |error| px): disc 0.100 / 0.75, border strip 0.112 / 1.16, L 0.024 / 1.03.
@pytest.mark.parametrize("name, known, mean_bound, max_bound", [
    ("disc hole r=60", (ROWS - 100) ** 2 + (COLS - 150) ** 2 > 60**2, 0.12, 0.8),
    ("border strip 30/40 px", ~hole((30, H - 30, 40, W - 40)), 0.13, 1.2),
    ("L-shaped hole", hole((30, 170, 40, 90), (120, 170, 40, 260)), 0.03, 1.1),
])
def test_arrival_matches_distance_transform(name, known, mean_bound, max_bound):
    error, relative = distance_errors(known)
    assert np.abs(error).mean() < mean_bound, name
    assert np.abs(error).max() < max_bound, name
    assert MIN_REL - 1e-4 <= relative.min() and relative.max() <= MAX_REL + 1e-4, name


def test_point_source_overestimates_diagonals_by_at_most_21_percent():
    known = np.zeros((H, W), bool)
    known[100, 150] = True
    error, relative = distance_errors(known)
    assert relative.min() > -1e-6  # a spreading front is never early
    assert relative.max() <= MAX_REL + 1e-4
    assert np.abs(error).mean() < 1.0  # measured 0.89 px at distances up to 180 px


# ---------------------------------------------------------------------------------------------------
# 2. Visiting order


def blobs_scene() -> tuple[np.ndarray, np.ndarray]:
    """Known blobs, a region to fill, and thin walls (neither) along a level line that cut deep basins off."""
    rng = np.random.default_rng(3)
    field = ndimage.gaussian_filter(rng.normal(size=(H, W)), 6)  # std about 0.047
    known = field > 0.03
    wall = (field > -0.04) & (field < -0.025)
    return known, ~known & ~wall


def test_order_is_monotone_in_arrival_and_visits_each_reachable_pixel_once():
    known, region = blobs_scene()
    order, arrival = fast_marching(known, region)

    # Reachable: 4-connected components of the region touching a known pixel through a 4-neighbour.
    labels, _ = ndimage.label(region)
    touching = np.unique(labels[ndimage.binary_dilation(known) & region])
    reachable = np.isin(labels, touching[touching > 0])
    assert 0 < reachable.sum() < region.sum()  # the scene has both kinds

    visited = order >= 0
    np.testing.assert_array_equal(visited, reachable)
    assert np.array_equal(np.sort(order[visited]), np.arange(visited.sum()))
    by_order = arrival[visited][np.argsort(order[visited])]
    assert np.all(np.diff(by_order) >= -1e-5)
    assert np.all(np.isinf(arrival[~visited & ~known])) and np.all(arrival[known] == 0)


def test_inpaint_visits_in_the_same_order_as_fast_marching():
    known, region = blobs_scene()
    order, arrival = fast_marching(known, region)
    result = inpaint_motion(np.zeros((H, W, 2), np.float32), known, np.zeros((H, W, 3), np.uint8), region=region)
    np.testing.assert_array_equal(result.order, order)
    np.testing.assert_array_equal(result.arrival, arrival)
    np.testing.assert_array_equal(result.filled, order >= 0)


# ---------------------------------------------------------------------------------------------------
# 3. Smooth flow


def affine_flow(a: np.ndarray, b: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    rows, cols = np.mgrid[: shape[0], : shape[1]].astype(np.float64)
    return np.stack([a[0, 0] * cols + a[0, 1] * rows + b[0], a[1, 0] * cols + a[1, 1] * rows + b[1]], axis=-1).astype(np.float32)


def test_affine_flow_through_border_strip_and_disc_stays_within_zero_order_bound():
    """Eq. 24 is a weighted mean (zero-order): the fill drifts by the field's slope times the depth.

    Measured: strip mean 0.242 / max 0.69 px, disc (r=30) mean 0.103 / max 0.23 px, and every pixel within
    |A| (T + 2) where |A| is the spectral norm of the affine part (0.0117 px/px here) and T its arrival.
    """
    shape = (240, 320)
    a, b = np.array([[0.01, -0.006], [0.004, 0.008]]), np.array([1.5, -0.7])
    flow = affine_flow(a, b, shape)
    rows, cols = np.mgrid[: shape[0], : shape[1]]
    strip = (rows < 40) | (rows >= shape[0] - 40) | (cols < 40) | (cols >= shape[1] - 40)
    disc = (rows - 120) ** 2 + (cols - 160) ** 2 <= 30**2
    known = ~(strip | disc)
    result = inpaint_motion(flow, known, np.full((*shape, 3), 128, np.uint8))

    assert result.filled.sum() == (~known).sum()
    epe = np.linalg.norm(result.flow - flow, axis=-1)
    assert epe[strip].mean() < 0.27 and epe[strip].max() < 0.75
    assert epe[disc].mean() < 0.12 and epe[disc].max() < 0.26
    slope = np.linalg.norm(a, 2)
    assert np.all(epe[~known] <= slope * (result.arrival[~known] + 3))
    np.testing.assert_array_equal(result.flow[known], flow[known])


def test_constant_flow_is_reproduced_exactly():
    flow = np.full((H, W, 2), (1.25, -0.5), np.float32)
    rng = np.random.default_rng(0)
    result = inpaint_motion(flow, hole((0, 40, 0, W), (80, 120, 100, 200)), rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    np.testing.assert_allclose(result.flow, flow, atol=1e-5)


# ---------------------------------------------------------------------------------------------------
# 4. Colour similarity steers the propagation


def two_objects(size: int = 160, hole_rows: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Two flat-coloured objects meeting along a slanted line, the bottom rows missing.

    Frame t: left of x = 60 + 0.5 (y - y0) a red object moving with F = (-3, 0), right of it a blue one
    with F = (+2, +1) (p in t matches p + F in the neighbour). They move apart, so the neighbour shows
    each object's pixels once and, between them, a strip of disoccluded background (random clutter).
    The missing rows continue the slanted boundary: marching straight down from the known rows carries
    the blue flow into a wedge of red pixels; only colour says they belong to the red object.
    Returns (true flow, known, neighbour rgb, wedge mask).
    """
    rows, cols = np.mgrid[:size, :size]
    y0 = size - hole_rows
    red_flow, blue_flow = (-3.0, 0.0), (2.0, 1.0)

    def is_red(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return x < 60 + 0.5 * (y - y0)

    red = is_red(cols, rows)
    flow = np.where(red[..., None], np.float32(red_flow), np.float32(blue_flow)).astype(np.float32)
    neighbour = np.random.default_rng(0).integers(0, 256, (size, size, 3), dtype=np.uint8)
    shows_red = is_red(cols - red_flow[0], rows - red_flow[1])
    shows_blue = ~is_red(cols - blue_flow[0], rows - blue_flow[1])
    assert not (shows_red & shows_blue).any()
    neighbour[shows_red] = (200, 60, 50)
    neighbour[shows_blue] = (50, 70, 200)
    known = rows < y0
    wedge = ~known & (red != red[y0 - 1][None, :])
    return flow, known, neighbour, wedge


def fraction_within(result, flow: np.ndarray, mask: np.ndarray, tolerance: float = 0.5) -> float:
    return float(np.mean(np.linalg.norm(result.flow - flow, axis=-1)[mask] < tolerance))


def test_colour_weights_give_missing_pixels_the_flow_of_their_own_object():
    """Measured (default radius 4): with colour 99.1 % of filled pixels within 0.5 px (wedge 91 %), mean EPE
    0.04 px; without colour the blue flow is extruded straight down (wedge 0 %)."""
    flow, known, neighbour, wedge = two_objects()
    assert wedge.sum() == 900
    coloured = inpaint_motion(flow, known, neighbour)
    plain = inpaint_motion(flow, known, neighbour, config=MotionInpaintConfig(use_colour=False))
    filled = coloured.filled
    assert filled.sum() == (~known).sum()

    assert fraction_within(coloured, flow, filled) > 0.97
    assert fraction_within(coloured, flow, wedge) > 0.85
    assert fraction_within(plain, flow, filled) < fraction_within(coloured, flow, filled) - 0.10
    assert fraction_within(plain, flow, wedge) < 0.05

    def mean_epe(result) -> float:
        return float(np.linalg.norm(result.flow - flow, axis=-1)[filled].mean())

    assert mean_epe(coloured) < 0.08 and mean_epe(plain) > 5 * mean_epe(coloured)


def test_unmeasurable_colour_falls_back_to_the_distance_weight():
    flow, known, neighbour, _ = two_objects()
    nowhere = np.zeros(known.shape, bool)
    blind = inpaint_motion(flow, known, neighbour, neighbour_valid=nowhere)
    plain = inpaint_motion(flow, known, neighbour, config=MotionInpaintConfig(use_colour=False))
    np.testing.assert_allclose(blind.flow, plain.flow, atol=1e-6)


def test_result_does_not_depend_on_where_the_hole_sits_in_the_frame():
    """The crop's origin is added back when sampling the neighbour: the same scene embedded at an offset."""
    flow, known, neighbour, _ = two_objects()
    size = flow.shape[0]
    big_shape, (oy, ox) = (size + 50, size + 90), (30, 70)
    inside = (slice(oy, oy + size), slice(ox, ox + size))
    big_flow = np.zeros((*big_shape, 2), np.float32)
    big_flow[inside] = flow
    big_known = np.zeros(big_shape, bool)
    big_known[inside] = known
    big_region = np.zeros(big_shape, bool)
    big_region[inside] = ~known
    big_neighbour = np.zeros((*big_shape, 3), np.uint8)
    big_neighbour[inside] = neighbour
    big_valid = np.zeros(big_shape, bool)
    big_valid[inside] = True

    small = inpaint_motion(flow, known, neighbour)
    big = inpaint_motion(big_flow, big_known, big_neighbour, neighbour_valid=big_valid, region=big_region)
    np.testing.assert_allclose(big.flow[inside], small.flow, atol=1e-5)


# ---------------------------------------------------------------------------------------------------
# 5. Degenerate inputs


def test_unreachable_pixels_stay_nan_inf_and_minus_one():
    known = np.zeros((H, W), bool)
    known[:, :50] = True
    region = np.zeros((H, W), bool)
    region[:, 50:120] = True  # touches the known columns
    region[80:120, 200:260] = True  # an island behind walls
    flow = np.full((H, W, 2), 2.0, np.float32)
    result = inpaint_motion(flow, known, np.zeros((H, W, 3), np.uint8), region=region)
    island = np.zeros((H, W), bool)
    island[80:120, 200:260] = True
    assert result.filled[:, 50:120].all() and not result.filled[island].any()
    assert np.isnan(result.flow[island]).all() and np.isinf(result.arrival[island]).all()
    assert (result.order[island] == -1).all() and (result.order[known] == -1).all()
    wall = ~known & ~region
    assert np.isnan(result.flow[wall]).all() and not result.filled[wall].any()


def test_nothing_known_reaches_nothing():
    result = inpaint_motion(np.zeros((H, W, 2), np.float32), np.zeros((H, W), bool), np.zeros((H, W, 3), np.uint8))
    assert not result.filled.any() and np.isnan(result.flow).all() and np.isinf(result.arrival).all()


def test_empty_region_and_all_known_return_the_input():
    flow = np.random.default_rng(1).normal(size=(H, W, 2)).astype(np.float32)
    known = hole((10, 30, 10, 30))
    rgb = np.zeros((H, W, 3), np.uint8)

    empty = inpaint_motion(flow, known, rgb, region=np.zeros((H, W), bool))
    assert not empty.filled.any() and (empty.order == -1).all()
    np.testing.assert_array_equal(empty.flow[known], flow[known])
    assert np.isnan(empty.flow[~known]).all()

    everything = inpaint_motion(flow, np.ones((H, W), bool), rgb)
    np.testing.assert_array_equal(everything.flow, flow)
    assert (everything.arrival == 0).all() and (everything.order == -1).all() and not everything.filled.any()

    order, arrival = fast_marching(np.ones((H, W), bool))
    assert (order == -1).all() and (arrival == 0).all()


def test_bad_inputs_are_refused():
    flow = np.zeros((H, W, 2), np.float32)
    flow[0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        inpaint_motion(flow, hole((50, 60, 50, 60)), np.zeros((H, W, 3), np.uint8))
    with pytest.raises(ValueError, match="neighbour_rgb"):
        inpaint_motion(np.zeros((H, W, 2), np.float32), hole((0, 5, 0, 5)), np.zeros((H, W), np.uint8))
    with pytest.raises(ConfigError):
        MotionInpaintConfig(radius_px=0)
    with pytest.raises(ConfigError):
        MotionInpaintConfig(colour_epsilon=0.0)


def test_sample_flow_interpolates_between_defined_vectors_only():
    rng = np.random.default_rng(3)
    flow = rng.normal(size=(20, 30, 2)).astype(np.float32) * 5
    flow[5:9, 10:14] = np.nan  # undefined patch
    flow[:, 25:] = np.nan  # undefined columns up to the right edge
    x = rng.uniform(-2, 31, 500)
    y = rng.uniform(-2, 21, 500)
    sampled = sample_flow(flow, x, y)
    for (px, py), got in zip(zip(x, y), sampled):
        x0, y0 = int(np.floor(px)), int(np.floor(py))
        fx, fy = px - x0, py - y0
        total, weight = np.zeros(2), 0.0
        for dy, wy in ((0, 1 - fy), (1, fy)):
            for dx, wx in ((0, 1 - fx), (1, fx)):
                value = flow[min(max(y0 + dy, 0), 19), min(max(x0 + dx, 0), 29)]  # edges replicated
                if np.isfinite(value[0]) and wy * wx > 0:
                    total += wy * wx * value
                    weight += wy * wx
        if weight < 1e-3:
            assert np.isnan(got).all()
        else:
            np.testing.assert_allclose(got, total / weight, rtol=1e-5, atol=1e-4)
    # At pixel centres a defined vector comes back as it is, an undefined one as NaN.
    np.testing.assert_array_equal(sample_flow(flow, np.array([3.0]), np.array([2.0]))[0], flow[2, 3])
    assert np.isnan(sample_flow(flow, np.array([11.0]), np.array([6.0]))).all()
    assert np.isnan(sample_flow(flow, np.array([27.5]), np.array([4.5]))).all()
