"""Ground-truth checks of the synthetic shaky-video generator (pipeline/evaluation/synthetic.py)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from pipeline.evaluation.synthetic import (
    SyntheticConfig,
    SyntheticVideo,
    apply_blur,
    default_blurred_frames,
    generate,
    make_two_frames,
    motion_blur_kernel,
    psnr,
    warp,
    write_video,
)

W, H = 640, 360


@pytest.fixture(scope="module")
def video() -> SyntheticVideo:
    return generate(SyntheticConfig())


def _interior(margin: int = 24, w: int = W, h: int = H) -> np.ndarray:
    m = np.zeros((h, w), bool)
    m[margin : h - margin, margin : w - margin] = True
    return m


def _dilate(mask: np.ndarray, px: int) -> np.ndarray:
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))
    return cv2.dilate(mask.astype(np.uint8), k) > 0


def _warp_mask(mask: np.ndarray, m: np.ndarray) -> np.ndarray:
    return warp(mask.astype(np.uint8), m, (mask.shape[1], mask.shape[0]), interpolation=cv2.INTER_NEAREST, border_value=0) > 0


# ---------------------------------------------------------------------- structure


def test_shapes_and_dtypes(video: SyntheticVideo):
    n = video.config.n_frames
    assert len(video.frames) == len(video.sharp_frames) == len(video.object_mask) == n == 90
    for f, s, m in zip(video.frames, video.sharp_frames, video.object_mask):
        assert f.shape == s.shape == (H, W, 3) and f.dtype == s.dtype == np.uint8
        assert m.shape == (H, W) and m.dtype == bool
    for name in ("frame_from_world", "intended_frame_from_world", "curr_from_prev"):
        a = getattr(video, name)
        assert a.shape == (n, 3, 3) and a.dtype == np.float64, name
        np.testing.assert_allclose(a[:, 2], np.tile([0.0, 0.0, 1.0], (n, 1)), atol=1e-12)
    assert video.world.dtype == np.uint8 and video.world.ndim == 3
    assert video.blurred == default_blurred_frames(n)
    assert 0 < len(video.blurred) < n
    assert 0 not in video.blurred and n - 1 not in video.blurred
    k = video.blur_kernel
    assert k.ndim == 2 and k.shape[0] % 2 == 1 and k.shape[1] % 2 == 1
    assert math.isclose(float(k.sum()), 1.0, rel_tol=1e-5)


def test_deterministic_for_a_seed_and_varies_with_it():
    cfg = SyntheticConfig(n_frames=12, seed=3)
    a, b = generate(cfg), generate(cfg)
    np.testing.assert_array_equal(a.frame_from_world, b.frame_from_world)
    for fa, fb in zip(a.frames, b.frames):
        np.testing.assert_array_equal(fa, fb)
    for ma, mb in zip(a.object_mask, b.object_mask):
        np.testing.assert_array_equal(ma, mb)
    c = generate(SyntheticConfig(n_frames=12, seed=4))
    assert not np.allclose(a.frame_from_world, c.frame_from_world)


def test_every_frame_is_covered_by_the_world(video: SyntheticVideo):
    hw, ww = video.world.shape[:2]
    corners = np.array([[0, 0, 1], [W - 1, 0, 1], [W - 1, H - 1, 1], [0, H - 1, 1]], float).T
    for fw in (video.frame_from_world, video.intended_frame_from_world):
        p = np.linalg.inv(fw) @ corners  # (N, 3, 4)
        x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
        assert x.min() >= 1 and y.min() >= 1 and x.max() <= ww - 2 and y.max() <= hw - 2
    # Every frame pixel samples inside the world: rendering with a constant border shows no border colour.
    for t in (0, 44, 89):
        cov = video.view_coverage(t, np.eye(3))
        assert cov.all()


# ---------------------------------------------------------------------- geometry truth


def test_curr_from_prev_consistent_with_frame_from_world(video: SyntheticVideo):
    fw = video.frame_from_world
    np.testing.assert_allclose(video.curr_from_prev[0], np.eye(3), atol=1e-12)
    for t in range(1, len(fw)):
        np.testing.assert_allclose(video.curr_from_prev[t], fw[t] @ np.linalg.inv(fw[t - 1]), atol=1e-9)


def test_frame_is_world_seen_through_frame_from_world(video: SyntheticVideo):
    t = 7
    expected = cv2.warpAffine(video.world_at(t), video.frame_from_world[t][:2], (W, H), flags=cv2.INTER_CUBIC)
    np.testing.assert_array_equal(expected, video.sharp_frames[t])


def test_background_motion_matches_curr_from_prev(video: SyntheticVideo):
    blurred = set(video.blurred)
    pairs = [t for t in range(1, video.config.n_frames) if t not in blurred and t - 1 not in blurred]
    assert len(pairs) >= 20
    interior = _interior(24)
    values = []
    for t in pairs[::3]:
        m = video.curr_from_prev[t]
        pred = warp(video.frames[t - 1], m, (W, H), interpolation=cv2.INTER_CUBIC)
        valid = interior & video.view_coverage(t - 1, m)  # always true here, kept for clarity
        valid &= _warp_mask(np.ones((H, W), bool), m)  # pixels that come from inside frame t-1
        obj = _dilate(video.object_mask[t] | _warp_mask(video.object_mask[t - 1], m), 4)
        valid &= ~obj
        assert valid.mean() > 0.5
        values.append(psnr(pred, video.frames[t], valid))
    assert min(values) > 30.0, values
    # ... and the identity is a poor model (the camera really moves).
    t = pairs[1]
    assert psnr(video.frames[t - 1], video.frames[t], interior) < min(values) - 8.0


def test_jitter_is_band_limited_hand_shake(video: SyntheticVideo):
    cfg = video.config
    n, fps = cfg.n_frames, cfg.fps
    centre = np.array([(W - 1) / 2.0, (H - 1) / 2.0, 1.0])

    def path(fw):  # world position seen at the frame centre, and roll
        p = np.linalg.inv(fw) @ centre
        roll = np.arctan2(np.linalg.inv(fw)[:, 1, 0], np.linalg.inv(fw)[:, 0, 0])
        return p[:, :2], roll

    (actual, roll_a), (intended, roll_i) = path(video.frame_from_world), path(video.intended_frame_from_world)
    jitter = actual - intended
    # Magnitudes match the config (per-axis std in px, roll std in degrees).
    np.testing.assert_allclose(jitter.std(axis=0), cfg.jitter_px, rtol=0.05)
    assert math.degrees(float(np.std(roll_a - roll_i))) == pytest.approx(cfg.jitter_deg, rel=0.05)

    f = np.fft.rfftfreq(n, d=1.0 / fps)

    def hf_energy(x, lo=1.5):  # energy above lo Hz after removing the best quadratic (pan) and windowing
        tt = np.arange(len(x))
        x = (x - np.polyval(np.polyfit(tt, x, 2), tt)) * np.hanning(len(x))
        spec = np.abs(np.fft.rfft(x)) ** 2
        return float(spec[f >= lo].sum()), float(spec[1:].sum())

    for axis in range(2):
        hf_act, _ = hf_energy(actual[:, axis])
        hf_int, _ = hf_energy(intended[:, axis])
        assert hf_act > 1000.0 * hf_int, (axis, hf_act, hf_int)
        hf_j, total_j = hf_energy(jitter[:, axis], lo=1.0)
        assert hf_j > 0.85 * total_j  # the jitter lives above 1 Hz
        # Band-limited: little energy above 9 Hz (not white noise), and not frame-to-frame independent.
        spec = np.abs(np.fft.rfft(jitter[:, axis] - jitter[:, axis].mean())) ** 2
        assert spec[f > 9.0].sum() < 0.1 * spec.sum()
        assert np.corrcoef(jitter[1:, axis], jitter[:-1, axis])[0, 1] > 0.3
    # Intended motion is a smooth pan: velocity close to the configured pan rate.
    vel = np.diff(intended[:, 0])
    assert abs(vel.mean() - cfg.pan_px_per_frame) < 0.5


def test_intended_from_frame_stabilises(video: SyntheticVideo):
    """Warping frame t by intended_from_frame[t] gives the intended view, which is world truth everywhere."""
    t = 30  # not blurred
    assert t not in video.blurred
    v = video.intended_from_frame[t]
    truth = video.render_view(t, v)
    assert video.view_coverage(t, v).all()  # the margin makes the intended view all truth
    inside = video.frame_coverage(t, v)
    assert 0.6 < inside.mean() < 1.0  # part of the view lies outside the input frame: to be completed
    approx = warp(video.frames[t], v, (W, H))
    ok = _interior(8) & ~_dilate(~inside, 3)
    assert psnr(approx, truth, ok) > 30.0
    np.testing.assert_allclose(v @ video.frame_from_world[t], video.intended_frame_from_world[t], atol=1e-9)


# ---------------------------------------------------------------------- render_view / blur truth


def test_render_view_identity_is_the_sharp_frame(video: SyntheticVideo):
    for t in (0, video.blurred[0], 89):
        np.testing.assert_array_equal(video.render_view(t, np.eye(3)), video.sharp_frames[t])
    t = video.blurred[0]
    np.testing.assert_array_equal(video.render_view(t, np.eye(3), sharp=False), video.frames[t])


def test_render_view_outside_the_field_of_view(video: SyntheticVideo):
    """A view shifted by 40 px shows world content that frame t lacks; it agrees with the neighbouring frame
    that does see it."""
    t = 40
    shift = np.array([[1.0, 0, 40.0], [0, 1.0, 0], [0, 0, 1.0]])  # content moves right: new content on the left
    view = video.render_view(t, shift)
    assert video.view_coverage(t, shift).all()
    assert not video.frame_coverage(t, shift)[:, :30].any()
    # Same view from frame t-1's perspective: view_from_prev = shift @ curr_from_prev[t].
    from_prev = warp(video.sharp_frames[t - 1], shift @ video.curr_from_prev[t], (W, H))
    src_ok = _warp_mask(np.ones((H, W), bool), shift @ video.curr_from_prev[t])
    obj = _dilate(video.object_mask[t] | _warp_mask(video.object_mask[t - 1], video.curr_from_prev[t]), 4)
    obj = _warp_mask(obj, shift)
    ok = _interior(10) & ~_dilate(~src_ok, 2) & ~obj
    assert psnr(from_prev, view, ok) > 30.0


def test_blurred_frames_differ_from_sharp_ones(video: SyntheticVideo):
    blurred = set(video.blurred)
    for t in range(video.config.n_frames):
        if t in blurred:
            assert psnr(video.frames[t], video.sharp_frames[t]) < 35.0
            np.testing.assert_array_equal(video.frames[t], apply_blur(video.sharp_frames[t], video.blur_kernel))
            # Blur removes gradient energy.
            g_b = cv2.Laplacian(cv2.cvtColor(video.frames[t], cv2.COLOR_RGB2GRAY), cv2.CV_32F).var()
            g_s = cv2.Laplacian(cv2.cvtColor(video.sharp_frames[t], cv2.COLOR_RGB2GRAY), cv2.CV_32F).var()
            assert g_b < 0.5 * g_s
        else:
            np.testing.assert_array_equal(video.frames[t], video.sharp_frames[t])
    # The frame arrays are independent copies (modifying an input never alters the truth).
    assert not np.shares_memory(video.frames[0], video.sharp_frames[0])


def test_blur_kernel_geometry():
    k = motion_blur_kernel(12.0, 0.0)
    assert k.shape == (1, 13)
    np.testing.assert_allclose(k, k[:, ::-1], atol=1e-7)
    k = motion_blur_kernel(12.0, 90.0)
    assert k.shape == (13, 1)
    k = motion_blur_kernel(12.0, 20.0)
    np.testing.assert_allclose(k, k[::-1, ::-1], atol=1e-7)
    ys, xs = np.nonzero(k > 0.01)
    cy, cx = k.shape[0] // 2, k.shape[1] // 2
    # Principal direction of the support is 20 degrees (y down).
    cov = np.cov(np.stack([xs - cx, ys - cy]), aweights=k[ys, xs])
    evals, evecs = np.linalg.eigh(cov)
    d = evecs[:, -1]
    ang = math.degrees(math.atan2(d[1], d[0])) % 180.0
    assert ang == pytest.approx(20.0, abs=3.0)
    # Extent ~ length: second moment of a uniform segment of length L is L^2 / 12.
    assert math.sqrt(12 * evals[-1]) == pytest.approx(12.0, rel=0.1)
    assert motion_blur_kernel(0.0, 10.0).shape == (1, 1)


def test_blur_options():
    v = generate(SyntheticConfig(n_frames=6, blurred_frames=()))
    assert v.blurred == ()
    assert all(np.array_equal(a, b) for a, b in zip(v.frames, v.sharp_frames))
    v = generate(SyntheticConfig(n_frames=6, blurred_frames=(3, 1)))
    assert v.blurred == (1, 3)
    with pytest.raises(ValueError):
        generate(SyntheticConfig(n_frames=6, blurred_frames=(6,)))


# ---------------------------------------------------------------------- moving object


def test_object_moves_independently_of_the_camera(video: SyntheticVideo):
    areas = np.array([m.sum() for m in video.object_mask])
    r = video.config.object_radius_px
    visible = areas > 0.9 * math.pi * r * r
    assert visible.mean() > 0.8
    cents = np.array([np.argwhere(m).mean(axis=0)[::-1] for m in video.object_mask if m.sum() > 0])
    assert np.linalg.norm(cents[-1] - cents[0]) > 0.3 * W
    np.testing.assert_allclose(cents, video.object_center_frame[areas > 0], atol=1.5)
    # Its image motion is not the background motion: map the centre at t-1 with curr_from_prev[t].
    c = video.object_center_frame
    pred = (video.curr_from_prev[1:] @ np.concatenate([c[:-1], np.ones((len(c) - 1, 1))], axis=1)[..., None])[..., 0]
    err = np.linalg.norm(pred[:, :2] / pred[:, 2:3] - c[1:], axis=1)
    assert np.median(err) > 2.0
    # The object is distinct in colour: its pixels differ from the background world it covers.
    t = 45
    m = video.object_mask[t] & ~_dilate(~video.object_mask[t], 3)
    bg = cv2.warpAffine(video.world, video.frame_from_world[t][:2], (W, H), flags=cv2.INTER_CUBIC)
    diff = np.abs(video.sharp_frames[t].astype(float) - bg.astype(float)).mean(axis=2)
    assert diff[m].mean() > 40.0
    # Outside the object (plus interpolation support) the frame is exactly the background.
    away = ~_dilate(video.object_mask[t], 5)
    assert np.array_equal(video.sharp_frames[t][away], bg[away])


def test_no_object_option():
    v = generate(SyntheticConfig(n_frames=4, moving_object=False, blurred_frames=()))
    assert not any(m.any() for m in v.object_mask)
    np.testing.assert_array_equal(
        v.frames[2], cv2.warpAffine(v.world, v.frame_from_world[2][:2], (W, H), flags=cv2.INTER_CUBIC)
    )


# ---------------------------------------------------------------------- other configs, I/O, two frames


@pytest.mark.parametrize("image", ["astronaut", "rocket", "chelsea"])
def test_other_images_and_sizes(image):
    cfg = SyntheticConfig(image=image, width=320, height=240, n_frames=8, jitter_px=10.0, jitter_deg=2.0)
    v = generate(cfg)
    assert v.frames[0].shape == (240, 320, 3)
    assert all(v.view_coverage(t, np.eye(3)).all() for t in range(8))


def test_write_video_round_trip(tmp_path):
    av = pytest.importorskip("av")
    v = generate(SyntheticConfig(n_frames=5, width=160, height=96))
    path = tmp_path / "clip.mp4"
    write_video(v, path)
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        assert s.codec_context.name in ("h264", "libx264")
        assert float(s.average_rate) == pytest.approx(30.0)
        got = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(got) == 5
    assert got[0].shape == (96, 160, 3)
    # yuv420p halves chroma resolution: compare luma, which crf 12 keeps nearly intact.
    def luma(x):
        return cv2.cvtColor(x, cv2.COLOR_RGB2GRAY)

    assert psnr(luma(got[0]), luma(v.frames[0])) > 38.0
    assert psnr(got[-1], v.frames[-1]) > 25.0


@pytest.mark.parametrize(
    "transform",
    [
        np.array([[1, 0, 7.3], [0, 1, -4.6], [0, 0, 1.0]]),
        np.array([[math.cos(0.03), -math.sin(0.03), 12.0], [math.sin(0.03), math.cos(0.03), 3.0], [0, 0, 1.0]]),
        np.array([[1.02, 0.01, -5.0], [-0.015, 0.99, 8.0], [0, 0, 1.0]]),
        np.array([[1.0, 0.02, -4.0], [0.01, 1.0, 2.0], [2e-5, -1e-5, 1.0]]),
    ],
)
def test_make_two_frames_related_by_transform(transform):
    f0, f1 = make_two_frames(transform, size=(W, H), seed=1)
    assert f0.shape == f1.shape == (H, W, 3) and f0.dtype == np.uint8
    pred = warp(f0, transform, (W, H))
    valid = _interior(16) & _warp_mask(np.ones((H, W), bool), transform)
    valid = valid & ~_dilate(~valid, 3)
    assert psnr(pred, f1, valid) > 30.0
    assert psnr(f0, f1, _interior(16)) < psnr(pred, f1, valid) - 8.0
    # Deterministic.
    g0, g1 = make_two_frames(transform, size=(W, H), seed=1)
    np.testing.assert_array_equal(f0, g0)
    np.testing.assert_array_equal(f1, g1)
