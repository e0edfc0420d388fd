"""Threads (pipeline/runtime/parallel.py): ordered results, bounded look-ahead, errors at their turn, early stops that
neither hang nor compute everything; decoding ahead (Prefetch, PrefetchedSource) with decoder warnings kept
at their frame; and a stabilized clip identical for any number of workers."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from pipeline.frames import Frame
from pipeline.runtime import parallel
from pipeline.evaluation import synthetic
from pipeline.runtime.observer import StageCollector
from pipeline.runtime.source import ArraySource, PrefetchedSource, one_pass
from pipeline.stabilize import StabilizeConfig, stabilize_source

# --- ordered_map ------------------------------------------------------------------------------------------


def _slow_for_early(n: int, step_s: float = 0.002):
    """func(i) = i * i, the earlier the item the longer it takes (later items finish first)."""
    def func(i: int) -> int:
        time.sleep(step_s * (n - i))
        return i * i
    return func


def test_default_workers_is_a_positive_core_count():
    workers = parallel.default_workers()
    assert isinstance(workers, int) and workers >= 1


@pytest.mark.parametrize("workers", [1, 3])
def test_ordered_map_keeps_input_order_when_later_items_finish_first(workers):
    n = 20
    finished: list[int] = []
    lock = threading.Lock()
    slow = _slow_for_early(n)

    def func(i: int) -> int:
        result = slow(i)
        with lock:
            finished.append(i)
        return result

    assert list(parallel.ordered_map(func, range(n), workers)) == [i * i for i in range(n)]
    if workers > 1:
        assert finished != sorted(finished)  # the case the test is about did happen: out-of-order completion


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_ordered_map_takes_at_most_2x_workers_items_ahead(workers):
    pulled = 0

    def items() -> Iterator[int]:
        nonlocal pulled
        for i in range(30):
            pulled += 1
            yield i

    taken_when_yielded = []
    for k, result in enumerate(parallel.ordered_map(_slow_for_early(30, 0.0005), items(), workers)):
        assert result == k * k
        taken_when_yielded.append(pulled)
    # Items taken from the input but not yet yielded, counting the one being yielded.
    ahead = [taken - k for k, taken in enumerate(taken_when_yielded)]
    assert max(ahead) <= 2 * workers, ahead
    if workers == 1:
        assert max(ahead) == 1  # inline: one item at a time
    else:
        assert max(ahead) > workers  # it did read ahead (several calls in flight)


@pytest.mark.parametrize("workers", [1, 3])
def test_ordered_map_raises_an_error_at_its_items_turn(workers):
    n, bad = 12, 5

    def func(i: int) -> int:
        if i == bad:
            raise ValueError(f"item {i}")  # fails at once, while the items before it are still sleeping
        time.sleep(0.01 * (bad - i) if i < bad else 0)
        return i

    received = []
    with pytest.raises(ValueError, match="item 5"):
        for result in parallel.ordered_map(func, range(n), workers):
            received.append(result)
    assert received == list(range(bad))


@pytest.mark.parametrize("workers", [1, 3])
def test_ordered_map_yields_every_earlier_result_before_an_input_error(workers):
    def items() -> Iterator[int]:
        yield from range(10)
        raise OSError("read error")

    received = []
    with pytest.raises(OSError, match="read error"):
        for result in parallel.ordered_map(lambda i: i, items(), workers):
            received.append(result)
    assert received == list(range(10))


@pytest.mark.parametrize("workers", [0, -1, 1, 4])
def test_ordered_map_of_nothing_and_of_non_positive_workers(workers):
    assert list(parallel.ordered_map(lambda i: i + 1, [], workers)) == []
    assert list(parallel.ordered_map(lambda i: i + 1, range(5), workers)) == [1, 2, 3, 4, 5]


@pytest.mark.parametrize("workers", [1, 3])
def test_ordered_map_stopped_early_does_not_hang_and_cancels_the_rest(workers):
    n = 200
    started = []
    lock = threading.Lock()

    def func(i: int) -> int:
        with lock:
            started.append(i)
        time.sleep(0.01)
        return i

    before = time.perf_counter()
    received = []
    for result in parallel.ordered_map(func, range(n), workers):
        received.append(result)
        if len(received) == 3:
            break  # the generator is dropped (closed) here
    elapsed = time.perf_counter() - before
    assert received == [0, 1, 2]
    assert elapsed < 1.0  # 200 items at 10 ms would take 2 s / workers
    assert len(started) <= 3 + 2 * workers, sorted(started)
    time.sleep(0.05)
    with lock:
        assert len(started) <= 3 + 2 * workers  # nothing keeps running after the stop
    assert not [t for t in threading.enumerate() if t.name.startswith("ffviz-frame")]


def test_ordered_map_closed_explicitly_joins_its_threads():
    stream = parallel.ordered_map(lambda i: (time.sleep(0.005), i)[1], iter(range(10_000)), 3)
    assert [next(stream) for _ in range(4)] == [0, 1, 2, 3]
    stream.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("ffviz-frame")]


# --- Prefetch -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("depth", [1, 4])
def test_prefetch_yields_everything_in_order(depth):
    ahead = parallel.Prefetch(iter(range(200)), depth)
    assert list(ahead) == list(range(200))
    assert not ahead._thread.is_alive()
    assert next(ahead, "done") == "done"  # exhausted stays exhausted


def test_prefetch_raises_a_source_error_after_the_earlier_items():
    def items() -> Iterator[int]:
        yield from range(5)
        raise OSError("disk gone")

    ahead = parallel.Prefetch(items(), 2)
    received = []
    with pytest.raises(OSError, match="disk gone"):
        for item in ahead:
            received.append(item)
    assert received == [0, 1, 2, 3, 4]
    assert not ahead._thread.is_alive()


def test_prefetch_close_midway_stops_the_thread_and_closes_the_source():
    state = {"finally": False, "produced": 0}

    def items() -> Iterator[int]:
        try:
            i = 0
            while True:  # endless: only close() can end it
                state["produced"] += 1
                yield i
                i += 1
        finally:
            state["finally"] = True

    ahead = parallel.Prefetch(items(), 3)
    assert [next(ahead) for _ in range(5)] == [0, 1, 2, 3, 4]
    ahead.close()
    assert not ahead._thread.is_alive()
    assert state["finally"]  # the generator was closed on its own thread, its files released
    assert state["produced"] <= 5 + 3 + 2  # bounded by the depth (the queue plus one item in hand)
    assert next(ahead, "done") == "done"
    ahead.close()  # twice is harmless


def test_prefetch_close_before_anything_is_read():
    closed = threading.Event()

    def items() -> Iterator[int]:
        try:
            yield from range(1000)
        finally:
            closed.set()

    ahead = parallel.Prefetch(items(), 2)
    ahead.close()
    assert not ahead._thread.is_alive() and closed.is_set()


# --- PrefetchedSource -----------------------------------------------------------------------------------------


class WarningSource:
    """Frames in memory, like ArraySource, whose decoder 'complains' at given frames: some warnings arise while
    a frame is produced, some when decoding resumes after it, one after the last frame (a truncated stream)."""

    def __init__(self, frames: list[np.ndarray], while_producing: dict[int, int], after: dict[int, int],
                 trailing: bool = True, fps: float = 25.0) -> None:
        self.inner = ArraySource(frames, fps=fps, name="<warnings>")
        self.info = self.inner.info
        self.while_producing, self.after, self.trailing = while_producing, after, trailing
        self.warnings: list[str] = []
        self.closed_passes = 0
        self.passes = 0

    def frames(self) -> Iterator[Frame]:
        self.passes += 1
        try:
            for frame in self.inner.frames():
                for k in range(self.while_producing.get(frame.index, 0)):
                    self.warnings.append(f"corrupt packet {k} before frame {frame.index}")
                yield frame
                for k in range(self.after.get(frame.index, 0)):
                    self.warnings.append(f"late complaint {k} after frame {frame.index}")
            if self.trailing:
                self.warnings.append("truncated stream: the last packet was cut short")
        finally:
            self.closed_passes += 1

    def drain_warnings(self) -> list[str]:
        drained, self.warnings = self.warnings, []
        return drained


def _small_frames(n: int, width: int = 64, height: int = 48) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (height, width, 3), dtype=np.uint8) for _ in range(n)]


def _drains_per_frame(source) -> list[tuple[int | None, list[str]]]:
    """(frame index, drain_warnings() right after consuming it), then (None, drain after the pass)."""
    seen = []
    with one_pass(source) as frames:
        for frame in frames:
            seen.append((frame.index, source.drain_warnings()))
    seen.append((None, source.drain_warnings()))
    return seen


def _warning_source() -> WarningSource:
    return WarningSource(_small_frames(12), while_producing={0: 1, 3: 2, 7: 1, 11: 1}, after={3: 1, 5: 2, 11: 1})


@pytest.mark.parametrize("depth", [1, 4])
def test_prefetched_source_drains_the_same_warnings_at_the_same_frames(depth):
    plain = _drains_per_frame(_warning_source())
    assert plain[-1] == (None, ["late complaint 0 after frame 11", "truncated stream: the last packet was cut short"])
    assert plain[4] == (4, ["late complaint 0 after frame 3"])  # a test of the fake itself
    wrapped = _warning_source()
    prefetched = PrefetchedSource(wrapped, depth=depth)
    assert prefetched.info == wrapped.info
    assert _drains_per_frame(prefetched) == plain
    # A second pass is a fresh one, with the same answers.
    assert _drains_per_frame(prefetched) == plain
    assert wrapped.passes == wrapped.closed_passes == 2


def test_prefetched_source_frames_are_the_wrapped_ones():
    frames = _small_frames(9)
    prefetched = [(f.index, f.pts, f.time_s, f.rgb.tobytes()) for f in PrefetchedSource(ArraySource(frames)).frames()]
    plain = [(f.index, f.pts, f.time_s, f.rgb.tobytes()) for f in ArraySource(frames).frames()]
    assert prefetched == plain


def test_prefetched_source_stopped_early_closes_the_wrapped_pass():
    wrapped = _warning_source()
    prefetched = PrefetchedSource(wrapped, depth=2)
    with one_pass(prefetched) as frames:
        for frame in frames:
            if frame.index == 2:
                break
    assert wrapped.closed_passes == 1  # the decode thread closed its pass (file released)
    assert not [t for t in threading.enumerate() if t.name == "ffviz-decode"]


# --- end to end: the same output for any number of workers --------------------------------------------------


@pytest.fixture(scope="module")
def clip() -> list[np.ndarray]:
    return synthetic.generate(synthetic.SyntheticConfig(n_frames=16, width=320, height=180)).frames


def _run(frames, mode: str, workers: int, source=None):
    collector = StageCollector("output", "motion")
    report = stabilize_source(source or ArraySource(frames), None, StabilizeConfig(mode=mode), observer=collector,
                              workers=workers)
    return report, collector


@pytest.fixture(scope="module")
def clip_runs(clip):
    """(mode, workers) -> (report, collector), each run once (a full-mode run is 3-4 s here)."""
    cache: dict[tuple[str, int], tuple] = {}

    def run(mode: str, workers: int):
        if (mode, workers) not in cache:
            cache[mode, workers] = _run(clip, mode, workers)
        return cache[mode, workers]
    return run


@pytest.mark.parametrize("mode, workers", [("none", 1), ("none", 3), ("full", 1), ("full", 3)])
def test_every_frame_reaches_the_observer_in_order(clip, clip_runs, mode, workers):
    report, collector = clip_runs(mode, workers)
    assert report.n_frames == len(clip)
    assert [stamp.index for stamp, _ in collector.results["output"]] == list(range(len(clip)))
    assert [stamp.index for stamp, _ in collector.results["motion"]] == list(range(len(clip)))


@pytest.mark.parametrize("mode", ["none", "full"])
def test_output_and_motion_are_identical_for_one_and_three_workers(clip_runs, mode):
    (report1, serial), (report3, threaded) = clip_runs(mode, 1), clip_runs(mode, 3)
    assert len(serial.results["output"]) == len(threaded.results["output"])
    for (_, a), (_, b) in zip(serial.results["output"], threaded.results["output"]):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    for (_, a), (_, b) in zip(serial.results["motion"], threaded.results["motion"]):
        assert np.array_equal(a.curr_from_prev, b.curr_from_prev) and a.status == b.status
    assert report1.warnings == report3.warnings
    assert report1.cuts == report3.cuts and report1.fallbacks == report3.fallbacks
    assert serial.warnings == threaded.warnings


def test_decoder_warnings_are_reported_alike_for_one_and_three_workers():
    frames = synthetic.generate(synthetic.SyntheticConfig(n_frames=10, width=160, height=96, blurred_frames=(),
                                                          moving_object=False)).frames

    def source() -> WarningSource:
        return WarningSource(frames, while_producing={2: 1, 6: 2}, after={4: 1})

    report1, serial = _run(frames, "none", 1, source())
    report3, threaded = _run(frames, "none", 3, source())
    assert report1.warnings == report3.warnings
    assert serial.warnings == threaded.warnings
    decoder = [w for w in report1.warnings if "corrupt" in w[1] or "late" in w[1] or "truncated" in w[1]]
    assert decoder == [(2, "corrupt packet 0 before frame 2"), (5, "late complaint 0 after frame 4"),
                       (6, "corrupt packet 0 before frame 6"), (6, "corrupt packet 1 before frame 6"),
                       (None, "truncated stream: the last packet was cut short")]


def test_scene_cut_is_found_alike_for_one_and_three_workers():
    from tests.test_scene_cuts import two_shots

    frames, cut = two_shots(8)
    (report1, serial), (report3, threaded) = _run(frames, "none", 1), _run(frames, "none", 3)
    assert report1.cuts == report3.cuts == [cut]
    assert report1.warnings == report3.warnings
    for (_, a), (_, b) in zip(serial.results["output"], threaded.results["output"]):
        assert a.tobytes() == b.tobytes()


# --- the CLI option -------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory) -> Path:
    from tests.test_reliability import photo_frames, write_video

    return write_video(tmp_path_factory.mktemp("workers") / "tiny.mp4", photo_frames(10))


def test_cli_accepts_one_worker(tiny_clip, tmp_path, capfd):
    from tests.test_reliability import decode, run_in_process

    output = tmp_path / "out.mp4"
    result = run_in_process(capfd, "stabilize", str(tiny_clip), "-o", str(output), "--mode", "none", "--workers", "1")
    assert result.returncode == 0, result.stderr
    assert len(decode(output)[1]) == 10


def test_cli_workers_option_reaches_the_pipeline_and_changes_nothing(tiny_clip, tmp_path, capsys, monkeypatch):
    """Frames as handed to the writer (the encoded file itself is not compared: x264 is not always
    bit-reproducible from run to run, whatever the workers)."""
    from ffviz import cli

    used: list[int] = []
    real_ordered_map = parallel.ordered_map

    def recording_ordered_map(func, items, workers):
        used.append(workers)
        return real_ordered_map(func, items, workers)

    monkeypatch.setattr(parallel, "ordered_map", recording_ordered_map)
    outputs = {}
    for workers in ("1", "2"):
        output = tmp_path / f"out{workers}.mp4"
        args = cli.build_parser().parse_args(["stabilize", str(tiny_clip), "-o", str(output), "--mode", "none",
                                              "-j", workers])
        assert args.workers == int(workers)
        collector = StageCollector("output")
        cli.run_stabilize(args.input, args.output, args, overwrite=False, observers=[collector])
        outputs[workers] = [frame for _, frame in collector.results["output"]]
    assert used == [1, 1, 2, 2]  # pass 1 and pass 2 of each run
    assert len(outputs["1"]) == len(outputs["2"]) == 10
    assert all(a.tobytes() == b.tobytes() for a, b in zip(outputs["1"], outputs["2"]))


@pytest.mark.parametrize("flag, value", [("--workers", "0"), ("-j", "0"), ("--workers", "-2")])
def test_cli_refuses_fewer_than_one_worker(tiny_clip, tmp_path, capfd, flag, value):
    from tests.test_reliability import assert_one_line_error, run_in_process

    output = tmp_path / "out.mp4"
    result = run_in_process(capfd, "stabilize", str(tiny_clip), "-o", str(output), flag, value)
    message = assert_one_line_error(result, 2, r"--workers")
    assert value in message
    assert not output.exists()


# --- import_in_background ----------------------------------------------------------------------------------


def test_import_in_background_loads_the_modules_and_leaves_failures_to_the_later_import():
    import importlib
    import sys

    thread = parallel.import_in_background("json.tool", "no_such_module_for_ffviz", "never_reached_for_ffviz")
    thread.join(timeout=30)
    assert not thread.is_alive()
    assert "json.tool" in sys.modules
    assert "no_such_module_for_ffviz" not in sys.modules and "never_reached_for_ffviz" not in sys.modules
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("no_such_module_for_ffviz")


def test_linear_programs_are_planned_in_crop_mode_and_on_the_l1_path_only():
    from pipeline.stages.smoothing import SmoothingConfig

    assert StabilizeConfig(mode="crop").plans_by_linear_programs
    assert not StabilizeConfig(mode="none").plans_by_linear_programs  # auto is eq. 18's outside crop mode
    assert not StabilizeConfig(mode="full").plans_by_linear_programs
    assert StabilizeConfig(mode="none", smoothing=SmoothingConfig(path="l1")).plans_by_linear_programs
    assert StabilizeConfig(mode="full", smoothing=SmoothingConfig(path="tripod")).plans_by_linear_programs
