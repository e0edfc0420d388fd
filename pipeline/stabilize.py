"""The orchestrator: two streaming passes over the video.

Pass 1 decodes every frame once and estimates the motion to its predecessor, keeping only the previous
(downscaled) frame and one 3x3 matrix per frame. The path is smoothed as a whole (it is tiny). Pass 2
decodes again, warps, and encodes. Memory is bounded by the frame window, not by the video's length.
Every stage's result goes to the observer.
"""

from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Literal

import cv2
import numpy as np

from pipeline.stages import completion, deblur, motion, neighbours, smoothing, warping
from pipeline.runtime import parallel, video_io
from pipeline.runtime.source import FileSource, FrameSource, PrefetchedSource, one_pass
from pipeline.runtime.window import Windowed, sliding_window
from pipeline.errors import ConfigError, InputError
from pipeline.runtime.observer import NullObserver, Observer, ProgressFactory, Stamp, is_null, null_progress

OutputMode = Literal["full", "none", "crop"]
OUTPUT_MODES: tuple[str, ...] = ("full", "none", "crop")


@dataclass(frozen=True)
class StabilizeConfig:
    mode: OutputMode = "full"
    motion: motion.MotionConfig = field(default_factory=motion.MotionConfig)
    smoothing: smoothing.SmoothingConfig = field(default_factory=smoothing.SmoothingConfig)
    completion: completion.CompletionConfig = field(default_factory=completion.CompletionConfig)
    deblur: deblur.DeblurConfig = field(default_factory=deblur.DeblurConfig)

    def __post_init__(self) -> None:
        if self.mode not in OUTPUT_MODES:
            raise ConfigError(f"mode must be one of {', '.join(OUTPUT_MODES)}, not {self.mode!r}")


@dataclass
class MotionPass:
    """What pass 1 leaves for pass 2: one transform and one status per frame."""

    curr_from_prev: np.ndarray  # (N, 3, 3)
    statuses: list[str]
    times_s: list[float]
    warnings: list[tuple[int | None, str]]

    @property
    def cuts(self) -> list[int]:
        return [t for t, status in enumerate(self.statuses) if status == "cut"]


@dataclass
class StabilizeReport:
    input_path: Path
    output_path: Path | None
    n_frames: int
    mode: str
    crop: warping.CropWindow | None
    cuts: list[int]
    fallbacks: list[int]
    warnings: list[tuple[int | None, str]]
    seconds_motion: float
    seconds_render: float

    @property
    def seconds(self) -> float:
        return self.seconds_motion + self.seconds_render


