"""Stabilize a video: pass 1 estimates the motion of every frame pair (chapter 3), the path is planned as a whole
(pipeline/chain.py), pass 2 renders every frame through the per-frame chain and writes it. ``run_passes`` is
the one orchestration; ``stabilize_source`` runs both passes in this process (threads), pipeline/segments.py
runs them segment by segment through a mapper (serial or Ray). Memory is bounded by the frame
window, not by the video's length: pass 1 keeps the previous downscaled frame and one 3x3 matrix per frame.
"""

from __future__ import annotations

import collections
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator

import cv2
import numpy as np

from pipeline.chain import FrameChain, plan_path, render_frames
from pipeline.config import (DEFAULT_CROP_FILL, DEFAULT_PATH, DEFAULT_RADIUS, HARD_CROP_RADIUS, OUTPUT_MODES,
                             OutputMode, StabilizeConfig, default_path, default_radius)
from pipeline.errors import ConfigError, InputError
from pipeline.results import FrameResult, MotionPass, PathPlan, Stamp
from pipeline.frames import Frame
from pipeline.runtime.encoding import Encoding
from pipeline.runtime.video_info import VideoInfo
from pipeline.runtime import parallel, video_reader, video_writer
from pipeline.runtime.observer import NullObserver, Observer, ProgressFactory, is_null, null_progress
from pipeline.runtime.source import FileSource, FrameSource, PrefetchedSource, one_pass
from pipeline.stages.adaptive_crop import AdaptiveCrop
from pipeline.stages import background, motion, rolling_shutter, warping

__all__ = ["DEFAULT_CROP_FILL", "DEFAULT_PATH", "DEFAULT_RADIUS", "HARD_CROP_RADIUS", "OUTPUT_MODES", "default_path",
           "default_radius", "OutputMode", "StabilizeConfig", "MotionPass", "PathPlan", "FrameResult",
           "FrameChain", "StabilizeReport", "estimate_motion", "run_passes", "stabilize", "stabilize_source"]


@dataclass
class StabilizeReport:
    input_path: Path
    output_path: Path | None
    n_frames: int
    mode: str
    crop: warping.CropWindow | AdaptiveCrop | None  # the fixed window, or the adaptive crop's windows
    cuts: list[int]
    fallbacks: list[int]
    warnings: list[tuple[int | None, str]]
    seconds_motion: float
    seconds_render: float

    @property
    def seconds(self) -> float:
        return self.seconds_motion + self.seconds_render


def estimate_motion(source: FrameSource, config: motion.MotionConfig, *, observer: Observer,
                    progress: ProgressFactory, total: int | None, workers: int = 1,
                    keep_tracks: bool = False) -> MotionPass:
    """Pass 1, over the whole clip in order: every pair's motion, with the layers of the pair before carried on
    (motion.continued), the camera's chosen where a pair holds several (pipeline/stages/background.py; each
    estimate reaches ``observer`` once chosen, up to 2 x background.LAG_PAIRS pairs later). ``workers``: pairs
    estimated at once (threads); results are taken in frame order, the same either way. ``keep_tracks``: keep each
    pair's inlier tracks (rolling-shutter correction fits them after the pass)."""
    collected = _PassOne(observer, keep_tracks)
    bar = progress("pass 1/2: motion", total)
    ignore = _IgnoreMasks(config, source.info.width, source.info.height)
    evidence = background.LayerEvidence()

    def estimate_pair(pair: _MotionPair) -> tuple[_MotionPair, motion.MotionEstimate]:
        if pair.previous is None:
            return pair, motion.first_frame_estimate()
        if pair.prepared.gray.shape != pair.previous.gray.shape:
            return pair, motion.MotionEstimate(np.eye(3), "cut", warning="frame size changed: treated as a cut")
        return pair, motion.estimate(pair.previous, pair.prepared, config)

    before = None  # the pair before's estimate as motion.continued returned it
    try:
        with one_pass(source) as decoded:
            pairs = _motion_pairs(decoded, source, config, ignore)
            for pair, measured in parallel.ordered_map(estimate_pair, pairs, workers):
                bar.update()
                collected.waiting.append(_Waiting(pair.frame.index, pair.frame.time_s, pair.decoder_warnings))
                estimate = before = motion.continued(before, measured, pair.previous, pair.prepared, config)
                for raw, layers in evidence.push(estimate, pair.previous, pair.prepared):
                    collected.add(raw, layers)
            for raw, layers in evidence.finish():
                collected.add(raw, layers)
            collected.finish()
        _forward_warnings(source, None, observer, collected.warnings)
    finally:
        bar.close()
        ignore.close()
    if not collected.transforms:
        raise InputError(f"{source.info.path}: no decodable video frames")
    return collected.motion_pass()


