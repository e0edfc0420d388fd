"""L1-optimal camera paths (pipeline/stages/l1_path.py) on ground truth: the pieces a viewer reads as a tripod, a dolly
and a smooth pan are recovered from a shaken path; the bound holds; long paths are solved in windows without a
jump; end to end the output is steadier than eq. 18's."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.stages import l1_path, smoothing
from pipeline.evaluation.synthetic import SyntheticConfig, generate


def shaken_path(n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Still for 100 frames, then 2 px a frame, then accelerating by 0.04 px a frame^2; plus hand shake."""
    t = np.arange(n, dtype=float)
    intended = np.where(t < 100, 0.0, np.where(t < 200, 2.0 * (t - 100), 200 + 2.0 * (t - 200) + 0.02 * (t - 200) ** 2))
    rng = np.random.default_rng(seed)
    shake = np.convolve(rng.normal(0, 1, n + 10), np.ones(3) / 3, "same")[5:5 + n] * 6
    return intended, intended + shake


def test_l1_path_recovers_still_constant_velocity_and_constant_acceleration_pieces():
    intended, shaken = shaken_path()
    margin = 10.0
    path = l1_path.plan(shaken, margin)
    assert np.all(np.abs(path - shaken) <= margin + 1e-6)  # the bound
    # Inside each piece (away from its ends) the path is still, straight, or of constant acceleration.
    assert np.abs(np.diff(path[10:90])).max() < 0.15
    assert np.abs(np.diff(path, 2)[110:190]).max() < 0.15
    assert np.abs(np.diff(path, 3)[215:285]).max() < 0.6
    # And it follows the intended path, much closer than the shake's own excursions allow the input to.
    assert np.sqrt(np.mean((path - intended) ** 2)) < 4.0
    # The L1 path is exactly straight there (second differences ~0 on most frames); a low-pass of the same path
    # (eq. 18's Gaussian, k = 15) wanders.
    low_pass = np.convolve(shaken, np.exp(-0.5 * (np.arange(-15, 16) / 5.5) ** 2) / 13.79, "same")
    assert (np.abs(np.diff(path, 2)[110:190]) < 0.01).mean() > 0.8
    assert (np.abs(np.diff(low_pass, 2)[110:190]) < 0.01).mean() < 0.4


def test_long_paths_are_solved_in_windows_without_a_jump():
    rng = np.random.default_rng(3)
    shaken = np.cumsum(rng.normal(0, 3, 2000))
    path = l1_path.plan(shaken, 15.0, window=400, overlap=60)
    assert np.all(np.abs(path - shaken) <= 15.0 + 1e-6)
    whole = np.abs(np.diff(path))
    # Steps at the windows' seams are no larger than the path's steps elsewhere.
    seams = [400 - 60 + k * 340 for k in range(5)]
    assert max(whole[s - 3:s + 3].max() for s in seams if s + 3 < len(whole)) <= whole.max() + 1e-9


@pytest.mark.parametrize("path", ["gaussian", "l1"])
def test_smoothing_path_stays_within_bounds_and_l1_is_steadier(path):
    video = generate(SyntheticConfig(n_frames=90, moving_object=False, blurred_frames=()))
    config = smoothing.SmoothingConfig(path=path)
    result = smoothing.smooth(video.curr_from_prev, config, width=640, height=360)
    # Where the stabilized frame's centre lands in the world: its second differences are the output's shake.
    shake = np.abs(np.diff(_centre_in_world(video, result), 2, axis=0)).mean()
    if path == "l1":
        departure = np.abs(result.smoothed_trajectory - result.original_trajectory).max(axis=0)
        assert departure[0] <= 0.03 * 640 + 0.5 and departure[1] <= 0.03 * 640 + 0.5 and departure[2] <= 2.05
        gaussian = smoothing.smooth(video.curr_from_prev, smoothing.SmoothingConfig(), width=640, height=360)
        assert shake < 0.8 * np.abs(np.diff(_centre_in_world(video, gaussian), 2, axis=0)).mean()
        # Corrections are similarities: no shear, equal scales.
        for m in result.orig_from_stab:
            assert abs(m[0, 0] - m[1, 1]) < 1e-9 and abs(m[0, 1] + m[1, 0]) < 1e-9
    assert shake < 0.5