def estimate_motion(source: FrameSource, config: motion.MotionConfig, *, observer: Observer,
                    progress: ProgressFactory, total: int | None, frames: range | None = None,
                    workers: int = 1) -> MotionPass:
    """``frames``: estimate only these (a segment); the pair (start - 1, start) is estimated here, so each
    segment reads one frame before its range and every pair gets the estimate a whole-video run gives it.
    ``workers``: pairs estimated at once (threads); results are taken in frame order, the same either way."""
    transforms: list[np.ndarray] = []
    statuses: list[str] = []
    times: list[float] = []
    warnings: list[tuple[int | None, str]] = []
    bar = progress("pass 1/2: motion", total)
    frames_range = frames

    ignore = _IgnoreMasks(config, source.info.width, source.info.height)

    def pairs(decoded: Iterable[video_io.Frame]) -> Iterator[_MotionPair]:
        """Each frame with its predecessor, prepared (downscaled, histogram) on this thread."""
        previous: motion.PreparedFrame | None = None
        for frame in decoded:
            mask = ignore.at(frame)
            if frames_range is not None and frame.index >= frames_range.stop:
                source.drain_warnings()  # the next segment's
                return
            if frames_range is not None and frame.index < frames_range.start:
                source.drain_warnings()  # an earlier segment's
                if frame.index == frames_range.start - 1:
                    previous = motion.prepare(frame.rgb, config, mask)
                continue
            prepared = motion.prepare(frame.rgb, config, mask)
            yield _MotionPair(frame, previous, prepared, source.drain_warnings())
            previous = prepared

    def estimate_pair(pair: _MotionPair) -> tuple[_MotionPair, motion.MotionEstimate]:
        if pair.previous is None:
            return pair, motion.first_frame_estimate()
        if pair.prepared.gray.shape != pair.previous.gray.shape:
            return pair, motion.MotionEstimate(np.eye(3), "cut", warning="frame size changed: treated as a cut")
        return pair, motion.estimate(pair.previous, pair.prepared, config)

    previous: motion.MotionEstimate | None = None  # the pair before, for motion.choose_background
    try:
        with one_pass(source) as decoded:
            for pair, estimate in parallel.ordered_map(estimate_pair, pairs(decoded), workers):
                frame = pair.frame
                stamp = Stamp(frame.index, frame.time_s)
                estimate = motion.choose_background(estimate, previous, pair.prepared.width, pair.prepared.height)
                previous = estimate
                for message in pair.decoder_warnings:  # decoder complaints (corrupt packets skipped)
                    warnings.append((frame.index, message))
                    observer.on_warning(stamp, message)
                if estimate.warning:
                    warnings.append((frame.index, estimate.warning))
                    observer.on_warning(stamp, estimate.warning)
                observer.on_stage("motion", stamp, estimate)
                transforms.append(estimate.curr_from_prev)
                statuses.append(estimate.status)
                times.append(frame.time_s)
                bar.update()
        _forward_warnings(source, None, observer, warnings)
    finally:
        bar.close()
        ignore.close()
    if not transforms:
        raise InputError(f"{source.info.path}: no decodable video frames")
    return MotionPass(np.array(transforms), statuses, times, warnings)


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
        self.reader: video_io.VideoReader | None = None
        self.frames: Iterator[video_io.Frame] | None = None
        if config.ignore_mask is not None:
            path = Path(config.ignore_mask)
            if not path.is_file():
                raise InputError(f"ignore mask not found: {path}")
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if image is not None:
                self.still = self._checked(image > 127, path)
            else:
                self.reader = video_io.VideoReader(path)
                self.frames = iter(self.reader)
                self.path = path

    def _checked(self, mask: np.ndarray, path: Path) -> np.ndarray:
        if (mask.shape[1], mask.shape[0]) != self.size:
            raise InputError(f"ignore mask {path} is {mask.shape[1]}x{mask.shape[0]}, the video "
                             f"{self.size[0]}x{self.size[1]}")
        return mask

    def at(self, frame: video_io.Frame) -> np.ndarray | None:
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
    frame: video_io.Frame
    previous: motion.PreparedFrame | None  # None: the first frame (of the video, or after nothing decodable)
    prepared: motion.PreparedFrame
    decoder_warnings: list[str]  # raised while decoding up to this frame


def _forward_warnings(source: FrameSource, stamp: Stamp | None, observer: Observer,
                      sink: list[tuple[int | None, str]]) -> None:
    """Decoder complaints (corrupt packets skipped) become warnings like any other."""
    for message in source.drain_warnings():
        sink.append((stamp.index if stamp else None, message))
        observer.on_warning(stamp, message)


def output_transforms(orig_from_stab: np.ndarray, mode: str, width: int, height: int,
                      ) -> tuple[np.ndarray, warping.CropWindow | None, str | None]:
    """orig_from_out per frame for the output mode, the crop window, and a warning if cropping gave up."""
    if mode != "crop":
        return orig_from_stab, None, None
    window = warping.largest_crop(orig_from_stab, width, height)
    if window is None:
        return orig_from_stab, None, "no area is common to all stabilized frames: crop disabled, borders left black"
    return orig_from_stab @ window.stab_from_out, window, None


def stabilize(input_path: Path | str, output_path: Path | str | None, config: StabilizeConfig = StabilizeConfig(), *,
              observer: Observer | None = None, progress: ProgressFactory = null_progress,
              overwrite: bool = False, encoding: video_io.Encoding = video_io.Encoding(),
              workers: int | None = None) -> StabilizeReport:
    """Stabilize ``input_path`` into ``output_path`` (None: run and observe, write nothing).

    ``encoding``: the output's codec and quality (H.264 at CRF 18 by default). ``workers``: frames rendered at
    once on threads (None: one per CPU core); the frames written are the same."""
    input_path = Path(input_path)
    output_path = Path(output_path) if output_path is not None else None
    source = FileSource(input_path)
    if output_path is not None:
        video_io.check_output_path(output_path, input_path, overwrite=overwrite)
    return stabilize_source(source, output_path, config, observer=observer, progress=progress, encoding=encoding,
                            workers=workers)


