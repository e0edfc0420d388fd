"""Reading video on PyAV: probe, count, and read upright RGB frames.

Frames are numpy RGB arrays of shape (H, W, 3): uint8, or float32 on the same 0..255 scale for video of more
than 8 bits read with keep_depth (pipeline/runtime/colour.py: matrix, range, tags and depth are the input's).
The reader applies the container's rotation, so frames are upright. Every expected failure is raised as
InputError with a one-line message that names the file.
"""

from __future__ import annotations

import dataclasses
import heapq
import itertools
import math
import os
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import av
import av.error
import numpy as np

from pipeline.errors import ConfigError, InputError
from pipeline.frames import Frame
from pipeline.runtime import colour as colours
from pipeline.runtime.video_info import AV_ERRORS, VideoInfo, reason


def checked_input_path(path: str | os.PathLike[str]) -> Path:
    """Fail early, with a plain message, on the cases FFmpeg would only call 'invalid data'."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"input file not found: {path}")
    if path.is_dir():
        raise InputError(f"input is a directory, not a video file: {path}")
    if not path.is_file():
        raise InputError(f"input is not a regular file: {path}")
    if not os.access(path, os.R_OK):
        raise InputError(f"input file is not readable (permission denied): {path}")
    if path.stat().st_size == 0:
        raise InputError(f"input file is empty: {path}")
    return path


def _looks_like_mp4(path: Path) -> bool:
    """An ISO media file (MP4, MOV, M4A...) starts with one of these boxes."""
    try:
        with open(path, "rb") as file:
            return file.read(8)[4:] in (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip")
    except OSError:
        return False


def open_input(path: Path) -> av.container.InputContainer:
    """``path`` opened for reading (the video and, for the writer, its audio); InputError, naming the file, where
    FFmpeg cannot open it or it is text rather than video."""
    try:
        # Tags are not always UTF-8 (or are damaged): replace what does not decode rather than fail.
        container = av.open(str(path), "r", metadata_errors="replace")
    except av.error.InvalidDataError:
        if _looks_like_mp4(path):
            # The index (moov box) comes last unless the file was written with faststart.
            raise InputError(f"damaged or truncated MP4/MOV: its index (moov box) is missing or cut: {path}") from None
        raise InputError(f"not a video file (FFmpeg cannot recognise its format): {path}") from None
    except av.error.EOFError:
        raise InputError(f"file ends too early (truncated?): {path}") from None
    except AV_ERRORS as error:
        raise InputError(f"cannot open {path}: {reason(error)}") from None
    # FFmpeg's "tty" demuxer turns any text file into an ANSI-art video stream.
    if container.format.name == "tty":
        container.close()
        raise InputError(f"not a video file (looks like text): {path}")
    return container


def _video_stream(container: av.container.InputContainer, path: Path) -> av.VideoStream:
    # Cover art in audio files shows up as a one-picture video stream; it is not a video.
    for stream in container.streams.video:
        if not stream.disposition & av.stream.Disposition.attached_pic:
            return stream
    if container.streams.audio:
        raise InputError(f"no video stream in {path} (audio only)")
    if not container.streams:
        raise InputError(f"no video stream in {path} (no streams at all: empty, damaged or truncated)")
    raise InputError(f"no video stream in {path}")


def _frame_rate(stream: av.VideoStream, path: Path) -> Fraction:
    """The average rate, snapped to FFmpeg's guessed rate (mostly r_frame_rate) within 1%.

    MP4 reports the average over a duration that leaves out the last frame's (245 frames at
    25 fps read as 6125/244); the guessed rate is the exact 25 then. For a VFR file the guess
    can be far off, which is why it is used only when the two agree.
    """
    average, base = stream.average_rate, stream.guessed_rate
    if average and base and abs(float(average / base) - 1.0) < 0.01:
        return Fraction(base)
    rate = average or base
    if not rate or rate <= 0:
        raise InputError(f"video stream has no frame rate: {path}")
    return Fraction(rate)


def _clockwise(ccw_degrees: float) -> int:
    """FFmpeg's display-matrix angle (counterclockwise) as a clockwise quarter turn."""
    return int(round(-ccw_degrees / 90.0)) % 4 * 90


