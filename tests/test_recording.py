"""Recordings read back: every entity family, with the pipeline's own values, and the stage-stepping traces."""

from __future__ import annotations

import dataclasses
import errno
import fnmatch
import os
import typing
import subprocess
import threading
import time
from types import SimpleNamespace

import av
import numpy as np
import pytest
import rerun as rr

import ffviz
from ffviz import cli, entities as ent, snapshot, trace, visual
from ffviz.recorder import RerunRecorder
from ffviz.recording import about, legends
from ffviz.recording.digest import WEIGHTS_STEP
from ffviz.recording.legends import FILLED_BY_BASE
from ffviz.rrd import Recording
from ffviz.viewer import rerun_executable
from pipeline import geometry
from pipeline.evaluation import synthetic
from pipeline.stages.adaptive_crop import CropConfig
from pipeline.stages.completion import SOURCE_FALLBACK, SOURCE_MOSAIC, SOURCE_NAMES, from_a_neighbour
from pipeline.stages.neighbours import WarpedNeighbour
from pipeline.results import FrameResult, Stamp
from pipeline.runtime.observer import Observers, StageCollector
from pipeline.errors import OutputError
from pipeline.stages.deblur import DeblurConfig, DeblurResult
from pipeline.stages.motion import IgnoreRegion, MotionConfig
from pipeline.stabilize import StabilizeConfig, stabilize

N_FRAMES = 30
TRACED = (5, 18)
STAGES = ("motion", "smoothing", "input", "warp", "completion", "deblur", "output")
# completion/stats: the missing share and one series per way of filling (completion.SOURCE_NAMES after "original")
COMPLETION_SERIES = tuple(f"{ent.COMPLETION_STATS}/{name.replace(' ', '_')}" for name in ("missing", *SOURCE_NAMES[1:]))
PER_FRAME_IMAGES = (ent.INPUT_FRAME, ent.STABILIZED_FRAME, ent.STABILIZED_MISSING, ent.COMPLETION_FRAME,
                    ent.COMPLETION_VARIANCE, ent.COMPLETION_ACCEPTED, ent.COMPLETION_FILLED_BY,
                    ent.COMPLETION_FALLBACK, ent.COMPLETION_SOURCE, ent.OUTPUT_FRAME)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """320x180 shaky clip; frame 20 black so that motion estimation warns (the `log` family)."""
    config = synthetic.SyntheticConfig(width=320, height=180, n_frames=N_FRAMES, seed=3, jitter_px=4.0,
                                       blur_length_px=6.0)
    video = synthetic.generate(config)
    video.frames[20] = np.zeros_like(video.frames[20])
    path = tmp_path_factory.mktemp("clip") / "shaky.mp4"
    synthetic.write_video(video, path)
    return path


@pytest.fixture(scope="module")
def full_run(clip, tmp_path_factory):
    """Full mode, full level, lossless (so images compare exactly), traced frames + one outside the clip."""
    rrd = tmp_path_factory.mktemp("rec") / "full.rrd"
    collector = StageCollector(*STAGES)
    recorder = RerunRecorder(rrd, level="full", jpeg_quality=None, trace_frames=TRACED + (999,))
    stabilize(clip, None, StabilizeConfig(mode="full"), observer=Observers(recorder, collector))
    return Recording.load(rrd), collector


def by_frame(collector, stage):
    return {stamp.index: result for stamp, result in collector.results[stage]}


def test_every_family_has_one_row_per_frame_on_both_timelines(full_run):
    recording, collector = full_run
    frames = list(range(N_FRAMES))
    for entity in PER_FRAME_IMAGES:
        assert recording.indices(entity) == frames, entity
        assert recording.timelines(entity) == {ent.FRAME_TIMELINE, ent.VIDEO_TIME_TIMELINE}, entity
    series = [f"{ent.MOTION_PARAMS}/{name}" for name in ent.MOTION_PARAM_NAMES]
    series += [ent.MOTION_INLIERS, ent.MOTION_INLIER_RATIO, ent.MOTION_RESIDUAL]
    series += [f"{root}/{axis}" for root in (ent.TRAJECTORY_ORIGINAL, ent.TRAJECTORY_SMOOTHED)
               for axis in ent.TRAJECTORY_AXES]
    series += [*COMPLETION_SERIES, ent.COMPLETION_TEMPORAL]
    for entity in series:
        assert recording.scalars(entity)[0].tolist() == frames, entity
    motion = by_frame(collector, "motion")
    with_features = [t for t in frames if len(motion[t].curr_points)]
    assert recording.indices(f"{ent.MOTION_FEATURES}/points", column="Points2D:positions") == with_features
    assert recording.indices(f"{ent.MOTION_FEATURES}/arrows", column="Arrows2D:vectors") == with_features
    completion = by_frame(collector, "completion")
    with_fills = [t for t in frames if completion[t].fills]
    assert with_fills, "the clip should need local warps somewhere"
    for entity in (ent.COMPLETION_FLOW_IMAGE, ent.COMPLETION_FMM_ORDER, ent.COMPLETION_FMM_ARRIVAL):
        assert recording.indices(entity) == with_fills, entity
    assert recording.indices(ent.COMPLETION_FLOW_ARROWS, column="Arrows2D:vectors") == with_fills
    assert recording.texts(ent.MOTION_STATUS, "TextLog:text") == [motion[t].status for t in frames]


def test_logged_values_equal_the_pipelines(full_run):
    recording, collector = full_run
    motion = by_frame(collector, "motion")
    width, height = 320, 180
    params = np.array([geometry.decompose(motion[t].curr_from_prev, width, height) for t in range(N_FRAMES)])
    for column, name in enumerate(ent.MOTION_PARAM_NAMES):
        np.testing.assert_allclose(recording.scalars(f"{ent.MOTION_PARAMS}/{name}")[1], params[:, column], atol=1e-9)
    np.testing.assert_array_equal(recording.scalars(ent.MOTION_INLIERS)[1], [motion[t].n_inliers for t in range(N_FRAMES)])
    np.testing.assert_allclose(recording.scalars(ent.MOTION_RESIDUAL)[1], [motion[t].residual_px for t in range(N_FRAMES)])
    (_, smoothed), = collector.results["smoothing"]
    for root, truth in ((ent.TRAJECTORY_ORIGINAL, smoothed.original_trajectory),
                        (ent.TRAJECTORY_SMOOTHED, smoothed.smoothed_trajectory)):
        for column, axis in enumerate(ent.TRAJECTORY_AXES):
            np.testing.assert_allclose(recording.scalars(f"{root}/{axis}")[1], truth[:, column], atol=1e-9)

    inputs, warps, outputs = by_frame(collector, "input"), by_frame(collector, "warp"), by_frame(collector, "output")
    completion = by_frame(collector, "completion")
    for t in (0, 5, 20, 29):
        np.testing.assert_array_equal(recording.image(ent.INPUT_FRAME, t), inputs[t].rgb)
        np.testing.assert_array_equal(recording.image(ent.STABILIZED_FRAME, t), warps[t].frame)
        np.testing.assert_array_equal(recording.image(ent.STABILIZED_MISSING, t) > 0, warps[t].missing)
        np.testing.assert_array_equal(recording.image(ent.OUTPUT_FRAME, t), outputs[t])
        result = completion[t]
        np.testing.assert_array_equal(recording.image(ent.COMPLETION_FRAME, t), result.frame)
        np.testing.assert_array_equal(recording.image(ent.COMPLETION_FALLBACK, t) > 0, result.fallback)
        np.testing.assert_array_equal(recording.image(ent.COMPLETION_ACCEPTED, t) == 2, result.mosaic.accepted)
        np.testing.assert_array_equal(recording.map(ent.COMPLETION_VARIANCE, t),
                                      np.where(np.isfinite(result.mosaic.variance), result.mosaic.variance, np.nan)
                                      .astype(np.float32))
        filled_by = recording.image(ent.COMPLETION_FILLED_BY, t)
        np.testing.assert_array_equal(filled_by == 1, result.source == SOURCE_MOSAIC)
        np.testing.assert_array_equal(filled_by == 2, result.source == SOURCE_FALLBACK)
        warped = from_a_neighbour(result.source)
        np.testing.assert_array_equal(filled_by[warped].astype(int) - FILLED_BY_BASE, result.filled_by[warped])
        np.testing.assert_array_equal(recording.image(ent.COMPLETION_SOURCE, t), result.source)
        if result.fills:
            inpainted = result.fills[0].inpainted
            order = recording.map(ent.COMPLETION_FMM_ORDER, t)
            np.testing.assert_array_equal(np.nan_to_num(order, nan=-1), inpainted.order)
            np.testing.assert_array_equal(recording.image(ent.COMPLETION_FLOW_IMAGE, t), visual.flow_to_rgb(inpainted.flow))
        frame_area = result.missing.size
        for name, value in (("missing", result.missing.sum()), ("fallback", result.fallback.sum()),
                            *((name.replace(" ", "_"), (result.source == code).sum())
                              for code, name in enumerate(SOURCE_NAMES) if code)):
            frames, values = recording.scalars(f"{ent.COMPLETION_STATS}/{name}")
            assert values[t] == pytest.approx(value / frame_area, abs=1e-12)


