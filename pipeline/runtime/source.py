"""Where frames come from: a video file, or frames already in memory (tests, ground-truth evaluation).

The orchestrator makes two passes, so a source hands out a fresh iterator per pass.
"""

from __future__ import annotations

import dataclasses
from contextlib import contextmanager
from fractions import Fraction
from pathlib import Path
from typing import Iterator, Protocol, Sequence

import numpy as np

from pipeline.frames import Frame
from pipeline.runtime.video_info import VideoInfo
from pipeline.runtime import parallel, video_reader
from pipeline.errors import InputError


class FrameSource(Protocol):
    info: VideoInfo

    def frames(self) -> Iterator[Frame]:
        """A new pass over every frame; closing the iterator releases what it holds."""

    def drain_warnings(self) -> list[str]:
        """Decoder warnings gathered since the last call."""


class FileSource:
    """A video file's frames; ``start_s``/``end_s``: only that part of it (seconds; see video_reader.VideoReader), and
    ``info.clip`` says so, so the output and its audio start at the first frame read (a preview)."""

    def __init__(self, path: Path | str, *, start_s: float | None = None, end_s: float | None = None) -> None:
        self.path = Path(path)
        self.info = video_reader.probe_video(self.path)
        self._range = (start_s, end_s)
        if start_s is not None or end_s is not None:
            self.info = video_reader.clipped_info(self.info, start_s, end_s)
        self._warnings: list[str] = []
        self._reader: video_reader.VideoReader | None = None

    def frames(self) -> Iterator[Frame]:
        start_s, end_s = self._range
        with video_reader.VideoReader(self.path, keep_depth=True, start_s=start_s, end_s=end_s) as reader:
            self._reader = reader
            try:
                yield from reader
            finally:
                self._warnings.extend(reader.warnings)
                reader.warnings.clear()
                self._reader = None

    def drain_warnings(self) -> list[str]:
        if self._reader is not None:
            self._warnings.extend(self._reader.warnings)
            self._reader.warnings.clear()
        drained, self._warnings = self._warnings, []
        return drained


class WindowSource:
    """Frames ``first`` to ``stop`` (not included) of a video file whose frames' times (``times_s``, a whole pass's)
    are known, decoded from the key frame before the first, numbered as in a whole pass. One frame's window is
    rendered alone this way (the debugger), without decoding the video before it."""

    def __init__(self, path: Path | str, times_s: Sequence[float], first: int, stop: int) -> None:
        if not 0 <= first < stop <= len(times_s):
            raise ValueError(f"frames {first}-{stop - 1} are not within the video's {len(times_s)}")
        self.path = Path(path)
        self.info = video_reader.probe_video(self.path)
        self._times, self._first, self._stop = list(times_s), first, stop
        self._warnings: list[str] = []

    def frames(self) -> Iterator[Frame]:
        times, first, stop = self._times, self._first, self._stop
        end_s = times[stop] if stop < len(times) else None
        leeway = 0.5 / float(self.info.fps or 30)
        with video_reader.VideoReader(self.path, keep_depth=True, start_s=times[first] if first else None,
                                      end_s=end_s) as reader:
            try:
                for offset, frame in enumerate(reader):
                    index = first + offset
                    if index >= stop or abs(frame.time_s - times[index]) > leeway:
                        raise InputError(f"{self.path}: frame {index} decodes at {frame.time_s:.3f} s after a seek, "
                                         f"not at {times[index]:.3f} s as read from the start")
                    yield dataclasses.replace(frame, index=index)
            finally:
                self._warnings.extend(reader.warnings)

    def drain_warnings(self) -> list[str]:
        drained, self._warnings = self._warnings, []
        return drained


class ArraySource:
    """RGB uint8 frames held in memory, at a constant frame rate."""

    def __init__(self, frames: Sequence[np.ndarray], fps: float = 30.0, name: str = "<frames>") -> None:
        if not len(frames):
            raise InputError(f"{name}: no frames")
        self._frames = frames
        height, width = frames[0].shape[:2]
        rate = Fraction(fps).limit_denominator(1001)
        self.info = VideoInfo(path=Path(name), width=width, height=height, fps=rate,
                                       frame_count=len(frames), duration_s=len(frames) / float(rate), rotation=0,
                                       has_audio=False, codec="raw", time_base=1 / rate)

    def frames(self) -> Iterator[Frame]:
        for index, rgb in enumerate(self._frames):
            yield Frame(index=index, pts=index, time_s=index / float(self.info.fps), rgb=rgb)

    def drain_warnings(self) -> list[str]:
        return []


class PrefetchedSource:
    """Another source's frames decoded ahead on a background thread (pipeline/runtime/parallel.py).

    Decoder warnings travel with the frame they were raised by, so ``drain_warnings`` answers exactly what the
    wrapped source answers at the same point of a pass.
    """

    def __init__(self, source: FrameSource, depth: int = 4) -> None:
        self.source = source
        self.info = source.info
        self.depth = depth
        self._warnings: list[str] = []

    def frames(self) -> Iterator[Frame]:
        def decoded() -> Iterator[tuple[Frame | None, list[str]]]:
            with one_pass(self.source) as frames:
                for frame in frames:
                    yield frame, self.source.drain_warnings()
            yield None, self.source.drain_warnings()  # raised after the last frame (e.g. a truncated stream)

        ahead = parallel.Prefetch(decoded(), self.depth)
        try:
            for frame, warnings in ahead:
                self._warnings.extend(warnings)
                if frame is not None:
                    yield frame
        finally:
            ahead.close()

    def drain_warnings(self) -> list[str]:
        drained, self._warnings = self._warnings, []
        return drained


@contextmanager
def one_pass(source: FrameSource) -> Iterator[Iterator[Frame]]:
    """A pass over the source that is closed however the loop ends."""
    frames = source.frames()
    try:
        yield frames
    finally:
        close = getattr(frames, "close", None)
        if close is not None:
            close()