def _centre_in_world(video, result):
    centre = np.array([319.5, 179.5, 1.0])
    return np.array([(np.linalg.inv(video.frame_from_world[t]) @ result.orig_from_stab[t] @ centre)[:2]
                     for t in range(video.n_frames)])


def test_tripod_leaves_a_static_scene_motionless_and_says_when_it_must_move():
    still = generate(SyntheticConfig(n_frames=90, moving_object=False, blurred_frames=(), pan_px_per_frame=0.0,
                                     drift_px=0.0, drift_deg=0.0, seed=4))
    config = smoothing.SmoothingConfig(path="tripod")
    result = smoothing.smooth(still.curr_from_prev, config, width=640, height=360)
    assert np.abs(np.diff(_centre_in_world(still, result), axis=0)).max() < 0.3
    assert np.abs(np.diff(result.smoothed_trajectory[:, 2])).max() < 0.01  # no turn either
    assert smoothing.path_warnings(result, config) == []
    # A camera that pans far: the view must follow, by as little as it can, and the user hears of it.
    panning = generate(SyntheticConfig(n_frames=90, moving_object=False, blurred_frames=(), pan_px_per_frame=3.0,
                                       seed=4))
    result = smoothing.smooth(panning.curr_from_prev, config, width=640, height=360)
    departure = np.abs(result.smoothed_trajectory - result.original_trajectory)
    assert departure[:, :2].max() <= 0.1 * 640 + 0.5
    warnings = smoothing.path_warnings(result, config)
    assert len(warnings) == 1 and warnings[0].startswith("tripod: the camera moved further")


@pytest.mark.parametrize("path", ["gaussian", "l1"])
def test_horizon_lock_holds_the_output_rotation_at_zero(path):
    video = generate(SyntheticConfig(n_frames=90, moving_object=False, blurred_frames=(), drift_deg=3.0, seed=2))
    result = smoothing.smooth(video.curr_from_prev, smoothing.SmoothingConfig(path=path, horizon_lock=True),
                              width=640, height=360)
    assert np.abs(result.smoothed_trajectory[:, 2]).max() < 0.05
    # Truth: the stabilized frames' roll in the world is the first frame's.
    def roll(m):
        return np.degrees(np.arctan2(m[1, 0] - m[0, 1], m[0, 0] + m[1, 1]))
    rolls = [roll(video.frame_from_world[0] @ np.linalg.inv(video.frame_from_world[t]) @ result.orig_from_stab[t])
             for t in range(video.n_frames)]
    assert np.abs(rolls).max() < 0.1
    free = smoothing.smooth(video.curr_from_prev, smoothing.SmoothingConfig(path=path), width=640, height=360)
    assert np.abs(free.smoothed_trajectory[:, 2]).max() > 1.0  # the case has teeth: the path does turn


def test_cli_path_options_end_to_end(tmp_path, capsys):
    """--path l1, --tripod and --horizon-lock run through the command line; --tripod with --path l1 is refused
    in one line."""
    from ffviz import cli
    from pipeline.evaluation import synthetic
    from pipeline.runtime import video_io

    video = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=30, seed=3,
                                                         blurred_frames=()))
    source = tmp_path / "shaky.mp4"
    synthetic.write_video(video, source)
    for index, options in enumerate((["--path", "l1"], ["--tripod", "--horizon-lock"])):
        out = tmp_path / f"out{index}.mp4"
        assert cli.main(["stabilize", str(source), "-o", str(out), "--mode", "none", "--no-deblur", *options]) == 0
        assert video_io.probe_video(out).frame_count == 30
    capsys.readouterr()
    assert cli.main(["stabilize", str(source), "-o", str(tmp_path / "x.mp4"), "--tripod", "--path", "l1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--tripod" in err[0]
