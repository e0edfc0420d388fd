"""How a recording stores pictures: frame streams as H.264 samples, class maps as paletted PNG, float maps' values
as 16-bit PNG, sparse pictures as JPEG. Pure encoding; the recorder decides what goes where.

Masks and maps are single-channel PNGs written here (``grey_png``): rows unfiltered, deflated with zlib's run-length
strategy by zlib-ng, which does it in a third of zlib's time for the same bytes. Their pictures are runs of a few
values (most pixels have none): a filter buys ~10 % of the bytes for twice the time (docs/benchmarks-recording.md).
"""

from __future__ import annotations

import functools
import struct
import zlib
from fractions import Fraction
from typing import Sequence

import av
import cv2
import numpy as np
import rerun as rr
from zlib_ng import zlib_ng

from ffviz.recording.columns import ColumnBuffer, Row
from pipeline.results import Stamp

# H.264 frame streams (rr.VideoStream): no B-frames (rerun takes each sample's time as its PTS), zerolatency so that
# each frame's packet comes out with it (live view, no reordering, nothing held in the encoder), a keyframe a second
# for seeking. ultrafast: about half superfast's CPU for a fraction of a dB (docs/benchmarks-recording.md).
H264_OPTIONS = {"preset": "ultrafast", "tune": "zerolatency", "crf": "20", "bf": "0", "threads": "1"}
KEYFRAME_INTERVAL = 30
FRAME_SIZE_FIELD = "frame_size"  # (width, height) of a frame stream whose size is odd (ffviz.rrd crops to it)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_GREY, PNG_PALETTED = 0, 3  # IHDR colour types


class VideoTrack:
    """One frame stream as H.264 samples on a ``rr.VideoStream`` entity, encoded as frames arrive (PyAV)."""

    def __init__(self, rec: rr.RecordingStream, entity: str, fps: float, columns: ColumnBuffer) -> None:
        self.rec, self.entity, self.fps = rec, entity, fps
        self.columns = columns  # where the samples are held with the recording's other rows
        self._codec: av.CodecContext | None = None
        self._times: dict[int, float] = {}
        self.frames = 0
        self.bytes = 0

    def _open(self, width: int, height: int) -> None:
        codec = av.CodecContext.create("libx264", "w")
        codec.width, codec.height, codec.pix_fmt = width + width % 2, height + height % 2, "yuv420p"
        rate = Fraction(self.fps).limit_denominator(1001) if self.fps and self.fps > 0 else Fraction(30)
        codec.framerate, codec.time_base = rate, 1 / rate
        codec.options = dict(H264_OPTIONS, g=str(KEYFRAME_INTERVAL))
        self._codec = codec
        self.rec.log(self.entity, rr.VideoStream(codec=rr.VideoCodec.H264), static=True)
        if width % 2 or height % 2:  # the frames' true size, for reading back (4:2:0 pads odd sizes by a row/column)
            self.rec.log(self.entity, rr.AnyValues(**{FRAME_SIZE_FIELD: np.array([width, height], np.int32)}),
                         static=True)

    def add(self, stamp: Stamp, rgb: np.ndarray) -> None:
        height, width = rgb.shape[:2]
        if self._codec is None:
            self._open(width, height)
        if width % 2 or height % 2:  # 4:2:0 needs even sizes: repeat the last row / column
            rgb = np.pad(rgb, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge")
        # OpenCV's BT.601 conversion: 4x cheaper than swscale's here, the same colours back (mean error 1.1 levels).
        frame = av.VideoFrame.from_ndarray(cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2YUV_I420),
                                           format="yuv420p")
        frame.pts = stamp.index
        self._times[stamp.index] = stamp.time_s
        self._send(self._codec.encode(frame))

    def _send(self, packets: Sequence[av.Packet]) -> None:
        """Each packet's sample into the column buffer at its own frame's time (with zerolatency, the frame being
        recorded; a late one keeps its own time, not the recording's current one)."""
        for packet in packets:
            index = int(packet.pts)
            sample = np.frombuffer(bytes(packet), np.uint8)
            self.bytes += sample.size
            self.frames += 1
            row = Row(rr.VideoStream, {"sample": sample, "is_keyframe": bool(packet.is_keyframe)})
            self.columns.add(self.entity, row, index, self._times.pop(index, 0.0))

    def close(self) -> None:
        if self._codec is not None:
            self._send(self._codec.encode(None))
            self._codec = None


def png(rgb: np.ndarray) -> bytes:
    """An RGB(A) picture as PNG."""
    conversion = cv2.COLOR_RGBA2BGRA if rgb.shape[-1] == 4 else cv2.COLOR_RGB2BGR
    ok, data = cv2.imencode(".png", cv2.cvtColor(rgb, conversion))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


def jpeg(rgb: np.ndarray, quality: int) -> bytes:
    """An RGB picture as JPEG (OpenCV's encoder: 2-3x Pillow's speed, the same quality scale)."""
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return data.tobytes()


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def grey_png(pixels: np.ndarray, colour_type: int = PNG_GREY, chunks: bytes = b"") -> bytes:
    """A single-channel PNG of ``pixels`` (uint8 or uint16), with ``chunks`` (e.g. PLTE) before its data."""
    height, width = pixels.shape
    size = pixels.dtype.itemsize
    rows = np.zeros((height, 1 + width * size), np.uint8)  # each row: filter type 0 (none), then its samples
    rows[:, 1:] = np.ascontiguousarray(pixels, pixels.dtype.newbyteorder(">")).view(np.uint8).reshape(height, -1)
    deflate = zlib_ng.compressobj(6, zlib_ng.DEFLATED, 15, 9, zlib_ng.Z_RLE)
    data = deflate.compress(rows) + deflate.flush()
    header = struct.pack(">IIBBBBB", width, height, 8 * size, colour_type, 0, 0, 0)
    return (PNG_SIGNATURE + _png_chunk(b"IHDR", header) + chunks + _png_chunk(b"IDAT", data)
            + _png_chunk(b"IEND", b""))


def indexed_png(indices: np.ndarray, palette: np.ndarray) -> bytes:
    """An 8-bit paletted PNG: ``indices`` (uint8) into ``palette`` ((256, 4) RGBA; alpha in a tRNS chunk). The
    viewer honours the alphas when the image's opacity is below 1 (SEE_THROUGH); ffviz.rrd reads the indices back."""
    indices = np.asarray(indices, np.uint8)
    used = int(np.max(indices, initial=0)) + 1  # PLTE and tRNS need no entries past the highest index
    return grey_png(indices, PNG_PALETTED, _png_chunk(b"PLTE", palette[:used, :3].tobytes())
                    + _png_chunk(b"tRNS", palette[:used, 3].tobytes()))


@functools.lru_cache(maxsize=32)
def legend_palette(legend: tuple) -> np.ndarray:
    """(256, 4) RGBA palette of a legend's (class, name, colour) rows; classes it does not name are transparent."""
    palette = np.zeros((256, 4), np.uint8)
    for code, _, colour in legend:
        palette[code, :len(colour)] = colour
        if len(colour) == 3:
            palette[code, 3] = 255
    return palette


def palette_png(classes: np.ndarray, legend: Sequence[tuple]) -> bytes:
    """A class map as a paletted PNG whose indices are the classes, coloured (with alpha) by the legend, which
    is also logged as the entity's AnnotationContext (names of the classes). Lossless by construction."""
    return indexed_png(classes, legend_palette(tuple(legend)))


def png16(stored: np.ndarray) -> bytes:
    """A grey PNG of ``stored`` (8 or 16 bits)."""
    return grey_png(stored)
