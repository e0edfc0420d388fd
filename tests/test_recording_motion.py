"""The debugger's view of robust motion, read back from a recording: the other motion's (foreground) tracks, the
ignore mask's outline, and the rolling-shutter correction's per-band motion, each against the pipeline's values."""

from __future__ import annotations

import numpy as np
import pytest

from ffviz import entities as ent
from ffviz.recorder import RerunRecorder
from ffviz.recorder import ROLLING_SHUTTER_BANDS, ROLLING_SHUTTER_GAIN
from ffviz.rrd import Recording
from pipeline.evaluation import synthetic
from pipeline.runtime.observer import Observers, StageCollector
from pipeline.stabilize import StabilizeConfig, stabilize
from pipeline.stages import motion

N_FRAMES = 16
BOX = motion.IgnoreRegion(0, 0, 80, 60, start_s=0.2, end_s=0.35)  # frames 6-10 at 30 fps


def rows_at(recording: Recording, entity: str, column: str) -> dict[int, list]:
    """frame -> the last value of ``column`` logged at it (None for a Clear)."""
    out: dict[int, list] = {}
    for batch in recording.batches.get(entity, []):
        names = batch.schema.names
        if ent.FRAME_TIMELINE not in names:
            continue
        values = batch.column(column).to_pylist() if column in names else [None] * batch.num_rows
        for frame, value in zip(batch.column(ent.FRAME_TIMELINE).to_pylist(), values):
            out[frame] = value
    return out


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A 320x180 clip with a rolling shutter (readout 0.8) and a figure filling most of the frame, recorded at full
    level with --ignore BOX and --rolling-shutter 0.8."""
    video = synthetic.generate(synthetic.SyntheticConfig(
        width=320, height=180, n_frames=N_FRAMES, seed=2, object_kind="person", person_size=(0.9, 1.0),
        object_sweep=0.15, blurred_frames=(), image="astronaut", readout=0.8))
    folder = tmp_path_factory.mktemp("robust")
    clip, rrd = folder / "clip.mp4", folder / "run.rrd"
    synthetic.write_video(video, clip)
    collector = StageCollector("motion", "path")
    config = StabilizeConfig(mode="none", rolling_shutter=0.8, motion=motion.MotionConfig(ignore=(BOX,)))
    stabilize(clip, None, config, observer=Observers(RerunRecorder(rrd, level="full", jpeg_quality=None), collector))
    return Recording.load(rrd), collector


def _others(estimate) -> np.ndarray | None:
    """Every other motion's track ends, as the recorder draws them (None: no other motion)."""
    points = [other.curr_points for other in estimate.others if len(other.curr_points)]
    return np.concatenate(points) if points else None


def test_foreground_tracks_are_the_other_motions(run):
    recording, collector = run
    logged = rows_at(recording, ent.MOTION_FOREGROUND, "Points2D:positions")
    estimates = {stamp.index: e for stamp, e in collector.results["motion"]}
    with_other = [t for t, e in estimates.items() if _others(e) is not None]
    assert with_other, "the figure gives no second motion: the test shows nothing"
    for t in with_other:
        assert np.allclose(np.array(logged[t]), _others(estimates[t]), atol=1e-3)
    # A frame without another motion after one with: cleared, so stale points do not stay on screen.
    for t in range(1, N_FRAMES):
        if _others(estimates[t]) is None and _others(estimates[t - 1]) is not None:
            assert logged.get(t, "missing") is None


def test_each_pair_says_which_motion_the_camera_took_and_why(run):
    """The camera's choice at every pair (pipeline/stages/background.py): a line naming the motion taken, the rule
    that weighed most and the motions tracked on from pairs before, and the evidence for it charted, as the estimates
    say."""
    recording, collector = run
    estimates = {stamp.index: e for stamp, e in collector.results["motion"]}
    lines = {t: text[0] for t, text in rows_at(recording, ent.MOTION_CAMERA_RULE, "TextLog:text").items()}
    assert sorted(lines) == sorted(estimates)
    for t, estimate in estimates.items():
        choice = estimate.camera
        if choice.rule == "one motion":
            assert lines[t].startswith("one motion")
        else:
            assert f"motion {choice.taken + 1} of {len(estimate.others) + 1}" in lines[t] and choice.rule in lines[t]
            carried = [k for k in choice.carried if k]  # layers tracked on from pairs before (motion.continued)
            assert lines[t].count("tracked on") == len(carried)
            assert all(f"tracked on {k} pair" in lines[t] for k in carried)
    frames, linked = recording.scalars(f"{ent.MOTION_CAMERA}/linked")
    assert frames.tolist() == sorted(estimates)
    assert np.allclose(linked, [estimates[t].camera.linked for t in frames.tolist()])


def recorded_pass_one(frames, rrd) -> tuple[Recording, dict]:
    """``frames`` run in mode none with a full-level recording at ``rrd``: the recording, and each pair's estimate."""
    from pipeline.runtime.source import ArraySource
    from pipeline.stabilize import stabilize_source

    collector = StageCollector("motion")
    stabilize_source(ArraySource(frames), None, StabilizeConfig(mode="none"), workers=1,
                     observer=Observers(RerunRecorder(rrd, level="full", jpeg_quality=None), collector))
    return Recording.load(rrd), {stamp.index: e for stamp, e in collector.results["motion"]}