def stabilize_source(source: FrameSource, output_path: Path | None, config: StabilizeConfig = StabilizeConfig(), *,
                     observer: Observer | None = None, progress: ProgressFactory = null_progress,
                     encoding: video_io.Encoding = video_io.Encoding(), workers: int | None = None,
                     ) -> StabilizeReport:
    """The two passes over any frame source; the output (if any) must already be checked."""
    observer = observer or NullObserver()
    workers = parallel.default_workers() if workers is None else max(int(workers), 1)
    if workers > 1:
        source = PrefetchedSource(source)  # decoding overlaps the per-frame work
    info = source.info
    observer.on_start(info, config)

    started = time.perf_counter()
    motion_pass = estimate_motion(source, config.motion, observer=observer, progress=progress,
                                  total=info.frame_count or None, workers=workers)
    n_frames = len(motion_pass.statuses)
    if n_frames == 1:
        add_warning(motion_pass.warnings, observer, "only one frame: there is no motion to smooth, written as it is")
    smoothed = smoothing.smooth(motion_pass.curr_from_prev, config.smoothing, cuts=motion_pass.cuts,
                                width=info.width, height=info.height)
    observer.on_stage("smoothing", None, smoothed)
    orig_from_out, crop, crop_warning = output_transforms(smoothed.orig_from_stab, config.mode, info.width, info.height)
    warnings = list(motion_pass.warnings)
    for message in smoothing.path_warnings(smoothed, config.smoothing):
        add_warning(warnings, observer, message)
    if crop_warning:
        add_warning(warnings, observer, crop_warning)
    if crop is not None:
        observer.on_stage("crop", None, crop)
    seconds_motion = time.perf_counter() - started

    started = time.perf_counter()
    for message in render(source, output_path, motion_pass.curr_from_prev, smoothed, orig_from_out, config,
                          observer=observer, progress=progress, total=n_frames, encoding=encoding,
                          workers=workers):
        add_warning(warnings, observer, message)
    report = StabilizeReport(
        input_path=info.path, output_path=output_path, n_frames=n_frames, mode=config.mode, crop=crop,
        cuts=motion_pass.cuts, fallbacks=[t for t, s in enumerate(motion_pass.statuses) if s == "fallback"],
        warnings=warnings, seconds_motion=seconds_motion, seconds_render=time.perf_counter() - started,
    )
    observer.on_finish(report)
    return report


def add_warning(sink: list[tuple[int | None, str]], observer: Observer, message: str) -> None:
    sink.append((None, message))
    observer.on_warning(None, message)


def render(source: FrameSource, output_path: Path | None, curr_from_prev: np.ndarray,
            smoothed: smoothing.SmoothingResult, orig_from_out: np.ndarray, config: StabilizeConfig, *,
            observer: Observer, progress: ProgressFactory, total: int,
            encoding: video_io.Encoding = video_io.Encoding(), frames: range | None = None, workers: int = 1,
            ) -> list[str]:
    """Pass 2; returns the writer's warnings (odd size padded, timestamps nudged, audio cut short).

    ``frames``: render only these (a segment); the window still reads ``radius`` frames either side of the
    range, so each frame sees the neighbours it sees in a whole-video run. ``workers``: frames rendered at
    once (threads); frames reach the observer and the writer in order either way, identical."""
    full = config.mode == "full"
    deblurring = config.deblur.enabled and config.deblur.radius > 0
    radius = max(config.completion.radius if full else 0, config.deblur.radius if deblurring else 0)
    renderer = _FrameRenderer(config, curr_from_prev, smoothed, orig_from_out,
                              keep_events=not is_null(observer))
    bar = progress("pass 2/2: warp + complete + encode" if full else "pass 2/2: warp + encode", total)
    info = source.info
    audio_from = info.path if info.has_audio else None
    writer = video_io.VideoWriter(output_path, like=info, audio_from=audio_from,
                                  encoding=encoding) if output_path else None
    try:
        with one_pass(source) as decoded:
            windows = sliding_window(decoded, radius)
            if frames is not None:
                windows = (w for w in itertools.takewhile(lambda w: w.centre.index < frames.stop, windows)
                           if w.centre.index >= frames.start)
            for rendered in parallel.ordered_map(renderer, windows, workers):
                for stage, stamp, result in rendered.events:
                    observer.on_stage(stage, stamp, result)
                if writer is not None:
                    writer.write(rendered.output, pts=rendered.frame.pts, time_s=rendered.frame.time_s)
                bar.update()
        if writer is not None:
            writer.close()
            return writer.warnings
        return []
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    finally:
        bar.close()


@dataclass
class _RenderedFrame:
    frame: video_io.Frame  # the input frame
    output: np.ndarray  # the frame to write
    events: list[tuple[str, Stamp, object]]  # (stage, stamp, result) for the observer, in stage order


