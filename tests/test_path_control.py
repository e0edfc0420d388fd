"""Path control (issue 25) on synthetic ground truth: smoothness strengths per axis, the departure bound, path
segments switching at the right frame without a jump, and the adaptive crop against the fixed one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline import geometry
from pipeline.errors import ConfigError
from pipeline.evaluation.synthetic import SyntheticConfig, generate
from pipeline.stages import adaptive_crop, path_control, smoothing, warping

W, H = 640, 360
STRENGTHS = (0, 25, 50, 75, 100)


@pytest.fixture(scope="module")
def clip():
    return generate(SyntheticConfig(n_frames=90, moving_object=False, blurred_frames=(), seed=11,
                                    jitter_scale=0.02))


def output_in_world(video, orig_from_stab, first: int = 0) -> np.ndarray:
    """(N, 4): where each output frame's centre lies in the world (x, y), its roll (rad) and log zoom; the
    transforms are those of frames ``first``, ``first + 1``, ..."""
    rows = []
    for i, s_t in enumerate(orig_from_stab):
        world_from_stab = np.linalg.inv(video.frame_from_world[first + i]) @ s_t
        x, y, angle, scale = geometry.decompose(world_from_stab, W, H)
        rows.append((x, y, math.radians(angle), math.log(scale)))
    return np.array(rows)


def shake(video, orig_from_stab) -> np.ndarray:
    """Roughness of the output's path in the world per axis (translation px, roll rad, log zoom): Grundmann et
    al.'s measure, the mean of 10 |D P| + |D^2 P| + 100 |D^3 P| (x and y summed). Lower is smoother; 0 is still."""
    path = output_in_world(video, orig_from_stab)
    cost = sum(w * np.abs(np.diff(path, k, axis=0)).mean(axis=0) for k, w in ((1, 10.0), (2, 1.0), (3, 100.0)))
    return np.array([cost[0] + cost[1], cost[2], cost[3]])


@pytest.mark.parametrize("path", ["gaussian", "l1"])
@pytest.mark.parametrize("axis", range(3))
def test_each_smoothness_strength_gives_a_smoother_path_on_its_axis_only(clip, path, axis):
    name = path_control.AXES[axis]
    shakes = []
    for strength in STRENGTHS:
        smoothness = path_control.Smoothness(**{name: float(strength)})
        result = smoothing.smooth(clip.curr_from_prev, smoothing.SmoothingConfig(path=path, smoothness=smoothness),
                                  width=W, height=H)
        shakes.append(shake(clip, result.orig_from_stab))
    shakes = np.array(shakes)  # (strengths, axes)
    # Strength 0 follows the input on that axis: the input's own shake.
    assert shakes[0, axis] == pytest.approx(shake(clip, np.broadcast_to(np.eye(3), (90, 3, 3)))[axis], rel=0.05)
    # Monotonically smoother (strictly, until the L1 path is still), and by far in the end.
    roughness = shakes[:, axis]
    assert np.all((np.diff(roughness) < 0) | (roughness[1:] < 1e-9)), roughness
    assert roughness[-1] < 0.02 * roughness[0]
    # The other axes stay where the default strength puts them.
    others = [a for a in range(3) if a != axis]
    np.testing.assert_allclose(shakes[:, others], np.broadcast_to(shakes[2, others], (5, 2)), rtol=0.1, atol=1e-6)


def test_smoothness_50_is_the_default_path(clip):
    default = smoothing.smooth(clip.curr_from_prev, smoothing.SmoothingConfig(), width=W, height=H)
    fifty = smoothing.smooth(clip.curr_from_prev, smoothing.SmoothingConfig(smoothness=path_control.Smoothness()),
                             width=W, height=H)
    np.testing.assert_allclose(fifty.orig_from_stab, default.orig_from_stab, atol=1e-9)


