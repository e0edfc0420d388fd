"""Recordings of phone-sized footage: pictures at the recorded size (classes exact, maps and flow consistent), memory
bounded in bytes between the chain and the file, a 4K clip recorded and read back, the layout by aspect."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from ffviz import blueprint, entities as ent
from ffviz.recorder import RerunRecorder
from ffviz.recording.backlog import Backlog
from ffviz.recording.view import RECORD_SIZE, ViewSize, _majority_nonzero, parse_record_size
from ffviz.rrd import Recording
from pipeline.evaluation import synthetic
from pipeline.stabilize import StabilizeConfig, stabilize


def _blocks(view: ViewSize, height: int, width: int):
    """(rows, cols) of the input block under each recorded pixel, as the downscaling partitions the input."""
    rows = [((i * height) // view.height, max(((i + 1) * height) // view.height, (i * height) // view.height + 1))
            for i in range(view.height)]
    cols = [((j * width) // view.width, max(((j + 1) * width) // view.width, (j * width) // view.width + 1))
            for j in range(view.width)]
    return rows, cols


@pytest.mark.parametrize("shape, long_side, seed", [((360, 640), 200, 0), ((1920, 1080), 960, 1),
                                                    ((257, 431), 100, 2)])
def test_class_maps_keep_exact_classes_and_thin_bands(shape, long_side, seed):
    """Each recorded pixel holds the commonest non-zero class of its input block (0 only where the block is all 0):
    no class that is not in the block, and a band one input pixel wide stays visible."""
    rng = np.random.default_rng(seed)
    height, width = shape
    classes = np.zeros(shape, np.uint8)
    blobs = rng.integers(0, 4, (height // 16 + 1, width // 16 + 1)).astype(np.uint8) * 50
    classes[:] = np.kron(blobs, np.ones((16, 16), np.uint8))[:height, :width]
    classes[rng.random(shape) < 0.02] = 7  # speckle
    classes[:, :16] = 0
    classes[:, 3] = 200  # a one-pixel column band in an empty strip
    view = ViewSize.of(width, height, long_side)
    small = view.classes(classes)
    assert small.shape == (view.height, view.width) and view.scale < 1
    rows, cols = _blocks(view, height, width)
    for i in rng.integers(0, view.height, 40):
        for j in rng.integers(0, view.width, 40):
            block = classes[rows[i][0]:rows[i][1], cols[j][0]:cols[j][1]].ravel()
            nonzero = block[block > 0]
            if not nonzero.size:
                assert small[i, j] == 0
            else:
                counts = np.bincount(nonzero, minlength=256)
                assert counts[small[i, j]] == counts.max()
    band_col = max(j for j, (first, _) in enumerate(cols) if first <= 3)
    assert (small[:, band_col] == 200).all()


@pytest.mark.parametrize("shape, long_side", [((1920, 1080), 960), ((2160, 3840), 960), ((720, 1280), 960),
                                              ((1080, 1920), 997), ((257, 431), 100)])
def test_class_maps_count_only_the_occupied_blocks_and_lose_no_pixel(shape, long_side):
    """The majority is counted only where the area-averaged non-zero mask says a block holds a class: the same map
    as counting every block, down to single pixels at any block's edge, at integer and fractional scales."""
    rng = np.random.default_rng(3)
    view = ViewSize.of(shape[1], shape[0], long_side)
    classes = np.zeros(shape, np.uint8)
    classes[rng.random(shape) < 0.0005] = 9  # lone pixels, some at blocks' edges
    classes[:, :5] = rng.integers(0, 4, (shape[0], 5))  # a border strip of mixed classes
    everywhere = np.full((view.height, view.width), 255, np.uint8)
    assert np.array_equal(view.classes(classes), _majority_nonzero(classes, view.height, view.width, everywhere))
    assert np.count_nonzero(view.classes(classes) == 9) > 0


def test_float_maps_and_flow_are_means_of_the_values_under_each_pixel():
    view = ViewSize.of(800, 400, 200)  # 4x4 blocks
    values = np.full((400, 800), np.nan, np.float32)
    values[:, :400] = np.arange(400, dtype=np.float32)[None, :]  # left half only
    small = view.values(values)
    assert np.isnan(small[:, 100:]).all() and np.isfinite(small[:, :100]).all()
    np.testing.assert_allclose(small[0, :100], np.arange(100) * 4 + 1.5, atol=1e-4)
    flow = np.dstack([np.full((400, 800), 8.0, np.float32), np.full((400, 800), -4.0, np.float32)])
    flow[:2, :2] = np.nan  # a block half without flow keeps the mean of the rest
    np.testing.assert_allclose(view.flow(flow)[0, 0], (2.0, -1.0))  # vectors in recorded pixels: x 0.25


def test_record_size_choices():
    assert parse_record_size("full") is None and parse_record_size("1280") == 1280
    assert ViewSize.of(1080, 1920, RECORD_SIZE) == ViewSize(540, 960, 0.5)
    assert ViewSize.of(640, 360, RECORD_SIZE).native
    for bad in ("0", "abc", "-5", "12"):
        with pytest.raises(ValueError, match="record-size"):
            parse_record_size(bad)


