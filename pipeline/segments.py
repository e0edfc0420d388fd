"""Segment-parallel stabilization of one video, with frames identical to the whole-video run.

Pass 1 (motion) runs over the whole video in one task, in order: a pair's motions depend on the pairs before it
(motion.continued tracks each layer on from pair to pair), and the camera's choice is made over the clip. The path is
smoothed as a whole (it is tiny). Pass 2, completion and deblurring, the costly part, is cut into segments of
consecutive frames that run in parallel, each reading ``radius`` frames either side of it (the completion/deblur
window), so every frame sees the neighbours it sees in one run. The frames come back in order and are written once,
with the audio, by the caller's process.

No scheduler here: ``run`` takes a ``mapper`` that applies a function to a list of argument tuples and
yields the results in order (``serial_map`` below, or Ray in ffviz/batch.py).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

from pipeline import stabilize as stab
from pipeline.chain import render_frames
from pipeline.errors import ConfigError, InputError
from pipeline.results import FrameResult, MotionPass, PathPlan, Stamp
from pipeline.runtime.encoding import Encoding
from pipeline.runtime import video_reader, video_writer
from pipeline.runtime.observer import NullObserver, Observer, null_progress
from pipeline.runtime.source import FileSource

Mapper = Callable[[Callable[..., Any], Sequence[tuple]], Iterable[Any]]
OPEN_END = sys.maxsize  # the last segment reads to the end, whatever the header's frame count said


def serial_map(fn: Callable[..., Any], jobs: Sequence[tuple]) -> Iterator[Any]:
    for args in jobs:
        yield fn(*args)


def plan(n_frames: int, segment_frames: int) -> list[range]:
    """Consecutive ranges of ``segment_frames`` frames covering 0..n_frames (the last one open-ended)."""
    if segment_frames < 1:
        raise ConfigError(f"segment length must be at least 1 frame, not {segment_frames}")
    starts = list(range(0, max(n_frames, 1), segment_frames))
    return [range(a, b) for a, b in zip(starts, starts[1:] + [OPEN_END])]


def motion_pass(path: Path, config: stab.StabilizeConfig) -> MotionPass:
    """Pass 1 over the whole video (in a task of the mapper's)."""
    return stab.estimate_motion(FileSource(path), config.motion, observer=NullObserver(), progress=null_progress,
                                total=None, keep_tracks=config.rolling_shutter is not None)


def render_segment(path: Path, config: stab.StabilizeConfig, frames: range, plan: PathPlan) -> list[FrameResult]:
    """Pass 2 over one segment: output frames only (intermediates stay here); the window reads
    ``config.window_frames`` frames beyond each end."""
    return list(render_frames(FileSource(path), plan, config, keep=None, frames=frames))


def run(input_path: Path | str, output_path: Path | str | None, config: stab.StabilizeConfig = stab.StabilizeConfig(),
        *, segment_frames: int, mapper: Mapper = serial_map, observer: Observer | None = None,
        overwrite: bool = False, encoding: Encoding = Encoding(),
        on_segment: Callable[[int, int], None] | None = None,
        ) -> stab.StabilizeReport:
    """Stabilize one video segment by segment (``mapper`` decides where the segments run), through the same
    orchestration as a single-process run (stab.run_passes).

    ``observer`` sees the start, the path plan, every frame's output and the finish, in this process;
    per-frame intermediates and motion estimates stay in the segments' processes. ``on_segment(done, total)``
    reports rendered segments as they are written.
    """
    input_path = Path(input_path)
    output_path = Path(output_path) if output_path is not None else None
    observer = observer or NullObserver()
    info = video_reader.probe_video(input_path)
    if output_path is not None:
        video_writer.check_output_path(output_path, input_path, overwrite=overwrite)

    def whole_motion() -> MotionPass:
        found = next(iter(mapper(motion_pass, [(input_path, config)])))
        for frame, message in found.warnings:
            observer.on_warning(None if frame is None else Stamp(frame, found.times_s[frame]), message)
        return found

    def frames(path_plan: PathPlan) -> Iterator[FrameResult]:
        n_frames = path_plan.motion.n_frames
        ranges = [range(r.start, min(r.stop, n_frames)) for r in plan(n_frames, segment_frames)]
        written = 0
        for done, (frames_range, results) in enumerate(
                zip(ranges, mapper(render_segment, [(input_path, config, r, path_plan) for r in ranges])), start=1):
            if frames_range.start != written or len(results) != len(frames_range):
                raise InputError(f"{input_path}: segment {frames_range} rendered {len(results)} frames "
                                 "(the file decodes differently from one read to the next)")
            yield from results
            written = frames_range.stop
            if on_segment is not None:
                on_segment(done, len(ranges))

    return stab.run_passes(info, output_path, config, whole_motion, frames, observer=observer, encoding=encoding)