def test_deblur_family_matches_the_pipeline(full_run):
    recording, collector = full_run
    deblurred = by_frame(collector, "deblur")
    assert deblurred, "full mode deblurs by default (StabilizeConfig().deblurring), yet no frame reached the observer"
    frames = sorted(deblurred)
    logged_frames, blurriness = recording.scalars(ent.DEBLUR_BLURRINESS)
    assert logged_frames.tolist() == frames
    np.testing.assert_allclose(blurriness, [deblurred[t].blurriness for t in frames], rtol=1e-12)
    np.testing.assert_array_equal(recording.scalars(ent.DEBLUR_NEIGHBOURS)[1], [len(deblurred[t].neighbours) for t in frames])
    sharpened = [t for t in frames if deblurred[t].neighbours]
    assert sharpened, "the clip's blurred frames should have sharper neighbours"
    for entity in (ent.DEBLUR_BEFORE, ent.DEBLUR_AFTER, ent.DEBLUR_WEIGHTS, ent.map_values(ent.DEBLUR_WEIGHTS)):
        assert recording.indices(entity) == sharpened, entity
    t = sharpened[0]
    np.testing.assert_array_equal(recording.image(ent.DEBLUR_BEFORE, t), deblurred[t].before)
    np.testing.assert_array_equal(recording.image(ent.DEBLUR_AFTER, t), deblurred[t].frame)
    stored = recording.image(ent.map_values(ent.DEBLUR_WEIGHTS), t)
    assert_weights(stored, deblurred[t].weights)
    # The view shows the stored weights in the key's colours, opaque (as a depth image with a colour map, rerun
    # drew every weight in the map's lowest colour).
    shown = recording.image(ent.DEBLUR_WEIGHTS, t)
    expected = visual.colour_mapped(stored.astype(np.float32) / ent.DEBLUR_WEIGHTS_SCALE, "viridis", (0.0, 1.0))
    np.testing.assert_array_equal(shown, expected)
    assert (shown[..., 3] == 255).all() and stored.max() > stored.min()
    # Where each pixel came from: the main source's offset, and the refused pixels, per frame.
    np.testing.assert_allclose(recording.scalars(ent.DEBLUR_REFUSED)[1],
                               [0.0 if deblurred[f].refused is None else deblurred[f].refused.mean() for f in frames])
    source = recording.image(ent.DEBLUR_SOURCE, t).astype(int)
    result = deblurred[t]
    # Red where a sharper neighbour was refused and none gave the pixel; elsewhere the neighbour that gave most.
    taken = result.main_source != 0
    np.testing.assert_array_equal(source == 1, result.refused & ~taken)
    np.testing.assert_array_equal(source[taken] - FILLED_BY_BASE, result.main_source[taken])
    assert taken.any() and (result.refused & taken).any()  # some refusals hide under a neighbour's pixels


def test_log_and_meta(full_run):
    recording, collector = full_run
    logged = recording.texts(ent.LOG, "TextLog:text")
    warnings = [message for _, message in collector.warnings]
    assert warnings, "the black frame should make motion estimation warn"
    # Per-frame warnings sit at their frame; the others are static.
    assert recording.indices(ent.LOG, column="TextLog:text") == sorted(
        {stamp.index for stamp, _ in collector.warnings if stamp is not None})
    # Every pipeline warning, plus the recorder's note about the traced frame outside the clip.
    assert sorted(m for m in logged if "traced frame" not in m) == sorted(warnings)
    assert any("999" in m and "not traced" in m for m in logged)
    meta = recording.texts(ent.META, "TextDocument:text")[0]
    assert f"rerun-sdk {rr.__version__}" in meta and f"ffviz {ffviz.__version__}" in meta


def test_traced_frames_step_through_every_stage_in_order(full_run):
    recording, collector = full_run
    inputs, warps, outputs = by_frame(collector, "input"), by_frame(collector, "warp"), by_frame(collector, "output")
    completion, deblurred = by_frame(collector, "completion"), by_frame(collector, "deblur")
    assert ent.trace_image(999) not in recording.entities
    for t in TRACED:
        image, label = ent.trace_image(t), ent.trace_label(t)
        expected_stages = [0, 1, 2, 3] + ([4] if t in deblurred else []) + [5]
        assert recording.indices(image, ent.STAGE_TIMELINE) == expected_stages
        assert recording.indices(image, ent.FRAME_TIMELINE) == [t]  # findable on the frame timeline
        labels = recording.labels(label, ent.STAGE_TIMELINE)
        assert sorted(labels) == expected_stages
        for stage, text in labels.items():
            assert text.endswith(ent.TRACE_STAGES[stage]) and f"frame {t}" in text
        result = completion[t]
        local_warp = np.where(from_a_neighbour(result.source)[..., None], result.frame, result.mosaic.frame)
        expected = {0: inputs[t].rgb, 1: warps[t].frame, 2: result.mosaic.frame, 3: local_warp, 5: outputs[t]}
        if t in deblurred:
            expected[4] = deblurred[t].frame
        for stage, rgb in expected.items():
            np.testing.assert_array_equal(recording.image(image, stage, ent.STAGE_TIMELINE), rgb, err_msg=f"stage {stage}")
    # Nothing else landed on the stage timeline: it was switched off after each trace.
    assert recording.indices(ent.OUTPUT_FRAME, ent.STAGE_TIMELINE) == []


def test_fast_marching_band_advances_in_the_pipelines_visiting_order(full_run):
    recording, collector = full_run
    completion = by_frame(collector, "completion")
    for t in TRACED:
        order = completion[t].fills[0].inpainted.order
        n_filled = int(order.max()) + 1
        steps = min(trace.FMM_STEPS, n_filled)
        entity = ent.trace_fmm(t)
        assert recording.indices(entity, ent.FMM_STEP_TIMELINE) == list(range(steps + 1))
        assert recording.indices(entity, ent.FRAME_TIMELINE) == [t]
        pictures = [recording.image(entity, s, ent.FMM_STEP_TIMELINE) for s in range(steps + 1)]
        to_fill = order >= 0
        final = pictures[-1][to_fill]
        thresholds = trace.fmm_thresholds(n_filled)  # even shares of the order (rounded as linspace does)
        assert np.abs(thresholds - np.arange(steps + 1) * n_filled / steps).max() <= 0.5 + 1e-9
        for step, picture in enumerate(pictures):
            # Exactly the pixels Fast Marching visited before this step's share of the order show their final
            # colour; the rest show the "to fill" colour or the band.
            threshold = thresholds[step]
            shown = (picture[to_fill] == final).all(axis=-1)
            np.testing.assert_array_equal(shown, order[to_fill] < threshold, err_msg=f"frame {t} step {step}")
            band = (picture == trace.BAND_RGB).all(axis=-1) & to_fill
            if 0 < step < steps:
                assert band.any() and (order[band] >= threshold).all()
        labels = recording.labels(ent.trace_fmm_label(t), ent.FMM_STEP_TIMELINE)
        assert f"{n_filled} of {n_filled} pixels filled" in labels[steps]


