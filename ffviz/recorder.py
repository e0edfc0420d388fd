"""The Rerun observer: maps each stage's result to the entity layout in ``ffviz.entities``.

It writes to its own RecordingStream (no global state), saved straight to a .rrd with the default
blueprint embedded. The file is written beside the target and renamed on success, like videos.

Traced frames (``trace_frames``; by default a few with missing area, chosen once the path is smoothed)
are also logged stage by stage on the ``stage`` timeline and their Fast Marching fill step by step on
``fmm_step`` (see ffviz.trace). The blueprint, which has a view per traced frame, is sent once they are known.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import queue
import struct
import tempfile
import threading
import time
import uuid
import zlib
from fractions import Fraction
from pathlib import Path
from typing import Any, Literal, Sequence

import av
import cv2
import numpy as np
import rerun as rr

import ffviz
from ffviz import entities as ent, trace, visual
from ffviz.blueprint import default_blueprint
from pipeline import geometry
from pipeline.stages.completion import (SOURCE_AS_IS, SOURCE_CARRIED_ON, SOURCE_FALLBACK, SOURCE_LOCAL_WARP,
                                        SOURCE_MAJORITY, SOURCE_MOSAIC,
                                        SOURCE_NAMES, CompletionResult, from_a_neighbour)
from pipeline.stages.motion import MotionEstimate
from pipeline.stages.rolling_shutter import Correction
from pipeline.results import FrameResult, PathComparison, PathPlan, Stamp
from pipeline.runtime.colour import ColourDescription, display_rgb
from pipeline.frames import Frame
from pipeline.stages.deblur import DeblurResult
from pipeline.stages.adaptive_crop import AdaptiveCrop
from pipeline.stages.smoothing import SmoothingResult
from pipeline.stages.warping import CropWindow, WarpResult

RecordLevel = Literal["summary", "full"]
RECORD_LEVELS: tuple[str, ...] = ("summary", "full")
MISSING_CLASS = 1
MAX_FEATURE_ARROWS = 300  # enough to read the motion, few enough to keep files small
FILLED_BY_BASE = 100  # filled_by class of a local-warp pixel: FILLED_BY_BASE + neighbour offset
# H.264 frame streams (rr.VideoStream): no B-frames (rerun takes each sample's time as its PTS), zerolatency so
# that each frame's packet comes out with it (live view, no reordering), a keyframe a second for seeking.
# superfast: 0.57x veryfast's CPU time on vplab_C's four streams for 1.2x the bytes (~0.006 MB a frame more).
H264_OPTIONS = {"preset": "superfast", "tune": "zerolatency", "crf": "20", "bf": "0", "threads": "1"}
KEYFRAME_INTERVAL = 30
FRAME_SIZE_FIELD = "frame_size"  # (width, height) of a frame stream whose size is odd (ffviz.rrd crops to it)
# deblur/source's class 1, in its legend and its colour key alike
DEBLUR_REFUSED_NAME = "own: every sharper one refused (other content)"
WEIGHTS_STEP = 8  # deblur/weights in the compact recording: multiples of 8/255 (--lossless: of 1/255)
QUEUE_EVENTS = 48  # stage results waiting for the recorder's thread (~6 frames' worth): bounds the memory held
_STOP = object()
# Masks and maps as PNG: every row Paeth-filtered and zlib's run-length strategy, half the time of OpenCV's default
# (each row's filter chosen by trying all five, zlib's default strategy) for 1-7 % more bytes on vplab_C's maps
# and masks (docs/recording.md).
PNG_OPTIONS = [cv2.IMWRITE_PNG_COMPRESSION, 6, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
               cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_PAETH]
# Chunks of up to 4 MB / 4096 rows. A file-only recording flushes on those alone (a tick would make the file's size
# depend on the machine's speed: every flush writes each entity's schema again; vplab_C's full recording
# carried 1.0 MB beyond its data in a 214 s run and 5.9 MB in a 1189 s one);
# a live view also flushes every 2 s so that the viewer follows the run.
BATCHER = rr.ChunkBatcherConfig(flush_tick=3600.0, flush_num_bytes=4 << 20, flush_num_rows=4096)
LIVE_BATCHER = rr.ChunkBatcherConfig(flush_tick=2.0, flush_num_bytes=4 << 20, flush_num_rows=4096)
MISSING_LEGEND = [(0, "valid", (0, 0, 0, 0)), (MISSING_CLASS, "missing", (255, 0, 64, 160))]
ACCEPTED_LEGEND = [(0, "known", (0, 0, 0, 0)), (1, "missing, rejected by the mosaic", (255, 0, 64, 160)),
                   (2, "missing, accepted by the mosaic", (40, 200, 90, 160))]
FALLBACK_LEGEND = [(0, "other", (0, 0, 0, 0)), (1, "fallback", (255, 200, 0, 200))]
# completion/source: how each pixel was filled (the classes are CompletionResult.source's codes)
SOURCE_LEGEND = [(0, "original", (0, 0, 0, 0)), (SOURCE_MOSAIC, "mosaic", (40, 200, 90, 170)),
                 (SOURCE_LOCAL_WARP, "local warp (flow)", (80, 150, 255, 190)),
                 (SOURCE_FALLBACK, "fallback", (255, 200, 0, 200)),
                 (SOURCE_CARRIED_ON, "carried on (moving content)", (230, 60, 200, 200)),
                 (SOURCE_AS_IS, "neighbour as is (no local motion)", (150, 110, 60, 190)),
                 (SOURCE_MAJORITY, "neighbours' majority (median, no local motion)", (0, 200, 200, 190))]
CROP_COLOUR = (255, 220, 0)
FOREGROUND_COLOUR = (255, 150, 0)  # tracks of the motion not taken for the camera's
IGNORED_COLOUR = (200, 120, 255)  # outline of --ignore / --ignore-mask
ROLLING_SHUTTER_COLOUR = (0, 220, 255)
ROLLING_SHUTTER_GAIN = 5.0  # the bands' arrows are drawn this many times their length (shifts are a few px)
ROLLING_SHUTTER_BANDS = 8
# An RGBA image's alpha is used by the viewer (rerun 0.41) only when the image's opacity is below 1: at the default
# 1 it is drawn opaque, its transparent pixels black (checked headless). 0.99 changes the colours by 1 %.
SEE_THROUGH = 0.99
MASK_DRAW_ORDER = 10.0  # masks above the frame streams they are drawn over
LABEL_COLOUR = (255, 255, 255, 255)  # stage labels: opaque white reads as dark text on a light tag (checked headless)
VARIANCE_RANGE = visual.VARIANCE_RANGE
ARRIVAL_RANGE = visual.ARRIVAL_RANGE



class NotRecorded(str):
    """A result field the recording leaves out, and why."""


class Nested(str):
    """A field whose value is another result type: recorded as that type's own row of RECORDED_FIELDS says."""


_MOTION_SERIES = tuple(f"{ent.MOTION_PARAMS}/{name}" for name in ent.MOTION_PARAM_NAMES)
_TRAJECTORY = {root: tuple(f"{root}/{axis}" for axis in ent.TRAJECTORY_AXES)
               for root in (ent.TRAJECTORY_ORIGINAL, ent.TRAJECTORY_SMOOTHED, ent.TRAJECTORY_GAUSSIAN, ent.TRAJECTORY_L1)}
_COMPLETION_STATS = tuple(f"{ent.COMPLETION_STATS}/{name.replace(' ', '_')}" for name in ("missing", *SOURCE_NAMES[1:]))

