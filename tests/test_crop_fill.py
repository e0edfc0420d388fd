"""Crop mode's default window: the largest whose parts outside the input frames are at most --crop-fill of the
output's pixels over the clip, completed there as in full mode (pipeline/stages/warping.py's window_for_fill,
pipeline/config.py's crop_fill), against ground truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ffviz import cli
from pipeline import geometry
from pipeline.config import DEFAULT_CROP_FILL, StabilizeConfig
from pipeline.errors import ConfigError
from pipeline.evaluation import metrics
from pipeline.evaluation.synthetic import SyntheticConfig, generate
from pipeline.runtime.observer import NullObserver
from pipeline.runtime.source import ArraySource
from pipeline.stabilize import stabilize_source
from pipeline.stages import smoothing, warping
from pipeline.stages.adaptive_crop import CropConfig

W, H = 320, 180


def dense_share_outside(orig_from_stab: np.ndarray, scale: float) -> np.ndarray:
    """Ground truth for window_share_outside: every output pixel of the centred window of ``scale`` mapped to its
    input frame, counted outside it."""
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    centre = np.array([(W - 1) / 2.0, (H - 1) / 2.0])
    window = np.stack([centre[0] + scale * (xs.ravel() - centre[0]), centre[1] + scale * (ys.ravel() - centre[1])], 1)
    shares = []
    for m in orig_from_stab:
        x, y = geometry.apply(m, window).T
        shares.append(np.mean((x < 0) | (x > W - 1) | (y < 0) | (y > H - 1)))
    return np.array(shares)


def wandering_path(n: int = 120, seed: int = 0) -> np.ndarray:
    """orig_from_stab of a path that departs from its frames by up to ~6 % of the width, turns up to 2 degrees and
    zooms 2 %, one frame in eight in perspective: the window leaves some frames at every scale above ~0.85."""
    rng = np.random.default_rng(seed)
    out = []
    for t in range(n):
        dx, dy = 20 * math.sin(t / 9.0) + rng.normal(0, 3), 8 * math.cos(t / 13.0) + rng.normal(0, 2)
        angle, zoom = math.radians(2 * math.sin(t / 17.0)), 1.0 + 0.02 * math.sin(t / 11.0)
        c, s = zoom * math.cos(angle), zoom * math.sin(angle)
        centre = np.array([(W - 1) / 2.0, (H - 1) / 2.0])
        m = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        m[:2, 2] = centre + (dx, dy) - m[:2, :2] @ centre
        if t % 8 == 0:
            m = m @ np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [2e-5, -1e-5, 1.0]])
        out.append(m)
    return np.array(out)


def test_the_share_outside_matches_a_count_of_every_pixel():
    path = wandering_path()
    for scale in (0.8, 0.9, 0.95, 1.0):
        measured = warping.window_share_outside(path, W, H, scale)
        truth = dense_share_outside(path, scale)
        assert np.abs(measured - truth).max() < 0.01 and abs(measured.mean() - truth.mean()) < 1e-3, scale


@pytest.mark.parametrize("fill", [0.0, 0.001, 0.003, 0.02])
def test_the_window_is_the_largest_within_the_fill(fill):
    path = wandering_path(seed=1)
    window, share = warping.window_for_fill(path, W, H, fill)
    assert share == pytest.approx(warping.window_share_outside(path, W, H, window.scale).mean(), abs=1e-9)
    centre = np.array([(W - 1) / 2.0, (H - 1) / 2.0])
    np.testing.assert_allclose(window.stab_from_out[:2, 2] + window.scale * centre, centre)  # centred
    assert 0.5 < window.scale < 1.0
    assert dense_share_outside(path, window.scale).mean() <= fill + 3e-4
    assert dense_share_outside(path, window.scale + 0.003).mean() > fill  # a larger window leaves by more
    if fill == 0.0:  # inside every frame; the free window of largest_crop may sit off centre and be larger
        assert window.scale <= warping.largest_crop(path, W, H).scale + 1e-3


def test_a_still_camera_keeps_the_whole_frame():
    window, share = warping.window_for_fill(np.repeat(np.eye(3)[None], 10, 0), W, H, DEFAULT_CROP_FILL)
    assert window.scale == 1.0 and share == 0.0


class _Keep(NullObserver):
    def __init__(self) -> None:
        self.plan, self.outputs, self.missing = None, {}, {}

    def on_path(self, plan) -> None:
        self.plan = plan

    def on_frame(self, result) -> None:
        """The output and what completion synthesized in it (nothing where the window stays inside the frame); the
        recorded stabilized frame is the one the window is cut from."""
        self.outputs[result.stamp.index] = result.output
        completed = result.completion
        self.missing[result.stamp.index] = (completed.missing if completed is not None
                                            else np.zeros(result.output.shape[:2], bool))
        assert result.warp.frame.shape == result.output.shape
        if self.plan.crop.scale < 1.0:
            uncropped = self.plan.smoothing.orig_from_stab[result.stamp.index]
            np.testing.assert_allclose(result.warp.orig_from_out, uncropped)


def _view_jitter(video, orig_from_out: np.ndarray) -> float:
    """Residual jitter (px) of the output's view centre in the world."""
    return metrics.residual_jitter(video.view_path(orig_from_out), 30.0)[0]