def test_smoothness_and_segments_parse_and_refuse_in_one_line():
    assert path_control.Smoothness.parse("70") == path_control.Smoothness(70, 70, 70)
    assert path_control.Smoothness.parse("t=70,r=90") == path_control.Smoothness(70, 90, 50)
    segment = path_control.PathSegment.parse("5-:gaussian:t=80,z=20")
    assert (segment.start_s, segment.end_s, segment.path) == (5.0, None, "gaussian")
    assert segment.smoothness == path_control.Smoothness(80, 50, 20)
    assert path_control.PathSegment.parse("-2.5:tripod") == path_control.PathSegment(0.0, 2.5, "tripod")
    for bad in ("101", "x=3", "t=", "abc"):
        with pytest.raises(ConfigError):
            path_control.Smoothness.parse(bad)
    for bad in ("5:tripod", "0-5", "5-2:l1", "0-5:tripod:80"):
        with pytest.raises(ConfigError):
            path_control.PathSegment.parse(bad)
    with pytest.raises(ConfigError, match="overlap"):
        smoothing.SmoothingConfig(segments=(path_control.PathSegment.parse("0-5:tripod"),
                                            path_control.PathSegment.parse("4-:l1")))
    with pytest.raises(ConfigError, match="must be one of"):
        smoothing.SmoothingConfig(segments=(path_control.PathSegment.parse("0-5:dolly"),))


@pytest.mark.parametrize("path", ["gaussian", "l1", "tripod"])
def test_the_departure_bound_holds_on_every_path(path):
    video = generate(SyntheticConfig(n_frames=90, moving_object=False, blurred_frames=(), seed=2, jitter_px=10,
                                     jitter_deg=2.0))
    free = smoothing.smooth(video.curr_from_prev, smoothing.SmoothingConfig(path=path), width=W, height=H)
    bounded = smoothing.smooth(video.curr_from_prev,
                               smoothing.SmoothingConfig(path=path, max_shift=4.0, max_angle=0.5), width=W, height=H)

    def departures(result):
        return np.array([geometry.decompose(s, W, H)[:3] for s in result.orig_from_stab])

    # Without the bound the path goes further (the case has teeth); with it, never.
    assert np.abs(departures(free)[:, :2]).max() > 6.0 and np.abs(departures(free)[:, 2]).max() > 0.8
    within = np.abs(departures(bounded))
    assert within[:, :2].max() <= 4.0 + 1e-6 and within[:, 2].max() <= 0.5 + 1e-6
    # And it still stabilizes, within the bound: steadier than the input.
    identity = np.broadcast_to(np.eye(3), (90, 3, 3))
    assert shake(video, bounded.orig_from_stab)[0] < 0.9 * shake(video, identity)[0]


def test_segments_switch_at_the_right_frame_without_a_jump():
    """Tripod for the first 2 s, eq. 18 after: held through the switch frame, then exactly each setting's own plan
    (the tripod's before, eq. 18's once the ease is over), and no step at the switch larger than the path's
    steps elsewhere; a hard switch would jump."""
    video = generate(SyntheticConfig(n_frames=150, moving_object=False, blurred_frames=(), seed=3,
                                     pan_px_per_frame=0.6))
    times = np.arange(150) / 30.0
    config = smoothing.SmoothingConfig(segments=(path_control.PathSegment.parse("0-2:tripod"),))
    result = smoothing.smooth(video.curr_from_prev, config, width=W, height=H, times_s=times)
    switch, blend = 60, path_control.blend_frames(times)
    tripod = smoothing.smooth(video.curr_from_prev[:switch + 1], smoothing.SmoothingConfig(path="tripod"),
                              width=W, height=H)
    after = video.curr_from_prev[switch - 1:].copy()
    after[0] = np.eye(3)
    gaussian = smoothing.smooth(after, smoothing.SmoothingConfig(), width=W, height=H)
    np.testing.assert_allclose(result.orig_from_stab[:switch + 1], tripod.orig_from_stab, atol=1e-9)
    np.testing.assert_allclose(result.orig_from_stab[switch + blend:], gaussian.orig_from_stab[1 + blend:],
                               atol=1e-9)
    centre = output_in_world(video, result.orig_from_stab)[:, :2]
    steps = np.linalg.norm(np.diff(centre, axis=0), axis=1)
    assert steps[:switch].max() < 0.3  # held still up to the switch frame
    assert steps[switch:switch + blend + 10].mean() > 0.3  # and panning after it
    later = output_in_world(video, gaussian.orig_from_stab, switch - 1)[:, :2]
    assert steps[switch - 3:switch + 3].max() <= np.linalg.norm(np.diff(later, axis=0), axis=1).max() + 0.1
    # A hard switch (each setting's own S_t at the switch frame) would jump by this much.
    hard = np.linalg.norm(centre[switch] - later[1])
    assert hard > 3 * steps[switch - 3:switch + 3].max()