def test_summary_level_keeps_series_and_output_and_traces_only_when_asked(clip, tmp_path):
    default = tmp_path / "default.rrd"
    stabilize(clip, None, StabilizeConfig(mode="none"), observer=RerunRecorder(default, level="summary"))
    asked = tmp_path / "asked.rrd"
    collector = StageCollector("output", "deblur")
    stabilize(clip, None, StabilizeConfig(mode="none"),
              observer=Observers(RerunRecorder(asked, level="summary", trace_frames=[7]), collector))
    recording = Recording.load(default)
    assert not any(e.startswith(f"{ent.TRACE}/") for e in recording.entities)
    assert recording.indices(ent.OUTPUT_FRAME) == list(range(N_FRAMES))
    assert recording.indices(ent.INPUT_FRAME) == [] and recording.indices(ent.STABILIZED_FRAME) == []
    # Frame streams are H.264 by default: close to the pipeline's output, not equal (ringing at the black border
    # of mode none; measured 3.8-4.1 levels mean, PSNR about 31 dB, on different runs).
    outputs = by_frame(collector, "output")
    decoded = recording.image(ent.OUTPUT_FRAME, 10)
    assert synthetic.psnr(decoded, outputs[10]) > 27.0
    assert np.mean(np.abs(decoded.astype(float) - outputs[10])) < 6.0
    asked_recording = Recording.load(asked)
    # Mode none: no completion stages.
    deblurred = [4] if 7 in by_frame(collector, "deblur") else []
    assert asked_recording.indices(ent.trace_image(7), ent.STAGE_TIMELINE) == [0, 1] + deblurred + [5]
    # The default blueprint is embedded, with a view of the traced frame.
    printed = subprocess.run([rerun_executable(), "rrd", "print", "-vvv", str(asked)], capture_output=True, text=True,
                             env=dict(os.environ, RERUN_ANALYTICS="0"), check=True).stdout
    assert "Blueprint" in printed and "frame 7: stages (time line stage)" in printed


def test_default_traced_frames_are_spread_and_have_missing_area():
    n, width, height = 30, 320, 180
    orig_from_stab = np.repeat(np.eye(3)[None], n, axis=0)
    shifted = {4: 6.0, 13: 2.0, 14: 9.0, 25: 3.0}  # frame: x shift (px) -> a missing strip that wide
    for t, dx in shifted.items():
        orig_from_stab[t, 0, 2] = dx
    missing = trace.missing_fractions(orig_from_stab, width, height)
    np.testing.assert_allclose(missing[list(shifted)], [dx / width for dx in shifted.values()], atol=1e-6)
    assert trace.default_trace_frames(orig_from_stab, width, height, count=3) == [4, 14, 25]
    # No frame with missing area: the middle of each part.
    assert trace.default_trace_frames(np.repeat(np.eye(3)[None], n, axis=0), width, height, count=3) == [5, 15, 25]


def test_frame_lists_parse_or_explain():
    assert trace.parse_frame_list("10,40") == (10, 40)
    assert trace.parse_frame_list(" 40, 10,10 ") == (10, 40)
    assert trace.parse_frame_list("none") == () and trace.parse_frame_list("auto") is None
    for bad in ("ten", "3,-1"):
        with pytest.raises(ValueError, match="frame"):
            trace.parse_frame_list(bad)


def assert_weights(recorded, weights):
    """Weights are recorded as uint8 (255 = 1): equal to the pipeline's to half a step."""
    np.testing.assert_allclose(recorded / ent.DEBLUR_WEIGHTS_SCALE, weights, atol=0.5 / ent.DEBLUR_WEIGHTS_SCALE + 1e-6)


def _info(width=64, height=48):
    return SimpleNamespace(path="fake.mp4", width=width, height=height, fps=30.0, frame_count=2)


def _deblur_run(tmp_path, results):
    """Hand deblurring results for frames 0, 1, ... to a lossless recorder tracing frame 0; read it back."""
    rrd = tmp_path / "deblur.rrd"
    height, width = results[0].frame.shape[:2]
    recorder = RerunRecorder(rrd, level="full", jpeg_quality=None, trace_frames=[0])
    recorder.on_start(_info(width, height), None)
    for t, result in enumerate(results):
        recorder.on_frame(FrameResult(Stamp(t, t / 30), None, result.frame, deblur=result))
    recorder.close()
    return Recording.load(rrd)


def test_deblur_results_are_recorded(tmp_path):
    rng = np.random.default_rng(0)
    image = lambda: rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    sharpened = DeblurResult(frame=image(), before=image(), blurriness=2.5e-4, neighbours=(-1, 2),
                             weights=rng.random((48, 64), dtype=np.float32))
    untouched = image()
    unchanged = DeblurResult(frame=untouched, before=untouched, blurriness=1.0e-4, neighbours=(),
                             weights=np.zeros((48, 64), np.float32))
    recording = _deblur_run(tmp_path, [sharpened, unchanged])
    np.testing.assert_allclose(recording.scalars(ent.DEBLUR_BLURRINESS)[1], [2.5e-4, 1.0e-4])
    np.testing.assert_array_equal(recording.scalars(ent.DEBLUR_NEIGHBOURS)[1], [2, 0])
    # Only the sharpened frame has before/after/weights (the other frame clears them).
    for entity in (ent.DEBLUR_BEFORE, ent.DEBLUR_AFTER, ent.DEBLUR_WEIGHTS, ent.map_values(ent.DEBLUR_WEIGHTS)):
        assert recording.indices(entity) == [0], entity
        assert recording.rows(entity) == 2, entity
    np.testing.assert_array_equal(recording.image(ent.DEBLUR_BEFORE, 0), sharpened.before)
    np.testing.assert_array_equal(recording.image(ent.DEBLUR_AFTER, 0), sharpened.frame)
    assert_weights(recording.image(ent.map_values(ent.DEBLUR_WEIGHTS), 0), sharpened.weights)
    np.testing.assert_array_equal(recording.image(ent.trace_image(0), 4, ent.STAGE_TIMELINE), sharpened.frame)


def test_real_deblur_results_are_recorded(tmp_path):
    from pipeline.stages import deblur
    video = synthetic.generate(synthetic.SyntheticConfig(width=160, height=96, n_frames=4, seed=1, moving_object=False,
                                                         blurred_frames=(2,), blur_length_px=6.0))
    everywhere = np.ones((96, 160), bool)
    # Frame 2 is blurred; its sharp version, perfectly aligned, is a sharper neighbour. The other way round,
    # a blurred neighbour of a sharp frame contributes nothing.
    def run(target, neighbour):
        b_t = deblur.blurriness(target)
        return deblur.deblur(target, everywhere, [WarpedNeighbour(1, neighbour, everywhere)],
                             ratios={1: b_t / deblur.blurriness(neighbour)}, blurriness_t=b_t)

    sharpened = run(video.frames[2], video.sharp_frames[2])
    unchanged = run(video.sharp_frames[2], video.frames[2])
    assert sharpened.neighbours == (1,) and unchanged.neighbours == ()
    recording = _deblur_run(tmp_path, [sharpened, unchanged])
    np.testing.assert_allclose(recording.scalars(ent.DEBLUR_BLURRINESS)[1], [sharpened.blurriness, unchanged.blurriness])
    np.testing.assert_array_equal(recording.scalars(ent.DEBLUR_NEIGHBOURS)[1], [1, 0])
    assert recording.indices(ent.DEBLUR_AFTER) == [0]
    np.testing.assert_array_equal(recording.image(ent.DEBLUR_AFTER, 0), sharpened.frame)
    assert_weights(recording.image(ent.map_values(ent.DEBLUR_WEIGHTS), 0), sharpened.weights)