@pytest.mark.parametrize("kind, seed", [("person", 0), ("disc", 1)])
def test_crop_mode_completes_its_window_where_it_leaves_the_frames(kind, seed):
    """A shaken synthetic camera with a large moving object (a person in the photograph's own colours, or a disc):
    crop mode's default keeps a larger window than one inside every frame, leaves the frames by the fill on average,
    completes what it leaves with pixels close to the truth (the world seen through the output's view), and shows
    no black pixel; its view of the world is steady."""
    video = generate(SyntheticConfig(width=W, height=H, n_frames=60, seed=seed, jitter_px=6.0, object_kind=kind))
    filled, hard = _Keep(), _Keep()
    stabilize_source(ArraySource(video.frames), None, StabilizeConfig(mode="crop"), observer=filled, workers=1)
    stabilize_source(ArraySource(video.frames), None, StabilizeConfig(mode="crop", crop=CropConfig(fill=0.0)),
                     observer=hard, workers=1)
    assert filled.plan.crop.scale > hard.plan.crop.scale + 0.03  # measured 0.90 against 0.83-0.86
    np.testing.assert_allclose(filled.plan.orig_from_out,
                               filled.plan.smoothing.orig_from_stab @ filled.plan.crop.stab_from_out)
    shares = np.array([filled.missing[t].mean() for t in range(video.n_frames)])
    assert 0.5 * DEFAULT_CROP_FILL < shares.mean() < 1.5 * DEFAULT_CROP_FILL and (shares > 0).sum() >= 5
    synthesized, truth = [], []
    for t in range(video.n_frames):
        out_from_orig = np.linalg.inv(filled.plan.orig_from_out[t])
        known = filled.missing[t] & video.view_coverage(t, out_from_orig)
        synthesized.append(filled.outputs[t][known])
        truth.append(video.render_view(t, out_from_orig)[known])
        assert metrics.black_fraction(filled.outputs[t]) < 1e-3  # dark picture content at most, no border
    error = np.concatenate(synthesized).astype(np.float64) - np.concatenate(truth)
    psnr = 10 * math.log10(255.0**2 / np.mean(error**2))
    assert psnr > 24.0  # measured 31.7 (person) and 26.4 dB (disc)
    shaken = _view_jitter(video, np.repeat(np.eye(3)[None], video.n_frames, 0))
    assert _view_jitter(video, filled.plan.orig_from_out) < 0.5 * shaken


def test_crop_fill_settings():
    assert StabilizeConfig(mode="crop").crop_fill == DEFAULT_CROP_FILL
    assert StabilizeConfig(mode="crop", crop=CropConfig(fill=0.01)).crop_fill == 0.01
    assert StabilizeConfig(mode="crop", crop=CropConfig(fill=0.01)).completing
    for config in (dict(mode="full"), dict(mode="crop", smoothing=smoothing.SmoothingConfig(path="l1")),
                   dict(mode="crop", crop=CropConfig(kind="adaptive", fill=0.01)),
                   dict(mode="crop", crop=CropConfig(scale=0.9, fill=0.01))):
        with pytest.raises(ConfigError, match="--crop-fill"):
            StabilizeConfig(**{**config, "crop": config.get("crop", CropConfig(fill=0.01))})
    for bad in (-0.1, 0.5, float("nan")):
        with pytest.raises(ConfigError, match="crop fill"):
            CropConfig(fill=bad)