class _FrameRenderer:
    """Pass 2 for one frame and its window: warp, complete (full mode), deblur. Safe to call from several
    threads at once: it only reads the window and the transforms (the deblur energy cache is locked)."""

    def __init__(self, config: StabilizeConfig, curr_from_prev: np.ndarray, smoothed: smoothing.SmoothingResult,
                 orig_from_out: np.ndarray, *, keep_events: bool) -> None:
        self.config = config
        self.curr_from_prev = curr_from_prev
        self.orig_from_stab = smoothed.orig_from_stab
        self.orig_from_out = orig_from_out
        self.segment_of = np.searchsorted(smoothed.segment_starts, np.arange(len(self.orig_from_stab)),
                                          side="right") - 1
        self.energy_cache = deblur.EnergyCache()  # each frame's gradients computed once while it is in the window
        self.downscaled: neighbours.Downscaled | None = None  # frames at completion's flow resolution
        self._downscaled_lock = threading.Lock()
        self.keep_events = keep_events

    def _downscaled(self, shape: tuple[int, int], t: int) -> neighbours.Downscaled | None:
        """The frames at local flow's working resolution (each shrunk once for all the frames it is a neighbour
        of); None when that is full resolution."""
        scale = completion.flow_scale(shape, self.config.completion)
        if scale >= 1.0:
            return None
        size = (max(round(shape[1] * scale), 1), max(round(shape[0] * scale), 1))
        with self._downscaled_lock:
            if self.downscaled is None or self.downscaled.size != size:
                self.downscaled = neighbours.Downscaled(size)
            downscaled = self.downscaled
        # A few frames of slack: frames are rendered a little out of order on several threads.
        downscaled.forget_before(t - self.config.completion.radius - 8)
        return downscaled

    def __call__(self, window: Windowed[video_io.Frame]) -> _RenderedFrame:
        config = self.config
        frame = window.centre
        stamp = Stamp(frame.index, frame.time_s)
        events: list[tuple[str, Stamp, object]] = []

        def emit(stage: str, result: object) -> None:
            if self.keep_events:
                events.append((stage, stamp, result))

        # Decoding is deterministic, so pass 2 sees pass 1's frames; guard anyway.
        t = min(frame.index, len(self.orig_from_stab) - 1)
        emit("input", frame)
        # Crop mode writes its own warp (by orig_from_out): the stabilized frame is made there only to be shown.
        stabilized = None
        if config.mode != "crop" or self.keep_events:
            stabilized = warping.warp_frame(frame.rgb, self.orig_from_stab[t])
            emit("warp", stabilized)
        # Neighbours from the same shot only: nothing is carried across a scene cut.
        same_shot = {n.index: n.rgb for n in window.neighbours.values()
                     if n.index < len(self.segment_of) and self.segment_of[n.index] == self.segment_of[t]}
        warped: list[neighbours.WarpedNeighbour] = []
        if config.mode == "full":
            near = {i: rgb for i, rgb in same_shot.items() if abs(i - t) <= config.completion.radius}
            downscaled = self._downscaled(frame.rgb.shape[:2], t)
            warped = neighbours.warp_neighbours(near, t, self.curr_from_prev, self.orig_from_stab[t],
                                                downscaled=downscaled)
            itself = neighbours.warp_neighbours({t: frame.rgb}, t, self.curr_from_prev, self.orig_from_stab[t],
                                                downscaled=downscaled)[0]
            completed = completion.complete(stabilized.frame, stabilized.missing, warped, config.completion,
                                            target_original=itself)
            emit("completion", completed)
            output, output_valid = completed.frame, None
        elif config.mode == "crop":
            output, output_valid = warping.warp(frame.rgb, self.orig_from_out[t]), None
        else:
            output, output_valid = stabilized.frame, ~stabilized.missing
        if config.deblur.enabled and config.deblur.radius > 0:
            # Last, on the frame as it will be written: in full mode completion's neighbours are reused (deblurring
            # warps the sharper ones' colours itself), transferred pixels are resampled once, and completed pixels
            # are sharpened like the rest (measured +0.06 dB over the frame, +5.7 dB on the completed pixels,
            # against deblurring before completion), so the frame stays full; missing pixels of --mode none stay
            # missing. Sharpness is compared on the original frames (pipeline/stages/deblur.py).
            deblurred = deblur.deblur_frame(output, output_valid, t, {**same_shot, t: frame.rgb},
                                            self.curr_from_prev, self.orig_from_out[t], config.deblur,
                                            warped=warped, cache=self.energy_cache)
            emit("deblur", deblurred)
            output = deblurred.frame
        emit("output", output)
        return _RenderedFrame(frame, output, events)
