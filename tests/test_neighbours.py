"""Neighbours warped only where they are looked at (pipeline/stages/neighbours.py), and the two completion helpers
that look at them locally (local_warp.work_boxes, candidates.LocalError).

A lazy neighbour must answer what the whole-frame warp (pipeline.stages.warping.warp_frame) answers: crops and
integer-point lookups within OpenCV's fixed-point rounding (measured: at most 1 level on < 0.1% of pixels,
validity equal except on its 1-pixel boundary); bilinear samples at fractional points exactly as a bilinear
lookup of the original frame at M p.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage
from skimage import data

from pipeline import geometry, imaging
from pipeline.stages import candidates, local_warp, warping
from pipeline.stages.neighbours import Downscaled, WarpedNeighbour, shrink, shrink_all, warp_neighbours

H, W = 240, 320


@pytest.fixture(scope="module")
def photo() -> np.ndarray:
    return np.ascontiguousarray(cv2.resize(data.astronaut(), (W, H), interpolation=cv2.INTER_AREA))


def _translation(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def _affine() -> np.ndarray:
    """Rotation by 3 degrees and zoom by 3% about the centre, then a shift of (7.3, -4.6)."""
    angle, scale = np.radians(3.0), 1.03
    c, s = np.cos(angle) * scale, np.sin(angle) * scale
    rotate = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return _translation(7.3, -4.6) @ _translation(W / 2, H / 2) @ rotate @ _translation(-W / 2, -H / 2)


def _projective() -> np.ndarray:
    m = _affine()
    m[2, :2] = [2e-4, -1.5e-4]
    return m


TRANSFORMS = {"affine": _affine(), "projective": _projective()}
BOXES = [  # (rows, cols): corners, edges, the whole frame, an interior box, odd sizes
    (slice(0, 60), slice(0, 80)),
    (slice(100, 160), slice(200, 320)),
    (slice(180, 240), slice(250, 320)),
    (slice(0, 240), slice(0, 320)),
    (slice(37, 91), slice(13, 177)),
    (slice(0, 240), slice(300, 320)),
    (slice(239, 240), slice(5, 6)),
]


def _boundary(valid: np.ndarray) -> np.ndarray:
    """Pixels within 1 px (8-connected) of the edge between valid and invalid."""
    kernel = np.ones((3, 3), np.uint8)
    as_u8 = valid.astype(np.uint8)
    return cv2.dilate(as_u8, kernel) != cv2.erode(as_u8, kernel, borderType=cv2.BORDER_REPLICATE)


def _lazy(frame: np.ndarray, m: np.ndarray, offset: int = 1) -> WarpedNeighbour:
    return WarpedNeighbour(offset, original=frame, other_from_stab=m)


def _assert_close(colours, valid, ref_colours, ref_valid, boundary):
    """Colours within 1 level on at most 0.5% of the pixels both call valid; validity equal off the boundary."""
    both = valid & ref_valid
    difference = np.abs(colours.astype(np.int16) - ref_colours.astype(np.int16)).max(axis=-1)[both]
    assert difference.max(initial=0) <= 1
    assert (difference > 0).mean() <= 0.005 if difference.size else True
    assert not ((valid != ref_valid) & ~boundary).any()
    assert not colours[~valid].any()  # invalid is black


# --- lazy against whole-frame warps ------------------------------------------------------------------------


@pytest.mark.parametrize("kind", TRANSFORMS)
def test_lazy_whole_frame_is_warp_frame(photo, kind):
    m = TRANSFORMS[kind]
    neighbour = _lazy(photo, m)
    assert neighbour.shape == (H, W)
    warped = warping.warp_frame(photo, m)
    assert np.array_equal(neighbour.rgb, warped.frame)
    assert np.array_equal(neighbour.valid, ~warped.missing)
    assert neighbour.rgb is neighbour.rgb  # computed once
    assert 0.5 < neighbour.valid.mean() < 1.0  # the case has borders to get right


@pytest.mark.parametrize("kind", TRANSFORMS)
def test_lazy_crop_is_the_whole_warp_cut(photo, kind):
    m = TRANSFORMS[kind]
    whole = warping.warp_frame(photo, m)
    rgb, valid = whole.frame, ~whole.missing
    boundary = _boundary(valid)
    worst_valid_mismatch = 0
    for box in BOXES:
        neighbour = _lazy(photo, m)  # fresh: crop must not rely on a whole-frame warp
        crop_rgb, crop_valid = neighbour.crop(box)
        assert neighbour._rgb is None
        assert crop_rgb.shape == rgb[box].shape and crop_rgb.dtype == np.uint8
        assert crop_valid.shape == valid[box].shape and crop_valid.dtype == bool
        _assert_close(crop_rgb, crop_valid, rgb[box], valid[box], boundary[box])
        worst_valid_mismatch = max(worst_valid_mismatch, int((crop_valid != valid[box]).sum()))
    assert worst_valid_mismatch == 0  # measured: crops and the whole warp agree on validity exactly


@pytest.mark.parametrize("kind", TRANSFORMS)
def test_lazy_at_integer_points_is_the_whole_warp(photo, kind):
    m = TRANSFORMS[kind]
    whole = warping.warp_frame(photo, m)
    rgb, valid = whole.frame, ~whole.missing
    ys, xs = (a.ravel() for a in np.mgrid[0:H, 0:W])
    colours, covered = _lazy(photo, m).at(ys, xs)
    assert colours.shape == (H * W, 3) and covered.shape == (H * W,)
    _assert_close(colours.reshape(H, W, 3), covered.reshape(H, W), rgb, valid, _boundary(valid))
    # Measured: 8 boundary pixels whose sample lies within 1/64 px outside the frame count as valid here.
    assert (covered.reshape(H, W) != valid).sum() <= 20
    sampled, sampled_valid = _lazy(photo, m).sample(xs.astype(np.float64), ys.astype(np.float64))
    assert np.array_equal(sampled, colours) and np.array_equal(sampled_valid, covered)


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Float64 bilinear interpolation with zeros outside."""
    image = image.astype(np.float64)
    height, width = image.shape[:2]
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]

    def pixel(yy, xx):
        inside = (yy >= 0) & (yy < height) & (xx >= 0) & (xx < width)
        return np.where(inside[:, None], image[np.clip(yy, 0, height - 1), np.clip(xx, 0, width - 1)], 0.0)

    return (pixel(y0, x0) * (1 - fx) * (1 - fy) + pixel(y0, x0 + 1) * fx * (1 - fy)
            + pixel(y0 + 1, x0) * (1 - fx) * fy + pixel(y0 + 1, x0 + 1) * fx * fy)