def test_the_rule_line_names_the_layers_tracked_on(tmp_path):
    """Three figures over a sky: on pairs where a layer of an earlier pair was tracked on and added as a motion
    (motion.continued), the camera's rule line says so of each such motion, with how many pairs."""
    from pipeline.evaluation import foreground

    recording, estimates = recorded_pass_one(foreground.clip("three figures", "rocket", 2, n_frames=30).frames,
                                             tmp_path / "sky.rrd")
    lines = {t: text[0] for t, text in rows_at(recording, ent.MOTION_CAMERA_RULE, "TextLog:text").items()}
    carried = {t: [k for k in e.camera.carried if k] for t, e in estimates.items()}
    assert any(carried.values()), "no layer was tracked on: the test shows nothing"
    for t, counts in carried.items():
        assert lines[t].count("tracked on") == len(counts)
        assert all(f"tracked on {k} pair" in lines[t] for k in counts)


def test_the_rule_line_says_where_the_cameras_layer_was_lost(tmp_path):
    """Three figures over a sky, seed 13: at a pair where no motion goes on the camera's layer of the pair before
    (background.PairLayers.lost), the chain had to switch layer, and the camera's rule line says so there only."""
    from pipeline.evaluation import foreground

    recording, estimates = recorded_pass_one(foreground.clip("three figures", "rocket", 13, n_frames=40).frames,
                                             tmp_path / "lost.rrd")
    lines = {t: text[0] for t, text in rows_at(recording, ent.MOTION_CAMERA_RULE, "TextLog:text").items()}
    lost = sorted(t for t, e in estimates.items() if e.camera.lost)
    assert lost, "no layer was lost: the test shows nothing"
    assert [t for t, line in sorted(lines.items()) if "(lost)" in line] == lost


def test_a_frame_without_tracks_shows_none_of_the_frame_before(tmp_path):
    """A black frame has no corners to track: the motion tab shows no tracks there, not the frame before's."""
    video = synthetic.generate(synthetic.SyntheticConfig(n_frames=10, seed=0))
    frames = [np.zeros_like(frame) if t == 6 else frame for t, frame in enumerate(video.frames)]
    recording, _ = recorded_pass_one(frames, tmp_path / "black.rrd")
    points = rows_at(recording, f"{ent.MOTION_FEATURES}/points", "Points2D:positions")
    assert points[5] and points[6] is None and points[8]


def test_ignore_box_is_outlined_while_active(run):
    recording, _ = run
    logged = rows_at(recording, ent.MOTION_IGNORED, "LineStrips2D:strips")
    shown = sorted(t for t, v in logged.items() if v is not None)
    assert shown and min(shown) == 7  # drawn from the first pair whose earlier frame (6) it covers
    strip = np.array(logged[shown[0]][0])
    # The outline lies on the box's border (full-resolution px; the motion pass works at full size here).
    assert strip[:, 0].min() == pytest.approx(BOX.x, abs=1)
    assert strip[:, 0].max() == pytest.approx(BOX.x + BOX.width - 1, abs=1)
    assert strip[:, 1].min() == pytest.approx(BOX.y, abs=1)
    assert strip[:, 1].max() == pytest.approx(BOX.y + BOX.height - 1, abs=1)
    cleared = [t for t, v in logged.items() if v is None]
    assert cleared and min(cleared) == 12  # and cleared after the last such pair (10, 11)


def test_rolling_shutter_bands_are_the_corrections(run):
    recording, collector = run
    (_, plan), = collector.results["path"]
    correction = plan.rolling_shutter
    assert correction is not None and correction.readout == 0.8
    arrows = rows_at(recording, ent.ROLLING_SHUTTER_BANDS, "Arrows2D:vectors")
    origins = rows_at(recording, ent.ROLLING_SHUTTER_BANDS, "Arrows2D:origins")
    assert sorted(arrows) == list(range(N_FRAMES))
    t = N_FRAMES // 2
    centres, bands = correction.rows[t].bands(ROLLING_SHUTTER_BANDS)
    start = np.array(origins[t])
    moved = np.einsum("nij,nj->ni", np.repeat(bands, len(start) // len(bands), axis=0),
                      np.c_[start, np.ones(len(start))])[:, :2]
    assert np.allclose(np.array(arrows[t]), (moved - start) * ROLLING_SHUTTER_GAIN, atol=1e-3)
    assert np.allclose(np.unique(start[:, 1]), centres, atol=1e-3)
    # The skew series: one value a frame, and the clip's shake does bend the frames.
    frames, dx = recording.scalars(f"{ent.ROLLING_SHUTTER_SKEW}/dx")
    assert frames.tolist() == list(range(N_FRAMES)) and np.abs(dx).max() > 0.5
    assert any("readout 0.80" in text for text in recording.texts(ent.LOG, "TextLog:text"))
