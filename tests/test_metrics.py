"""pipeline.evaluation.metrics: cropping, distortion, black borders, stability and residual jitter.

Synthetic videos are rendered in-test from a real photo (skimage's coffee: textured, almost no black
pixels) by known camera transforms and written losslessly (FFV1, RGB) so codec noise does not blur
the expected values.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
import skimage.data

from pipeline.evaluation import metrics
from pipeline.errors import InputError
from tests.conftest import real_clip

W, H = 320, 240
FPS = 30


@pytest.fixture(scope="module")
def photo() -> np.ndarray:
    return skimage.data.coffee()  # 400 x 600 RGB


def _shift(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def _about_centre(sx: float, sy: float) -> np.ndarray:
    """Output pixel -> input pixel for an output that shows the input scaled by (sx, sy) about its centre."""
    cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    return _shift(cx, cy) @ np.diag([1.0 / sx, 1.0 / sy, 1.0]) @ _shift(-cx, -cy)


def _render(photo: np.ndarray, frame_to_photo: np.ndarray) -> np.ndarray:
    return cv2.warpPerspective(photo, frame_to_photo, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)


def _pan(n: int, vx: float = 0.8, vy: float = 0.3, x0: float = 90.0, y0: float = 60.0) -> list[np.ndarray]:
    return [_shift(x0 + vx * t, y0 + vy * t) for t in range(n)]


def _write(path, frames, fps: int = FPS, *, turned: bool = False):
    """Lossless FFV1 in MKV. ``turned``: store each frame turned 90 degrees counterclockwise, tagged
    "turn 90 degrees clockwise to display" (a phone held upright), so a reader that honours the tag
    gets ``frames`` back."""
    if turned:
        frames = [np.rot90(rgb, k=1) for rgb in frames]
    container = av.open(str(path), "w")
    stream = container.add_stream("ffv1", rate=fps)
    stream.width, stream.height = frames[0].shape[1], frames[0].shape[0]
    stream.pix_fmt = "bgr0"  # lossless RGB
    if turned:
        stream.set_display_rotation(-90)  # FFmpeg's display matrix counts counterclockwise
    for rgb in frames:
        for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()
    return path


def _pair_of_videos(tmp_path, photo, n: int, output_from_input) -> tuple:
    """Input = a slow pan over the photo; output frame t = the input frame t seen through output_from_input(t)."""
    path = _pan(n)
    inp = [_render(photo, A) for A in path]
    out = [_render(photo, A @ output_from_input(t)) for t, A in enumerate(path)]
    return _write(tmp_path / "in.mkv", inp), _write(tmp_path / "out.mkv", out)


# ---------------------------------------------------------------------------------------------
# Reading


def test_metrics_read_only_through_video_reader():
    # video_reader applies the rotation tag and stands in for undecodable frames; reading PyAV directly
    # here would skip both (a tagged phone clip read sideways).
    source = Path(metrics.__file__).read_text()
    assert "import av" not in source and "av.open" not in source


def test_rotation_tag_is_honoured(tmp_path, photo):
    # The same pictures stored upright and stored turned with a rotation tag give the same measures,
    # also when only the input carries the tag (a phone clip and the stabilizer's untagged output).
    path = _pan(24)
    jitter = np.random.default_rng(3).normal(0, 1.5, (len(path), 2))
    inp = [_render(photo, A) for A in path]
    out = [_render(photo, A @ _shift(jx, jy) @ _about_centre(1.2, 1.1)) for A, (jx, jy) in zip(path, jitter)]
    upright = metrics.compare(_write(tmp_path / "in.mkv", inp), _write(tmp_path / "out.mkv", out))
    turned_in = _write(tmp_path / "in_turned.mkv", inp, turned=True)
    for output in (_write(tmp_path / "out_turned.mkv", out, turned=True), tmp_path / "out.mkv"):
        r = metrics.compare(turned_in, output)
        assert r.n_frames == upright.n_frames and r.failed_pairs == upright.failed_pairs == 0
        for key in ("distortion", "distortion_mean", "cropping_ratio", "stability_translation",
                    "stability_rotation"):
            assert getattr(r, key) == pytest.approx(getattr(upright, key), abs=0.02), (output.name, key)
        assert r.input.stability_translation == pytest.approx(upright.input.stability_translation, abs=0.02)
    assert upright.distortion == pytest.approx(1.1 / 1.2, abs=0.02)  # the measures are the expected ones
    assert upright.cropping_ratio == pytest.approx(1 / math.sqrt(1.2 * 1.1), abs=0.02)
    stats = metrics.video_motion_stats(turned_in)
    assert stats.stability_translation == pytest.approx(upright.input.stability_translation, abs=0.02)


def test_unreadable_inputs_raise_input_error(tmp_path):
    with pytest.raises(InputError) as info:
        metrics.video_motion_stats(tmp_path / "missing.mp4")
    assert "missing.mp4" in str(info.value)
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"this is not a video" * 100)
    with pytest.raises(InputError) as info:
        metrics.compare(junk, junk)
    assert "\n" not in str(info.value) and "junk.mp4" in str(info.value)
    with pytest.raises(InputError, match="no video stream"):
        metrics.video_motion_stats(_write_audio_only(tmp_path / "audio.mka"))


def _write_audio_only(path):
    with av.open(str(path), "w") as container:
        stream = container.add_stream("pcm_s16le", rate=8000, layout="mono")
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 800), np.int16), format="s16", layout="mono")
        frame.sample_rate = 8000
        for packet in stream.encode(frame):
            container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
    return path


def test_mismatched_frame_counts_raise_input_error(tmp_path, photo):
    frames = [_render(photo, A) for A in _pan(8)]
    a = _write(tmp_path / "a.mkv", frames)
    b = _write(tmp_path / "b.mkv", frames[:6])
    with pytest.raises(InputError, match="input has 8 frames, output has 6"):
        metrics.compare(a, b)


# ---------------------------------------------------------------------------------------------
# Pairwise homography and per-frame measures


def test_pair_homography_recovers_a_known_warp(photo):
    a = _render(photo, _shift(100, 80))
    truth = np.linalg.inv(_about_centre(1.1, 1.1)) @ _shift(2.3, -1.7)  # b ~ truth a
    b = cv2.warpPerspective(a, truth, (W, H), flags=cv2.INTER_LINEAR)
    est = metrics.pair_homography(a, b)
    assert est is not None
    pts = np.float32([[80, 60], [240, 60], [240, 180], [80, 180]]).reshape(-1, 1, 2)
    err = np.abs(cv2.perspectiveTransform(pts, est) - cv2.perspectiveTransform(pts, truth)).max()
    assert err < 0.3


def test_pair_homography_fails_on_featureless_frames(photo):
    grey = np.full((H, W, 3), 128, np.uint8)
    assert metrics.pair_homography(grey, grey) is None
    assert metrics.pair_homography(_render(photo, _shift(100, 80)), np.zeros((H, W, 3), np.uint8)) is None


def test_per_frame_cropping_and_distortion_formulas():
    assert metrics.frame_cropping(np.diag([1.25, 1.25, 1.0])) == pytest.approx(0.8)
    assert metrics.frame_cropping(np.diag([0.8, 0.8, 1.0])) == 1.0  # zoomed out: clipped to 1
    rot = cv2.getRotationMatrix2D((0, 0), 30, 1.25)
    assert metrics.frame_cropping(np.vstack([rot, [0, 0, 1]])) == pytest.approx(0.8)  # rotation does not count
    assert metrics.frame_distortion(np.diag([1.0, 1.2, 1.0])) == pytest.approx(1 / 1.2)
    assert metrics.frame_distortion(np.vstack([rot, [0, 0, 1]])) == pytest.approx(1.0)


# ---------------------------------------------------------------------------------------------
# compare(): cropping, distortion (a, b, c, f)


def test_identical_output_scores_no_crop_no_distortion(tmp_path, photo):
    inp, out = _pair_of_videos(tmp_path, photo, 20, lambda t: np.eye(3))
    calls = []
    r = metrics.compare(inp, out, progress=lambda done, total: calls.append((done, total)))
    assert r.n_frames == 20 and r.failed_pairs == 0 and r.input.failed_pairs == 0
    assert r.cropping_ratio == pytest.approx(1.0, abs=0.01)
    assert r.distortion == pytest.approx(1.0, abs=0.01)
    assert r.distortion_mean == pytest.approx(1.0, abs=0.01)
    assert r.black_fraction == 0.0
    assert calls[-1][0] == 20 and [c[0] for c in calls] == list(range(1, 21))
    # the output is the input: its motion stats are the input's
    assert r.residual_jitter_px == pytest.approx(r.input.residual_jitter_px, abs=1e-6)
    assert r.stability_translation == pytest.approx(r.input.stability_translation, abs=1e-6)
    d = r.to_dict()
    json.dumps(d, allow_nan=False)
    assert d["input"]["n_frames"] == 20 and "cropping_ratio" in d


def test_zoomed_output_crops_to_0_8(tmp_path, photo):
    inp, out = _pair_of_videos(tmp_path, photo, 16, lambda t: _about_centre(1.25, 1.25))
    r = metrics.compare(inp, out)
    assert r.failed_pairs == 0
    assert r.cropping_ratio == pytest.approx(0.8, abs=0.02)
    assert r.distortion == pytest.approx(1.0, abs=0.02)


def test_anisotropic_output_gives_distortion(tmp_path, photo):
    inp, out = _pair_of_videos(tmp_path, photo, 16, lambda t: _about_centre(1.0, 1.2))
    r = metrics.compare(inp, out)
    assert r.distortion == pytest.approx(1 / 1.2, abs=0.02)
    assert r.distortion_mean == pytest.approx(1 / 1.2, abs=0.02)
    assert r.cropping_ratio == pytest.approx(1 / math.sqrt(1.2), abs=0.02)


def test_cropping_is_not_reinverted_each_frame(tmp_path, photo):
    # Regression: the DIFRINT script re-inverts its running sequence every frame. Odd frames zoomed
    # by 1.25 (0.8) and even ones not (1.0) must average 0.9, not drift to something else.
    inp, out = _pair_of_videos(tmp_path, photo, 16, lambda t: _about_centre(1.25, 1.25) if t % 2 else np.eye(3))
    r = metrics.compare(inp, out)
    assert r.cropping_ratio == pytest.approx(0.9, abs=0.02)


# ---------------------------------------------------------------------------------------------
# Black borders (e)


def test_black_fraction_counts_border_black_only():
    frame = np.full((100, 200, 3), 120, np.uint8)
    frame[:, :20] = 0  # left band touching the border: 2000 px
    frame[:, -10:] = (7, 3, 0)  # right band, within the black level (codec noise): 1000 px
    frame[40:60, 90:110] = 0  # dark content inside the picture: not counted
    assert metrics.black_fraction(frame) == pytest.approx(3000 / 20000)
    frame[0, 50] = (0, 8, 0)  # one channel above the level: not black
    assert metrics.black_fraction(frame) == pytest.approx(3000 / 20000)
    assert metrics.black_fraction(frame, level=3) == pytest.approx(2000 / 20000)
    assert metrics.black_fraction(np.zeros((10, 10, 3), np.uint8)) == 1.0


def test_output_with_black_borders(tmp_path, photo):
    left, top = 24, 16

    def with_borders(rgb):
        rgb = rgb.copy()
        rgb[:, :left] = 0
        rgb[:top, :] = 0
        rgb[100:130, 150:190] = 0  # a dark object in the picture, not touching the border
        return rgb

    frames = [_render(photo, A) for A in _pan(10)]
    inp = _write(tmp_path / "in.mkv", frames)
    out = _write(tmp_path / "out.mkv", [with_borders(f) for f in frames])
    r = metrics.compare(inp, out)
    expected = (left * H + top * (W - left)) / (W * H)
    assert r.black_fraction == pytest.approx(expected, abs=0.01)
    assert r.cropping_ratio == pytest.approx(1.0, abs=0.01)


# ---------------------------------------------------------------------------------------------
# Stability and residual jitter (d)


def test_residual_jitter_ignores_a_constant_velocity_pan():
    t = np.arange(120, dtype=float)
    traj = np.stack([3.0 * t, -1.5 * t, 0.002 * t], axis=1)
    px, deg = metrics.residual_jitter(traj, 30)
    assert px < 1e-9 and deg < 1e-9  # odd-reflection padding: no end effects


def test_residual_jitter_measures_white_jitter():
    rng = np.random.default_rng(1)
    jitter = rng.normal(0, 2.0, (300, 2))
    traj = np.zeros((300, 3))
    traj[:, :2] = jitter + np.arange(300)[:, None] * 0.5
    px, _ = metrics.residual_jitter(traj, 30)
    injected = math.sqrt(np.mean(np.sum(jitter**2, axis=1)))
    assert px == pytest.approx(injected, rel=0.05)


def test_residual_jitter_end_frame_shake_counts_like_any_other():
    # one shaken frame at the very end must weigh like one in the middle: the end padding is anchored
    # on a fitted line, not on the (shaken) end sample itself
    base = np.zeros((150, 3))
    base[:, 0] = 0.7 * np.arange(150)
    middle, end = base.copy(), base.copy()
    middle[75, :2] += (4.0, -3.0)
    end[0, :2] += (4.0, -3.0)
    px_middle, _ = metrics.residual_jitter(middle, 30)
    px_end, _ = metrics.residual_jitter(end, 30)
    assert px_middle == pytest.approx(5.0 / math.sqrt(150), rel=0.05)
    assert px_end == pytest.approx(px_middle, rel=0.15)


def test_stability_score_prefers_low_frequency_paths():
    t = np.arange(200, dtype=float)
    xs, angles = 10 * np.sin(2 * np.pi * t / 400), 0.05 * np.sin(2 * np.pi * t / 300)
    smooth = [np.array([[math.cos(a), -math.sin(a), x], [math.sin(a), math.cos(a), 0.5 * x], [0, 0, 1]])
              for x, a in zip(xs, angles)]
    rng = np.random.default_rng(2)
    shaky = [P @ np.vstack([cv2.getRotationMatrix2D((0, 0), rng.normal(0, 1.0), 1.0), [0, 0, 1]])
             @ _shift(rng.normal(0, 3), rng.normal(0, 3)) for P in smooth]
    st_s, sr_s = metrics.stability_score(smooth)
    st_j, sr_j = metrics.stability_score(shaky)
    assert st_s > 0.95 and sr_s > 0.95
    assert st_j < st_s - 0.3
    assert sr_j < sr_s - 0.2
    assert metrics.stability_score([np.eye(3)] * 10) == (1.0, 1.0)  # no motion at all
    assert all(math.isnan(v) for v in metrics.stability_score([np.eye(3)]))


def test_accumulate_path_composes_on_the_left():
    a, b = _shift(1, 0), np.diag([2.0, 2.0, 1.0])
    P = metrics.accumulate_path([a, None, b])
    assert np.allclose(P[0], a) and np.allclose(P[1], a) and np.allclose(P[2], b @ a)


def test_jittered_video_vs_smooth_video(tmp_path, photo):
    n = 90
    rng = np.random.default_rng(7)
    jitter = rng.normal(0, 1.5, (n, 2))
    # a slow drift: the Liu stability score is dominated by the largest low-frequency motion, so a
    # fast pan would hide the jitter from it (residual_jitter_px does not have that weakness)
    smooth = _pan(n, vx=0.1, vy=0.0)
    shaky = [A @ _shift(jx, jy) for A, (jx, jy) in zip(smooth, jitter)]
    smooth_path = _write(tmp_path / "smooth.mkv", [_render(photo, A) for A in smooth])
    shaky_path = _write(tmp_path / "shaky.mkv", [_render(photo, A) for A in shaky])

    s = metrics.video_motion_stats(smooth_path)
    j = metrics.video_motion_stats(shaky_path)
    injected = math.sqrt(np.mean(np.sum(jitter**2, axis=1)))
    assert s.n_frames == n and s.failed_pairs == 0 and j.failed_pairs == 0
    assert s.residual_jitter_px < 0.3
    assert j.residual_jitter_px == pytest.approx(injected, rel=0.25)
    assert s.residual_jitter_deg < 0.2 and j.residual_jitter_deg < 0.2  # no rotation injected
    assert s.stability_translation > j.stability_translation + 0.15


def test_a_jump_that_cannot_be_camera_motion_fails_instead_of_counting_as_shake(tmp_path, photo):
    path = _pan(30, vx=0.2, vy=0.0)
    cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    turned = _shift(cx, cy) @ np.vstack([cv2.getRotationMatrix2D((0, 0), 90, 1.0), [0, 0, 1]]) @ _shift(-cx, -cy)
    path[12] = path[12] @ turned  # one frame shows the scene turned by 90 degrees (like a cut)
    stats = metrics.video_motion_stats(_write(tmp_path / "cut.mkv", [_render(photo, A) for A in path]))
    assert stats.failed_pairs == 2  # 11 -> 12 and 12 -> 13
    assert stats.residual_jitter_deg < 0.2
    assert stats.residual_jitter_px < 0.3


def test_featureless_frames_are_counted_as_failed(tmp_path, photo):
    path = _pan(14)
    inp = [_render(photo, A) for A in path]
    out = [f.copy() for f in inp]
    for t in (5, 6, 7):
        out[t][:] = 0  # black frames: nothing to match
    r = metrics.compare(_write(tmp_path / "in.mkv", inp), _write(tmp_path / "out.mkv", out))
    # 3 input-output pairs and the 4 output pairs touching a black frame (4-5, 5-6, 6-7, 7-8)
    assert r.failed_pairs == 3 + 4
    assert r.input.failed_pairs == 0
    assert r.cropping_ratio == pytest.approx(1.0, abs=0.01)
    assert r.black_fraction == pytest.approx(3 / 14, abs=1e-9)


# ---------------------------------------------------------------------------------------------
# Real clip


@pytest.mark.real_video
def test_real_clip_against_itself():
    clip = real_clip("sudheerachary_small-shaky-5.avi")
    r = metrics.compare(clip, clip)
    assert r.n_frames > 100
    assert r.cropping_ratio == pytest.approx(1.0, abs=0.01)
    assert r.distortion == pytest.approx(1.0, abs=0.02)
    assert r.black_fraction < 0.01
    stats = metrics.video_motion_stats(clip)
    assert stats.residual_jitter_px > 0.5  # it is shaky
    assert stats.residual_jitter_px == pytest.approx(r.input.residual_jitter_px, rel=1e-6)
    assert stats.residual_jitter_px == pytest.approx(r.residual_jitter_px, rel=1e-6)


# ---------------------------------------------------------------------------------------------
# Flicker of synthesized pixels


def _completed_pair(tmp_path, photo, flicker: float, n: int = 30, zoom: float = 0.88, noise: float = 3.0) -> tuple:
    """A shaky input and a full-frame "stabilized" output of it with known real and synthesized areas.

    The output pans over the photo by whole pixels; input frame t is the output's view shrunk by ``zoom``
    about the centre and shifted by a random jitter, so it covers the output's centre and the rest of the
    output (about 1 - zoom^2 of it) is synthesized, here by the true photo. Every output frame gets fresh
    Gaussian noise (sigma ``noise``, so the real area changes too); the synthesized area also gets a per-frame
    offset of +-``flicker`` grey levels (random sign).
    """
    rng = np.random.default_rng(11)
    inp, out = [], []
    for t in range(n):
        view = _shift(90.0 + t, 60.0)  # output pixel -> photo
        jx, jy = np.clip(rng.normal(0, 3.0, 2), -6, 6)
        out_from_in = _shift(jx, jy) @ np.linalg.inv(_about_centre(zoom, zoom))
        inp.append(_render(photo, view @ out_from_in))
        real = cv2.warpPerspective(np.ones((H, W), np.uint8), out_from_in, (W, H), flags=cv2.INTER_NEAREST) > 0
        frame = _render(photo, view).astype(np.float64) + rng.normal(0, noise, (H, W, 1))
        frame[~real] += flicker * rng.choice([-1.0, 1.0])
        out.append(np.clip(np.round(frame), 0, 255).astype(np.uint8))
    return _write(tmp_path / "in.mkv", inp), _write(tmp_path / f"out{flicker:g}.mkv", out)


def test_flicker_ratio_separates_flickering_from_steady_synthesized_areas(tmp_path, photo):
    steady = metrics.compare(*_completed_pair(tmp_path, photo, flicker=0.0))
    flickering = metrics.compare(*_completed_pair(tmp_path, photo, flicker=10.0))
    for r in (steady, flickering):
        assert r.synth_flicker_pairs >= 25  # of 29: every pair has about 22 % synthesized pixels
        assert 2.5 < r.real_change_mean < 5.0  # the noise: E|N(0, 3 sqrt 2)| = 3.4, plus alignment error
    assert steady.synth_flicker_ratio <= 1.2
    assert flickering.synth_flicker_ratio > 1.5
    assert flickering.synth_change_mean > 8.0  # half the pairs change sign: 20 levels, the others about 3.4
    assert flickering.to_dict()["synth_flicker_ratio"] == pytest.approx(flickering.synth_flicker_ratio)


def test_flicker_ratio_is_none_without_synthesized_pixels(tmp_path, photo, capsys):
    from ffviz.cli import main

    inp, out = _pair_of_videos(tmp_path, photo, 12, lambda t: _about_centre(1.25, 1.25))  # a crop
    r = metrics.compare(inp, out)
    assert r.synth_flicker_pairs == 0
    assert all(math.isnan(v) for v in (r.synth_flicker_ratio, r.synth_change_mean, r.real_change_mean))
    d = r.to_dict()
    assert d["synth_flicker_ratio"] is None and d["synth_change_mean"] is None and d["real_change_mean"] is None
    json.dumps(d)
    assert main(["metrics", str(inp), str(out)]) == 0
    row = [line for line in capsys.readouterr().out.splitlines() if line.startswith("synthesized-pixel flicker")]
    assert len(row) == 1 and row[0].split()[-1] == "-"


def test_synthesized_labels_and_change_on_known_frames():
    shape = (60, 80)
    labels = metrics.synthesized_labels(_shift(10, 0), shape, seam_px=2)  # input covers columns 10..79
    assert (labels[:, :8] == metrics.LABEL_SYNTH).all() and (labels[:, 12:] == metrics.LABEL_REAL).all()
    assert (labels[:, 8:12] == metrics.LABEL_SEAM).all()  # 2 px either side of the outline
    assert (metrics.synthesized_labels(np.eye(3), shape) == metrics.LABEL_REAL).all()
    rng = np.random.default_rng(3)
    prev = rng.integers(0, 200, shape, dtype=np.uint8)
    cur = prev.copy()
    cur[:, :8] += 20  # the synthesized strip changes by 20, the real area not at all
    ss, sn, rs, rn = metrics.synthesized_change(prev, labels, cur, labels, np.eye(3))
    assert sn == 60 * 8 and ss == pytest.approx(20 * sn)
    assert rn == 60 * (80 - 12) and rs == 0.0


@pytest.mark.parametrize("shift_px, counted", [(4, False), (30, True)])
def test_a_sliver_within_the_fits_tolerance_is_not_a_synthesized_area(shift_px, counted):
    """A crop's window touches the warped input at its tightest frame, so an H fitted a few pixels off puts a sliver
    of 'synthesized' pixels along the edge: 4 px at 320x180 (SIFT's RANSAC tolerance is 3 px) leaves two columns
    beyond the 2 px seam, 360 pixels, over the 0.5 % a pair needs. It must not give a crop a flicker figure, while a
    30 px strip (a real uncovered border) still does."""
    shape = (180, 320)
    rng = np.random.default_rng(1)
    tally = metrics._FlickerTally(metrics.MetricsConfig())
    for _ in range(3):
        tally.add(rng.integers(0, 255, shape, dtype=np.uint8), _shift(shift_px, 0), np.eye(3))
    ratio, synth, real = tally.result()
    assert (tally.pairs == 2 and np.isfinite(ratio) and synth > 0) if counted else (tally.pairs == 0 and np.isnan(ratio))