# The one table from result field to recording: every field of every result type the recorder receives, with the
# entity paths it is recorded under, Nested (another type's row), or NotRecorded and why. Keyed by type name, the
# rows are checked against the dataclasses themselves (tests/test_recording.py): a new field fails that test until
# it is mapped here, and every entity named here must be in a full recording.
RECORDED_FIELDS: dict[str, dict[str, tuple[str, ...] | Nested | NotRecorded]] = {
    "MotionEstimate": {  # on_motion, every frame of pass 1
        "curr_from_prev": _MOTION_SERIES,
        "status": (ent.MOTION_STATUS,),
        "n_tracked": (ent.MOTION_INLIER_RATIO,),  # inliers / tracked
        "n_inliers": (ent.MOTION_INLIERS, ent.MOTION_INLIER_RATIO),
        "residual_px": (ent.MOTION_RESIDUAL,),
        "hist_distance": NotRecorded("cut detection's input; its decision is the status"),
        "warning": (ent.LOG,),
        "prev_points": (f"{ent.MOTION_FEATURES}/arrows",),
        "curr_points": (f"{ent.MOTION_FEATURES}/points", f"{ent.MOTION_FEATURES}/arrows"),
        "inliers": (f"{ent.MOTION_FEATURES}/points",),  # as the points' colours
        "alternative": NotRecorded("the second motion among the outliers; its effect is curr_from_prev"),
        "alternative_prev_points": NotRecorded("where the other motion's tracks start; their ends are drawn"),
        "alternative_curr_points": (ent.MOTION_FOREGROUND,),
        "chose_alternative": (ent.LOG,),
        "ignored": (ent.MOTION_IGNORED,),
    },
    "PathPlan": {  # on_path, once
        "motion": Nested("MotionPass"),
        "smoothing": Nested("SmoothingResult"),
        "orig_from_out": NotRecorded("equal to the smoothed path but for the crop, both recorded"),
        "rolling_shutter": Nested("Correction"),
        "crop": Nested("CropWindow"),
        "adaptive_crop": Nested("AdaptiveCrop"),
        "warnings": (ent.LOG,),
        "paths": Nested("PathComparison"),
    },
    "PathComparison": {
        "gaussian": _TRAJECTORY[ent.TRAJECTORY_GAUSSIAN],
        "l1": _TRAJECTORY[ent.TRAJECTORY_L1],
        "crop_corners": (ent.CROP_CONSTRAINT,),
        "crop_room_px": (ent.CROP_ROOM,),
    },
    "MotionPass": {
        "curr_from_prev": NotRecorded("recorded frame by frame from on_motion"),
        "tracks": NotRecorded("the inlier tracks, recorded frame by frame from on_motion"),
        "statuses": NotRecorded("recorded frame by frame from on_motion"),
        "times_s": (ent.VIDEO_TIME_TIMELINE,),
        "warnings": (ent.LOG,),
    },
    "SmoothingResult": {
        "orig_from_stab": NotRecorded("chooses the traced frames; shown as the smoothed trajectory"),
        "segment_starts": NotRecorded("scene cuts; the trajectories restart there"),
        "original_trajectory": _TRAJECTORY[ent.TRAJECTORY_ORIGINAL],
        "smoothed_trajectory": _TRAJECTORY[ent.TRAJECTORY_SMOOTHED],
        "settings": (ent.PATH_SETTINGS,),
        "setting_of": (ent.PATH_SETTING,),
        "planner": NotRecorded("the settings' labels name it (auto's choice included)"),
    },
    "AdaptiveCrop": {
        "scales": (ent.CROP_SCALE, ent.CROP_WINDOW),
        "anchor": (ent.CROP_WINDOW,),
        "width": NotRecorded("the frame's size"),
        "height": NotRecorded("the frame's size"),
    },
    "CropWindow": {"x0": (ent.CROP_WINDOW,), "y0": (ent.CROP_WINDOW,),
                   "scale": (ent.CROP_WINDOW, ent.CROP_SCALE, ent.META)},
    "Correction": {  # --rolling-shutter
        "readout": (ent.LOG,),
        "rows": Nested("RowMotion"),
        "curr_from_prev": NotRecorded("the motions between corrected views; the trajectories are their sums"),
    },
    "RowMotion": {
        "readout": (ent.ROLLING_SHUTTER_BANDS, ent.ROLLING_SHUTTER_SKEW + "/dx", ent.ROLLING_SHUTTER_SKEW + "/dy"),
        "height": NotRecorded("the frame's size"),
        "velocity": (ent.ROLLING_SHUTTER_BANDS, ent.ROLLING_SHUTTER_SKEW + "/dx", ent.ROLLING_SHUTTER_SKEW + "/dy"),
        "acceleration": (ent.ROLLING_SHUTTER_BANDS, ent.ROLLING_SHUTTER_SKEW + "/dx",
                         ent.ROLLING_SHUTTER_SKEW + "/dy"),
    },
    "FrameResult": {  # on_frame, every frame of pass 2
        "stamp": Nested("Stamp"),
        "pts": NotRecorded("the container's timestamp; the recording is timed by frame and video_time"),
        "output": (ent.OUTPUT_FRAME,),
        "input": Nested("Frame"),
        "warp": Nested("WarpResult"),
        "completion": Nested("CompletionResult"),
        "deblur": Nested("DeblurResult"),
        "temporal": Nested("TemporalResult"),
        "completed": Nested("CompletedFrame"),
        "cpu_seconds": NotRecorded("per-stage CPU time, for ffviz bench --profile"),
    },
    "CompletedFrame": {  # held for temporal consistency only, dropped before the recorder sees it
        "frame": NotRecorded("completion's frame, recorded as CompletionResult.frame"),
        "synthesized": NotRecorded("completion's missing pixels, recorded as CompletionResult.missing"),
    },
    "TemporalResult": {
        "frame": NotRecorded("the output before deblurring's change to the synthesized pixels; the output is recorded"),
        "share": (ent.COMPLETION_TEMPORAL,),  # its mean over the synthesized pixels
        "neighbours": NotRecorded("always t-r..t+r of the same shot; the share says how much they gave"),
    },
    "Stamp": {"index": (ent.FRAME_TIMELINE,), "time_s": (ent.VIDEO_TIME_TIMELINE,)},
    "Frame": {
        "index": (ent.FRAME_TIMELINE,), "time_s": (ent.VIDEO_TIME_TIMELINE,),
        "pts": NotRecorded("the container's timestamp"),
        "rgb": (ent.INPUT_FRAME,),
    },
    "WarpResult": {
        "frame": (ent.STABILIZED_FRAME,),
        "missing": (ent.STABILIZED_MISSING,),
        "orig_from_out": NotRecorded("the smoothed path's matrix for this frame, recorded as the trajectory"),
    },
    "CompletionResult": {
        "frame": (ent.COMPLETION_FRAME,),
        "missing": (f"{ent.COMPLETION_STATS}/missing", ent.COMPLETION_ACCEPTED),
        "mosaic": Nested("MosaicResult"),
        "neighbour_order": NotRecorded("the order neighbours were tried in; filled_by shows which one served"),
        "fills": Nested("NeighbourFill"),
        "source": _COMPLETION_STATS + (ent.COMPLETION_SOURCE, ent.COMPLETION_FILLED_BY),
        "filled_by": (ent.COMPLETION_FILLED_BY,),
        "fallback": (ent.COMPLETION_FALLBACK,),
        "corrected": NotRecorded("mosaic pixels replaced by a local warp; shown within filled_by"),
        "registered": NotRecorded("neighbours whose warps local registration refined; their pixels are in filled_by"),
        "unregistered_mosaic": NotRecorded("made only on request: the evaluation's baseline without registration"),
    },
    "MosaicResult": {
        "frame": (ent.trace_image("*"),),  # traced frames' "mosaic" stage
        "variance": (ent.COMPLETION_VARIANCE, ent.map_values(ent.COMPLETION_VARIANCE)),
        "accepted": (ent.COMPLETION_ACCEPTED,),
        "remaining": NotRecorded("missing minus accepted, both recorded"),
        "coverage": NotRecorded("how many neighbours covered each pixel; the variance map shows where"),
    },
    "NeighbourFill": {  # the first neighbour's, as in the thesis's Fig. 18
        "offset": (ent.trace_fmm_label("*"),),
        "alignment_error": NotRecorded("orders the neighbours; not shown"),
        "pieces": Nested("FlowPiece"),
        "shape": NotRecorded("the frame's size"),
        "filled": (ent.COMPLETION_FILLED_BY,),
        "reached": NotRecorded("where this neighbour could fill; filled shows what it did"),
    },
    "FlowPiece": {
        "box": NotRecorded("where the piece lies; the flow image is assembled from the pieces"),
        "scale": NotRecorded("the flow's working resolution"),
        "flow": Nested("LocalFlowResult"),
        "inpainted": Nested("MotionInpaintResult"),
        "owned": NotRecorded("which part of the piece is its own"),
    },
    "LocalFlowResult": {
        "flow": NotRecorded("kept within the inpainted flow (measured where reliable, inpainted elsewhere)"),
        "common": NotRecorded("where both frames are known"),
        "reliable": NotRecorded("where the measured flow is kept; the rest is inpainted (fmm/order shows where)"),
    },
    "MotionInpaintResult": {
        "flow": (ent.COMPLETION_FLOW_IMAGE, ent.COMPLETION_FLOW_ARROWS),
        "order": (ent.COMPLETION_FMM_ORDER, ent.map_values(ent.COMPLETION_FMM_ORDER), ent.trace_fmm("*")),
        "arrival": (ent.COMPLETION_FMM_ARRIVAL, ent.map_values(ent.COMPLETION_FMM_ARRIVAL)),
        "filled": (ent.trace_fmm("*"),),
    },
    "DeblurResult": {
        "frame": (ent.DEBLUR_AFTER,),
        "before": (ent.DEBLUR_BEFORE,),
        "blurriness": (ent.DEBLUR_BLURRINESS,),
        "neighbours": (ent.DEBLUR_NEIGHBOURS,),
        "weights": (ent.DEBLUR_WEIGHTS, ent.map_values(ent.DEBLUR_WEIGHTS)),
        "ratios": NotRecorded("b_t / b_t' per neighbour compared; the blurriness series shows b_t"),
        "provenance": (ent.DEBLUR_SOURCE, ent.DEBLUR_REFUSED),
    },
}


