"""What the video reader and writer share: the input's description (``VideoInfo``) and how PyAV's failures are
caught and told (``AV_ERRORS``, ``reason``)."""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import av.error

from pipeline.runtime.colour import ColourDescription

AV_ERRORS = (av.error.FFmpegError, OSError)


@dataclass(frozen=True)
class VideoInfo:
    """What probe_video learns from the container header and the first decoded frame."""

    path: Path
    width: int  # display width, after rotation
    height: int  # display height, after rotation
    fps: Fraction  # average frame rate, see video_reader._frame_rate
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



def reason(error: BaseException) -> str:
    """FFmpeg's reason without the errno and path PyAV adds, on one line."""
    text = getattr(error, "strerror", None) or str(error) or type(error).__name__
    return " ".join(str(text).split())