def _motion_pairs(decoded: Iterable[Frame], source: FrameSource, config: motion.MotionConfig,
                  ignore: _IgnoreMasks) -> Iterator[_MotionPair]:
    """Each frame with its predecessor, prepared (downscaled, histogram) on this thread."""
    previous: motion.PreparedFrame | None = None
    for frame in decoded:
        prepared = motion.prepare(frame.rgb, config, ignore.at(frame))
        yield _MotionPair(frame, previous, prepared, source.drain_warnings())
        previous = prepared


class _PassOne:
    """What pass 1 collects, pair by pair in frame order: the raw estimates wait (``waiting``) until the camera
    chooser has decided them."""

    def __init__(self, observer: Observer, keep_tracks: bool) -> None:
        self.observer, self.keep_tracks = observer, keep_tracks
        self.chooser = background.CameraChooser()
        self.waiting: collections.deque[_Waiting] = collections.deque()  # not the frames: 180 at 4K are 4 GB
        self.raw: collections.deque[motion.MotionEstimate] = collections.deque()
        self.transforms: list[np.ndarray] = []
        self.tracks: list = []
        self.statuses: list[str] = []
        self.times: list[float] = []
        self.warnings: list[tuple[int | None, str]] = []

    def add(self, raw: motion.MotionEstimate, layers: background.PairLayers) -> None:
        self.raw.append(raw)
        for _, choice in self.chooser.push(layers):
            self._emit(self.waiting.popleft(), motion.with_camera(self.raw.popleft(), choice))

    def finish(self) -> None:
        for _, choice in self.chooser.finish():
            self._emit(self.waiting.popleft(), motion.with_camera(self.raw.popleft(), choice))

    def _emit(self, frame: _Waiting, estimate: motion.MotionEstimate) -> None:
        stamp = Stamp(frame.index, frame.time_s)
        for message in frame.decoder_warnings:  # decoder complaints (corrupt packets skipped)
            self.warnings.append((frame.index, message))
            self.observer.on_warning(stamp, message)
        if estimate.warning:
            self.warnings.append((frame.index, estimate.warning))
            self.observer.on_warning(stamp, estimate.warning)
        self.observer.on_motion(stamp, estimate)
        self.transforms.append(estimate.curr_from_prev)
        if self.keep_tracks:
            self.tracks.append(rolling_shutter.inlier_tracks(estimate))
        self.statuses.append(estimate.status)
        self.times.append(frame.time_s)

    def motion_pass(self) -> MotionPass:
        return MotionPass(np.array(self.transforms), self.statuses, self.times, self.warnings,
                          self.tracks if self.keep_tracks else None)


class _IgnoreMasks:
    """Where motion estimation ignores features, frame by frame: the config's boxes active at the frame's time,
    and the --ignore-mask image (one for every frame) or video (frame by frame), white meaning ignore. Checked
    against the input's size when made (one-line errors)."""

    def __init__(self, config: motion.MotionConfig, width: int, height: int) -> None:
        self.boxes = config.ignore
        self.size = (width, height)
        for box in self.boxes:
            if box.x + box.width > width or box.y + box.height > height:
                raise ConfigError(f"ignore box {box.x},{box.y},{box.width},{box.height} reaches outside the "
                                  f"{width}x{height} frame")
        self.still: np.ndarray | None = None
        self.reader: video_reader.VideoReader | None = None
        self.frames: Iterator[Frame] | None = None
        if config.ignore_mask is not None:
            path = Path(config.ignore_mask)
            if not path.is_file():
                raise InputError(f"ignore mask not found: {path}")
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if image is not None:
                self.still = self._checked(image > 127, path)
            else:
                self.reader = video_reader.VideoReader(path)
                self.frames = iter(self.reader)
                self.path = path

    def _checked(self, mask: np.ndarray, path: Path) -> np.ndarray:
        if (mask.shape[1], mask.shape[0]) != self.size:
            raise InputError(f"ignore mask {path} is {mask.shape[1]}x{mask.shape[0]}, the video "
                             f"{self.size[0]}x{self.size[1]}")
        return mask

    def at(self, frame: Frame) -> np.ndarray | None:
        mask = self.still
        if self.frames is not None:
            picture = next(self.frames, None)
            if picture is None:
                raise InputError(f"ignore mask video {self.path} ends before frame {frame.index}")
            mask = self._checked(picture.rgb.max(axis=2) > 127, self.path)
        active = [box for box in self.boxes if box.active(frame.time_s)]
        if not active:
            return mask
        mask = np.zeros((self.size[1], self.size[0]), bool) if mask is None else mask.copy()
        for box in active:
            mask[box.y:box.y + box.height, box.x:box.x + box.width] = True
        return mask

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()


@dataclass(frozen=True)
class _MotionPair:
    frame: Frame
    previous: motion.PreparedFrame | None  # None: the first frame (of the video, or after nothing decodable)
    prepared: motion.PreparedFrame
    decoder_warnings: list[str]  # raised while decoding up to this frame


@dataclass(frozen=True)
class _Waiting:
    """A pair's frame while its camera motion waits to be chosen: what is said of it then, not its pixels."""

    index: int
    time_s: float
    decoder_warnings: list[str]