def test_the_backlog_holds_at_most_its_budget_with_a_slow_writer():
    """A writer slower than the producer: the producer waits, the bytes held never pass the budget, nothing is
    lost and the work runs in order."""
    done: list[int] = []
    backlog = Backlog(budget_bytes=10 << 20)
    for k in range(12):
        backlog.put(3 << 20, lambda k=k: (time.sleep(0.02), done.append(k)))
        assert backlog.held_bytes <= 10 << 20
    backlog.close()
    assert done == list(range(12)) and 9 << 20 <= backlog.peak_bytes <= 10 << 20


def test_the_backlog_takes_one_item_larger_than_its_budget_and_raises_the_writers_error():
    backlog = Backlog(budget_bytes=1)
    ran = threading.Event()
    backlog.put(100, ran.set)
    backlog.put(100, lambda: (_ for _ in ()).throw(OSError("broken")))
    with pytest.raises(OSError, match="broken"):
        for _ in range(100):
            backlog.put(100, lambda: None)
            time.sleep(0.01)
    backlog.close(drop=True)
    assert ran.is_set()


def test_a_recording_with_a_slow_writer_holds_at_most_its_budget(tmp_path, monkeypatch):
    clip = tmp_path / "clip.mp4"
    synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=24)), clip)
    recorder = RerunRecorder(tmp_path / "slow.rrd", backlog_bytes=2 << 20)
    write = recorder._write_frame
    monkeypatch.setattr(recorder, "_write_frame", lambda view: (time.sleep(0.05), write(view)))
    stabilize(clip, None, StabilizeConfig(), observer=recorder)
    backlog = recorder._backlog
    frame_view = 4 * 320 * 180 * 3  # a frame's digest holds about four frame streams
    assert frame_view <= backlog.peak_bytes <= (2 << 20) + 2 * frame_view
    assert len(Recording.load(tmp_path / "slow.rrd").indices(ent.OUTPUT_FRAME)) == 24


def test_a_4k_recording_holds_its_pictures_at_the_recorded_size(uhd_recording):
    rrd, recorder = uhd_recording
    recording = Recording.load(rrd)
    assert recording.size(ent.SIZES, "input_size") == (3840, 2160)
    assert recording.size(ent.SIZES, "recorded_size") == (960, 540) == (recorder.view.width, recorder.view.height)
    for entity in (ent.INPUT_FRAME, ent.OUTPUT_FRAME, ent.COMPLETION_FRAME):
        assert recording.image(entity, 3).shape == (540, 960, 3)
    for entity in (ent.STABILIZED_MISSING, ent.COMPLETION_SOURCE, ent.COMPLETION_FILLED_BY):
        assert recording.image(entity, 3).shape == (540, 960)
    assert recording.map(ent.COMPLETION_VARIANCE, 3).shape == (540, 960)
    assert recording.image(ent.trace_image(4), 4, ent.FRAME_TIMELINE).shape[:2] == (540, 960)  # traced frames too
    about = recording.texts(ent.META, "TextDocument:text")[-1]
    assert "at 960x540 (the input's 3840x2160 scaled by 0.25)" in about  # the about tab states the size


def test_a_4k_recordings_classes_are_the_pipelines_and_its_statistics_full_resolution(uhd_recording):
    recording = Recording.load(uhd_recording[0])
    legend_classes = set(recording.annotation_colours(ent.COMPLETION_SOURCE).values())
    for t in recording.indices(ent.COMPLETION_SOURCE):
        classes = recording.image(ent.COMPLETION_SOURCE, t)
        assert set(np.unique(classes)) <= legend_classes
    frames, missing = recording.scalars(f"{ent.COMPLETION_STATS}/missing")
    assert len(frames) == 8 and (missing > 0).any() and (missing < 0.5).all()


def test_the_layout_lays_portrait_frames_side_by_side():
    def frame_rows(bp):
        overview = bp.root_container.contents[0]
        return type(overview).__name__

    assert frame_rows(blueprint.default_blueprint((), portrait=True)) == "Horizontal"
    assert frame_rows(blueprint.default_blueprint((), portrait=False)) == "Vertical"


def test_the_recorder_hands_the_sdk_its_data_every_flush_bytes(tmp_path, monkeypatch):
    """The SDK holds what it is given until a flush: the recorder flushes each time ``flush_bytes`` were logged, so
    the recording's share of memory does not grow with the clip."""
    clip = tmp_path / "clip.mp4"
    synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=30)), clip)
    recorder = RerunRecorder(tmp_path / "flushed.rrd", jpeg_quality=None)  # raw pictures: megabytes a frame
    recorder.flush_bytes = 4 << 20
    held_at_flush, logged_by_frame = [], []
    flush, write = recorder.rec.flush, recorder._write_frame

    def write_counting(view):
        before, flushes = recorder._unflushed, len(held_at_flush)
        write(view)
        after = held_at_flush[-1] if len(held_at_flush) > flushes else recorder._unflushed
        logged_by_frame.append(after - before)

    monkeypatch.setattr(recorder.rec, "flush", lambda **kw: (held_at_flush.append(recorder._unflushed), flush(**kw)))
    monkeypatch.setattr(recorder, "_write_frame", write_counting)
    stabilize(clip, None, StabilizeConfig(), observer=recorder)
    periodic = [held for held in held_at_flush if held >= recorder.flush_bytes]
    assert len(periodic) >= sum(logged_by_frame) // (recorder.flush_bytes + max(logged_by_frame))
    assert len(periodic) >= 5
    assert max(periodic) < recorder.flush_bytes + max(logged_by_frame)
    assert len(Recording.load(tmp_path / "flushed.rrd").indices(ent.OUTPUT_FRAME)) == 30