def test_segments_need_frame_times():
    with pytest.raises(ConfigError, match="times_s"):
        smoothing.smooth(np.broadcast_to(np.eye(3), (10, 3, 3)),
                         smoothing.SmoothingConfig(segments=(path_control.PathSegment.parse("0-1:l1"),)))


def corner_jitter(video, orig_from_out) -> float:
    """Residual jitter of the output's four corners, in output px (zoom changes count as motion): the accumulated
    inter-frame motion of the output minus its Gaussian low-pass (sigma 0.5 s), RMS (docs/metrics.md's residual
    jitter, at the corners)."""
    from scipy.ndimage import gaussian_filter1d

    corners = geometry.frame_corners(W, H)
    steps = [np.zeros((4, 2))]
    for t in range(1, video.n_frames):
        out_from_prev_out = (np.linalg.inv(orig_from_out[t]) @ video.frame_from_world[t]
                             @ np.linalg.inv(video.frame_from_world[t - 1]) @ orig_from_out[t - 1])
        steps.append(geometry.apply(out_from_prev_out, corners) - corners)
    track = np.cumsum(steps, axis=0)
    residual = track - gaussian_filter1d(track, 15, axis=0, mode="nearest")
    return float(np.sqrt((residual**2).sum(axis=-1).mean()))


def test_adaptive_crop_keeps_more_than_the_fixed_crop_at_no_more_jitter_and_no_black_pixel():
    video = generate(SyntheticConfig(n_frames=240, moving_object=False, blurred_frames=(), seed=6, jitter_px=8,
                                     jitter_envelope=(0.1, 1.0)))  # calm first half, shaky second
    path = smoothing.smooth(video.curr_from_prev, smoothing.SmoothingConfig(), width=W, height=H)
    fixed = warping.largest_crop(path.orig_from_stab, W, H)
    adaptive = adaptive_crop.adaptive_crop(path.orig_from_stab, W, H)
    fixed_out = path.orig_from_stab @ fixed.stab_from_out
    adaptive_out = path.orig_from_stab @ adaptive.stab_from_out
    assert adaptive.cropping_ratio > fixed.cropping_ratio + 0.03
    # The zoom follows the shake: wider in the calm half than in the shaky one, changing at the bounded rate.
    assert adaptive.scales[:90].mean() > adaptive.scales[150:].mean() + 0.03
    assert np.abs(np.diff(adaptive.scales)).max() <= adaptive_crop.DEFAULT_ZOOM_SPEED / 100 + 1e-12
    assert corner_jitter(video, adaptive_out) <= corner_jitter(video, fixed_out)
    for t in range(video.n_frames):
        assert not warping.warp_frame(video.frames[t], adaptive_out[t]).missing.any(), t
    # The window has teeth: each frame's largest window, unsmoothed, would be larger somewhere and then black
    # nowhere either, but a window 2 % larger than the chosen one shows black on some frame.
    grown = adaptive_crop.AdaptiveCrop(np.minimum(adaptive.scales * 1.02, 1.0), adaptive.anchor, W, H)
    grown_out = path.orig_from_stab @ grown.stab_from_out
    assert any(warping.warp_frame(video.frames[t], grown_out[t]).missing.any() for t in range(video.n_frames))