def test_crop_fill_on_the_command_line(tmp_path, capsys):
    video = generate(SyntheticConfig(width=W, height=H, n_frames=12, seed=3, moving_object=False))
    from pipeline.evaluation.synthetic import write_video

    clip = tmp_path / "clip.mp4"
    write_video(video, clip)
    assert cli.main(["stabilize", str(clip), "-o", str(tmp_path / "out.mp4"), "--mode", "crop", "--crop-fill",
                     "0", "--path", "l1"]) == 0
    assert cli.main(["stabilize", str(clip), "-o", str(tmp_path / "bad.mp4"), "--mode", "crop", "--crop-fill",
                     "0.01", "--path", "l1"]) == 2
    error = capsys.readouterr().err
    assert "--crop-fill" in error and "Traceback" not in error and not (tmp_path / "bad.mp4").exists()


def test_the_command_lines_crop_mode_paths():
    """What `--mode crop` plans from the command line: eq. 18 at k = 60 with the fill by default; a window inside
    every frame (auto at k = 30) with --crop-fill 0, --crop-scale, --crop adaptive or a path segment the L1 program
    plans in the window; -k and --path as given."""
    from ffviz.runner import stabilize_config

    parser = cli.build_parser()

    def config(*options: str) -> StabilizeConfig:
        return stabilize_config(parser.parse_args(["stabilize", "in.mp4", "-o", "out.mp4", "--mode", "crop", *options]))

    def planned(c: StabilizeConfig) -> tuple:
        return c.smoothing.path, c.smoothing.radius_frames, c.crop_fill

    assert planned(config()) == ("gaussian", 60, DEFAULT_CROP_FILL) and config() == StabilizeConfig(mode="crop")
    assert planned(config("--crop-fill", "0.01", "-k", "40")) == ("gaussian", 40, 0.01)
    for options in (["--crop-fill", "0"], ["--crop-scale", "0.9"], ["--crop", "adaptive"],
                    ["--path-segment", "0-3:tripod"]):
        assert planned(config(*options)) == ("auto", 30, 0.0), options
    assert planned(config("--path", "gaussian", "--crop-fill", "0")) == ("gaussian", 30, 0.0)
    assert planned(config("--path", "l1")) == ("l1", 30, 0.0)


def test_a_path_too_far_from_its_frames_for_any_window_is_told():
    """One frame seen 90 % of the width away from its neighbours (a glitch eq. 18 smooths over): even the smallest
    window leaves that frame whole, more than the fill over 40 frames. The plan keeps that smallest window,
    completes what it must, and says so in one warning."""
    from pipeline.chain import CROP_FILL_WARNING, plan_path
    from pipeline.results import MotionPass

    n = 40
    curr_from_prev = np.repeat(np.eye(3)[None], n, 0)
    curr_from_prev[20, 0, 2], curr_from_prev[21, 0, 2] = 0.9 * W, -0.9 * W
    motion = MotionPass(curr_from_prev, ["ok"] * n, [t / 30.0 for t in range(n)], [])
    plan = plan_path(motion, StabilizeConfig(mode="crop", smoothing=smoothing.SmoothingConfig(radius_frames=60)), W, H)
    assert plan.crop.scale == warping.FILL_MIN_SCALE
    share = warping.window_share_outside(plan.smoothing.orig_from_stab, W, H, plan.crop.scale).mean()
    assert share > DEFAULT_CROP_FILL
    told = [w for w in plan.warnings if w.startswith(CROP_FILL_WARNING[:30])]
    assert len(told) == 1 and f"{share:.1%}" in told[0]
    calm = plan_path(MotionPass(np.repeat(np.eye(3)[None], n, 0), ["ok"] * n, [t / 30.0 for t in range(n)], []),
                     StabilizeConfig(mode="crop"), W, H)
    assert calm.crop.scale == 1.0 and not calm.warnings