def _forward_warnings(source: FrameSource, stamp: Stamp | None, observer: Observer,
                      sink: list[tuple[int | None, str]]) -> None:
    """Decoder complaints (corrupt packets skipped) become warnings like any other."""
    for message in source.drain_warnings():
        sink.append((stamp.index if stamp else None, message))
        observer.on_warning(stamp, message)


def stabilize(input_path: Path | str, output_path: Path | str | None, config: StabilizeConfig = StabilizeConfig(), *,
              observer: Observer | None = None, progress: ProgressFactory = null_progress,
              overwrite: bool = False, encoding: Encoding = Encoding(),
              workers: int | None = None) -> StabilizeReport:
    """Stabilize ``input_path`` into ``output_path`` (None: run and observe, write nothing).

    ``encoding``: the output's codec and quality (H.264 at CRF 18 by default). ``workers``: frames rendered at
    once on threads (None: one per CPU core); the frames written are the same."""
    input_path = Path(input_path)
    output_path = Path(output_path) if output_path is not None else None
    source = FileSource(input_path)
    if output_path is not None:
        video_writer.check_output_path(output_path, input_path, overwrite=overwrite)
    return stabilize_source(source, output_path, config, observer=observer, progress=progress, encoding=encoding,
                            workers=workers)


def stabilize_source(source: FrameSource, output_path: Path | None, config: StabilizeConfig = StabilizeConfig(), *,
                     observer: Observer | None = None, progress: ProgressFactory = null_progress,
                     encoding: Encoding = Encoding(), workers: int | None = None,
                     ) -> StabilizeReport:
    """Both passes in this process over any frame source (``workers`` threads); the output must be checked."""
    observer = observer or NullObserver()
    workers = parallel.default_workers() if workers is None else max(int(workers), 1)
    if workers > 1:
        source = PrefetchedSource(source)  # decoding overlaps the per-frame work
    keep = None if is_null(observer) else observer.keep

    def motion_pass() -> MotionPass:
        return estimate_motion(source, config.motion, observer=observer, progress=progress,
                               total=source.info.frame_count or None, workers=workers,
                               keep_tracks=config.rolling_shutter is not None)

    def frames(plan: PathPlan) -> Iterator[FrameResult]:
        description = "pass 2/2: warp + complete + encode" if config.completing else "pass 2/2: warp + encode"
        bar = progress(description, plan.motion.n_frames)
        try:
            for result in render_frames(source, plan, config, keep=keep, workers=workers):
                yield result
                bar.update()
        finally:
            bar.close()

    return run_passes(source.info, output_path, config, motion_pass, frames, observer=observer, encoding=encoding)


def run_passes(info: VideoInfo, output_path: Path | None, config: StabilizeConfig,
               motion_pass: Callable[[], MotionPass], frames: Callable[[PathPlan], Iterable[FrameResult]], *,
               observer: Observer, encoding: Encoding) -> StabilizeReport:
    """The one orchestration of a run, whoever executes its passes.

    ``motion_pass()``: pass 1 (its per-frame warnings already shown to ``observer``); ``frames(plan)``: pass 2's
    results in frame order. This function plans the path, shows every result and warning to ``observer``,
    writes the frames with the input's audio (nothing is left at ``output_path`` if anything fails), and
    reports."""
    observer.on_start(info, config)
    started = time.perf_counter()
    if config.plans_by_linear_programs:  # scipy.optimize's import (~0.3 s) is paid while pass 1 runs, not after it
        parallel.import_in_background("scipy.optimize", "scipy.ndimage")
    motion_result = motion_pass()
    plan = plan_path(motion_result, config, info.width, info.height)
    warnings = list(motion_result.warnings)
    observer.on_path(plan)
    for message in plan.warnings:
        _add_warning(warnings, observer, message)
    seconds_motion = time.perf_counter() - started

    started = time.perf_counter()
    writer = None
    if output_path is not None:
        writer = video_writer.VideoWriter(output_path, like=info, audio_from=info.path if info.has_audio else None,
                                          encoding=encoding)
    try:
        for result in frames(plan):
            observer.on_frame(result)
            if writer is not None:
                writer.write(result.output, pts=result.pts, time_s=result.stamp.time_s)
        if writer is not None:
            writer.close()
            for message in writer.warnings:  # odd size padded, timestamps nudged, audio cut short
                _add_warning(warnings, observer, message)
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    report = StabilizeReport(
        input_path=info.path, output_path=output_path, n_frames=motion_result.n_frames, mode=config.mode,
        crop=plan.crop or plan.adaptive_crop, cuts=motion_result.cuts, fallbacks=motion_result.fallbacks,
        warnings=warnings,
        seconds_motion=seconds_motion, seconds_render=time.perf_counter() - started,
    )
    observer.on_finish(report)
    return report


def _add_warning(sink: list[tuple[int | None, str]], observer: Observer, message: str) -> None:
    sink.append((None, message))
    observer.on_warning(None, message)