@pytest.mark.parametrize("kind", TRANSFORMS)
def test_lazy_sample_at_fractional_points_is_one_bilinear_lookup_of_the_original(photo, kind):
    m = TRANSFORMS[kind]
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-3, W + 3, 50_000), rng.uniform(-3, H + 3, 50_000)
    colours, valid = _lazy(photo, m).sample(x, y)
    source = m @ np.stack([x, y, np.ones_like(x)])
    sx, sy = source[0] / source[2], source[1] / source[2]
    inside = (sx >= 0) & (sx <= W - 1) & (sy >= 0) & (sy <= H - 1)
    near_edge = (np.minimum(np.abs(sx), np.abs(sx - (W - 1))) < 1 / 32) | \
                (np.minimum(np.abs(sy), np.abs(sy - (H - 1))) < 1 / 32)
    assert not ((valid != inside) & ~near_edge).any()
    assert 0.5 < valid.mean() < 0.95
    difference = np.abs(colours - _bilinear(photo, sx, sy)).max(axis=1)[valid]
    assert difference.max() <= 1.0  # measured 0.50 (rounding to uint8)
    assert not colours[~valid].any()


@pytest.mark.parametrize("kind", TRANSFORMS)
def test_lazy_sample_agrees_with_remapping_the_eager_warp_on_a_smooth_frame(photo, kind):
    """Sampling the whole-frame warp resamples twice; on a smooth frame that is the same within 2 levels
    (measured on this frame: at most 2 with a sigma-5 blur, 3 with sigma 3, 5 with sigma 2)."""
    m = TRANSFORMS[kind]
    smooth = cv2.GaussianBlur(photo, (0, 0), 5.0)
    eager = _lazy(smooth, m)
    rng = np.random.default_rng(2)
    x = rng.uniform(-3, W + 3, 60_000).astype(np.float32)
    y = rng.uniform(-3, H + 3, 60_000).astype(np.float32)
    colours, valid = _lazy(smooth, m).sample(x, y)
    grid = (-1, 600)
    reference = cv2.remap(eager.rgb, x.reshape(grid), y.reshape(grid), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT).reshape(-1, 3)

    def covered(mask: np.ndarray) -> np.ndarray:
        return cv2.remap(mask.astype(np.uint8) * 255, x.reshape(grid), y.reshape(grid), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT).reshape(-1) == 255

    reference_valid = covered(eager.valid)
    assert not (reference_valid & ~valid).any()  # the eager mask is the stricter one (one more resampling)
    # ... and only by the one pixel the second resampling costs (inside the stabilized frame, which is all the
    # eager warp has; a lazy neighbour also samples just beyond it).
    in_frame = (x >= 0) & (x <= W - 1) & (y >= 0) & (y <= H - 1)
    grown = cv2.dilate(eager.valid.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert not (valid & in_frame & ~covered(grown)).any()
    both = valid & reference_valid
    assert both.mean() > 0.5
    assert np.abs(colours.astype(np.int16) - reference.astype(np.int16))[both].max() <= 2
    # Once the whole frame exists, a lazy neighbour samples it instead: the eager answer.
    after, after_valid = eager.sample(x, y)
    assert np.array_equal(after[both], reference[both]) and np.array_equal(after_valid, reference_valid)


@pytest.mark.parametrize("eager", [False, True])
def test_sample_beyond_remaps_size_limit_keeps_the_shape(photo, eager):
    """cv2.remap's maps must have sides below 32767: 250 x 200 = 50,000 points go through in rows."""
    neighbour = _lazy(photo, _affine())
    if eager:
        neighbour = WarpedNeighbour(1, neighbour.rgb.copy(), neighbour.valid.copy())
    rng = np.random.default_rng(3)
    x, y = rng.uniform(0, W - 1, (250, 200)), rng.uniform(0, H - 1, (250, 200))
    colours, valid = neighbour.sample(x, y)
    assert colours.shape == (250, 200, 3) and valid.shape == (250, 200)
    assert colours.dtype == np.uint8 and valid.dtype == bool
    flat, flat_valid = neighbour.sample(x.ravel(), y.ravel())
    assert flat.shape == (50_000, 3)
    assert np.array_equal(flat.reshape(250, 200, 3), colours) and np.array_equal(flat_valid.reshape(250, 200), valid)
    for start in (0, 4095, 4096, 32_766, 49_990):  # one point at a time: the same answer at every place
        one, one_valid = neighbour.sample(x.ravel()[start:start + 10], y.ravel()[start:start + 10])
        assert np.array_equal(one, flat[start:start + 10]) and np.array_equal(one_valid, flat_valid[start:start + 10])
    long, long_valid = neighbour.sample(np.full(40_001, 160.5), np.full(40_001, 120.25))  # one long row
    assert long.shape == (40_001, 3) and (long == long[0]).all() and long_valid.all() and long[0].any()


def test_sample_of_no_points(photo):
    for neighbour in (_lazy(photo, _affine()), WarpedNeighbour(1, photo, np.ones((H, W), bool))):
        colours, valid = neighbour.sample(np.zeros(0), np.zeros(0))
        assert colours.shape == (0, 3) and valid.shape == (0,)


def test_eager_neighbour_returns_its_own_arrays(photo):
    valid = np.ones((H, W), bool)
    valid[:, :40] = False
    rgb = photo.copy()
    rgb[~valid] = 0
    neighbour = WarpedNeighbour(-2, rgb, valid)
    assert neighbour.offset == -2 and neighbour.shape == (H, W)
    assert neighbour.rgb is rgb and neighbour.valid is valid
    for box in BOXES:
        crop_rgb, crop_valid = neighbour.crop(box)
        assert np.array_equal(crop_rgb, rgb[box]) and np.array_equal(crop_valid, valid[box])
    rng = np.random.default_rng(4)
    ys, xs = rng.integers(0, H, 500), rng.integers(0, W, 500)
    colours, covered = neighbour.at(ys, xs)
    assert np.array_equal(colours, rgb[ys, xs]) and np.array_equal(covered, valid[ys, xs])


def test_a_neighbour_is_either_eager_or_lazy(photo):
    valid = np.ones((H, W), bool)
    with pytest.raises(ValueError):
        WarpedNeighbour(1)
    with pytest.raises(ValueError):
        WarpedNeighbour(1, photo, valid, original=photo, other_from_stab=np.eye(3))
    with pytest.raises(ValueError):
        WarpedNeighbour(1, photo)  # rgb without valid
    with pytest.raises(ValueError):
        WarpedNeighbour(1, original=photo)  # original without its transform
    with pytest.raises(ValueError):
        WarpedNeighbour(1, photo, valid, other_from_stab=np.eye(3))


# --- warp_neighbours --------------------------------------------------------------------------------------------


def test_warp_neighbours_nearest_first_with_their_transforms(photo):
    n, t = 10, 5
    rng = np.random.default_rng(5)
    # Integer translations: every warp is an exact shift, checked pixel for pixel.
    shifts = rng.integers(-4, 5, (n, 2))
    curr_from_prev = np.stack([_translation(*map(float, s)) for s in shifts])
    orig_from_stab_t = _translation(3.0, -2.0)
    frames = {i: np.ascontiguousarray(np.roll(photo, 7 * i, axis=1)) for i in (2, 3, 4, 6, 7, 9)}
    warped = warp_neighbours(frames, t, curr_from_prev, orig_from_stab_t)
    assert [w.offset for w in warped] == [-1, 1, -2, 2, -3, 4]  # nearest first, the earlier of a tie first
    t_from = geometry.neighbour_transforms(curr_from_prev, t, 2, 9)
    for neighbour in warped:
        other = t + neighbour.offset
        assert neighbour.original is frames[other]
        expected_m = np.linalg.inv(t_from[other]) @ orig_from_stab_t
        assert np.allclose(neighbour.other_from_stab, expected_m)
        expected = warping.warp_frame(frames[other], expected_m)
        assert np.array_equal(neighbour.rgb, expected.frame) and np.array_equal(neighbour.valid, ~expected.missing)
        # The same, from first principles: pixel p of t's stabilized frame is pixel p + d of frame t'.
        dx, dy = np.rint(expected_m[:2, 2]).astype(int)
        assert np.allclose(expected_m[:2, 2], (dx, dy))
        if other < t:  # frame t' content moved into frame t by the shifts between them
            d = np.array([3, -2]) - shifts[other + 1:t + 1].sum(axis=0)
        else:
            d = np.array([3, -2]) + shifts[t + 1:other + 1].sum(axis=0)
        assert (dx, dy) == tuple(d)
        ys, xs = np.mgrid[0:H, 0:W]
        inside = (ys + dy >= 0) & (ys + dy < H) & (xs + dx >= 0) & (xs + dx < W)
        assert np.array_equal(neighbour.valid, inside)
        assert np.array_equal(neighbour.rgb[inside], frames[other][(ys + dy)[inside], (xs + dx)[inside]])


def test_warp_neighbours_of_nothing_and_of_the_frame_itself(photo):
    assert warp_neighbours({}, 3, np.stack([np.eye(3)] * 5), np.eye(3)) == []
    (only,) = warp_neighbours({3: photo}, 3, np.stack([np.eye(3)] * 5), _translation(2.0, 1.0))
    assert only.offset == 0 and np.allclose(only.other_from_stab, _translation(2.0, 1.0))


# --- local_warp.work_boxes --------------------------------------------------------------------------------------


def _grown(ys: slice, xs: slice, margin: int, shape: tuple[int, int]) -> tuple[int, int, int, int]:
    return (max(ys.start - margin, 0), max(xs.start - margin, 0), min(ys.stop + margin, shape[0]),
            min(xs.stop + margin, shape[1]))


def _as_tuple(box: tuple[slice, slice]) -> tuple[int, int, int, int]:
    return box[0].start, box[1].start, box[0].stop, box[1].stop


def _contains(outer: tuple[int, int, int, int], inner: tuple[int, int, int, int]) -> bool:
    return outer[0] <= inner[0] and outer[1] <= inner[1] and outer[2] >= inner[2] and outer[3] >= inner[3]


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _boxes(wanted: np.ndarray, margin: int | None) -> list[tuple[tuple[int, int, int, int], list[tuple[int, int, int, int]]]]:
    return [(_as_tuple(w.box), [_as_tuple(r) for r in w.owned]) for w in local_warp.work_boxes(wanted, margin)]


def _area(box: tuple[int, int, int, int]) -> int:
    return (box[2] - box[0]) * (box[3] - box[1])


def _owned_mask(rects: list[tuple[int, int, int, int]], shape: tuple[int, int]) -> np.ndarray:
    mask = np.zeros(shape, bool)
    for y0, x0, y1, x1 in rects:
        mask[y0:y1, x0:x1] = True
    return mask


def test_work_boxes_around_two_far_clusters():
    shape, margin = (200, 300), 20
    wanted = np.zeros(shape, bool)
    clusters = [(slice(5, 11), slice(30, 37)), (slice(150, 156), slice(250, 259))]  # the first near the top edge
    for cluster in clusters:
        wanted[cluster] = True
    boxes = sorted(_boxes(wanted, margin))
    assert [box for box, _ in boxes] == sorted(_grown(*c, margin, shape) for c in clusters)
    for (_, owned), cluster in zip(boxes, sorted(clusters, key=lambda c: (c[0].start, c[1].start))):
        alone = np.zeros(shape, bool)
        alone[cluster] = True
        assert (_owned_mask(owned, shape) == alone).all()  # each box owns its cluster's pixels, no others
    assert boxes[0][0][0] == 0  # clipped to the frame


def test_work_boxes_merge_only_where_one_box_costs_no_more_than_two():
    shape, margin = (200, 300), 20
    wanted = np.zeros(shape, bool)
    a, b = (slice(50, 58), slice(50, 58)), (slice(52, 60), slice(66, 74))  # 8 px apart: grown boxes overlap mostly
    wanted[a] = wanted[b] = True
    (only,) = _boxes(wanted, margin)
    assert only[0] == (30, 30, 80, 94) and _owned_mask(only[1], shape)[wanted].all()
    # Farther apart, the joint box would cost more than the two grown ones: they stay two, even overlapping.
    wanted = np.zeros(shape, bool)
    wanted[50:60, 50:60] = wanted[60:70, 95:100] = True
    (first, _), (second, _) = _boxes(wanted, margin)
    assert _overlap(first, second)
    assert {first, second} == {_grown(slice(50, 60), slice(50, 60), margin, shape),
                               _grown(slice(60, 70), slice(95, 100), margin, shape)}


def test_work_boxes_keep_strips_on_two_sides_apart():
    """A border missing on the left and on the right, joined along the top: one cluster, whose single box was
    the whole frame; the flows now cover three strips, about three quarters of it."""
    shape, margin = (360, 640), 96
    wanted = np.zeros(shape, bool)
    wanted[:, :30] = wanted[:, -40:] = wanted[:6, :] = True
    boxes = _boxes(wanted, margin)
    assert len(boxes) == 3
    assert sum(_area(box) for box, _ in boxes) < 0.8 * shape[0] * shape[1]


def test_work_boxes_own_every_pixel_once_with_its_margin():
    rng = np.random.default_rng(6)
    shape = (180, 320)
    for trial in range(20):
        wanted = np.zeros(shape, bool)
        for _ in range(rng.integers(1, 12)):
            y, x = rng.integers(0, shape[0]), rng.integers(0, shape[1])
            h, w = rng.integers(1, 60, 2)
            wanted[y:y + h, x:x + w] = True
        margin = int(rng.integers(0, 40))
        boxes = _boxes(wanted, margin)
        owned = np.zeros(shape, np.int64)
        for box, rects in boxes:
            for rect in rects:
                assert _contains(box, _grown(slice(rect[0], rect[2]), slice(rect[1], rect[3]), margin, shape))
                owned[rect[0]:rect[2], rect[1]:rect[3]] += 1
        assert owned.max() <= 1, trial  # owned rectangles never overlap
        assert (owned[wanted] == 1).all(), trial  # and every pixel needing a flow has exactly one owner
        for i in range(len(boxes)):  # the greedy merge leaves no pair that one joint box would cover cheaper
            for j in range(i + 1, len(boxes)):
                (a, _), (b, _) = boxes[i], boxes[j]
                joint = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                assert _area(joint) > _area(a) + _area(b), (trial, a, b)


def test_a_pixel_takes_the_flow_of_the_box_that_owns_it_where_boxes_overlap():
    from types import SimpleNamespace

    first = SimpleNamespace(box=(slice(0, 50), slice(0, 60)), owned=((slice(0, 20), slice(0, 30)),))
    second = SimpleNamespace(box=(slice(10, 80), slice(20, 100)), owned=((slice(40, 60), slice(50, 90)),))
    ys = np.array([5, 15, 45, 45, 70, 90])
    xs = np.array([5, 25, 55, 10, 95, 5])
    # Owned by the first though inside the second's box too; owned by the second; only in the first's box;
    # only in the second's; in none.
    assert local_warp.owners([first, second], ys, xs).tolist() == [0, 0, 1, 0, 1, -1]


def test_work_boxes_without_a_margin_are_the_whole_frame():
    wanted = np.zeros((90, 160), bool)
    wanted[3, 4] = True
    whole = (slice(0, 90), slice(0, 160))
    assert [(w.box, w.owned) for w in local_warp.work_boxes(wanted, None)] == [(whole, (whole,))]
    assert local_warp.work_boxes(np.zeros((90, 160), bool), 10) == []
    assert local_warp.work_boxes(np.zeros((90, 160), bool), None) == []


# --- candidates.LocalError --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def target() -> np.ndarray:
    """A photograph kept below 245, so that adding 10 never clips."""
    return np.ascontiguousarray((data.astronaut()[40:200, 100:300] * 0.9).astype(np.uint8))


def _strip(shape: tuple[int, int]) -> np.ndarray:
    missing = np.zeros(shape, bool)
    missing[:20] = True
    return missing


def _rotated(target: np.ndarray) -> np.ndarray:
    c, s = np.cos(0.1), np.sin(0.1)
    return warping.warp_frame(target, np.array([[c, -s, 15.0], [s, c, -12.0], [0.0, 0.0, 1.0]])).missing


def _brute_force(target, known, neighbour, landed, ys, xs, nearest_y, nearest_x, radius):
    """Mean |I_t - I_w| over the known, landed pixels of the (2r+1)^2 window around each given nearest pixel."""
    height, width = known.shape
    target_i, neighbour_i = imaging.intensity(target), imaging.intensity(neighbour)
    errors = []
    for y, x in zip(nearest_y, nearest_x):
        rows = slice(max(y - radius, 0), min(y + radius + 1, height))
        cols = slice(max(x - radius, 0), min(x + radius + 1, width))
        use = known[rows, cols] & landed[rows, cols]
        values = np.abs(target_i[rows, cols] - neighbour_i[rows, cols])[use]
        errors.append(values.mean() if values.size else np.nan)
    return np.array(errors)


@pytest.mark.parametrize("region", ["strip", "rotated"])
def test_local_error_constant_cases(target, region):
    missing = _strip(target.shape[:2]) if region == "strip" else _rotated(target)
    ys, xs = np.nonzero(missing)
    local = candidates.LocalError(target, ~missing, ys, xs, radius=4)
    band_y, band_x = local.band_y, local.band_x
    assert not missing[band_y, band_x].any()  # the band is known pixels only
    everywhere = np.ones(len(band_y), bool)
    same = local(target[band_y, band_x], everywhere)
    assert same.shape == (len(ys),) and np.array_equal(same, np.zeros(len(ys), np.float32))
    brighter = np.clip(target.astype(np.int16) + 10, 0, 255).astype(np.uint8)
    assert np.abs(local(brighter[band_y, band_x], everywhere) - 10).max() <= 0.5  # measured 1e-5
    assert np.isnan(local(brighter[band_y, band_x], np.zeros(len(band_y), bool))).all()
    if region == "strip":  # the band is the 5 rows below the strip
        assert set(band_y.tolist()) == set(range(20, 25)) and len(band_y) == 5 * target.shape[1]


@pytest.mark.parametrize("region", ["strip", "rotated"])
def test_local_error_against_brute_force(target, region):
    radius = 4
    missing = _strip(target.shape[:2]) if region == "strip" else _rotated(target)
    known = ~missing
    ys, xs = np.nonzero(missing)
    local = candidates.LocalError(target, known, ys, xs, radius)
    rng = np.random.default_rng(7)
    neighbour = cv2.GaussianBlur(np.roll(target, 3, axis=1), (0, 0), 1.5)  # misaligned and blurred
    landed = rng.random(known.shape) > 0.3
    errors = local(neighbour[local.band_y, local.band_x], landed[local.band_y, local.band_x])
    assert np.isfinite(errors).all()

    distance, (edt_y, edt_x) = ndimage.distance_transform_edt(missing, return_indices=True)
    # The implementation's nearest known pixel of each pixel to fill (the centre of its window).
    centre = local.window[:, local.window.shape[1] // 2]
    assert (centre >= 0).all()
    chosen_y, chosen_x = local.band_y[centre][local.point_of], local.band_x[centre][local.point_of]
    assert known[chosen_y, chosen_x].all()
    excess = np.hypot(chosen_y - ys, chosen_x - xs) - distance[ys, xs]
    assert excess.max() <= 0.25  # cv2's 5x5 approximation: measured at most 0.18 px further than the nearest

    # Windows around the implementation's own nearest pixels: the same means, every pixel.
    own = _brute_force(target, known, neighbour, landed, ys, xs, chosen_y, chosen_x, radius)
    assert np.abs(errors - own).max() <= 1e-3

    # 20 random pixels against the exact nearest pixel (EDT): equal where the nearest pixel is the same.
    pick = rng.choice(len(ys), 20, replace=False)
    exact = _brute_force(target, known, neighbour, landed, ys[pick], xs[pick], edt_y[ys[pick], xs[pick]],
                         edt_x[ys[pick], xs[pick]], radius)
    same_pixel = (chosen_y[pick] == edt_y[ys[pick], xs[pick]]) & (chosen_x[pick] == edt_x[ys[pick], xs[pick]])
    assert np.abs(errors[pick] - exact)[same_pixel].max(initial=0) <= 1e-3
    # Over all pixels: the nearest pixel differs for 0% (strip) / 2.3% (rotated edge) of them, and the error
    # then by at most 8.8 intensity levels on this textured case (the window moves by a pixel or so).
    all_exact = _brute_force(target, known, neighbour, landed, ys, xs, edt_y[ys, xs], edt_x[ys, xs], radius)
    differs = (chosen_y != edt_y[ys, xs]) | (chosen_x != edt_x[ys, xs])
    assert differs.mean() <= (0.0 if region == "strip" else 0.05)
    assert np.abs(errors - all_exact)[~differs].max() <= 1e-3
    assert np.abs(errors - all_exact).max() <= 10.0


@pytest.mark.parametrize("name", sorted(TRANSFORMS))
def test_crops_at_a_working_size_from_the_downscaled_original_match_crop_then_shrink(photo, name):
    """Warping the shared downscaled copy (a third of the size, as at 1080p) instead of warping whole-size and
    shrinking: measured mean difference 1.1 levels on this photo, validity equal but on its 1-px boundary."""
    large = cv2.resize(photo, (3 * W, 3 * H), interpolation=cv2.INTER_CUBIC)
    stab_from_large = np.diag([1 / 3, 1 / 3, 1.0])
    other_from_stab = np.linalg.inv(stab_from_large) @ TRANSFORMS[name] @ stab_from_large
    downscaled = Downscaled((W, H))
    direct = WarpedNeighbour(1, original=large, other_from_stab=other_from_stab)
    via_small = WarpedNeighbour(1, original=large, other_from_stab=other_from_stab,
                                small_original=lambda: downscaled.get(7, large))
    for box in [(slice(0, 3 * H), slice(0, 3 * W)), (slice(30, 400), slice(500, 960)), (slice(11, 131), slice(7, 300))]:
        size = (round((box[1].stop - box[1].start) / 3), round((box[0].stop - box[0].start) / 3))
        rgb, valid = via_small.crop(box, size)
        want_rgb, want_valid = direct.crop(box, size)
        np.testing.assert_array_equal(want_rgb, shrink(direct.crop(box)[0], size))
        np.testing.assert_array_equal(want_valid, shrink_all(direct.crop(box)[1], size))
        assert rgb.shape == want_rgb.shape and valid.shape == want_valid.shape
        assert (valid != want_valid).sum() <= (_boundary(want_valid) | _boundary(valid)).sum()
        both = valid & want_valid
        assert both.mean() > 0.5
        assert np.abs(rgb[both].astype(float) - want_rgb[both]).mean() < 1.5
        assert not rgb[~valid].any()
    assert len(downscaled._by_frame) == 1  # made once, shared
    downscaled.forget_before(8)
    assert not downscaled._by_frame