def test_the_recording_holds_each_setting_path_and_crop_and_the_figure_shows_them(tmp_path):
    """A run with a tripod segment, a smoothness and the adaptive crop, recorded and read back: the original and
    smoothed paths (x, y, angle, zoom) equal the plan's, each frame's setting is there with its label, the crop scale
    per frame is the plan's, and the trajectory figure shades and labels the two stretches."""
    from ffviz import entities as ent, figures
    from ffviz.recorder import RerunRecorder
    from ffviz.rrd import Recording
    from pipeline.evaluation import synthetic
    from pipeline.runtime.observer import Observers, StageCollector
    from pipeline.stabilize import StabilizeConfig, stabilize

    video = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=45, seed=3,
                                                         blurred_frames=(), moving_object=False))
    source = tmp_path / "in.mp4"
    synthetic.write_video(video, source)
    config = StabilizeConfig(mode="crop", crop=adaptive_crop.CropConfig(kind="adaptive"),
                             smoothing=smoothing.SmoothingConfig(
                                 smoothness=path_control.Smoothness(70, 30, 50),
                                 segments=(path_control.PathSegment.parse("-0.5:tripod"),)))
    rrd = tmp_path / "run.rrd"
    collector = StageCollector("path")
    stabilize(source, None, config, observer=Observers(RerunRecorder(rrd, level="summary"), collector))
    [(_, plan)] = collector.results["path"]
    recording = Recording.load(rrd)
    frames, setting = recording.scalars(ent.PATH_SETTING)
    assert list(setting.astype(int)) == [1] * 15 + [0] * 30  # 0.5 s at 30 frames/s
    assert recording.texts(ent.PATH_SETTINGS, "TextDocument:text")[-1].split("\n") == [
        "gaussian:t=70,r=30,z=50", "0-0.5:tripod"]
    for axis in ent.TRAJECTORY_AXES:
        original = recording.scalars(f"{ent.TRAJECTORY_ORIGINAL}/{axis}")[1]
        smoothed = recording.scalars(f"{ent.TRAJECTORY_SMOOTHED}/{axis}")[1]
        assert len(original) == len(smoothed) == 45
        column = ent.TRAJECTORY_AXES.index(axis)
        np.testing.assert_allclose(original, plan.smoothing.original_trajectory[:, column], atol=1e-4)
        np.testing.assert_allclose(smoothed, plan.smoothing.smoothed_trajectory[:, column], atol=1e-4)
    scales = recording.scalars(ent.CROP_SCALE)[1]
    assert len(scales) == 45 and 0.3 < scales.min() <= scales.max() <= 1.0
    np.testing.assert_allclose(scales, plan.adaptive_crop.scales, atol=1e-6)
    assert "adaptive crop: scale" in recording.texts(ent.META, "TextDocument:text")[-1]
    fig = figures.trajectories(recording)
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert "0-0.5:tripod" in texts and "gaussian:t=70,r=30,z=50" in texts
    assert len(fig.axes) == 4


def test_cli_path_control_options_end_to_end(tmp_path, capsys):
    from ffviz import cli
    from pipeline.evaluation import synthetic
    from pipeline.runtime import video_reader

    video = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=30, seed=3,
                                                         blurred_frames=(), moving_object=False))
    source = tmp_path / "shaky.mp4"
    synthetic.write_video(video, source)
    out = tmp_path / "out.mp4"
    assert cli.main(["stabilize", str(source), "-o", str(out), "--mode", "crop", "--crop", "adaptive", "--no-deblur",
                     "--smoothness", "t=80,z=20", "--max-shift", "10", "--max-angle", "1",
                     "--path-segment", "0-0.5:tripod", "--path-segment", "0.5-:l1:60"]) == 0
    assert video_reader.probe_video(out).frame_count == 30
    assert "on average" in capsys.readouterr().out
    for bad, words in ((["--smoothness", "t=120"], "between 0 and 100"), (["--path-segment", "5:l1"], "T0-T1:PATH"),
                       (["--path-segment", "0-5:tripod", "--path-segment", "4-:l1"], "overlap"),
                       (["--crop", "adaptive"], "--mode crop"), (["--smoothness", "60", "-k", "10"], "not both"),
                       (["--max-shift", "-1"], ">= 0"), (["--tripod", "--smoothness", "60"], "tripod")):
        assert cli.main(["stabilize", str(source), "-o", str(tmp_path / "x.mp4"), *bad]) == 2, bad
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], (bad, err)
    assert not (tmp_path / "x.mp4").exists()