# -- the default (compact) recording: video frame streams, PNG masks and maps, colour keys, layout ---------------

@pytest.fixture(scope="module")
def compact_run(clip, tmp_path_factory):
    """Full mode, full level, default encoding (what `ffviz stabilize --rrd` writes)."""
    rrd = tmp_path_factory.mktemp("compact") / "compact.rrd"
    collector = StageCollector(*STAGES)
    stabilize(clip, None, StabilizeConfig(mode="full"),
              observer=Observers(RerunRecorder(rrd, level="full", trace_frames=TRACED), collector))
    return rrd, Recording.load(rrd), collector


def test_frame_streams_are_h264_video_that_decodes_to_every_frame(compact_run):
    rrd, recording, collector = compact_run
    stages = {ent.INPUT_FRAME: [f.rgb for _, f in collector.results["input"]],
              ent.STABILIZED_FRAME: [r.frame for _, r in collector.results["warp"]],
              ent.COMPLETION_FRAME: [r.frame for _, r in collector.results["completion"]],
              ent.OUTPUT_FRAME: [rgb for _, rgb in collector.results["output"]]}
    for entity, truth in stages.items():
        assert recording.video_codec(entity) == rr.VideoCodec.H264.value, entity
        samples = recording.video_samples(entity)
        assert [frame for frame, _, _ in samples] == list(range(N_FRAMES)), entity
        assert samples[0][2], "the first sample is a keyframe"
        frames = recording.video_frames(entity)  # PyAV decodes the stored samples
        assert sorted(frames) == list(range(N_FRAMES))
        errors = [np.mean(np.abs(frames[t].astype(float) - truth[t])) for t in range(N_FRAMES)]
        assert max(errors) < 6.0, (entity, max(errors))  # H.264 at crf 20: close, not exact
        assert recording.indices(entity) == list(range(N_FRAMES))


def test_odd_sized_frames_read_back_at_their_own_size(tmp_path):
    """4:2:0 H.264 needs even sizes, so a 161x97 clip is recorded padded by a row and a column; reading back
    crops to the frame's own size."""
    video = synthetic.generate(synthetic.SyntheticConfig(width=161, height=97, n_frames=6, seed=2))
    clip = tmp_path / "odd.mkv"
    with av.open(str(clip), "w") as container:  # FFV1 4:4:4 keeps the odd size (x264's 4:2:0 would not)
        stream = container.add_stream("ffv1", rate=30)
        stream.width, stream.height, stream.pix_fmt = 161, 97, "yuv444p"
        for rgb in video.frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24").reformat(format="yuv444p")))
        container.mux(stream.encode(None))
    rrd = tmp_path / "odd.rrd"
    outputs = StageCollector("output")
    stabilize(clip, None, StabilizeConfig(mode="none", deblur=DeblurConfig(enabled=False)),
              observer=Observers(RerunRecorder(rrd, level="summary"), outputs))
    frames = Recording.load(rrd).video_frames(ent.OUTPUT_FRAME)
    assert sorted(frames) == list(range(6))
    for stamp, truth in outputs.results["output"]:
        back = frames[stamp.index].astype(float)
        assert back.shape == truth.shape == (97, 161, 3)
        aligned = np.mean(np.abs(back - truth))  # H.264 at crf 20 on a small textured frame: ~6 levels
        shifted = np.mean(np.abs(back[1:, 1:] - truth[:-1, :-1]))  # what a crop on the wrong side would match
        assert aligned < 8.0 and shifted > 1.3 * aligned, (aligned, shifted)


def test_masks_are_exact_and_maps_within_half_a_step(compact_run):
    _, recording, collector = compact_run
    warps, completion = by_frame(collector, "warp"), by_frame(collector, "completion")
    for t in (0, 5, 18, 29):
        result = completion[t]
        np.testing.assert_array_equal(recording.image(ent.STABILIZED_MISSING, t) > 0, warps[t].missing)
        np.testing.assert_array_equal(recording.image(ent.COMPLETION_ACCEPTED, t) == 2, result.mosaic.accepted)
        np.testing.assert_array_equal(recording.image(ent.COMPLETION_FALLBACK, t) > 0, result.fallback)
        filled_by = recording.image(ent.COMPLETION_FILLED_BY, t)
        warped = from_a_neighbour(result.source)
        np.testing.assert_array_equal(filled_by == 1, result.source == SOURCE_MOSAIC)
        np.testing.assert_array_equal(recording.image(ent.COMPLETION_SOURCE, t), result.source)
        np.testing.assert_array_equal(filled_by[warped].astype(int) - FILLED_BY_BASE, result.filled_by[warped])
        variance = recording.map(ent.COMPLETION_VARIANCE, t)
        truth = result.mosaic.variance
        np.testing.assert_array_equal(np.isnan(variance), ~np.isfinite(truth))
        finite = np.isfinite(truth) & (truth < 16000)
        assert np.all(np.abs(variance[finite] - truth[finite]) <= ent.MAP_STEPS[ent.COMPLETION_VARIANCE] / 2 + 1e-3)
        if result.fills:
            order = recording.map(ent.COMPLETION_FMM_ORDER, t)
            truth = result.fills[0].inpainted.order.astype(np.float32)
            np.testing.assert_array_equal(np.isnan(order), truth < 0)
            visited = truth >= 0
            assert np.all(np.abs(order[visited] - truth[visited]) <= ent.MAP_STEPS[ent.COMPLETION_FMM_ORDER] / 2)
            arrival = recording.map(ent.COMPLETION_FMM_ARRIVAL, t)
            truth = result.fills[0].inpainted.arrival
            ok = np.isfinite(truth)
            np.testing.assert_array_equal(np.isnan(arrival), ~ok)
            assert np.all(np.abs(arrival[ok] - truth[ok]) <= ent.MAP_STEPS[ent.COMPLETION_FMM_ARRIVAL] / 2 + 1e-4)
    deblurred = by_frame(collector, "deblur")
    sharpened = [t for t in sorted(deblurred) if deblurred[t].neighbours]
    if sharpened:
        recorded = recording.image(ent.map_values(ent.DEBLUR_WEIGHTS), sharpened[0]) / ent.DEBLUR_WEIGHTS_SCALE
        np.testing.assert_allclose(recorded, deblurred[sharpened[0]].weights,
                                   atol=(WEIGHTS_STEP / 2 + 0.5) / ent.DEBLUR_WEIGHTS_SCALE + 1e-6)


