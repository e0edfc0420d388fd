"""The project's only video I/O layer, on PyAV: probe, count, read upright RGB frames, write H.264.

Frames are numpy RGB arrays of shape (H, W, 3): uint8, or float32 on the same 0..255 scale for video of more
than 8 bits read with keep_depth (pipeline/runtime/colour.py: matrix, range, tags and depth are the input's, in
and out). The reader applies the container's rotation, so frames are upright and the writer stores them with no
rotation tag. Every expected failure is
raised as InputError or OutputError with a one-line message that names the file.
"""

from __future__ import annotations

import dataclasses
import functools
import heapq
import itertools
import math
import os
import secrets
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from types import TracebackType

import av
import av.error
import numpy as np

from pipeline.errors import ConfigError, InputError, OutputError
from pipeline.runtime.colour import ColourDescription
from pipeline.runtime import colour as colours

# Output suffix -> FFmpeg muxer name. H.264 + AAC plays from all three.
OUTPUT_FORMATS = {".mp4": "mp4", ".mov": "mov", ".mkv": "matroska"}

# Audio codecs copied into each output format as they are; anything else is transcoded to AAC.
# Narrower than what the muxers claim: they accept PCM or Vorbis in MP4, which players often do not
# play, and claim FLAC in MOV, which then fails to mux.
COPYABLE_AUDIO_CODECS = {
    "mp4": frozenset({"aac", "mp3", "opus", "alac", "ac3", "eac3", "flac"}),
    "mov": frozenset(
        {"aac", "mp3", "alac", "ac3", "eac3", "pcm_s16le", "pcm_s16be", "pcm_s24le", "pcm_s24be"}
    ),
    "matroska": frozenset(
        {"aac", "mp3", "opus", "vorbis", "alac", "ac3", "eac3", "flac", "pcm_s16le", "pcm_s24le", "pcm_f32le"}
    ),
}
# What the AAC encoder accepts when transcoding: other layouts become mono/stereo, other rates 48 kHz.
_AAC_LAYOUTS = frozenset({"mono", "stereo", "2.1", "3.0", "4.0", "5.0", "5.1", "6.1", "7.1"})
_AAC_SAMPLE_RATES = frozenset(
    {96000, 88200, 64000, 48000, 44100, 32000, 24000, 22050, 16000, 12000, 11025, 8000, 7350}
)

_AV_ERRORS = (av.error.FFmpegError, OSError)


@dataclass(frozen=True)
class VideoInfo:
    """What probe_video learns from the container header and the first decoded frame."""

    path: Path
    width: int  # display width, after rotation
    height: int  # display height, after rotation
    fps: Fraction  # average frame rate, see _frame_rate
    # From the container's index (MP4/MOV sample table, AVI index): exact for well-formed files.
    # Containers without a count (MKV, MPEG-TS) give round(duration_s * fps), an estimate:
    # call count_frames for the exact number.
    frame_count: int
    duration_s: float
    rotation: int  # degrees clockwise to turn the stored frames for display: 0, 90, 180 or 270
    has_audio: bool
    codec: str
    time_base: Fraction  # of the video stream; Frame.pts counts in it
    colour: ColourDescription = ColourDescription()  # range, matrix, primaries, transfer, depth (first frame's)
    # (start, end) seconds (Frame.time_s) when only that part of the file is read (clipped_info); the writer
    # then starts the output, and the audio it copies, at the first frame and ends the audio at the last.
    clip: tuple[float, float] | None = None


@dataclass(frozen=True)
class Frame:
    index: int  # 0-based decode order after dropping undecodable frames
    pts: int | None  # presentation timestamp in the stream's time_base
    time_s: float  # seconds since the stream's start_time (absolute time is pts * time_base)
    rgb: np.ndarray  # (H, W, 3) uint8 (float32 0..255: deeper video read with keep_depth), rotation applied