def _offset_colour(offset: int, alpha: int = 190) -> tuple[int, int, int, int]:
    """Neighbour ``offset``'s colour: blues for earlier frames, oranges for later, darker further away."""
    base = np.array((40, 120, 255) if offset < 0 else (255, 110, 30), float)
    fade = min(abs(offset) - 1, 29) / 29  # distinct colours up to +-30 (the PNG's classes are read back by colour)
    light = base + (255 - base) * 0.45 * (1 - fade)
    return tuple(int(c) for c in light * (1 - 0.45 * fade)) + (alpha,)


def _png(rgb: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


class VideoTrack:
    """One frame stream as H.264 samples on a ``rr.VideoStream`` entity, encoded as frames arrive (PyAV)."""

    def __init__(self, rec: rr.RecordingStream, entity: str, fps: float) -> None:
        self.rec, self.entity, self.fps = rec, entity, fps
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
        self._send(self._codec.encode(frame), current=stamp.index)

    def _send(self, packets: Sequence[av.Packet], current: int | None = None) -> None:
        for packet in packets:
            index = int(packet.pts)
            data = bytes(packet)
            self.bytes += len(data)
            self.frames += 1
            sample = np.frombuffer(data, np.uint8)
            if index == current:  # the frame being recorded (always, with zerolatency): batched with its rows
                self._times.pop(index, None)
                self.rec.log(self.entity, rr.VideoStream.from_fields(sample=sample, is_keyframe=bool(packet.is_keyframe)))
                continue
            # A late packet: columns, so that the recording's current time (the frame being recorded) stays.
            self.rec.send_columns(self.entity, indexes=[
                rr.TimeColumn(ent.FRAME_TIMELINE, sequence=[index]),
                rr.TimeColumn(ent.VIDEO_TIME_TIMELINE, duration=[self._times.pop(index, 0.0)])],
                columns=rr.VideoStream.columns(sample=[np.frombuffer(data, np.uint8)],
                                               is_keyframe=[bool(packet.is_keyframe)]))

    def close(self) -> None:
        if self._codec is not None:
            self._send(self._codec.encode(None))
            self._codec = None


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def indexed_png(indices: np.ndarray, palette: np.ndarray) -> bytes:
    """An 8-bit paletted PNG: ``indices`` (uint8) into ``palette`` ((256, 4) RGBA; alpha in a tRNS chunk).

    OpenCV writes no paletted PNG, but the image data of an 8-bit grey PNG is laid out as a paletted one's:
    its grey encoding (a twentieth of an RGBA PNG's time here, fewer bytes) is relabelled (IHDR colour type 3)
    and given the palette. The viewer honours the alphas when the image's opacity is below 1 (SEE_THROUGH);
    ffviz.rrd reads the indices back."""
    ok, data = cv2.imencode(".png", np.ascontiguousarray(indices, np.uint8), PNG_OPTIONS)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    data = data.tobytes()
    header = bytearray(data[16:29])  # IHDR: width, height, bit depth 8, colour type 0 (grey), ...
    header[9] = 3  # paletted
    used = int(np.max(indices, initial=0)) + 1  # PLTE and tRNS need no entries past the highest index
    return (data[:8] + _png_chunk(b"IHDR", bytes(header)) + _png_chunk(b"PLTE", palette[:used, :3].tobytes())
            + _png_chunk(b"tRNS", palette[:used, 3].tobytes()) + data[33:])


@functools.lru_cache(maxsize=32)
def _legend_palette(legend: tuple) -> np.ndarray:
    palette = np.zeros((256, 4), np.uint8)
    for code, _, colour in legend:
        palette[code, :len(colour)] = colour
        if len(colour) == 3:
            palette[code, 3] = 255
    return palette


def palette_png(classes: np.ndarray, legend: Sequence[tuple]) -> bytes:
    """A class map as a paletted PNG whose indices are the classes, coloured (with alpha) by the legend, which
    is also logged as the entity's AnnotationContext (names of the classes). Lossless by construction."""
    return indexed_png(classes, _legend_palette(tuple(legend)))


def quantised_map(values: np.ndarray, step: float) -> np.ndarray:
    """uint16: round(value / step) + 1 where finite, 0 where not (see entities.MAP_STEPS)."""
    finite = np.isfinite(values)
    stored = np.zeros(values.shape, np.uint16)
    stored[finite] = np.clip(np.rint(values[finite] / step) + 1, 1, 65535).astype(np.uint16)
    return stored


def png16(stored: np.ndarray) -> bytes:
    """A grey PNG of ``stored`` (8 or 16 bits)."""
    ok, data = cv2.imencode(".png", stored, PNG_OPTIONS)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


class RerunRecorder:
    """Observer that records a run to ``path`` (.rrd).

    ``level``: "summary" records series and output frames; "full" adds every frame-sized intermediate.
    ``jpeg_quality``: None records images losslessly (raw frames, float maps); otherwise the frame streams
    (input, stabilized, completed, output) are H.264 video streams, float maps 16-bit PNGs, and the sparse
    images (deblurring, flow, traced frames) JPEGs at this quality. Masks are lossless either way.
    ``trace_frames``: frames to follow through every stage; None: ``trace.DEFAULT_TRACED`` frames with missing
    area at level "full", none at "summary".
    ``threaded``: encode and log on a thread of the recorder's own, in order, so that the pipeline's thread
    only hands results over (H.264 and PNG encoding release the GIL); an error there surfaces at the next
    call or at ``close()``.
    """

    def __init__(self, path: Path | str, *, level: RecordLevel = "full", jpeg_quality: int | None = 80,
                 trace_frames: Sequence[int] | None = None, application_id: str = "ffviz",
                 live_url: str | None = None, threaded: bool = True) -> None:
        if level not in RECORD_LEVELS:
            raise ValueError(f"record level must be one of {', '.join(RECORD_LEVELS)}, not {level!r}")
        self.path = Path(path)
        self.level = level
        self.jpeg_quality = jpeg_quality
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=".rrd.tmp", dir=self.path.parent)
        os.close(fd)
        self._tmp_path = Path(tmp)
        # Rows batched into chunks (BATCHER): a chunk per log call (the default for a slow producer) costs its
        # schema (a few kB) each time, more than a compressed mask or video sample.
        self.rec = rr.RecordingStream(application_id, recording_id=str(uuid.uuid4()),
                                      batcher_config=BATCHER if live_url is None else LIVE_BATCHER)
        self.live_url = live_url
        if live_url is None:
            self.rec.save(self._tmp_path)  # the default blueprint follows once the traced frames are known
        else:  # both sinks at once: a running viewer (live view) and the file
            rr.set_sinks(rr.GrpcSink(live_url), rr.FileSink(str(self._tmp_path)), recording=self.rec)
        self._times: dict[int, float] = {}
        self._size = (0, 0)
        self._closed = False
        self._foreground_shown = False
        self._ignored_drawn: bytes | None = None  # the ignore mask last outlined (redrawn only when it changes)
        self._trace_requested = None if trace_frames is None else tuple(sorted({int(t) for t in trace_frames}))
        self.traced: tuple[int, ...] = self._trace_requested or ()  # default ones chosen when the path is known
        self._blueprint_sent = False
        self._tracks: dict[str, VideoTrack] = {}
        self._fps = 30.0
        self._info: Any = None
        self._colour = ColourDescription()  # the input's (on_start): frames are shown as display RGB by it
        self._config: Any = None
        self._crop: Any = None
        # (planner, setting label) of the path the plan followed (crop mode's auto: the one it chose)
        self._planned: tuple[str, str] | None = None
        self._adaptive: AdaptiveCrop | None = None
        self._warnings = 0
        self._log_lines = 0  # lines logged to ent.LOG (warnings and notes): the about tab's table only when any
        self._started = time.perf_counter()
        self._cpu_started = time.process_time()
        self.seconds_logging = 0.0  # wall time the recorder spent encoding and logging (on its own thread)
        self._error: BaseException | None = None
        self._aborting = False
        self._queue: queue.Queue | None = None
        self._worker: threading.Thread | None = None
        if threaded:
            self._queue = queue.Queue(maxsize=QUEUE_EVENTS)
            self._worker = threading.Thread(target=self._drain, name="ffviz-recorder", daemon=True)
            self._worker.start()

    # -- the recorder's thread --------------------------------------------------------------------

    def _submit(self, call, *args) -> None:
        if self._error is not None:
            raise RuntimeError(f"recording to {self.path} failed: {self._error!r}") from self._error
        if self._queue is None:
            call(*args)
        else:
            self._queue.put((call, args))

    def _drain(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            if self._error is not None or self._aborting:
                continue
            call, args = item
            try:
                call(*args)
            except BaseException as error:  # noqa: BLE001 - handed to the pipeline's thread
                self._error = error

    def _stop_worker(self) -> None:
        if self._worker is not None:
            self._queue.put(_STOP)
            self._worker.join()
            self._worker = None

    @property
    def lossless(self) -> bool:
        return self.jpeg_quality is None

    # -- Observer ---------------------------------------------------------------------------------

    def on_start(self, info: Any, config: Any) -> None:
        self._submit(self._do_start, info, config)

    def _do_start(self, info: Any, config: Any) -> None:
        started = time.perf_counter()
        self._size = (info.width, info.height)
        self._info, self._config = info, config
        self._colour = getattr(info, "colour", None) or ColourDescription()
        try:
            self._fps = float(info.fps) or 30.0
        except (TypeError, ValueError, AttributeError):
            self._fps = 30.0
        self._log_meta()
        if self.live_url is not None:  # the layout from the first frame on; again once the traced frames are known
            self.rec.send_blueprint(default_blueprint(self._trace_requested or (), **self._layout_flags),
                                    make_active=True, make_default=True)
        # Class maps: the legend as an annotation context (hover names in --lossless SegmentationImages; the
        # colours of the paletted PNGs otherwise) and as a key picture beside the views.
        for entity, legend, title in ((ent.STABILIZED_MISSING, MISSING_LEGEND, "missing area"),
                                      (ent.COMPLETION_ACCEPTED, ACCEPTED_LEGEND, "mosaic (eqs. 20-21)"),
                                      (ent.COMPLETION_FALLBACK, FALLBACK_LEGEND, "fallback"),
                                      (ent.COMPLETION_SOURCE, SOURCE_LEGEND, "filled how"),
                                      (ent.COMPLETION_FILLED_BY, self._filled_by_legend(), "filled by"),
                                      (ent.DEBLUR_SOURCE, self._deblur_source_legend(), "deblurred pixel from")):
            self.rec.log(entity, rr.AnnotationContext(legend), static=True)
        self._log_keys()
        self._log_series_styles()
        self.seconds_logging += time.perf_counter() - started

    def _log_series_styles(self) -> None:
        """Every chart line: a name and a colour of its own (distinct hues, readable on the dark theme)."""
        styles = {f"{ent.MOTION_PARAMS}/dx": ("dx (px)", (230, 90, 60)), f"{ent.MOTION_PARAMS}/dy": ("dy (px)", (40, 150, 240)),
                  f"{ent.MOTION_PARAMS}/angle": ("angle (deg)", (240, 200, 40)),
                  f"{ent.MOTION_PARAMS}/scale": ("scale", (180, 100, 240)),
                  ent.MOTION_INLIERS: ("inliers", (60, 200, 120)), ent.MOTION_INLIER_RATIO: ("inlier ratio", (60, 200, 220)),
                  ent.MOTION_RESIDUAL: ("residual (px)", (240, 120, 180)),
                  f"{ent.COMPLETION_STATS}/missing": ("missing", (240, 60, 80)),
                  f"{ent.COMPLETION_STATS}/mosaic": ("mosaic", (60, 200, 90)),
                  f"{ent.COMPLETION_STATS}/local_warp": ("local warp (motion inpainting)", (80, 150, 255)),
                  f"{ent.COMPLETION_STATS}/fallback": ("fallback", (255, 200, 0)),
                  f"{ent.COMPLETION_STATS}/carried_on": ("carried on (moving content)", (230, 60, 200)),
                  f"{ent.COMPLETION_STATS}/neighbour_as_is": ("neighbour as is", (150, 110, 60)),
                  f"{ent.COMPLETION_STATS}/majority": ("neighbours' majority", (0, 200, 200)),
                  ent.COMPLETION_TEMPORAL: ("share averaged in",
                                            (235, 235, 235))}
        for entity, (name, colour) in styles.items():
            self.rec.log(entity, rr.SeriesLines(names=name, colors=[colour], widths=2.0), static=True)
        self.rec.log(ent.DEBLUR_REFUSED, rr.SeriesLines(names="a neighbour refused (share)", colors=[(230, 40, 60)]),
                     static=True)
        self.rec.log(ent.DEBLUR_BLURRINESS, rr.SeriesLines(names="blurriness b_t", colors=[(200, 80, 200)]), static=True)
        self.rec.log(ent.DEBLUR_NEIGHBOURS, rr.SeriesLines(names="sharper neighbours used", colors=[(90, 160, 90)]),
                     static=True)
        self.rec.log(ent.CROP_ROOM, rr.SeriesLines(names="crop window's room inside the input (px)",
                                                   colors=[CROP_COLOUR], widths=2.0), static=True)
        # Original in warm colours, smoothed in cool ones; eq. 18's and the L1 path on the same motion thin, in
        # colours of their own; x and y told apart within each (visual.TRAJECTORY_COLOURS).
        for root, kind, name, width in ((ent.TRAJECTORY_ORIGINAL, "original", "original", 2.0),
                                        (ent.TRAJECTORY_SMOOTHED, "smoothed", "smoothed", 2.0),
                                        (ent.TRAJECTORY_GAUSSIAN, "gaussian", "eq. 18 (gaussian)", 1.0),
                                        (ent.TRAJECTORY_L1, "l1", "L1", 1.0)):
            for axis in ent.TRAJECTORY_AXES:
                self.rec.log(f"{root}/{axis}", rr.SeriesLines(names=f"{axis} {name}", widths=width,
                                                              colors=[visual.TRAJECTORY_COLOURS[kind, axis]]),
                             static=True)

    def _log_keys(self) -> None:
        """Colour keys (static pictures) for every colour-mapped entity, and the tabs' notes."""
        from ffviz import blueprint

        for name, image in self.colour_keys().items():
            self.rec.log(ent.key_entity(name), rr.EncodedImage(contents=_png(image), media_type="image/png"),
                         static=True)
        for tab, text in blueprint.TAB_NOTES.items():
            self.rec.log(ent.note_entity(tab), rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)

    def colour_keys(self) -> dict[str, np.ndarray]:
        """Key pictures by name (entities.key_entity(name)); KEY_OF maps each colour-mapped entity to one."""
        return {
            "flow": visual.flow_wheel(),
            "variance": visual.colour_bar("turbo", 0, VARIANCE_RANGE[1], "intensity^2 (0-255 scale); threshold: "
                                          "green in the mosaic map", "mosaic variance (eq. 20)",
                                          no_value="not missing, or under 2 neighbours there"),
            "fmm_order": visual.colour_bar("viridis", 0, 1, "share of the neighbour's filled pixels visited before",
                                           "Fast Marching visiting order", fmt="{:.2f}",
                                           no_value="known, or not reached"),
            "fmm_arrival": visual.colour_bar("magma", 0, ARRIVAL_RANGE[1], "px from the nearest known pixel",
                                             "Fast Marching arrival time T", no_value="known (T = 0), or not reached"),
            "deblur_weights": visual.colour_bar("viridis", 0, 1, "share of the pixel from sharper neighbours",
                                                "deblurring weights (eqs. 30-31)", fmt="{:.2f}"),
            "missing": visual.palette_key([(n, c) for _, n, c in MISSING_LEGEND[1:]], "stabilized frame"),
            "accepted": visual.palette_key([(n, c) for _, n, c in ACCEPTED_LEGEND[1:]], "mosaic (eqs. 20-21)"),
            "source": visual.palette_key([(n, c) for _, n, c in SOURCE_LEGEND[1:]], "filled how"),
            "filled_by": visual.palette_key(
                [("mosaic", (40, 200, 90, 170)), ("fallback", (255, 200, 0, 200))]
                + [(f"neighbour {o:+d}", c) for o, c in ((-10, _offset_colour(-10)), (-1, _offset_colour(-1)),
                                                          (1, _offset_colour(1)), (10, _offset_colour(10)))],
                "filled by (neighbours: blue = earlier, orange = later)"),
            "deblur_source": visual.palette_key(
                [(DEBLUR_REFUSED_NAME, (230, 40, 60, 200))]
                + [(f"from neighbour {o:+d}", c) for o, c in ((-5, _offset_colour(-5)), (5, _offset_colour(5)))],
                "pixel from (blue: earlier, orange: later)"),
        }
    def on_motion(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        self._submit(self._timed, self._on_motion, stamp, estimate)

    def on_path(self, plan: PathPlan) -> None:
        self._submit(self._timed, self._on_path, plan)

    def on_frame(self, result: FrameResult) -> None:
        self._submit(self._timed, self._on_frame, result)

    def _log_line(self, line: rr.TextLog, static: bool = False) -> None:
        self._log_lines += 1
        self.rec.log(ent.LOG, line, static=static)

    def _timed(self, handler, *args) -> None:
        started = time.perf_counter()
        handler(*args)
        self.seconds_logging += time.perf_counter() - started

    def on_warning(self, stamp: Stamp | None, message: str) -> None:
        self._submit(self._do_warning, stamp, message)

    def _do_warning(self, stamp: Stamp | None, message: str) -> None:
        self._warnings += 1
        if stamp is not None:
            self._set_time(stamp)
        self._log_line(rr.TextLog(message, level=rr.TextLogLevel.WARN), static=stamp is None)

    def on_finish(self, report: Any) -> None:
        self._submit(self._log_meta, report)
        self.close()

    # -- stages -----------------------------------------------------------------------------------

    def _on_motion(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        self._times[stamp.index] = stamp.time_s
        self._set_time(stamp)
        width, height = self._size
        dx, dy, angle, scale = geometry.decompose(estimate.curr_from_prev, width, height)
        for name, value in zip(ent.MOTION_PARAM_NAMES, (dx, dy, angle, scale)):
            self.rec.log(f"{ent.MOTION_PARAMS}/{name}", rr.Scalars(value))
        self.rec.log(ent.MOTION_INLIERS, rr.Scalars(estimate.n_inliers))
        self.rec.log(ent.MOTION_INLIER_RATIO, rr.Scalars(estimate.inlier_ratio))
        self.rec.log(ent.MOTION_RESIDUAL, rr.Scalars(estimate.residual_px))
        self.rec.log(ent.MOTION_STATUS, rr.TextLog(estimate.status))
        if self.level == "full" and len(estimate.curr_points):
            inliers = estimate.inliers
            colours = np.where(inliers[:, None], [[60, 220, 90]], [[240, 60, 60]]).astype(np.uint8)
            self.rec.log(f"{ent.MOTION_FEATURES}/points", rr.Points2D(estimate.curr_points, colors=colours, radii=1.5))
            step = max(1, len(estimate.curr_points) // MAX_FEATURE_ARROWS)
            self.rec.log(f"{ent.MOTION_FEATURES}/arrows", rr.Arrows2D(
                origins=estimate.prev_points[::step], vectors=(estimate.curr_points - estimate.prev_points)[::step],
                colors=colours[::step]))
        self._on_foreground(estimate)
        self._on_ignored(estimate.ignored)

    def _on_foreground(self, estimate: MotionEstimate) -> None:
        """The other motion's tracks (a moving object's, or the RANSAC winner's when that was the object), orange
        over the green and red ones (full level), and a log line where the camera took the other motion."""
        if estimate.chose_alternative:
            self._log_line(rr.TextLog("the tracks most agree on move with a foreground object: the camera "
                                      "follows the other motion (orange: the object's)", level=rr.TextLogLevel.INFO))
        if self.level != "full":
            return
        points = estimate.alternative_curr_points
        if points is not None and len(points):
            self.rec.log(ent.MOTION_FOREGROUND, rr.Points2D(points, colors=FOREGROUND_COLOUR, radii=2.5))
            self._foreground_shown = True
        elif self._foreground_shown:
            self.rec.log(ent.MOTION_FOREGROUND, rr.Clear(recursive=False))
            self._foreground_shown = False

    def _on_ignored(self, ignored: np.ndarray | None) -> None:
        """Outline of where features were not used (--ignore boxes, --ignore-mask), logged when it changes."""
        key = None if ignored is None or not ignored.any() else np.packbits(ignored).tobytes()
        if key == self._ignored_drawn:
            return
        self._ignored_drawn = key
        if key is None:
            self.rec.log(ent.MOTION_IGNORED, rr.Clear(recursive=False))
            return
        mask = cv2.resize(ignored.view(np.uint8), self._size, interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        strips = [np.vstack([c.reshape(-1, 2), c.reshape(-1, 2)[:1]]).astype(np.float32) for c in contours]
        self.rec.log(ent.MOTION_IGNORED, rr.LineStrips2D(strips, colors=IGNORED_COLOUR, radii=1.5))

    def _on_rolling_shutter(self, correction: Correction) -> None:
        """--rolling-shutter: the readout time (log), each frame's bottom band shifted against its top band (series)
        and, at full level, arrows from every band's middle-row position to where its rows saw it (x5)."""
        width, height = self._size
        self._log_line(rr.TextLog(f"rolling shutter: readout {correction.readout:.2f} of the frame interval",
                                  level=rr.TextLogLevel.INFO), static=True)
        frames = np.arange(len(correction.rows))
        xs = np.linspace(0.1, 0.9, 5) * (width - 1)
        skew = []
        for t, rows in zip(frames, correction.rows):
            centres, bands = rows.bands(ROLLING_SHUTTER_BANDS)
            origins = np.array([(x, y) for y in centres for x in xs])
            moved = np.concatenate([geometry.apply(band, [(x, y) for x in xs]) for band, y in zip(bands, centres)])
            skew.append(moved[-3] - moved[2] - (origins[-3] - origins[2]))  # centre column, last band - first
            if self.level == "full":
                self._set_time(Stamp(int(t), self._times.get(int(t), 0.0)))
                self.rec.log(ent.ROLLING_SHUTTER_BANDS, rr.Arrows2D(
                    origins=origins, vectors=(moved - origins) * ROLLING_SHUTTER_GAIN, colors=ROLLING_SHUTTER_COLOUR))
        indexes = self._frame_indexes(len(frames))
        for column, (axis, colour) in enumerate((("dx", (0, 220, 255)), ("dy", (255, 110, 200)))):
            entity = f"{ent.ROLLING_SHUTTER_SKEW}/{axis}"
            self.rec.log(entity, rr.SeriesLines(names=f"bottom - top, {axis[1]} (px)", colors=[colour], widths=2.0),
                         static=True)
            self.rec.send_columns(entity, indexes=indexes, columns=rr.Scalars.columns(scalars=np.array(skew)[:, column]))

    def _on_path(self, plan: PathPlan) -> None:
        if plan.smoothing.settings:
            self._planned = (plan.smoothing.planner, plan.smoothing.settings[0])
        self._on_smoothing(plan.smoothing)
        if plan.paths is not None:
            self._on_paths(plan.paths())
        if plan.rolling_shutter is not None:
            self._on_rolling_shutter(plan.rolling_shutter)
        if plan.crop is not None:
            self._on_crop(plan.crop)
            self._on_crop_scales(np.full(len(plan.orig_from_out), plan.crop.scale))
        if plan.adaptive_crop is not None:
            self._adaptive = self._crop = plan.adaptive_crop
            self._on_crop_scales(plan.adaptive_crop.scales)
            self._log_meta()

    def _on_paths(self, paths: PathComparison) -> None:
        """Eq. 18's and the L1 path beside the run's own (the trajectory views), and in crop mode each frame's
        crop-window constraint: the output's corners on the input frame, and their room inside it (px)."""
        indexes = self._frame_indexes(len(paths.gaussian))
        self._send_trajectories(indexes, (ent.TRAJECTORY_GAUSSIAN, paths.gaussian), (ent.TRAJECTORY_L1, paths.l1))
        if paths.crop_room_px is not None:
            self.rec.send_columns(ent.CROP_ROOM, indexes=indexes, columns=rr.Scalars.columns(scalars=paths.crop_room_px))
        if paths.crop_corners is not None:
            for t, corners in enumerate(paths.crop_corners):
                self._set_time(Stamp(t, self._times.get(t, 0.0)))
                self.rec.log(ent.CROP_CONSTRAINT, rr.LineStrips2D([np.vstack([corners, corners[:1]])],
                                                                  colors=[CROP_COLOUR], radii=1.0))

    def _frame_indexes(self, count: int) -> list[rr.TimeColumn]:
        """The frame and video-time index columns of frames 0..count-1, for send_columns."""
        frames = np.arange(count)
        times = np.array([self._times.get(int(t), 0.0) for t in frames])
        return [rr.TimeColumn(ent.FRAME_TIMELINE, sequence=frames),
                rr.TimeColumn(ent.VIDEO_TIME_TIMELINE, duration=times)]

    def _send_trajectories(self, indexes: list[rr.TimeColumn], *paths: tuple[str, np.ndarray]) -> None:
        """Each (root, trajectory) as one series per axis (entities.TRAJECTORY_AXES: its columns)."""
        for root, values in paths:
            for column, axis in enumerate(ent.TRAJECTORY_AXES):
                self.rec.send_columns(f"{root}/{axis}", indexes=indexes,
                                      columns=rr.Scalars.columns(scalars=values[:, column]))

    def _on_crop_scales(self, scales: np.ndarray) -> None:
        """--mode crop: the window's scale per frame (constant for one window; --crop adaptive's follows the path)."""
        self.rec.send_columns(ent.CROP_SCALE, indexes=self._frame_indexes(len(scales)),
                              columns=rr.Scalars.columns(scalars=scales))

    def _on_adaptive_window(self, stamp: Stamp, crop: AdaptiveCrop) -> None:
        """--crop adaptive: this frame's window of the stabilized frame, drawn over it."""
        width, height = self._size
        scale = float(crop.scales[min(stamp.index, len(crop.scales) - 1)])
        x0, y0 = crop.anchor[0] - scale * (width - 1) / 2.0, crop.anchor[1] - scale * (height - 1) / 2.0
        self._set_time(stamp)
        self.rec.log(ent.CROP_WINDOW, rr.Boxes2D(
            array=[x0, y0, scale * width, scale * height], array_format=rr.Box2DFormat.XYWH, colors=[CROP_COLOUR],
            radii=1.5, labels=[f"crop window: {scale ** 2:.0%} of the area (adaptive)"], show_labels=True))

    def _on_frame(self, result: FrameResult) -> None:
        stamp = result.stamp
        if self._adaptive is not None:
            self._on_adaptive_window(stamp, self._adaptive)
        if result.input is not None:
            self._on_input(stamp, result.input)
        if result.warp is not None:
            self._on_warp(stamp, result.warp)
        if result.completion is not None:
            self._on_completion(stamp, result.completion)
        if result.deblur is not None:
            self._on_deblur(stamp, result.deblur)
        if result.temporal is not None and result.completion is not None:
            missing = result.completion.missing
            self._set_time(stamp)
            self.rec.log(ent.COMPLETION_TEMPORAL,
                         rr.Scalars(float(result.temporal.share[missing].mean()) if missing.any() else 0.0))
        self._on_output(stamp, result.output)

    def _on_smoothing(self, result: SmoothingResult) -> None:
        n = len(result.orig_from_stab)
        indexes = self._frame_indexes(n)
        self._send_trajectories(indexes, (ent.TRAJECTORY_ORIGINAL, result.original_trajectory),
                                (ent.TRAJECTORY_SMOOTHED, result.smoothed_trajectory))
        # Which path setting planned each frame (--path, --smoothness, --path-segment), by index into the list.
        if result.setting_of is not None:
            self.rec.send_columns(ent.PATH_SETTING, indexes=indexes,
                                  columns=rr.Scalars.columns(scalars=result.setting_of.astype(np.float64)))
        self.rec.log(ent.PATH_SETTINGS, rr.TextDocument("\n".join(result.settings)), static=True)
        if self._trace_requested is None:
            count = trace.DEFAULT_TRACED if self.level == "full" else 0
            self._set_traced(trace.default_trace_frames(result.orig_from_stab, *self._size, count=count))
        else:
            beyond = [t for t in self._trace_requested if t >= n]
            if beyond:
                self._log_line(rr.TextLog(f"traced frame(s) {', '.join(map(str, beyond))} not in the clip's {n} "
                                          "frames: not traced", level=rr.TextLogLevel.WARN), static=True)
            self._set_traced([t for t in self._trace_requested if t < n])

    def _on_crop(self, crop: CropWindow) -> None:
        """--mode crop: the window of the stabilized frame that becomes the output (static, drawn over it)."""
        self._crop = crop
        width, height = self._size
        self.rec.log(ent.CROP_WINDOW, rr.Boxes2D(
            array=[crop.x0, crop.y0, crop.scale * width, crop.scale * height], array_format=rr.Box2DFormat.XYWH,
            colors=[CROP_COLOUR], radii=1.5,
            labels=[f"crop window: {crop.cropping_ratio:.0%} of the area, scaled x{1 / crop.scale:.3f} to the output"],
            show_labels=True), static=True)
        self._log_meta()

    def _on_input(self, stamp: Stamp, frame: Frame) -> None:
        self._trace(stamp, "input", frame.rgb)
        if self.level == "full":
            self._set_time(stamp)
            self._frame(ent.INPUT_FRAME, stamp, frame.rgb)

    def _on_warp(self, stamp: Stamp, result: WarpResult) -> None:
        self._trace(stamp, "stabilized", result.frame)
        if self.level == "full":
            self._set_time(stamp)
            self._frame(ent.STABILIZED_FRAME, stamp, result.frame)
            self._classes(ent.STABILIZED_MISSING, result.missing.astype(np.uint8) * MISSING_CLASS, MISSING_LEGEND)

    def _on_completion(self, stamp: Stamp, result: CompletionResult) -> None:
        if stamp.index in self.traced:
            self._trace_completion(stamp, result)
        self._set_time(stamp)
        frame_area = result.missing.size
        counts = np.bincount(result.source.ravel(), minlength=len(SOURCE_NAMES))
        self.rec.log(f"{ent.COMPLETION_STATS}/missing", rr.Scalars(result.missing.sum() / frame_area))
        for code, name in enumerate(SOURCE_NAMES[1:], start=1):
            self.rec.log(f"{ent.COMPLETION_STATS}/{name.replace(' ', '_')}", rr.Scalars(counts[code] / frame_area))
        if self.level != "full":
            return
        self._frame(ent.COMPLETION_FRAME, stamp, result.frame)
        self._map(ent.COMPLETION_VARIANCE, result.mosaic.variance, "turbo", VARIANCE_RANGE)
        self._classes(ent.COMPLETION_ACCEPTED,
                      np.where(result.mosaic.accepted, 2, np.where(result.missing, 1, 0)).astype(np.uint8),
                      ACCEPTED_LEGEND)
        self._classes(ent.COMPLETION_FILLED_BY, self._filled_by_classes(result), self._filled_by_legend())
        self._classes(ent.COMPLETION_SOURCE, result.source, SOURCE_LEGEND)
        self._classes(ent.COMPLETION_FALLBACK, result.fallback.astype(np.uint8), FALLBACK_LEGEND)
        if result.fills:
            first = result.fills[0]
            self.rec.log(ent.COMPLETION_FLOW_IMAGE, self._image(visual.flow_to_rgb(first.inpainted.flow)))
            origins, vectors = visual.sparse_arrows(first.inpainted.flow)
            self.rec.log(ent.COMPLETION_FLOW_ARROWS, rr.Arrows2D(origins=origins, vectors=vectors))
            order = first.inpainted.order.astype(np.float32)
            order[order < 0] = np.nan
            self._map(ent.COMPLETION_FMM_ORDER, order, "viridis", (0.0, float(np.nanmax(order)) if (order >= 0).any() else 1.0))
            # Shown over the filled band only: T is 0 on every known pixel by definition.
            arrival = first.inpainted.arrival
            self._map(ent.COMPLETION_FMM_ARRIVAL, arrival, "magma", ARRIVAL_RANGE, shown=arrival > 0)
        else:  # no stale map from an earlier frame (nor its values)
            for entity in (ent.COMPLETION_FLOW_IMAGE, ent.COMPLETION_FLOW_ARROWS):
                self.rec.log(entity, rr.Clear(recursive=False))
            for entity in (ent.COMPLETION_FMM_ORDER, ent.COMPLETION_FMM_ARRIVAL):
                self.rec.log(entity, rr.Clear(recursive=True))

    def _filled_by_classes(self, result: CompletionResult) -> np.ndarray:
        """Class per pixel: 0 original, 1 mosaic, 2 fallback, FILLED_BY_BASE + offset where step 2 filled from one
        neighbour (local warp, carried on or as is: completion/source tells which)."""
        classes = np.zeros(result.source.shape, np.uint8)
        classes[result.source == SOURCE_MOSAIC] = 1
        classes[result.source == SOURCE_FALLBACK] = 2
        warped = from_a_neighbour(result.source)
        classes[warped] = (FILLED_BY_BASE + result.filled_by[warped]).astype(np.uint8)
        return classes

    def _on_deblur(self, stamp: Stamp, result: DeblurResult) -> None:
        self._trace(stamp, "deblurred", result.frame)
        self._set_time(stamp)
        neighbours = tuple(result.neighbours)
        self.rec.log(ent.DEBLUR_BLURRINESS, rr.Scalars(float(result.blurriness)))
        self.rec.log(ent.DEBLUR_NEIGHBOURS, rr.Scalars(len(neighbours)))
        refused = result.refused
        self.rec.log(ent.DEBLUR_REFUSED, rr.Scalars(float(refused.mean()) if refused is not None else 0.0))
        if self.level != "full":
            return
        # Where each pixel came from, and where a sharper neighbour was refused (shown even when none was used).
        classes = self._deblur_source_classes(result)
        if classes.any():
            self._classes(ent.DEBLUR_SOURCE, classes, self._deblur_source_legend())
        else:
            self.rec.log(ent.DEBLUR_SOURCE, rr.Clear(recursive=False))
        if not neighbours:  # nothing was sharpened: clear, so the viewer shows no stale frame from earlier
            for entity in (ent.DEBLUR_BEFORE, ent.DEBLUR_AFTER, ent.DEBLUR_WEIGHTS,
                           ent.map_values(ent.DEBLUR_WEIGHTS)):
                self.rec.log(entity, rr.Clear(recursive=False))
            return
        # Sparse video streams (only sharpened frames; cleared in between, which hides them there).
        self._frame(ent.DEBLUR_BEFORE, stamp, result.before)
        self._frame(ent.DEBLUR_AFTER, stamp, result.frame)
        weights = result.weights
        if weights is not None:
            # uint8 (255 = 1): a float32 map is 4x the bytes and does not compress; 1/255 is plenty to look at.
            quantised = np.clip(np.asarray(weights, np.float32) * ent.DEBLUR_WEIGHTS_SCALE + 0.5, 0, 255).astype(np.uint8)
            if not self.lossless:  # steps of 1/32 (multiples of 8): a third of the PNG's bytes (docs/recording.md)
                quantised = np.minimum(np.rint(quantised / WEIGHTS_STEP) * WEIGHTS_STEP, 255).astype(np.uint8)
            # What the view shows: the weights in their key's colours, a paletted PNG. (Logged as a depth image with
            # a colour map, rerun 0.41 drew every weight in the map's lowest colour.)
            shares = quantised.astype(np.float32) / np.float32(ent.DEBLUR_WEIGHTS_SCALE)
            picture = indexed_png(visual.map_indices(shares, (0.0, 1.0)), visual.map_palette("viridis"))
            self.rec.log(ent.DEBLUR_WEIGHTS, rr.EncodedImage(contents=picture, media_type="image/png"))
            # The values, for reading back: an 8-bit PNG, lossless for the stored values (~20 kB, not 230 kB).
            self.rec.log(ent.map_values(ent.DEBLUR_WEIGHTS), rr.EncodedDepthImage(
                png16(quantised), media_type="image/png", meter=ent.DEBLUR_WEIGHTS_SCALE, colormap="viridis",
                depth_range=(0.0, ent.DEBLUR_WEIGHTS_SCALE)))

    def _on_output(self, stamp: Stamp, rgb: np.ndarray) -> None:
        self._trace(stamp, "output", rgb)
        self._set_time(stamp)
        self._frame(ent.OUTPUT_FRAME, stamp, rgb)

    # -- stage stepping ---------------------------------------------------------------------------

    def _set_traced(self, frames: Sequence[int]) -> None:
        self.traced = tuple(frames)
        if self.live_url is not None:  # a file is read whole: its layout is sent once, at the end
            self._send_blueprint()

    @property
    def _layout_flags(self) -> dict[str, bool]:
        """The run's options that add views to the layout (blueprint.default_blueprint's flags)."""
        return {"crop": getattr(self._config, "mode", None) == "crop",
                "rolling_shutter": getattr(self._config, "rolling_shutter", None) is not None,
                "log": self._log_lines > 0 or not self._closed}  # while running, lines may still come

    def _send_blueprint(self) -> None:
        """The layout, once the traced frames are known (live) and again, final, at the end."""
        if self._closed or not self._blueprint_sent:
            self._blueprint_sent = True
            # Active too: it arrives after data, and the viewer would otherwise keep the layout it guessed from that.
            self.rec.send_blueprint(default_blueprint(self.traced, **self._layout_flags), make_active=True,
                                    make_default=True)

    def _trace(self, stamp: Stamp, stage: str, rgb: np.ndarray) -> None:
        """Log a traced frame's image after ``stage`` on the ``stage`` timeline (frame = the traced frame)."""
        if stamp.index not in self.traced:
            return
        step = ent.TRACE_STAGES.index(stage)
        self._set_time(stamp)
        self.rec.set_time(ent.STAGE_TIMELINE, sequence=step)
        height, width = rgb.shape[:2]
        self.rec.log(ent.trace_image(stamp.index), self._image(self._display(rgb)))
        self.rec.log(ent.trace_label(stamp.index), rr.Boxes2D(
            array=[0, 0, width, height], array_format=rr.Box2DFormat.XYWH, colors=[LABEL_COLOUR],
            labels=[trace.stage_label(stamp.index, step)], show_labels=True))
        self.rec.disable_timeline(ent.STAGE_TIMELINE)

    def _trace_completion(self, stamp: Stamp, result: CompletionResult) -> None:
        """Mosaic and local-warp stages, and the first neighbour's Fast Marching band (Fig. 18)."""
        self._trace(stamp, "mosaic", result.mosaic.frame)
        self._trace(stamp, "motion-inpainted", trace.local_warp_frame(result.mosaic.frame, result.frame,
                                                                       from_a_neighbour(result.source)))
        if not result.fills:
            return
        inpainted = result.fills[0].inpainted
        stabilized = np.where(result.missing[..., None], np.uint8(0), self._display(result.mosaic.frame))
        self._set_time(stamp)
        height, width = result.missing.shape
        for step, filled, total, image in trace.fmm_band_images(stabilized, inpainted.flow, inpainted.order):
            self.rec.set_time(ent.FMM_STEP_TIMELINE, sequence=step)
            self.rec.log(ent.trace_fmm(stamp.index), self._image(image))
            self.rec.log(ent.trace_fmm_label(stamp.index), rr.Boxes2D(
                array=[0, 0, width, height], array_format=rr.Box2DFormat.XYWH, colors=[LABEL_COLOUR],
                labels=[f"frame {stamp.index}: Fast Marching, {filled} of {total} pixels filled "
                        f"(neighbour {result.fills[0].offset:+d})"], show_labels=True))
        self.rec.disable_timeline(ent.FMM_STEP_TIMELINE)

    # -- helpers ----------------------------------------------------------------------------------

    def _set_time(self, stamp: Stamp) -> None:
        self.rec.set_time(ent.FRAME_TIMELINE, sequence=stamp.index)
        self.rec.set_time(ent.VIDEO_TIME_TIMELINE, duration=stamp.time_s)

    def _display(self, rgb: np.ndarray) -> np.ndarray:
        """A frame as a person sees it: 8-bit display RGB by the input's colour description (HDR tone-mapped,
        BT.2020 mapped into BT.709; 8-bit BT.601/709 frames as they are)."""
        return display_rgb(rgb, self._colour)

    def _frame(self, entity: str, stamp: Stamp, rgb: np.ndarray) -> None:
        """A frame stream: H.264 samples (or a raw image with --lossless), in display RGB."""
        rgb = self._display(rgb)
        if self.lossless:
            self.rec.log(entity, self._image(rgb))
            return
        track = self._tracks.get(entity)
        if track is None:
            track = self._tracks[entity] = VideoTrack(self.rec, entity, self._fps)
        track.add(stamp, rgb)

    def _classes(self, entity: str, classes: np.ndarray, legend: Sequence[tuple]) -> None:
        """A class map: SegmentationImage with --lossless (hover names), else a paletted PNG (a few kB)."""
        if self.lossless:
            self.rec.log(entity, rr.SegmentationImage(classes, draw_order=MASK_DRAW_ORDER))
        else:
            self.rec.log(entity, rr.EncodedImage(contents=palette_png(classes, legend), media_type="image/png",
                                                 opacity=SEE_THROUGH, draw_order=MASK_DRAW_ORDER))

    def _map(self, entity: str, values: np.ndarray, colormap: str, value_range: tuple[float, float],
             shown: np.ndarray | None = None) -> None:
        """A float map, twice. At ``entity``, what the views show: a paletted PNG colour-mapped as its key,
        transparent where the map has no value (or not ``shown``); a depth image would paint those pixels its lowest
        colour, reading as value 0 over the whole frame. At entities.map_values(entity), the values for reading back:
        a float32 DepthImage with --lossless, else a 16-bit PNG (entities.MAP_STEPS)."""
        values = visual.finite_or_nan(values)
        picture = indexed_png(visual.map_indices(values, value_range, shown), visual.map_palette(colormap))
        self.rec.log(entity, rr.EncodedImage(contents=picture, media_type="image/png", opacity=SEE_THROUGH))
        if self.lossless:
            self.rec.log(ent.map_values(entity), rr.DepthImage(values, meter=1.0, colormap=colormap,
                                                               depth_range=value_range))
            return
        step = ent.MAP_STEPS[entity]
        self.rec.log(ent.map_values(entity), rr.EncodedDepthImage(
            png16(quantised_map(values, step)), media_type="image/png", meter=1.0 / step, colormap=colormap,
            depth_range=(value_range[0] / step + 1, value_range[1] / step + 1)))

    def _image(self, rgb: np.ndarray) -> Any:
        if self.jpeg_quality is None:
            return rr.Image(np.ascontiguousarray(rgb), color_model="RGB")
        # OpenCV's encoder: 2-3x faster than Image.compress (Pillow) on 640x360, the same JPEG quality scale.
        ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        return rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg")

    @staticmethod
    @functools.cache
    def _filled_by_legend(max_offset: int = 30) -> tuple:
        legend = [(0, "original", (0, 0, 0, 0)), (1, "mosaic", (40, 200, 90, 170)), (2, "fallback", (255, 200, 0, 200))]
        for offset in range(-max_offset, max_offset + 1):
            if offset:
                legend.append((FILLED_BY_BASE + offset, f"neighbour {offset:+d}", _offset_colour(offset, 190)))
        return tuple(legend)  # cached: built once

    @staticmethod
    def _deblur_source_classes(result: Any) -> np.ndarray:
        """Class per pixel: FILLED_BY_BASE + offset the neighbour that gave most (5 % or more); 1 where none gave
        and a sharper neighbour was refused (other content: the frame keeps its own pixel for that reason); 0 the
        frame's own. (Marking every pixel where some neighbour was refused painted nearly whole frames red on real
        footage, where a far neighbour is refused almost everywhere while the near ones give most of the pixel.)"""
        shape = result.frame.shape[:2]
        classes = np.zeros(shape, np.uint8)
        source = getattr(result, "main_source", None)
        taken = np.zeros(shape, bool) if source is None else source != 0
        if taken.any():
            classes[taken] = (FILLED_BY_BASE + source[taken].astype(np.int16)).astype(np.uint8)
        refused = getattr(result, "refused", None)
        if refused is not None:
            classes[refused & ~taken] = 1
        return classes

    @staticmethod
    @functools.cache
    def _deblur_source_legend(max_offset: int = 30) -> tuple:
        legend = [(0, "own frame", (0, 0, 0, 0)), (1, DEBLUR_REFUSED_NAME, (230, 40, 60, 200))]
        for offset in range(-max_offset, max_offset + 1):
            if offset:
                legend.append((FILLED_BY_BASE + offset, f"from neighbour {offset:+d}", _offset_colour(offset, 170)))
        return tuple(legend)  # cached: built once

    def _log_meta(self, report: Any = None) -> None:
        """The about tab: a readable summary of the run, rewritten (static) as more becomes known."""
        text = self._meta_markdown(self._info, self._config, report=report, crop=self._crop, warnings=self._warnings,
                                   level=self.level, lossless=self.lossless,
                                   seconds_logging=self.seconds_logging, planned=self._planned)
        self.rec.log(ent.META, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)

    @staticmethod
    def _meta_markdown(info: Any, config: Any, *, report: Any = None, crop: Any = None, warnings: int = 0,
                       level: str = "full", lossless: bool = False, seconds_logging: float = 0.0,
                       planned: tuple[str, str] | None = None) -> str:
        lines = ["# About this recording", "",
                 f"- ffviz {ffviz.__version__}, rerun-sdk {rr.__version__} (open it with the same rerun version)"]
        if info is not None:
            lines.append(f"- input: `{info.path}`: {info.width}x{info.height}, {float(info.fps):.3f} frames/s, "
                         f"{info.frame_count} frames")
            colour = getattr(info, "colour", None)
            if colour is not None:
                shown = ("tone-mapped from HDR to SDR" if colour.hdr else "BT.2020 mapped into BT.709"
                         if colour.primaries == 9 else "as decoded")
                lines.append(f"- colour: {colour.summary()}; the output keeps it. Frames here are 8-bit display "
                             f"RGB ({shown})")
        lines.append(f"- recorded: `--record {level}`, " + ("lossless images (`--lossless`)" if lossless else
                     "frame streams as H.264 video, masks as lossless PNG, maps as colour-mapped PNG with their "
                     "values as 16-bit PNG"))
        if config is not None:
            lines += ["", "## Settings", ""] + [f"- {row}" for row in _settings_summary(config)]
            if planned is not None and getattr(getattr(config, "smoothing", None), "path", None) == "auto":
                planner, label = planned
                chose = "the L1 program in the crop window" if planner == "l1" else "eq. 18's path"
                lines.append(f"- auto chose: {chose} (`{label}`)")
        if crop is not None and hasattr(crop, "scales"):  # --crop adaptive
            lines.append(f"- adaptive crop: scale {crop.scales.min():.3f}-{crop.scales.max():.3f} about "
                         f"({crop.anchor[0]:.1f}, {crop.anchor[1]:.1f}), {crop.cropping_ratio:.1%} of the area kept "
                         f"on average (stabilized/crop_scale)")
        elif crop is not None:
            lines.append(f"- crop window: x0 {crop.x0:.1f}, y0 {crop.y0:.1f}, scale {crop.scale:.3f} "
                         f"({crop.cropping_ratio:.1%} of the area kept)")
        lines += ["", "## Run", ""]
        if report is not None:
            seconds = float(getattr(report, "seconds_motion", 0.0)) + float(getattr(report, "seconds_render", 0.0))
            lines.append(f"- {report.n_frames} frames in {seconds:.1f} s (motion pass "
                         f"{report.seconds_motion:.1f} s, render pass {report.seconds_render:.1f} s; the recorder, on "
                         f"its own thread, was busy {seconds_logging:.1f} s)")
            if getattr(report, "cuts", None):
                lines.append(f"- scene cuts at frames {', '.join(map(str, report.cuts))}")
        else:
            lines.append("- running (or interrupted): timings are written when the run finishes")
        lines.append(f"- warnings: {warnings}" + (" (listed below)" if warnings else ""))
        if config is not None:
            lines += ["", "## All settings", ""] + [f"- {row}" for row in _config_rows(config)]
        return "\n".join(lines) + "\n"

    def close(self) -> None:
        """Finish the file and move it into place."""
        if self._closed:
            return
        self._stop_worker()
        if self._error is not None:
            self.abort()
            raise RuntimeError(f"recording to {self.path} failed: {self._error!r}") from self._error
        self._closed = True
        self._send_blueprint()
        for track in self._tracks.values():
            track.close()
        self.rec.flush()
        self.rec.disconnect()
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(self._tmp_path, 0o666 & ~umask)  # mkstemp made it private; give it the usual mode
        os.replace(self._tmp_path, self.path)

    def abort(self) -> None:
        """Drop the recording: nothing half-written is left behind."""
        if self._closed:
            return
        self._aborting = True  # what is still queued is skipped
        self._stop_worker()
        self._closed = True
        self.rec.disconnect()
        self._tmp_path.unlink(missing_ok=True)


_MODE_WORDS = {"full": "full frame: stabilize, then complete the missing area (chapter 4)",
               "crop": "crop: stabilize, then crop to a window every frame covers",
               "none": "stabilize only: the missing area stays black"}


def _settings_summary(config: Any) -> list[str]:
    """The run's settings in a few words, then each setting that differs from the defaults (`section.name`)."""
    if not dataclasses.is_dataclass(config):
        return [f"`{config}`"]
    rows = []
    mode = getattr(config, "mode", None)
    if mode is not None:
        fill = getattr(config, "crop_fill", 0.0)
        rows.append(f"mode: {_MODE_WORDS.get(mode, mode)}" if not fill else
                    f"mode: crop: stabilize, then crop to the largest window whose parts outside the frames are at "
                    f"most {fill:.2%} of the pixels over the clip, completed there (chapter 4)")
    smoothing = getattr(config, "smoothing", None)
    if smoothing is not None:
        words = {"gaussian": f"eq. 18, Gaussian over k = {smoothing.radius_frames} frames each side",
                 "auto": "auto (the L1 program in the crop window where as steady as eq. 18, else eq. 18)"}
        rows.append("camera path: " + words.get(smoothing.path, f"{smoothing.path} (L1 program)"))
    deblur = getattr(config, "deblur", None)
    if mode == "full" and deblur is not None:
        rows.append("deblurring: " + (f"on, from neighbours {deblur.min_ratio:g}x sharper within "
                                      f"{deblur.neighbour_frames} frames" if deblur.enabled else "off"))
    try:  # the mode's own defaults (its camera path differs); the mode itself against the tool's default mode
        defaults = type(config)(**({"mode": mode} if mode is not None else {}))
    except (TypeError, ValueError):
        return rows
    changed = _changed_settings(config, defaults)
    mode_field = type(config).__dataclass_fields__.get("mode")
    if mode_field is not None and mode != mode_field.default:
        changed.insert(0, ("mode", mode))
    rows.append("changed from the defaults: " + (", ".join(f"`{name} = {value!r}`" for name, value in changed)
                                                if changed else "nothing"))
    return rows


def _changed_settings(config: Any, defaults: Any, prefix: str = "") -> list[tuple[str, Any]]:
    changed = []
    for field in dataclasses.fields(config):
        value, default = getattr(config, field.name), getattr(defaults, field.name, None)
        if dataclasses.is_dataclass(value) and type(value) is type(default):
            changed += _changed_settings(value, default, f"{prefix}{field.name}.")
        elif value != default:
            changed.append((f"{prefix}{field.name}", value))
    return changed


def _config_rows(config: Any) -> list[str]:
    """One line per setting: `section.name = value`, nested dataclasses flattened."""
    if not dataclasses.is_dataclass(config):
        return [f"`{config}`"]
    rows: list[str] = []
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if dataclasses.is_dataclass(value):
            inner = ", ".join(f"{f.name}={getattr(value, f.name)!r}" for f in dataclasses.fields(value))
            rows.append(f"**{field.name}**: {inner}")
        else:
            rows.append(f"**{field.name}**: {value!r}")
    return rows