def test_maps_are_shown_transparent_where_they_have_no_value(compact_run, full_run):
    """The maps the views show: opaque in their key's colours where the map has a value, alpha 0 elsewhere (a
    depth image paints those in the colour map's lowest colour, which read as value 0 over the whole frame)."""
    for recording, collector in ((compact_run[1], compact_run[2]), full_run):
        completion = by_frame(collector, "completion")
        checked = 0
        for t in (5, 18, 29):
            result = completion[t]
            maps = [(ent.COMPLETION_VARIANCE, result.mosaic.variance, np.isfinite(result.mosaic.variance),
                     "turbo", visual.VARIANCE_RANGE)]
            if result.fills:
                inpainted = result.fills[0].inpainted
                order = inpainted.order.astype(np.float32)
                maps += [(ent.COMPLETION_FMM_ORDER, order, order >= 0, "viridis", (0.0, float(order.max()))),
                         (ent.COMPLETION_FMM_ARRIVAL, inpainted.arrival,
                          np.isfinite(inpainted.arrival) & (inpainted.arrival > 0), "magma", visual.ARRIVAL_RANGE)]
            for entity, values, has_value, colormap, value_range in maps:
                shown = recording.image(entity, t)
                assert shown.shape == values.shape + (4,), entity
                assert has_value.any() and not has_value.all(), (entity, t)
                np.testing.assert_array_equal(shown[..., 3] == 255, has_value, err_msg=entity)
                assert not shown[~has_value].any(), f"{entity} {t}: pixels without a value are not transparent"
                expected = visual.colour_mapped(np.where(has_value, values, np.nan), colormap, value_range)
                np.testing.assert_array_equal(shown, expected, err_msg=entity)
                checked += 1
        for entity in (ent.COMPLETION_VARIANCE, ent.COMPLETION_FMM_ORDER, ent.COMPLETION_FMM_ARRIVAL):
            # The viewer draws an image of opacity 1 opaque, its transparent pixels black.
            opacity = component_values(recording, entity, "EncodedImage:opacity")
            assert opacity and max(opacity) < 1.0, entity
        assert checked >= 5


def component_values(recording, entity, column):
    return [v[0] if isinstance(v, list) else v for b in recording.batches[entity] if column in b.schema.names
            for v in b.column(column).to_pylist() if v is not None]


def test_masks_are_drawn_over_their_frames_and_let_them_show(compact_run):
    """Each mask's view holds the frame it describes, the mask above it and see-through (at opacity 1 the viewer
    draws its transparent pixels black, hiding the video)."""
    from ffviz import blueprint

    recording = compact_run[1]
    under = {ent.STABILIZED_MISSING: ent.STABILIZED_FRAME, ent.COMPLETION_ACCEPTED: ent.COMPLETION_FRAME,
             ent.COMPLETION_FILLED_BY: ent.COMPLETION_FRAME, ent.COMPLETION_SOURCE: ent.COMPLETION_FRAME,
             ent.DEBLUR_SOURCE: ent.DEBLUR_AFTER}
    def views(item):
        if isinstance(item, rr.blueprint.View):
            yield item
        else:
            for inner in getattr(item, "contents", None) or []:
                yield from views(inner)

    shown_with = [list(view.contents or []) for view in views(blueprint.default_blueprint(TRACED).root_container)]
    for mask, frame in under.items():
        holding = [contents for contents in shown_with if f"/{mask}" in contents]
        assert holding and all(contents.index(f"/{frame}") < contents.index(f"/{mask}") for contents in holding), mask
    for mask in (ent.STABILIZED_MISSING, ent.COMPLETION_ACCEPTED, ent.COMPLETION_FILLED_BY, ent.COMPLETION_FALLBACK,
                 ent.COMPLETION_SOURCE):
        opacity = component_values(recording, mask, "EncodedImage:opacity")
        assert opacity and max(opacity) < 1.0, mask
        assert min(component_values(recording, mask, "EncodedImage:draw_order")) > 0, mask