def _reason(error: BaseException) -> str:
    """FFmpeg's reason without the errno and path PyAV adds, on one line."""
    text = getattr(error, "strerror", None) or str(error) or type(error).__name__
    return " ".join(str(text).split())


def _checked_input_path(path: str | os.PathLike[str]) -> Path:
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


def _open_input(path: Path) -> av.container.InputContainer:
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
    except _AV_ERRORS as error:
        raise InputError(f"cannot open {path}: {_reason(error)}") from None
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
            except _AV_ERRORS as error:
                # A broken container cannot be resynced reliably: keep what decoded so far.
                self._warn(f"stopped reading at a container error: {_reason(error)}")
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
            except _AV_ERRORS as error:
                self._last_error = _reason(error)
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
    path = _checked_input_path(path)
    with _open_input(path) as container:
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
    path = _checked_input_path(path)
    with _open_input(path) as container:
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
        except _AV_ERRORS:
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
        self._container = _open_input(self.info.path)
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
        except _AV_ERRORS:
            first = None
        if first is not None and first[0] is not None and first[0] <= target:
            self._seeked = True
            return itertools.chain([first], pictures)
        del self.warnings[seen:]
        self._container.close()
        self._container = _open_input(self.info.path)
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


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def _check_output_format(output: Path) -> str:
    fmt = OUTPUT_FORMATS.get(output.suffix.lower())
    if fmt is None:
        supported = ", ".join(OUTPUT_FORMATS)
        raise OutputError(f"unsupported output type '{output.suffix}' for {output}: use one of {supported}")
    return fmt