def test_a_tripod_holds_the_median_view_not_a_corner_of_its_margins():
    """Among the equally still paths (any constant within every frame's margin), the L1 program's tie-break picks
    the one nearest the input: on a still scene, the held view is the input's median view, within 1 px / 0.05
    degrees (a corner of the margins would be up to 10 % of the frame away, and leave that much more to fill)."""
    video = generate(SyntheticConfig(n_frames=90, moving_object=False, blurred_frames=(), pan_px_per_frame=0.0,
                                     seed=4))
    result = smoothing.smooth(video.curr_from_prev, smoothing.SmoothingConfig(path="tripod"), width=W, height=H)
    held = result.smoothed_trajectory
    assert np.abs(held - held[0]).max() < 1e-6  # still
    median = np.median(result.original_trajectory, axis=0)
    assert np.abs(held[0, :2] - median[:2]).max() < 1.0 and abs(held[0, 2] - median[2]) < 0.05
    assert np.ptp(result.original_trajectory[:, :2], axis=0).min() > 20  # the input does move about it


def test_segments_and_scene_cuts_do_not_reach_across_each_other():
    """A shot after a cut, planned by one setting, is planned exactly as that shot alone; the switch inside the first
    shot happens there, on the L1 path too."""
    video = generate(SyntheticConfig(n_frames=120, moving_object=False, blurred_frames=(), seed=8))
    times = np.arange(120) / 30.0
    config = smoothing.SmoothingConfig(path="l1", segments=(path_control.PathSegment.parse("0-1:tripod"),))
    result = smoothing.smooth(video.curr_from_prev, config, cuts=[60], width=W, height=H, times_s=times)
    second = video.curr_from_prev[60:].copy()
    second[0] = np.eye(3)
    alone = smoothing.smooth(second, smoothing.SmoothingConfig(path="l1"), width=W, height=H)
    np.testing.assert_allclose(result.orig_from_stab[60:], alone.orig_from_stab, atol=1e-9)
    assert list(result.setting_of[[0, 29, 30, 59, 60, 119]]) == [1, 1, 0, 0, 0, 0]
    assert result.settings == ("l1", "0-1:tripod")
    tripod = smoothing.smooth(video.curr_from_prev[:31], smoothing.SmoothingConfig(path="tripod"), width=W, height=H)
    np.testing.assert_allclose(result.orig_from_stab[:31], tripod.orig_from_stab, atol=1e-9)


def test_a_tripod_segment_warns_only_for_its_own_frames():
    """A tripod over the first second of a fast pan cannot hold (the pan leaves its margin): the warning names
    frames within that second; the eq. 18 stretch after it moves freely and is not reported."""
    video = generate(SyntheticConfig(n_frames=90, moving_object=False, blurred_frames=(), seed=4,
                                     pan_px_per_frame=5.0))
    times = np.arange(90) / 30.0
    config = smoothing.SmoothingConfig(segments=(path_control.PathSegment.parse("0-1:tripod"),))
    result = smoothing.smooth(video.curr_from_prev, config, width=W, height=H, times_s=times)
    [warning] = smoothing.path_warnings(result, config)
    ranges = [tuple(int(v) for v in part.split("-")) for part in warning.split("frames ")[1].split(", ")]
    assert ranges and all(0 <= a < b <= 30 for a, b in ranges), warning
    assert smoothing.path_warnings(result, smoothing.SmoothingConfig()) == []
