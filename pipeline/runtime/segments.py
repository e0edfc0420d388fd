"""Segment-parallel stabilization of one video, with frames identical to the whole-video run.

A video is cut into segments of consecutive frames. Pass 1 estimates the motion of each segment
independently: the segment owning frame a also reads frame a - 1, so the pair (a - 1, a) is estimated
exactly as in one run (each estimate depends on its pair alone: RANSAC is reseeded per estimate, cut
detection compares the pair's histograms). The path is smoothed as a whole (it is tiny). Pass 2 renders
each segment while reading ``radius`` frames either side of it (the completion/deblur window), so every
frame sees the neighbours it sees in one run. The frames come back in order and are written once, with
the audio, by the caller's process.

No scheduler here: ``run`` takes a ``mapper`` that applies a function to a list of argument tuples and
yields the results in order (``serial_map`` below, or Ray in ffviz/batch.py).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from pipeline.stages import smoothing
from pipeline.runtime import video_io
from pipeline import stabilize as stab
from pipeline.errors import InputError
from pipeline.runtime.observer import NullObserver, Observer, Stamp, null_progress
from pipeline.runtime.source import FileSource

Mapper = Callable[[Callable[..., Any], Sequence[tuple]], Iterable[Any]]
OPEN_END = sys.maxsize  # the last segment reads to the end, whatever the header's frame count said


def serial_map(fn: Callable[..., Any], jobs: Sequence[tuple]) -> Iterator[Any]:
    for args in jobs:
        yield fn(*args)


def plan(n_frames: int, segment_frames: int) -> list[range]:
    """Consecutive ranges of ``segment_frames`` frames covering 0..n_frames (the last one open-ended)."""
    if segment_frames < 1:
        raise ValueError(f"segment length must be at least 1 frame, not {segment_frames}")
    starts = list(range(0, max(n_frames, 1), segment_frames))
    return [range(a, b) for a, b in zip(starts, starts[1:] + [OPEN_END])]


def render_radius(config: stab.StabilizeConfig) -> int:
    """Frames a segment must read either side of its range in pass 2 (the sliding window's radius)."""
    deblurring = config.deblur.enabled and config.deblur.radius > 0
    return max(config.completion.radius if config.mode == "full" else 0, config.deblur.radius if deblurring else 0)


def motion_segment(path: Path, config: stab.StabilizeConfig, frames: range) -> stab.MotionPass:
    """Pass 1 over one segment; empty where the header promised more frames than the file holds."""
    try:
        return stab.estimate_motion(FileSource(path), config.motion, observer=NullObserver(),
                                    progress=null_progress, total=None, frames=frames)
    except InputError:
        if frames.start == 0:
            raise
        return stab.MotionPass(np.zeros((0, 3, 3)), [], [], [])


def join_motion(parts: Iterable[stab.MotionPass]) -> stab.MotionPass:
    parts = [p for p in parts if p.statuses]
    return stab.MotionPass(np.concatenate([p.curr_from_prev for p in parts]),
                           [s for p in parts for s in p.statuses], [t for p in parts for t in p.times_s],
                           [w for p in parts for w in p.warnings])


@dataclass
class RenderedSegment:
    frames: range
    pts: list[int | None]
    times_s: list[float]
    output: list[np.ndarray]  # RGB uint8, before encoding


class _SegmentCollector(NullObserver):
    def __init__(self) -> None:
        self.pts: list[int | None] = []
        self.times_s: list[float] = []
        self.output: list[np.ndarray] = []

    def on_stage(self, stage: str, stamp: Stamp | None, result: Any) -> None:
        if stage == "input":
            self.pts.append(result.pts)
            self.times_s.append(result.time_s)
        elif stage == "output":
            self.output.append(result)


def render_segment(path: Path, config: stab.StabilizeConfig, frames: range, curr_from_prev: np.ndarray,
                   smoothed: smoothing.SmoothingResult, orig_from_out: np.ndarray) -> RenderedSegment:
    """Pass 2 over one segment; the window reads ``render_radius(config)`` frames beyond each end."""
    collector = _SegmentCollector()
    stab.render(FileSource(path), None, curr_from_prev, smoothed, orig_from_out, config, observer=collector,
                progress=null_progress, total=len(frames), frames=frames)
    return RenderedSegment(frames, collector.pts, collector.times_s, collector.output)


def run(input_path: Path | str, output_path: Path | str | None, config: stab.StabilizeConfig = stab.StabilizeConfig(),
        *, segment_frames: int, mapper: Mapper = serial_map, observer: Observer | None = None,
        overwrite: bool = False, encoding: video_io.Encoding = video_io.Encoding(),
        on_segment: Callable[[int, int], None] | None = None,
        ) -> stab.StabilizeReport:
    """Stabilize one video segment by segment (``mapper`` decides where the segments run).

    ``observer`` sees the start, the smoothed path, the crop, every output frame and the finish, in this
    process; per-frame intermediates stay in the segments' processes. ``on_segment(done, total)`` reports
    rendered segments as they are written.
    """
    input_path = Path(input_path)
    output_path = Path(output_path) if output_path is not None else None
    observer = observer or NullObserver()
    info = video_io.probe_video(input_path)
    if output_path is not None:
        video_io.check_output_path(output_path, input_path, overwrite=overwrite)
    observer.on_start(info, config)

    started = time.perf_counter()
    motion_plan = plan(video_io.count_frames(input_path), segment_frames)
    motion_pass = join_motion(mapper(motion_segment, [(input_path, config, r) for r in motion_plan]))
    n_frames = len(motion_pass.statuses)
    warnings = list(motion_pass.warnings)
    for frame, message in warnings:
        observer.on_warning(None if frame is None else Stamp(frame, motion_pass.times_s[frame]), message)
    if n_frames == 1:
        stab.add_warning(warnings, observer, "only one frame: there is no motion to smooth, written as it is")
    smoothed = smoothing.smooth(motion_pass.curr_from_prev, config.smoothing, cuts=motion_pass.cuts,
                                width=info.width, height=info.height)
    observer.on_stage("smoothing", None, smoothed)
    for message in smoothing.path_warnings(smoothed, config.smoothing):
        stab.add_warning(warnings, observer, message)
    orig_from_out, crop, crop_warning = stab.output_transforms(smoothed.orig_from_stab, config.mode,
                                                               info.width, info.height)
    if crop_warning:
        stab.add_warning(warnings, observer, crop_warning)
    if crop is not None:
        observer.on_stage("crop", None, crop)
    seconds_motion = time.perf_counter() - started

    started = time.perf_counter()
    render_plan = [range(r.start, min(r.stop, n_frames)) for r in plan(n_frames, segment_frames)]
    jobs = [(input_path, config, r, motion_pass.curr_from_prev, smoothed, orig_from_out) for r in render_plan]
    writer = None
    if output_path is not None:
        writer = video_io.VideoWriter(output_path, like=info, audio_from=info.path if info.has_audio else None,
                                      encoding=encoding)
    try:
        written = 0
        for done, segment in enumerate(mapper(render_segment, jobs), start=1):
            if segment.frames.start != written or len(segment.output) != len(segment.frames):
                raise InputError(f"{input_path}: segment {segment.frames} rendered {len(segment.output)} frames "
                                 "(the file decodes differently from one read to the next)")
            for t, (pts, time_s, rgb) in enumerate(zip(segment.pts, segment.times_s, segment.output),
                                                   start=segment.frames.start):
                observer.on_stage("output", Stamp(t, time_s), rgb)
                if writer is not None:
                    writer.write(rgb, pts=pts, time_s=time_s)
            written = segment.frames.stop
            if on_segment is not None:
                on_segment(done, len(jobs))
        if writer is not None:
            writer.close()
            for message in writer.warnings:
                stab.add_warning(warnings, observer, message)
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    report = stab.StabilizeReport(
        input_path=info.path, output_path=output_path, n_frames=n_frames, mode=config.mode, crop=crop,
        cuts=motion_pass.cuts, fallbacks=[t for t, s in enumerate(motion_pass.statuses) if s == "fallback"],
        warnings=warnings, seconds_motion=seconds_motion, seconds_render=time.perf_counter() - started,
    )
    observer.on_finish(report)
    return report