def _check_output_folder(output: Path) -> None:
    parent = output.parent
    if not parent.is_dir():
        raise OutputError(f"output folder does not exist: {parent}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"output folder is not writable: {parent}")


def check_output_path(output: Path, input: Path, *, overwrite: bool) -> None:
    """Refuse an output path before any work is done on it."""
    output, input = Path(output), Path(input)
    if _same_file(output, input):
        raise OutputError(f"output is the same file as the input: {output}")
    _check_output_format(output)
    if output.is_dir():
        raise OutputError(f"output is a directory: {output}")
    if output.exists() and not overwrite:
        raise OutputError(f"output already exists: {output} (pass --overwrite to replace it)")
    _check_output_folder(output)


def _reserve_temp_path(target: Path) -> Path:
    """An unused hidden name beside the target, so the final os.replace is atomic (same filesystem)."""
    while True:
        temp = target.with_name(f".{target.stem}.ffviz-tmp-{secrets.token_hex(4)}{target.suffix}")
        try:
            # Created here rather than by mkstemp so the final file gets normal (umask) permissions.
            os.close(os.open(temp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            return temp
        except FileExistsError:
            continue
        except OSError as error:
            raise OutputError(f"cannot create a file in {target.parent}: {_reason(error)}") from None


class _AudioPassthrough:
    """Feeds the audio of `source` into `output`, copied when the codec allows, else as AAC.

    Packets are read lazily and muxed up to the time of the latest video frame, so memory stays
    bounded; FFmpeg's interleaver absorbs the encoder's lookahead delay. After ``start_at(t)`` only the audio from
    t on (whole packets or decoded frames) is muxed, moved t earlier: the video was cut at t.
    """

    def __init__(self, source: Path, output: av.container.OutputContainer, warnings: list[str]) -> None:
        self._source_path = source
        self._warnings = warnings
        self._container = _open_input(_checked_input_path(source))
        self._output = output
        self._in = self._container.streams.audio[0] if self._container.streams.audio else None
        self._pending: av.Packet | None = None
        self._next_sample: int | None = None  # transcoding: pts of the next sample
        self._done = self._in is None
        self._start_s: float | None = None  # start_at: audio before it is dropped, the rest moved back by it
        self.copied = False
        if self._in is None:
            return
        codec = self._in.codec_context.codec.canonical_name
        self.copied = codec in COPYABLE_AUDIO_CODECS[output.format.name]
        if self.copied:
            self._out = output.add_stream_from_template(self._in)
        else:
            in_ctx = self._in.codec_context
            rate = in_ctx.sample_rate if in_ctx.sample_rate in _AAC_SAMPLE_RATES else 48000
            layout = in_ctx.layout.name
            if layout not in _AAC_LAYOUTS:  # e.g. "1 channels" (PCM in MKV), which the encoder refuses
                layout = "mono" if in_ctx.channels == 1 else "stereo"
            self._out = output.add_stream("aac", rate=rate, layout=layout)
        self._packets = self._container.demux(self._in)

    def _next_packet(self) -> av.Packet | None:
        try:
            return next(self._packets)
        except StopIteration:
            return None
        except _AV_ERRORS as error:
            self._warnings.append(f"{self._source_path.name}: audio stopped early: {_reason(error)}")
            return None

    def start_at(self, time_s: float) -> None:
        """Drop the audio before ``time_s`` (seconds, absolute: pts x time base) and start the rest at 0."""
        self._start_s = time_s

    def finish(self, end_s: float | None) -> None:
        """Mux the audio up to ``end_s`` (None: all that is left) and flush the encoder."""
        if end_s is None:
            self.mux_until(None)
            return
        self.mux_until(end_s)
        if not self._done and not self.copied:
            self._transcode(None)  # flush the decoder, then the encoder
            self._mux_encoded(None)
        self._done = True

    def mux_until(self, time_s: float | None) -> None:
        """Mux audio up to time_s seconds (everything left when None)."""
        while not self._done:
            packet = self._pending or self._next_packet()
            self._pending = None
            if packet is None:
                self._done = True
                if not self.copied:
                    self._mux_encoded(None)
                return
            if packet.dts is None and packet.pts is None:
                if not self.copied:  # the final empty packet flushes the decoder
                    self._transcode(packet)
                continue
            stamp = packet.pts if packet.pts is not None else packet.dts
            if time_s is not None and stamp * packet.time_base > time_s:
                self._pending = packet
                return
            if self.copied:
                if self._start_s is not None:
                    if stamp * packet.time_base < self._start_s:
                        continue
                    shift = round(self._start_s / packet.time_base)
                    packet.pts = None if packet.pts is None else packet.pts - shift
                    packet.dts = None if packet.dts is None else packet.dts - shift
                packet.stream = self._out
                self._output.mux(packet)
            else:
                self._transcode(packet)

    def _transcode(self, packet: av.Packet) -> None:
        try:
            frames = self._in.decode(packet)
        except _AV_ERRORS as error:
            self._warnings.append(f"{self._source_path.name}: skipped undecodable audio: {_reason(error)}")
            return
        for frame in frames:
            # Stamp by sample count: a millisecond time base (MKV) would jitter AAC's timestamps.
            if self._next_sample is None:
                start = frame.pts * frame.time_base if frame.pts is not None else 0
                if self._start_s is not None:
                    if start + Fraction(frame.samples, frame.sample_rate) <= self._start_s:
                        continue  # wholly before the cut
                    start = max(start - Fraction(self._start_s), 0)
                self._next_sample = round(start * frame.sample_rate)
            frame.pts, frame.time_base = self._next_sample, Fraction(1, frame.sample_rate)
            self._next_sample += frame.samples
            self._mux_encoded(frame)

    def _mux_encoded(self, frame: av.AudioFrame | None) -> None:
        for packet in self._out.encode(frame):
            self._output.mux(packet)

    def close(self) -> None:
        self._container.close()


X264_PRESETS: tuple[str, ...] = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow",
                                 "slower", "veryslow")  # x265's presets have the same names
_ENCODERS = {"h264": "libx264", "hevc": "libx265", "mpeg4": "mpeg4"}  # --codec name -> FFmpeg encoder
VIDEO_CODECS: tuple[str, ...] = ("auto", *_ENCODERS)
# the Encoding fields each codec uses
CODEC_OPTIONS = {"auto": ("crf", "preset"), "h264": ("crf", "preset"), "hevc": ("crf", "preset"), "mpeg4": ("qscale",)}
_MAX_DEPTH = {"h264": 10, "hevc": 12, "mpeg4": 8}  # bits per sample each encoder can write (4:2:0)
_MPEG4_MAX_TIME_BASE_DENOMINATOR = 65535  # the MPEG-4 Part 2 standard's limit (FFmpeg refuses more)


# /proc/cpuinfo's flag -> x264's name for that instruction set (its `asm` option), in x264's order
_X264_INSTRUCTION_SETS = (("sse", "SSE"), ("sse2", "SSE2Fast"), ("pni", "SSE3"), ("ssse3", "SSSE3"),
                          ("sse4_1", "SSE4.1"), ("sse4_2", "SSE4.2"), ("abm", "LZCNT"), ("avx", "AVX"),
                          ("fma", "FMA3"), ("bmi1", "BMI1"), ("bmi2", "BMI2"), ("avx2", "AVX2"))


@functools.cache
def x264_cpu_params(cpuinfo: Path = Path("/proc/cpuinfo")) -> tuple[str, ...]:
    """x264-params entries that keep libx264 off its AVX-512 routines on a CPU that has them; none elsewhere.

    Why: the libx264 that PyAV bundles reads uninitialised memory in an AVX-512 routine of its macroblock-tree
    rate control at some frame sizes (320x180 is one), so the same frames encode to different bytes from one run,
    or one encode, to the next: ``MALLOC_PERTURB_`` changes the output, while ``mbtree=0`` or an instruction set
    without AVX-512 makes it repeatable. Where the bug does not strike, the list gives the same bytes as x264's
    own detection. The sets named are those /proc/cpuinfo lists, so none the CPU lacks is forced on (x264 would
    run it and die of an illegal instruction)."""
    try:
        text = cpuinfo.read_text(errors="replace")
    except OSError:
        return ()
    lines = text.splitlines()
    flags = next((line.split(":", 1)[1].split() for line in lines if line.startswith("flags")), [])
    if "avx512f" not in flags:
        return ()
    names = [name for flag, name in _X264_INSTRUCTION_SETS if flag in flags]
    if any(line.startswith("clflush size") and line.split(":", 1)[1].strip() == "64" for line in lines):
        names.append("Cache64")
    return (f"asm={','.join(names)}",)


def x264_options(*params: str) -> dict[str, str]:
    """PyAV stream options carrying ``params`` and ``x264_cpu_params()`` as libx264's x264-params (empty: none)."""
    joined = ":".join((*params, *x264_cpu_params()))
    return {"x264-params": joined} if joined else {}


@dataclass(frozen=True)
class Encoding:
    """How the output video is compressed.

    ``auto`` (default): ``h264`` for 8-bit input, ``hevc`` for deeper input (10/12-bit, HDR: docs/colour.md).
    ``h264``: x264 at constant quality ``crf`` (0-51, lower is better) with its speed/size ``preset``; High 10
    for deeper input. ``hevc``: x265 (Main, Main 10 or Main 12 by the input's depth), the same two settings.
    ``mpeg4``: FFmpeg's MPEG-4 Part 2 encoder, which OpenCV's XVID writer uses, at the fixed quantiser
    ``qscale`` (2-31, lower is better): far less CPU than x264 medium, paid for in bits at a like quality, which
    is why OpenCV's sample writes it (figures: docs/benchmarks-speed.md, "From the decision log").
    """

    codec: str = "auto"
    crf: int = 18
    preset: str = "medium"
    qscale: int = 3

    def __post_init__(self) -> None:
        if self.codec not in VIDEO_CODECS:
            raise ConfigError(f"codec must be one of {', '.join(VIDEO_CODECS)}, not {self.codec!r}")
        if not 0 <= self.crf <= 51:
            raise ConfigError(f"crf must be between 0 and 51 (x264's range), not {self.crf}")
        if self.preset not in X264_PRESETS:
            raise ConfigError(f"preset must be one of {', '.join(X264_PRESETS)}, not {self.preset!r}")
        if not 2 <= self.qscale <= 31:
            raise ConfigError(f"qscale must be between 2 and 31 (MPEG-4's quantisers), not {self.qscale}")

    def encoder(self, bit_depth: int) -> str:
        """The --codec name used for video of ``bit_depth`` bits ("auto" resolved)."""
        if self.codec == "auto":
            return "hevc" if bit_depth > 8 else "h264"
        return self.codec

    def stream_options(self, bit_depth: int = 8) -> dict[str, str]:
        if self.encoder(bit_depth) in ("h264", "hevc"):
            return {"crf": str(self.crf), "preset": self.preset}
        # A fixed quantiser: FFmpeg's -q:v sets it per frame, which PyAV cannot; clamping the rate control's
        # range to one value does the same.
        return {"qmin": str(self.qscale), "qmax": str(self.qscale)}


_MAX_REORDER_FRAMES = 16  # more than x264's or x265's B-frame delay at any preset this writer uses


class VideoWriter:
    """Writes RGB frames (4:2:0, H.264 or for deeper input HEVC by default: ``Encoding``) with the input's
    timestamps and colour description (``like.colour``: matrix, range, tags, depth), atomically.

    Output goes to a hidden temp file beside `path`; close() moves it onto `path`, abort() (and an
    exception inside the `with` block) deletes it, so a failed run leaves no file behind.
    Frames are written upright with no rotation tag, since VideoReader already applied rotation.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        like: VideoInfo,
        width: int | None = None,
        height: int | None = None,
        audio_from: Path | None = None,
        encoding: Encoding = Encoding(),
    ) -> None:
        self.path = Path(path)
        self.warnings: list[str] = []
        self.width = width or like.width
        self.height = height or like.height
        self._time_base = like.time_base
        # Default spacing when write() gets no timestamp: one frame at the input's rate.
        self._frame_ticks = max(1, round(1 / (like.fps * like.time_base)))
        self._last_pts: int | None = None
        self._last_dts: int | None = None
        # like.clip: the frames are part of a file; the output starts at the first one (its pts become 0).
        self._clipped = like.clip is not None
        self._pts_offset: int | None = None
        self._temp: Path | None = None
        self._container: av.container.OutputContainer | None = None
        self._audio: _AudioPassthrough | None = None

        fmt = _check_output_format(self.path)
        for source in (like.path, audio_from):
            if source is not None and _same_file(self.path, Path(source)):
                raise OutputError(f"output is the same file as the input: {self.path}")
        _check_output_folder(self.path)

        if self.width % 2 or self.height % 2:
            self.warnings.append(
                f"odd frame size {self.width}x{self.height}: padded to {self.width + self.width % 2}x"
                f"{self.height + self.height % 2} by repeating the edge (4:2:0 video needs even sizes)"
            )
        self._temp = _reserve_temp_path(self.path)
        try:
            options = {}
            if fmt in ("mp4", "mov"):
                # faststart: index at the front, so the file plays before it has fully loaded.
                # movie_timescale: the edit list delaying a stream that starts after 0 is counted in
                # it; the default 1/1000 s would shift every frame of e.g. a 30000/1001 time base.
                options = {"movflags": "+faststart"}
                if like.time_base.denominator < 2**31:
                    options["movie_timescale"] = str(like.time_base.denominator)
            self._container = av.open(str(self._temp), "w", format=fmt, options=options)
            self._video = self._add_video_stream(like.fps, encoding, like.colour, fmt)
            if audio_from is not None:
                self._audio = _AudioPassthrough(Path(audio_from), self._container, self.warnings)
        except InputError:
            self.abort()
            raise
        except _AV_ERRORS as error:
            self.abort()
            raise OutputError(f"cannot start writing {self.path}: {_reason(error)}") from None
        except BaseException:  # e.g. Ctrl-C while opening: no temp file may stay behind
            self.abort()
            raise

    def _add_video_stream(self, fps: Fraction, encoding: Encoding, colour: ColourDescription,
                          fmt: str) -> av.VideoStream:
        codec = encoding.encoder(colour.bit_depth)
        depth = min(max(colour.bit_depth, 8), _MAX_DEPTH[codec])
        if depth in (9, 11):
            depth += 1
        options = {**encoding.stream_options(colour.bit_depth), **colours.encoder_options(colour)}
        if codec == "hevc":
            options["x265-params"] = ":".join(["log-level=error", *colour.x265_hdr_params(), *colour.chroma_params()])
        elif codec == "h264":
            options.update(x264_options(*colour.chroma_params()))
        if depth < colour.bit_depth:
            self.warnings.append(f"{codec} cannot store {colour.bit_depth}-bit video: written at {depth} bits, with "
                                 f"the input's colour tags ({colour.summary()}); --codec hevc keeps up to 12")
        elif colour.mastering is not None and codec != "hevc":
            self.warnings.append(f"{codec} output does not carry the input's HDR mastering display metadata "
                                 f"(colour tags kept); --codec hevc does")
        if colour.dynamic_metadata is not None:
            self.warnings.append(f"the input's {colour.dynamic_metadata} dynamic metadata is not carried over: the "
                                 f"output is plain {'HLG' if colour.transfer == colours.HLG else 'HDR10'}, tags kept")
        if colour.chroma in ("4:2:2", "4:4:4"):
            self.warnings.append(f"{colour.chroma} input written as 4:2:0 (colour tags and depth kept)")
        self._colour, self._pix_fmt = colour, "yuv420p" if depth == 8 else f"yuv420p{depth}le"
        stream = self._container.add_stream(_ENCODERS[codec], rate=fps, options=options)
        # PyAV asks for slice threads by default, so x264 would cut each frame into a slice per thread; AUTO lets it
        # use frame threads as the ffmpeg command line does (one slice a frame, the same CPU: docs/decisions.md D18)
        stream.codec_context.thread_type = "AUTO"
        # yuv420p halves chroma, so H.264 needs even sizes (its crop step is 2 pixels too). An odd
        # side is padded by one replicated edge pixel: the output is at most 1 px wider/taller,
        # which beats yuv444p (High 4:4:4 profile, which many players refuse).
        stream.width = self.width + self.width % 2
        stream.height = self.height + self.height % 2
        stream.pix_fmt = self._pix_fmt
        if codec == "hevc" and fmt in ("mp4", "mov"):
            stream.codec_context.codec_tag = "hvc1"  # what Apple's players require of HEVC in MP4/MOV
        # Input time base in, so input pts go through unchanged (the MP4 muxer may refine the
        # track's time base after the header; PyAV rescales packets to it exactly).
        stream.time_base = self._time_base
        codec_time_base = self._time_base
        if encoding.codec == "mpeg4" and codec_time_base.denominator > _MPEG4_MAX_TIME_BASE_DENOMINATOR:
            # e.g. MPEG-TS's 1/90000: frames keep their times to 1/60000 s (PyAV rescales their pts).
            codec_time_base = Fraction(1, 60000)
        stream.codec_context.time_base = codec_time_base
        # The input's matrix, range, primaries and transfer: write() converts by the same matrix and range.
        colours.tag_stream(stream.codec_context, colour)
        return stream

    def write(self, rgb: np.ndarray, *, pts: int | None = None, time_s: float | None = None) -> None:
        """Encode one frame. pts is in the input's time_base (keeps VFR timing and A/V sync exactly);
        else time_s seconds; else one frame after the previous one."""
        if self._container is None:
            raise RuntimeError(f"VideoWriter for {self.path} is already closed")
        if rgb.dtype not in (np.uint8, np.float32) or rgb.shape != (self.height, self.width, 3):
            expected = (self.height, self.width, 3)
            raise ValueError(f"expected a uint8 or float32 frame of shape {expected}, got {rgb.dtype} {rgb.shape}")
        if pts is None and time_s is not None:
            pts = round(time_s / self._time_base)
        if pts is not None and self._clipped:
            if self._pts_offset is None:
                self._pts_offset = pts
                if self._audio is not None:
                    self._audio.start_at(float(pts * self._time_base))
            pts -= self._pts_offset
        if pts is None:
            pts = 0 if self._last_pts is None else self._last_pts + self._frame_ticks
        if self._last_pts is not None and pts <= self._last_pts:
            # x264 and the muxer need strictly increasing timestamps; nudge rather than fail.
            self.warnings.append(f"pts {pts} is not after {self._last_pts}; wrote it at {self._last_pts + 1}")
            pts = self._last_pts + 1
        self._last_pts = pts
        if self.width % 2 or self.height % 2:
            rgb = np.pad(rgb, ((0, self.height % 2), (0, self.width % 2), (0, 0)), mode="edge")
        frame = colours.from_rgb(rgb, self._colour, self._pix_fmt)
        frame.pts = pts
        frame.time_base = self._time_base
        try:
            for packet in self._video.encode(frame):
                self._mux_video(packet)
            if self._audio is not None:
                self._audio.mux_until(float((pts + (self._pts_offset or 0)) * self._time_base))
        except _AV_ERRORS as error:
            self.abort()
            raise OutputError(f"cannot write {self.path}: {_reason(error)}") from None

    def _mux_video(self, packet: av.Packet) -> None:
        """Mux one encoded packet, its decoding time made sane first.

        libx265 leaves a packet's dts uninitialised when the whole video is one or two pictures (seen here as 0,
        -2 or a huge negative number from run to run), and the MP4 muxer then refuses the file. A dts is taken as
        given when it is at or before the pts, after the previous packet's, and within ``_MAX_REORDER_FRAMES``
        pictures of the pts (no encoder setting here reorders further); otherwise it becomes the earliest value
        that keeps decoding order, which for these short videos is their own pts.
        """
        dts, pts = packet.dts, packet.pts
        if pts is not None and (
                dts is None or dts > pts or dts < pts - _MAX_REORDER_FRAMES * self._frame_ticks
                or (self._last_dts is not None and dts <= self._last_dts)):
            packet.dts = pts if self._last_dts is None else min(pts, self._last_dts + 1)
        self._last_dts = packet.dts
        self._container.mux(packet)

    def close(self) -> None:
        """Flush the encoder, mux the rest of the audio, and move the file into place."""
        if self._container is None:
            return
        try:
            for packet in self._video.encode(None):
                self._mux_video(packet)
            if self._audio is not None:
                end_s = None
                if self._clipped and self._last_pts is not None:  # the audio ends with the last frame's time
                    end_s = float((self._last_pts + (self._pts_offset or 0) + self._frame_ticks) * self._time_base)
                self._audio.finish(end_s)
                self._audio.close()
                self._audio = None
            self._container.close()
            self._container = None
            os.replace(self._temp, self.path)
            self._temp = None
        except _AV_ERRORS as error:
            self.abort()
            raise OutputError(f"cannot finish writing {self.path}: {_reason(error)}") from None
        except BaseException:  # e.g. Ctrl-C during the flush: still leave no temp file
            self.abort()
            raise

    def abort(self) -> None:
        """Stop and delete the temp file; the target path is left as it was."""
        for closeable in (self._audio, self._container):
            if closeable is not None:
                try:
                    closeable.close()
                except _AV_ERRORS:
                    pass  # already failing; the temp file is deleted below anyway
        self._audio = None
        self._container = None
        if self._temp is not None:
            self._temp.unlink(missing_ok=True)
            self._temp = None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