def _upright(rgb: np.ndarray, rotation: int) -> np.ndarray:
    if rotation == 0:
        return rgb
    # np.rot90 turns counterclockwise for positive k; contiguous so OpenCV accepts it.
    return np.ascontiguousarray(np.rot90(rgb, k=-rotation // 90))


class _Pictures:
    """Decoded pictures in presentation order as (pts, frame), one per video packet.

    A packet that does not decode, or decodes to a picture FFmpeg flags corrupt, is stood in for by
    the last good picture (the first good one for losses at the start) at the lost packet's own pts,
    with a warning: the video keeps its frame count and timing. Pictures come out in presentation
    order, so a packet whose pts is passed without a picture of its own was lost. Without packet
    timestamps a loss cannot be placed, and the picture is skipped (also with a warning).
    """

    def __init__(self, container: av.container.InputContainer, stream: av.VideoStream, warnings: list[str],
                 path: Path, check_index: bool = True) -> None:
        self._container, self._stream, self._warnings, self._path = container, stream, warnings, path
        self._check_index_at_end = check_index  # off after a seek: the packets before it were never read
        self._pending: list[int] = []  # heap: pts of packets sent to the decoder, picture not out yet
        self._timed = True  # every packet has a pts
        self._last_good: av.VideoFrame | None = None
        self._lost_at_start: list[tuple[int, str]] = []  # (pts, why), waiting for a good picture
        self._damaged: set[int] = set()  # pts of packets the demuxer flagged corrupt (e.g. cut off)
        self._last_error: str | None = None  # the decoder's complaint since the last loss
        self.count = 0  # pictures handed out so far
        self.discarded = 0  # packets an edit list cuts (no picture expected)

    def _time(self, pts: int) -> str:
        start = self._stream.start_time or 0
        return f"{float((pts - start) * self._stream.time_base):.3f} s" if self._stream.time_base else f"pts {pts}"

    def _warn(self, message: str) -> None:
        self._warnings.append(f"{self._path.name}: {message}")

    def __iter__(self) -> Iterator[tuple[int | None, av.VideoFrame]]:
        demuxed = self._container.demux(self._stream)
        while True:
            try:
                packet = next(demuxed)
            except StopIteration:
                break
            except AV_ERRORS as error:
                # A broken container cannot be resynced reliably: keep what decoded so far.
                self._warn(f"stopped reading at a container error: {reason(error)}")
                packet = None
            if packet is not None and packet.size:
                if packet.is_discard:
                    self.discarded += 1
                elif packet.pts is None:
                    self._timed = False
                else:
                    heapq.heappush(self._pending, packet.pts)
                    if packet.is_corrupt:
                        self._damaged.add(packet.pts)
            try:
                frames = self._stream.decode(packet)  # None or the final empty packet flushes the decoder
            except AV_ERRORS as error:
                self._last_error = reason(error)
                if not self._timed:
                    where = f"pts {packet.pts}" if packet is not None else "the end"
                    self._warn(f"skipped an undecodable packet at {where}: {self._last_error}")
                frames = []
            for frame in frames:
                yield from self._place(frame)
            if packet is None:
                break
        if self._timed:  # packets still waiting for a picture at the end were lost too
            while self._pending:
                yield from self._stand_in(heapq.heappop(self._pending))
        if self._check_index_at_end:
            self._check_index()

    def _place(self, frame: av.VideoFrame) -> Iterator[tuple[int | None, av.VideoFrame]]:
        pts = frame.pts
        if pts is None:  # the decoder does not carry timestamps through: losses cannot be placed
            self._timed = False
        if not self._timed:
            if frame.is_corrupt:
                self._warn(f"skipped a corrupt frame (pts {pts})")
                return
            self.count += 1
            yield pts, frame
            return
        while self._pending and self._pending[0] < pts:
            yield from self._stand_in(heapq.heappop(self._pending))
        if self._pending and self._pending[0] == pts:
            heapq.heappop(self._pending)
        if frame.is_corrupt:
            self._last_error = "the decoder flagged the picture corrupt"
            yield from self._stand_in(pts)
            return
        if self._last_good is None:
            for lost, why in self._lost_at_start:
                self._warn(f"frame at {self._time(lost)} undecodable ({why}): the first good frame stands in for it")
                self.count += 1
                yield lost, frame
            self._lost_at_start.clear()
        self._last_good = frame
        self.count += 1
        yield pts, frame

    def _why_lost(self, pts: int) -> str:
        if pts in self._damaged:
            why = "its packet is damaged or cut off"
        else:
            why = self._last_error or "the decoder gave no picture"
        self._last_error = None
        return why

    def _stand_in(self, pts: int) -> Iterator[tuple[int, av.VideoFrame]]:
        why = self._why_lost(pts)
        if self._last_good is None:
            self._lost_at_start.append((pts, why))
            return
        self._warn(f"frame at {self._time(pts)} undecodable ({why}): the previous frame is repeated")
        self.count += 1
        yield pts, self._last_good

    def _check_index(self) -> None:
        """A file cut short loses its last packets without any error: the container's index tells."""
        listed = self._stream.frames
        if listed and self.count + self.discarded < listed:
            self._warn(f"ends early (truncated?): read {self.count} of the {listed} frames its index lists")


def _decoded_frames(
    container: av.container.InputContainer, stream: av.VideoStream, warnings: list[str], path: Path
) -> Iterator[tuple[int | None, av.VideoFrame]]:
    return iter(_Pictures(container, stream, warnings, path))


def probe_video(path: str | os.PathLike[str]) -> VideoInfo:
    """Read the header and decode the first frame (for rotation, and to prove it decodes)."""
    path = checked_input_path(path)
    with open_input(path) as container:
        stream = _video_stream(container, path)
        fps = _frame_rate(stream, path)
        time_base = stream.time_base
        if stream.duration is not None and time_base:
            duration_s = float(stream.duration * time_base)
        elif container.duration is not None:
            duration_s = container.duration / av.time_base
        else:
            duration_s = 0.0
        frame_count = stream.frames or round(duration_s * fps)
        first = next(_decoded_frames(container, stream, [], path), (None, None))[1]
        if first is None:
            raise InputError(f"no decodable video frame in {path}")
        rotation = _clockwise(first.rotation)
        width, height = first.width, first.height
        if rotation in (90, 270):
            width, height = height, width
        return VideoInfo(
            path=path,
            width=width,
            height=height,
            fps=fps,
            frame_count=int(frame_count),
            duration_s=duration_s,
            rotation=rotation,
            has_audio=bool(container.streams.audio),
            codec=stream.codec_context.name,
            time_base=Fraction(time_base) if time_base else Fraction(1, 1) / fps,
            colour=dataclasses.replace(colours.describe(first),
                                       chroma_location=colours.probe_chroma_location(path, stream.index)),
        )


def count_frames(path: str | os.PathLike[str]) -> int:
    """The exact number of frames VideoReader yields, from the packets (no decoding) when it can.

    One packet is one frame for every container this project meets (checked on all the shared
    clips). Decoding is the fallback when the packets cannot be read to the end, or when some
    are flagged corrupt, since the reader drops what does not decode.
    """
    path = checked_input_path(path)
    with open_input(path) as container:
        stream = _video_stream(container, path)
        count = 0
        try:
            for packet in container.demux(stream):
                if packet.is_corrupt:
                    count = 0
                    break
                # Empty packets are end-of-stream flushes; discard-flagged ones are cut by an edit list.
                if packet.size and not packet.is_discard:
                    count += 1
        except AV_ERRORS:
            count = 0
    if count:
        return count
    with VideoReader(path) as reader:
        return sum(1 for _ in reader.decoded_frames())


def clipped_info(info: VideoInfo, start_s: float | None, end_s: float | None) -> VideoInfo:
    """``info`` for the part of the video from ``start_s`` to ``end_s`` seconds (None: its start / end), as
    VideoReader(start_s=..., end_s=...) reads it; frame_count and duration_s are estimates (rate x length)."""
    start = float(start_s or 0.0)
    if not math.isfinite(start) or start < 0:
        raise ConfigError(f"start time must be 0 s or later, not {start_s}")
    if end_s is not None and not (math.isfinite(end_s) and end_s > start):
        raise ConfigError(f"end time {end_s:g} s must be after the start time {start:g} s")
    if info.duration_s > 0 and start >= info.duration_s:
        raise InputError(f"start time {start:g} s is past the end of {info.path} ({info.duration_s:.2f} s long)")
    end = float(end_s) if end_s is not None else math.inf
    if info.duration_s > 0:
        end = min(end, info.duration_s)
    if math.isinf(end):  # the container does not say how long it is
        count = max(1, info.frame_count - math.floor(start * info.fps))
        return dataclasses.replace(info, frame_count=count, duration_s=0.0, clip=(start, end))
    count = max(1, math.ceil((end - start) * info.fps - 0.25))
    return dataclasses.replace(info, frame_count=min(count, info.frame_count or count), duration_s=end - start,
                               clip=(start, end))


class VideoReader:
    """Streams a video as upright RGB Frames, one at a time. Single pass; use as a context manager.

    A frame that does not decode is replaced by the previous good one at its own time (see _Pictures),
    so frame count and timing are the file's; each such frame adds a line to `warnings`.
    RGB by the video's own matrix and range (info.colour); ``keep_depth``: video of more than 8 bits comes as
    float32 RGB on the 0..255 scale (else uint8 always).
    ``start_s``/``end_s``: only the frames from that time up to (not including) this one (seconds, Frame.time_s,
    a quarter frame's leeway), numbered from 0, with their times in the file; it seeks to the key frame
    before ``start_s`` rather than decoding everything before it.
    """

    def __init__(self, path: str | os.PathLike[str], *, keep_depth: bool = False, start_s: float | None = None,
                 end_s: float | None = None) -> None:
        self.info: VideoInfo = probe_video(path)
        if start_s is not None or end_s is not None:
            self.info = clipped_info(self.info, start_s, end_s)
        self.warnings: list[str] = []
        self.keep_depth = keep_depth
        self._start_s, self._end_s = start_s, end_s
        self._container = open_input(self.info.path)
        self._stream = _video_stream(self._container, self.info.path)
        self._stream.codec_context.thread_type = "AUTO"  # frame + slice threads: much faster on 720p
        self._started = False
        self._seeked = False

    def decoded_frames(self) -> Iterator[tuple[int | None, av.VideoFrame]]:
        """(pts, raw PyAV frame) before RGB conversion and rotation; a lost frame's stand-in has its pts."""
        if self._started:
            raise RuntimeError("VideoReader reads once; open a new one to read again")
        self._started = True
        if self._start_s:
            seeked = self._seeked_pictures(self._start_s)
            if seeked is not None:
                return seeked
        return _decoded_frames(self._container, self._stream, self.warnings, self.info.path)

    def _seeked_pictures(self, start_s: float) -> Iterator[tuple[int | None, av.VideoFrame]] | None:
        """Pictures from the key frame at or before ``start_s``; None (and the file reopened at its start) where
        the seek lands after it or the pictures carry no timestamps (a container without an index)."""
        stream = self._stream
        target = (stream.start_time or 0) + math.floor(start_s / self.info.time_base)
        seen = len(self.warnings)
        try:
            self._container.seek(target, stream=stream, backward=True)
            pictures = iter(_Pictures(self._container, stream, self.warnings, self.info.path, check_index=False))
            first = next(pictures, None)
        except AV_ERRORS:
            first = None
        if first is not None and first[0] is not None and first[0] <= target:
            self._seeked = True
            return itertools.chain([first], pictures)
        del self.warnings[seen:]
        self._container.close()
        self._container = open_input(self.info.path)
        self._stream = _video_stream(self._container, self.info.path)
        self._stream.codec_context.thread_type = "AUTO"
        return None

    def __iter__(self) -> Iterator[Frame]:
        info = self.info
        # Stored (pre-rotation) size: a mid-stream size change is scaled back to it.
        stored_w, stored_h = info.width, info.height
        if info.rotation in (90, 270):
            stored_w, stored_h = stored_h, stored_w
        leeway = 0.25 / float(info.fps)
        first_s = -math.inf if self._start_s is None else self._start_s - leeway
        stop_s = math.inf if self._end_s is None else self._end_s - leeway
        index = 0
        pictures = self.decoded_frames()
        start = self._stream.start_time or 0
        for decoded, (pts, frame) in enumerate(pictures):
            pts = pts if pts is not None else frame.dts
            if pts is not None:
                time_s = float((pts - start) * info.time_base)
            elif not self._seeked:
                time_s = float(decoded / info.fps)
            else:
                continue  # after a seek, a picture without a timestamp cannot be placed
            if time_s < first_s:
                continue
            if time_s >= stop_s:
                break
            rgb = colours.to_rgb(frame, info.colour, stored_w, stored_h, deep=self.keep_depth)
            yield Frame(index=index, pts=pts, time_s=time_s, rgb=_upright(rgb, info.rotation))
            index += 1

    def close(self) -> None:
        self._container.close()

    def __enter__(self) -> VideoReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
