"""Writing video on PyAV: RGB frames to H.264 (or HEVC, MPEG-4) with the input's timestamps, colour and audio.

The writer stores frames with no rotation tag (the reader made them upright) and writes atomically: a hidden
temp file moved onto the output at the end. Every expected failure is raised as OutputError (InputError for the
audio source) with a one-line message that names the file.
"""

from __future__ import annotations

import os
import secrets
from fractions import Fraction
from pathlib import Path
from types import TracebackType

import av
import numpy as np

from pipeline.errors import InputError, OutputError
from pipeline.runtime import colour as colours
from pipeline.runtime.audio import AudioPassthrough
from pipeline.runtime.colour import ColourDescription
from pipeline.runtime.encoding import ENCODERS, MAX_DEPTH, MPEG4_MAX_TIME_BASE_DENOMINATOR, Encoding, x264_options
from pipeline.runtime.video_info import AV_ERRORS, VideoInfo, reason

# Output suffix -> FFmpeg muxer name. H.264 + AAC plays from all three.
OUTPUT_FORMATS = {".mp4": "mp4", ".mov": "mov", ".mkv": "matroska"}


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
            raise OutputError(f"cannot create a file in {target.parent}: {reason(error)}") from None



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
        self._audio: AudioPassthrough | None = None

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
                self._audio = AudioPassthrough(Path(audio_from), self._container, self.warnings)
        except InputError:
            self.abort()
            raise
        except AV_ERRORS as error:
            self.abort()
            raise OutputError(f"cannot start writing {self.path}: {reason(error)}") from None
        except BaseException:  # e.g. Ctrl-C while opening: no temp file may stay behind
            self.abort()
            raise

    def _add_video_stream(self, fps: Fraction, encoding: Encoding, colour: ColourDescription,
                          fmt: str) -> av.VideoStream:
        codec = encoding.encoder(colour.bit_depth)
        depth = min(max(colour.bit_depth, 8), MAX_DEPTH[codec])
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
        stream = self._container.add_stream(ENCODERS[codec], rate=fps, options=options)
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
        if encoding.codec == "mpeg4" and codec_time_base.denominator > MPEG4_MAX_TIME_BASE_DENOMINATOR:
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
        except AV_ERRORS as error:
            self.abort()
            raise OutputError(f"cannot write {self.path}: {reason(error)}") from None

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
        except AV_ERRORS as error:
            self.abort()
            raise OutputError(f"cannot finish writing {self.path}: {reason(error)}") from None
        except BaseException:  # e.g. Ctrl-C during the flush: still leave no temp file
            self.abort()
            raise

    def abort(self) -> None:
        """Stop and delete the temp file; the target path is left as it was."""
        for closeable in (self._audio, self._container):
            if closeable is not None:
                try:
                    closeable.close()
                except AV_ERRORS:
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