def test_colour_mapped_pictures_follow_the_key():
    """visual.colour_mapped: the key's colour map over the range, ends included, clipped beyond; NaN and not
    shown pixels transparent."""
    values = np.array([[0.0, 50.0, 100.0, 150.0, np.nan, -5.0]], np.float32)
    rgba = visual.colour_mapped(values, "viridis", (0.0, 100.0), shown=np.array([[1, 1, 1, 1, 1, 0]], bool))
    bar = visual.colour_bar("viridis", 0, 100, "", "")[30, 14:-14]  # the key's ramp, low to high
    np.testing.assert_array_equal(rgba[0, 0, :3], bar[0])
    np.testing.assert_array_equal(rgba[0, 2, :3], bar[-1])
    np.testing.assert_array_equal(rgba[0, 3], rgba[0, 2])  # clipped at the top
    assert np.abs(rgba[0, 1, :3].astype(int) - bar[len(bar) // 2]).max() <= 8
    np.testing.assert_array_equal(rgba[0, :4, 3], 255)
    np.testing.assert_array_equal(rgba[0, 4:], 0)


def test_flow_pictures_show_no_value_in_the_keys_grey_and_every_flow_in_colour():
    """visual.flow_to_rgb: where no flow was computed (NaN), the grey every key names "no value", which no flow
    colour is (their HSV value is always full); zero flow white, a flow at the scale a saturated hue. The flow key
    carries the same grey swatch. (No value was once black, which the key did not name.)"""
    flow = np.array([[[0.0, 0.0], [3.0, 0.0], [0.0, -3.0], [np.nan, np.nan], [1.0, np.nan]]], np.float32)
    rgb = visual.flow_to_rgb(flow, max_magnitude=3.0)
    np.testing.assert_array_equal(rgb[0, 3:], [visual.NO_VALUE_COLOUR] * 2)
    np.testing.assert_array_equal(rgb[0, 0], (255, 255, 255))
    assert rgb[0, 1].max() == 255 and rgb[0, 1].min() == 0 and rgb[0, 2].max() == 255 and rgb[0, 2].min() == 0
    angles = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    for magnitude in (0.0, 0.5, 1.0, 2.0):
        every = np.stack([np.cos(angles), np.sin(angles)], axis=-1)[None].astype(np.float32) * magnitude
        assert (visual.flow_to_rgb(every, max_magnitude=1.0).max(axis=-1) == 255).all()
    key = visual.flow_wheel()
    assert (key == visual.NO_VALUE_COLOUR).all(axis=-1).sum() >= 100  # the swatch


def test_every_colour_mapped_entity_has_a_colour_key(compact_run, full_run):
    for recording in (compact_run[1], full_run[0]):
        for entity, key in ent.KEY_OF.items():
            assert entity in recording.entities, entity
            image = recording.image(ent.key_entity(key), 0) if recording.indices(ent.key_entity(key)) else None
            static = [b for b in recording.batches[ent.key_entity(key)] if "EncodedImage:blob" in b.schema.names]
            assert static or image is not None, f"no colour key {key!r} for {entity}"


def test_compact_recording_is_a_fraction_of_the_lossless_one(compact_run, full_run, tmp_path_factory):
    rrd, _, _ = compact_run
    lossless = next(p for p in tmp_path_factory.getbasetemp().glob("rec*/full.rrd"))
    assert rrd.stat().st_size < lossless.stat().st_size / 4, (rrd.stat().st_size, lossless.stat().st_size)


def test_crop_mode_records_the_crop_window(clip, tmp_path):
    rrd = tmp_path / "crop.rrd"
    collector = StageCollector("crop")
    stabilize(clip, None, StabilizeConfig(mode="crop"),
              observer=Observers(RerunRecorder(rrd, level="summary"), collector))
    (_, crop), = collector.results["crop"]
    recording = Recording.load(rrd)
    boxes = [b for b in recording.batches[ent.CROP_WINDOW] if "Boxes2D:half_sizes" in b.schema.names]
    assert boxes, "no crop window"
    batch = boxes[-1]
    centre = np.array(batch.column("Boxes2D:centers").to_pylist()[-1][0])
    size = 2 * np.array(batch.column("Boxes2D:half_sizes").to_pylist()[-1][0])
    np.testing.assert_allclose(size, [crop.scale * 320, crop.scale * 180], rtol=1e-5)
    np.testing.assert_allclose(centre - size / 2, [crop.x0, crop.y0], atol=1e-3)
    meta = recording.texts(ent.META, "TextDocument:text")[-1]
    assert "crop window" in meta and f"{crop.scale:.3f}" in meta
    assert snapshot.layout_facts(rrd)[1]["crop"]  # its layout has crop charts


def _chart_origins(bp) -> set[str]:
    import rerun.blueprint as rrb

    def walk(item):
        if isinstance(item, (rrb.TimeSeriesView, rrb.TextLogView)):
            yield str(item.origin).strip("/")
        for inner in getattr(item, "contents", None) or []:
            if not isinstance(inner, str):
                yield from walk(inner)

    return set(walk(bp.root_container))


def test_option_charts_appear_for_runs_with_the_option_only_so_no_panel_stays_empty(compact_run):
    from ffviz import blueprint

    crop_charts, skew_chart = {ent.CROP_SCALE, ent.CROP_ROOM}, {ent.ROLLING_SHUTTER_SKEW}
    assert crop_charts <= _chart_origins(blueprint.default_blueprint(TRACED, crop=True))
    assert skew_chart <= _chart_origins(blueprint.default_blueprint(TRACED, rolling_shutter=True))
    assert not (crop_charts | skew_chart) & _chart_origins(blueprint.default_blueprint(TRACED))
    assert ent.LOG in _chart_origins(blueprint.default_blueprint(TRACED, log=True))
    assert ent.LOG not in _chart_origins(blueprint.default_blueprint(TRACED, log=False))
    rrd, recording, collector = compact_run
    log = bool(recording.batches.get(ent.LOG))
    assert log == bool(collector.warnings)  # this clip's run notes nothing but its warnings
    assert snapshot.layout_facts(rrd) == (sorted(TRACED), {"crop": False, "rolling_shutter": False, "log": log,
                                                          "portrait": False})
    assert not len(recording.scalars(ent.CROP_SCALE)[0]) and not len(recording.scalars(ent.CROP_ROOM)[0])
    layout = _embedded_layout(rrd)  # the recorder's own layout says the same
    assert ("warnings and notes" in layout) == log and "crop scale" not in layout and "frame 5: stages" in layout


def _embedded_layout(rrd) -> str:
    return subprocess.run([rerun_executable(), "rrd", "print", "-vvv", str(rrd)], capture_output=True, text=True,
                          env=dict(os.environ, RERUN_ANALYTICS="0"), check=True).stdout


def test_blueprint_opens_on_frame_0_paused_with_the_overview_first():
    import rerun.blueprint as rrb

    from ffviz import blueprint

    bp = blueprint.default_blueprint((5,))
    tabs = bp.root_container
    assert isinstance(tabs, rrb.Tabs) and tabs.active_tab == 0
    assert [c.name for c in tabs.contents] == list(blueprint.TAB_ORDER)
    assert bp.time_panel.play_state == "paused" and bp.time_panel.timeline == ent.FRAME_TIMELINE
    for tab in blueprint.TAB_NOTES:
        assert tab in blueprint.TAB_ORDER


def test_about_tab_is_a_readable_summary(compact_run):
    _, recording, collector = compact_run
    meta = recording.texts(ent.META, "TextDocument:text")[-1]
    assert meta.startswith("# About this recording")
    assert "## Settings" in meta and "**smoothing**" in meta.split("## All settings")[1]
    settings = meta.split("## Settings")[1].split("##")[0]
    assert "- mode: full frame" in settings and "k = 60 frames" in settings
    assert "- changed from the defaults: nothing" in settings  # the fixture runs StabilizeConfig(mode="full")
    assert f"- warnings: {len(collector.warnings)}" in meta
    assert "frames in" in meta and "render pass" in meta


def test_about_tab_names_the_settings_that_differ_from_the_defaults():
    import dataclasses

    from pipeline.stages.deblur import DeblurConfig
    from pipeline.stages.smoothing import SmoothingConfig

    config = StabilizeConfig(mode="crop", smoothing=SmoothingConfig(radius_frames=12),
                             deblur=dataclasses.replace(DeblurConfig(), enabled=False))
    meta = about.about_markdown(None, config)
    settings = meta.split("## Settings")[1].split("##")[0]
    assert "- mode: crop" in settings and "k = 12 frames" in settings
    assert "`smoothing.radius_frames = 12`" in settings and "`deblur.enabled = False`" in settings
    assert "`mode = 'crop'`" in settings and "motion." not in settings
    # Crop mode's auto path: the tab says which path it planned (the recorder has it from the plan).
    hard = StabilizeConfig(mode="crop", crop=CropConfig(fill=0.0))  # a window inside every frame: the auto path
    auto = about.about_markdown(None, hard, planned=("l1", "l1"))
    assert "- auto chose: the L1 program in the crop window (`l1`)" in auto
    assert "a window every frame covers" in auto and "`crop.fill = 0.0`" in auto
    eq18 = ("gaussian", "gaussian:k=30")
    fallback = about.about_markdown(None, hard, planned=eq18)
    assert "- auto chose: eq. 18's path (`gaussian:k=30`)" in fallback
    assert "auto chose" not in about.about_markdown(None, StabilizeConfig(), planned=eq18)
    # Crop mode's default: eq. 18's path, its window completed where it leaves the frames
    filled = about.about_markdown(None, StabilizeConfig(mode="crop"))
    assert "at most 0.30% of the pixels over the clip, completed there" in filled and "k = 60" in filled


def test_live_view_and_file_at_once(clip, tmp_path):
    """--view: the recorder streams to a running viewer and writes the .rrd; here the viewer is the native one,
    headless, so that what it received can be asked over its control API."""
    import signal
    import socket
    import time

    from rerun.experimental import ViewerClient

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    viewer = subprocess.Popen([rerun_executable(), "--headless", "--bind", "127.0.0.1", "--port", str(port)],
                              env=dict(os.environ, RERUN_ANALYTICS="0"), stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        deadline = time.monotonic() + 30
        while True:
            try:
                client = ViewerClient.connect(url)
                client.get_state()
                break
            except Exception:
                assert time.monotonic() < deadline, "headless viewer did not start"
                time.sleep(0.3)
        rrd = tmp_path / "live.rrd"
        stabilize(clip, None, StabilizeConfig(mode="none"),
                  observer=RerunRecorder(rrd, level="summary", live_url=url))
        assert Recording.load(rrd).indices(ent.OUTPUT_FRAME) == list(range(N_FRAMES))
        deadline = time.monotonic() + 30
        while True:
            state = client.get_state()
            ends = [t.end for r in state.recordings for t in r.timelines if t.name == ent.FRAME_TIMELINE]
            if ends == [N_FRAMES - 1] or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        assert ends == [N_FRAMES - 1], state
    finally:
        os.killpg(viewer.pid, signal.SIGTERM)
        viewer.wait(timeout=15)


def test_every_chart_line_has_its_own_name_and_colour(compact_run):
    _, recording, _ = compact_run
    series = [f"{ent.MOTION_PARAMS}/{name}" for name in ent.MOTION_PARAM_NAMES]
    series += [ent.MOTION_INLIERS, ent.MOTION_INLIER_RATIO, ent.MOTION_RESIDUAL]
    paths = (ent.TRAJECTORY_ORIGINAL, ent.TRAJECTORY_SMOOTHED, ent.TRAJECTORY_GAUSSIAN, ent.TRAJECTORY_L1)
    series += [f"{root}/{axis}" for root in paths for axis in ent.TRAJECTORY_AXES]
    series += [*COMPLETION_SERIES, ent.COMPLETION_TEMPORAL]
    series += [ent.DEBLUR_BLURRINESS, ent.DEBLUR_NEIGHBOURS, ent.DEBLUR_REFUSED]
    styles = {}
    for entity in series:
        names = recording.texts(entity, "SeriesLines:names")
        colours = [b.column("SeriesLines:colors").to_pylist()[0][0] for b in recording.batches[entity]
                   if "SeriesLines:colors" in b.schema.names]
        assert names and colours, f"{entity}: no SeriesLines style"
        styles[entity] = (names[0], colours[0])
    # Lines drawn in one chart never share a colour.
    charts = [list(COMPLETION_SERIES),
              [f"{ent.MOTION_PARAMS}/{n}" for n in ent.MOTION_PARAM_NAMES],
              [f"{root}/{axis}" for root in paths for axis in ("x", "y")],
              [f"{root}/angle" for root in paths]]
    for chart in charts:
        assert len({styles[e][1] for e in chart}) == len(chart), chart
        assert len({styles[e][0] for e in chart}) == len(chart), chart


def test_class_colours_are_distinct_so_masks_read_back_exactly():
    for legend in (legends.MISSING_LEGEND, legends.ACCEPTED_LEGEND, legends.FALLBACK_LEGEND, legends.SOURCE_LEGEND,
                   legends.filled_by_legend(), legends.deblur_source_legend()):
        colours = [tuple(c) + ((255,) if len(c) == 3 else ()) for _, _, c in legend]
        assert len(set(colours)) == len(colours)


def test_notebook_recipe_streams_the_run_to_the_widgets_source(clip, tmp_path):
    """docs/recording.md's notebook recipe: the widget reads the live server's URL; a viewer reading that URL
    (here the native one, headless, as the widget would in a browser) gets every frame; the .rrd is written too."""
    import rerun_notebook  # noqa: F401 - the test extra has it (pyproject.toml): missing, the test fails
    import signal
    import socket
    import time

    from rerun.experimental import ViewerClient

    from ffviz.viewer import notebook_live

    ports = []
    for _ in range(3):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            ports.append(s.getsockname()[1])
    live, widget = notebook_live(web_port=ports[0], grpc_port=ports[1])
    reader = None
    try:
        assert widget._viewer._url == live.grpc_url
        rrd = tmp_path / "notebook.rrd"
        stabilize(clip, None, StabilizeConfig(mode="none"),
                  observer=RerunRecorder(rrd, level="summary", live_url=live.grpc_url))
        assert Recording.load(rrd).indices(ent.OUTPUT_FRAME) == list(range(N_FRAMES))
        reader = subprocess.Popen([rerun_executable(), "--headless", "--bind", "127.0.0.1", "--port", str(ports[2]),
                                   live.grpc_url], env=dict(os.environ, RERUN_ANALYTICS="0"),
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        deadline, ends = time.monotonic() + 60, []
        while time.monotonic() < deadline:
            try:
                state = ViewerClient.connect(f"rerun+http://127.0.0.1:{ports[2]}/proxy").get_state()
                ends = [t.end for r in state.recordings for t in r.timelines if t.name == ent.FRAME_TIMELINE]
            except Exception:
                ends = []
            if ends == [N_FRAMES - 1]:
                break
            time.sleep(0.5)
        assert ends == [N_FRAMES - 1]
    finally:
        live.stop()
        if reader is not None:
            os.killpg(reader.pid, signal.SIGTERM)
            reader.wait(timeout=15)


def test_an_error_on_the_recorders_thread_surfaces_in_one_line_and_leaves_no_file(clip, tmp_path, monkeypatch):
    rrd = tmp_path / "broken.rrd"
    recorder = RerunRecorder(rrd, level="summary")

    def broken(view):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(recorder, "_write_frame", broken)
    with pytest.raises(OutputError, match=r"cannot write the recording .*broken.rrd: Input/output error; the video "
                                          r"was not written either$"):
        stabilize(clip, tmp_path / "out.mp4", StabilizeConfig(mode="none"), observer=recorder)
    recorder.abort()  # what the CLI does on any error
    assert not rrd.exists() and not list(tmp_path.glob(".broken.*")) and not (tmp_path / "out.mp4").exists()


def test_a_full_disk_under_the_recording_is_one_line_and_leaves_nothing(clip, tmp_path, monkeypatch, capfd):
    """The recording's file fills its disk (its writes fail with ENOSPC after 100 kB): one line saying so and
    whether the video was written, exit 3, no temporary file, nothing of rerun's own on stderr."""
    from ffviz.recording import sink

    real_write = sink.PipedFile._write

    def write(self, target, chunk):
        if self.bytes_written + len(chunk) > 100_000:
            self.error = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return
        real_write(self, target, chunk)

    monkeypatch.setattr(sink.PipedFile, "_write", write)
    out, rrd = tmp_path / "out.mp4", tmp_path / "full.rrd"
    assert cli.main(["stabilize", str(clip), "-o", str(out), "--rrd", str(rrd)]) == 3
    err = capfd.readouterr().err.strip().splitlines()
    assert err[-1] == (f"ffviz: error: cannot write the recording {rrd}: No space left on device; the video was "
                       f"{'written' if out.exists() else 'not written either'}")
    assert not any("ERROR" in line or "re_log" in line for line in err)
    assert not rrd.exists() and not list(tmp_path.glob(".full.*"))


def test_a_recording_failing_after_the_last_frame_says_the_video_was_written(clip, tmp_path, monkeypatch):
    """The recorder's thread fails on a frame while the run is already past its last one (the backlog still held
    frames): the error surfaces at on_finish, after the video was closed, and says it was written."""
    rrd, out = tmp_path / "late.rrd", tmp_path / "out.mp4"
    recorder = RerunRecorder(rrd, level="summary")
    finishing = threading.Event()

    def failing(view):
        finishing.wait(120)  # the pipeline hands every frame over first
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    on_finish = recorder.on_finish

    def late(report):
        finishing.set()
        deadline = time.monotonic() + 120
        while recorder._backlog.error is None and time.monotonic() < deadline:  # failed before on_finish hands work
            time.sleep(0.01)
        on_finish(report)

    monkeypatch.setattr(recorder, "_write_frame", failing)
    monkeypatch.setattr(recorder, "on_finish", late)
    with pytest.raises(OutputError, match=r"cannot write the recording .*late.rrd: No space left on device; the video "
                                          r"was written$"):
        stabilize(clip, out, StabilizeConfig(mode="none"), observer=recorder)
    recorder.abort()
    assert out.exists() and not rrd.exists() and not list(tmp_path.glob(".late.*"))


def test_a_video_that_cannot_be_written_says_the_recording_was_not_written_either(clip, tmp_path, monkeypatch, capfd):
    from pipeline.runtime import video_writer

    def full(self):
        raise OutputError(f"cannot finish writing {out}: No space left on device")

    monkeypatch.setattr(video_writer.VideoWriter, "close", full)
    out, rrd = tmp_path / "out.mp4", tmp_path / "kept.rrd"
    assert cli.main(["stabilize", str(clip), "-o", str(out), "--mode", "none", "--rrd", str(rrd)]) == 3
    err = capfd.readouterr().err.strip().splitlines()
    assert err[-1] == (f"ffviz: error: cannot finish writing {out}: No space left on device; the recording {rrd} was "
                       "not written either")
    assert not rrd.exists() and not list(tmp_path.glob(".kept.*"))


def _dataclasses_in(hint) -> list[type]:
    """The dataclass types a field's type hint names (through Optional, tuple, list, dict)."""
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return [hint]
    return [found for arg in typing.get_args(hint) for found in _dataclasses_in(arg)]


def test_every_result_field_is_recorded_or_marked_not_recorded():
    """Walks the result types the recorder receives, field by field, through nested result types: each field has
    a row in the recorder's one table (entities, Nested or NotRecorded), and the table has no stale rows."""
    from ffviz.recording.fields import RECORDED_FIELDS, Nested
    from pipeline.results import PathPlan
    from pipeline.stages.motion import MotionEstimate

    seen: set[str] = set()
    todo = [MotionEstimate, PathPlan, FrameResult]
    while todo:
        cls = todo.pop()
        if cls.__name__ in seen:
            continue
        seen.add(cls.__name__)
        assert cls.__name__ in RECORDED_FIELDS, f"{cls.__name__} has no row in recorder.RECORDED_FIELDS"
        row = RECORDED_FIELDS[cls.__name__]
        hints = typing.get_type_hints(cls)
        names = [f.name for f in dataclasses.fields(cls)]
        assert sorted(row) == sorted(names), f"{cls.__name__}: table {sorted(row)} vs fields {sorted(names)}"
        for name in names:
            nested = _dataclasses_in(hints[name])
            if nested:
                assert row[name] == Nested(nested[0].__name__), f"{cls.__name__}.{name} should be Nested"
                todo.extend(nested)
            else:
                assert not isinstance(row[name], Nested), f"{cls.__name__}.{name} is not a result type"
    assert seen == set(RECORDED_FIELDS), f"rows for types no result holds: {set(RECORDED_FIELDS) - seen}"


def test_every_entity_of_the_field_table_is_in_a_recording(full_run, clip, tmp_path):
    """The table is what the recorder does: every entity it names is in a full recording or in a crop-mode one
    made with the options that add entities (--rolling-shutter, --ignore), every timeline it names is used."""
    from ffviz.recording.fields import RECORDED_FIELDS, NotRecorded

    crop_rrd = tmp_path / "crop.rrd"  # with the options whose results only they record
    options = StabilizeConfig(mode="crop", rolling_shutter=0.5,
                              motion=MotionConfig(ignore=(IgnoreRegion(10, 10, 60, 40),)))
    stabilize(clip, None, options, observer=RerunRecorder(crop_rrd, level="full"))
    # their charts are shown, and the log (the readout time is logged)
    assert snapshot.layout_facts(crop_rrd)[1] == {"crop": True, "rolling_shutter": True, "log": True, "portrait": False}
    layout = _embedded_layout(crop_rrd)  # the recorder's own layout says the same
    assert "crop scale" in layout and "rolling shutter:" in layout and "warnings and notes" in layout
    entities = set(full_run[0].entities) | set(Recording.load(crop_rrd).entities)
    timelines = {ent.FRAME_TIMELINE, ent.VIDEO_TIME_TIMELINE}
    named = {path for row in RECORDED_FIELDS.values() for target in row.values()
             if not isinstance(target, str) for path in target}
    assert named, "the table names no entity"
    missing = [path for path in sorted(named - timelines) if not any(fnmatch.fnmatch(e, path) for e in entities)]
    assert not missing, f"in the table but not in the recordings: {missing}"
    assert all(timelines <= full_run[0].timelines(e) for e in (ent.OUTPUT_FRAME, ent.INPUT_FRAME))
    assert all(isinstance(t, (tuple, NotRecorded)) or type(t).__name__ == "Nested"
               for row in RECORDED_FIELDS.values() for t in row.values())


def test_rows_sent_as_columns_read_back_as_the_same_log_calls_would(tmp_path):
    """recording/columns.py: scalars, encoded images, depth images, text and arrows (0-3 instances a row) held over
    several frames and sent as columns read back per frame exactly as one log call a frame writes them, in order
    where an entity's rows change shape in between (a Clear between held rows, another field given)."""
    from ffviz.recording.columns import ColumnBuffer, Row
    from ffviz.recording.encoders import indexed_png, legend_palette, png16
    rng = np.random.default_rng(3)
    frames = []
    for t in range(7):
        classes = rng.integers(0, 3, (12, 20)).astype(np.uint8)
        values = rng.integers(0, 4000, (12, 20)).astype(np.uint16)
        count = t % 4
        items = [("a/scalar", Row(rr.Scalars, {"scalars": float(rng.normal())})),
                 ("a/text", Row(rr.TextLog, {"text": f"frame {t}"})),
                 ("a/classes", Row(rr.EncodedImage, {"blob": indexed_png(classes, legend_palette(((1, "x", (9, 9, 9)),))),
                                                     "media_type": "image/png", "opacity": 0.99, "draw_order": 10.0})),
                 ("a/values", Row(rr.EncodedDepthImage, {"blob": png16(values), "media_type": "image/png",
                                                         "meter": 1.0, "colormap": "viridis", "depth_range": (0.0, t + 1.0)})),
                 ("a/arrows", Row(rr.Arrows2D, {"origins": rng.normal(size=(count, 2)).astype(np.float32),
                                                "vectors": rng.normal(size=(count, 2)).astype(np.float32)}, count))]
        if t == 4:  # another shape for the same entity, then a Clear, between held rows
            items.append(("a/shape", Row(rr.Scalars, {"scalars": 1.0})))
        elif t in (2, 5):
            items.append(("a/shape", Row(rr.EncodedImage, {"blob": png16(values), "media_type": "image/png"})))
        frames.append(items)

    def record(path, held):
        rec = rr.RecordingStream("test", recording_id="same")
        rec.save(str(path))
        buffer = ColumnBuffer(rec)
        for t, items in enumerate(frames):
            rec.set_time(ent.FRAME_TIMELINE, sequence=t)
            rec.set_time(ent.VIDEO_TIME_TIMELINE, duration=t / 30)
            for entity, row in items:
                if held:
                    buffer.add(entity, row, t, t / 30)
                else:
                    rec.log(entity, row.archetype())
            if t == 4:
                rec.log("a/shape", rr.Clear(recursive=False))
            if held and t == 3:
                buffer.send()
        buffer.send()
        rec.flush()
        rec.disconnect()
        return Recording.load(path)

    logged, held = record(tmp_path / "logged.rrd", False), record(tmp_path / "held.rrd", True)
    assert held.entities == logged.entities
    for entity in ("a/classes", "a/values", "a/shape"):
        assert held.indices(entity) == logged.indices(entity)
        for t in logged.indices(entity):
            np.testing.assert_array_equal(held.image(entity, t), logged.image(entity, t))
    for entity in ("a/scalar", "a/shape"):
        for mine, theirs in zip(held.scalars(entity), logged.scalars(entity)):
            np.testing.assert_array_equal(mine, theirs)
    assert held.texts("a/text", "TextLog:text") == logged.texts("a/text", "TextLog:text")

    def arrows(recording):
        rows = []
        for batch in recording.batches["a/arrows"]:
            for t, vectors in zip(batch.column(ent.FRAME_TIMELINE).to_pylist(),
                                  batch.column("Arrows2D:vectors").to_pylist()):
                rows.append((t, vectors))
        return sorted(rows)
    assert arrows(held) == arrows(logged)
    assert [len(v) for _, v in arrows(held)] == [t % 4 for t in range(7)]


def test_the_masks_and_maps_pngs_decode_to_their_values_anywhere():
    """encoders.grey_png (zlib-ng's deflate): 8- and 16-bit grey and paletted PNGs of odd sizes, sparse and full,
    read back exactly by OpenCV's decoder (the viewer's stand-in here) and by ffviz.rrd, alphas included."""
    import cv2
    from ffviz.recording import encoders
    from ffviz.rrd import _paletted_png
    rng = np.random.default_rng(5)
    palette = rng.integers(0, 256, (256, 4)).astype(np.uint8)
    for height, width, share in ((1, 1, 1.0), (7, 13, 0.3), (361, 641, 0.05), (90, 1, 1.0), (2, 500, 0.0)):
        values = (rng.integers(0, 65536, (height, width)) * (rng.random((height, width)) < share)).astype(np.uint16)
        decoded = cv2.imdecode(np.frombuffer(encoders.png16(values), np.uint8), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(decoded.reshape(height, width), values)
        classes = (values % 256).astype(np.uint8)
        indices, colours = _paletted_png(encoders.indexed_png(classes, palette))
        np.testing.assert_array_equal(indices, classes)
        np.testing.assert_array_equal(colours[classes], palette[classes])
        rgba = cv2.imdecode(np.frombuffer(encoders.indexed_png(classes, palette), np.uint8), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(rgba.reshape(height, width, 4)[..., [2, 1, 0, 3]], palette[classes])
