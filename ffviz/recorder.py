"""The Rerun observer: maps each stage's result to the entity layout in ``ffviz.entities``.

It writes to its own RecordingStream (no global state), saved straight to a .rrd with the default
blueprint embedded. The file is written beside the target and renamed on success, like videos.

Traced frames (``trace_frames``; by default a few with missing area, chosen once the path is smoothed)
are also logged stage by stage on the ``stage`` timeline and their Fast Marching fill step by step on
``fmm_step`` (see ffviz.trace). The blueprint, which has a view per traced frame, is sent once they are known.
"""

from __future__ import annotations

import os
import tempfile
import uuid
from pathlib import Path
from typing import Any, Literal, Sequence

import cv2
import numpy as np
import rerun as rr

import ffviz
from ffviz import entities as ent, trace, visual
from ffviz.blueprint import default_blueprint
from pipeline import geometry
from pipeline.completion import SOURCE_FALLBACK, SOURCE_LOCAL_WARP, SOURCE_MOSAIC, SOURCE_NAMES, CompletionResult
from pipeline.motion import MotionEstimate
from pipeline.observer import Stamp
from pipeline.smoothing import SmoothingResult
from pipeline.video_io import Frame
from pipeline.warping import WarpResult

RecordLevel = Literal["summary", "full"]
RECORD_LEVELS: tuple[str, ...] = ("summary", "full")
MISSING_CLASS = 1
MAX_FEATURE_ARROWS = 300  # enough to read the motion, few enough to keep files small
FILLED_BY_BASE = 100  # filled_by class of a local-warp pixel: FILLED_BY_BASE + neighbour offset


class RerunRecorder:
    """Observer that records a run to ``path`` (.rrd).

    ``level``: "summary" records series and output frames; "full" adds every frame-sized intermediate.
    ``jpeg_quality``: None records images losslessly.
    ``trace_frames``: frames to follow through every stage; None: ``trace.DEFAULT_TRACED`` frames with missing
    area at level "full", none at "summary".
    """

    def __init__(self, path: Path | str, *, level: RecordLevel = "full", jpeg_quality: int | None = 80,
                 trace_frames: Sequence[int] | None = None, application_id: str = "ffviz") -> None:
        if level not in RECORD_LEVELS:
            raise ValueError(f"record level must be one of {', '.join(RECORD_LEVELS)}, not {level!r}")
        self.path = Path(path)
        self.level = level
        self.jpeg_quality = jpeg_quality
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=".rrd.tmp", dir=self.path.parent)
        os.close(fd)
        self._tmp_path = Path(tmp)
        self.rec = rr.RecordingStream(application_id, recording_id=str(uuid.uuid4()))
        self.rec.save(self._tmp_path)  # the default blueprint follows once the traced frames are known
        self._times: dict[int, float] = {}
        self._size = (0, 0)
        self._closed = False
        self._trace_requested = None if trace_frames is None else tuple(sorted({int(t) for t in trace_frames}))
        self.traced: tuple[int, ...] = self._trace_requested or ()  # default ones chosen when the path is known
        self._blueprint_sent = False

    # -- Observer ---------------------------------------------------------------------------------

    def on_start(self, info: Any, config: Any) -> None:
        self._size = (info.width, info.height)
        self.rec.log(ent.META, rr.TextDocument(self._meta_markdown(info, config), media_type=rr.MediaType.MARKDOWN),
                     static=True)
        self.rec.log(ent.STABILIZED_MISSING, rr.AnnotationContext([(0, "valid", (0, 0, 0, 0)),
                                                                    (MISSING_CLASS, "missing", (255, 0, 64, 160))]),
                     static=True)
        self.rec.log(ent.COMPLETION_ACCEPTED, rr.AnnotationContext([
            (0, "known", (0, 0, 0, 0)), (1, "missing, rejected", (255, 0, 64, 160)),
            (2, "accepted by mosaic", (40, 200, 90, 160))]), static=True)
        self.rec.log(ent.COMPLETION_FALLBACK, rr.AnnotationContext([(0, "other", (0, 0, 0, 0)),
                                                                     (1, "fallback", (255, 200, 0, 200))]), static=True)
        self.rec.log(ent.COMPLETION_FILLED_BY, rr.AnnotationContext(self._filled_by_legend()), static=True)
        self.rec.log(ent.DEBLUR_SOURCE, rr.AnnotationContext(self._deblur_source_legend()), static=True)
        self.rec.log(ent.DEBLUR_REFUSED, rr.SeriesLines(names="refused (share of the frame)", colors=[(230, 40, 60)]),
                     static=True)
        self.rec.log(ent.DEBLUR_BLURRINESS, rr.SeriesLines(names="blurriness b_t", colors=[(200, 80, 200)]), static=True)
        self.rec.log(ent.DEBLUR_NEIGHBOURS, rr.SeriesLines(names="sharper neighbours used", colors=[(90, 160, 90)]),
                     static=True)
        for name, colour in (("original", (230, 90, 60)), ("smoothed", (40, 120, 230))):
            root = ent.TRAJECTORY_ORIGINAL if name == "original" else ent.TRAJECTORY_SMOOTHED
            for axis in ent.TRAJECTORY_AXES:
                self.rec.log(f"{root}/{axis}", rr.SeriesLines(names=f"{axis} {name}", colors=[colour]), static=True)

    def on_stage(self, stage: str, stamp: Stamp | None, result: Any) -> None:
        handler = getattr(self, f"_on_{stage}", None)
        if handler is not None:
            handler(stamp, result)

    def on_warning(self, stamp: Stamp | None, message: str) -> None:
        if stamp is not None:
            self._set_time(stamp)
        self.rec.log(ent.LOG, rr.TextLog(message, level=rr.TextLogLevel.WARN), static=stamp is None)

    def on_finish(self, report: Any) -> None:
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

    def _on_smoothing(self, stamp: None, result: SmoothingResult) -> None:
        frames = np.arange(len(result.orig_from_stab))
        times = np.array([self._times.get(int(t), 0.0) for t in frames])
        indexes = [rr.TimeColumn(ent.FRAME_TIMELINE, sequence=frames),
                   rr.TimeColumn(ent.VIDEO_TIME_TIMELINE, duration=times)]
        for root, values in ((ent.TRAJECTORY_ORIGINAL, result.original_trajectory),
                             (ent.TRAJECTORY_SMOOTHED, result.smoothed_trajectory)):
            for column, axis in enumerate(ent.TRAJECTORY_AXES):
                self.rec.send_columns(f"{root}/{axis}", indexes=indexes,
                                      columns=rr.Scalars.columns(scalars=values[:, column]))
        n = len(frames)
        if self._trace_requested is None:
            count = trace.DEFAULT_TRACED if self.level == "full" else 0
            self._set_traced(trace.default_trace_frames(result.orig_from_stab, *self._size, count=count))
        else:
            beyond = [t for t in self._trace_requested if t >= n]
            if beyond:
                self.rec.log(ent.LOG, rr.TextLog(f"traced frame(s) {', '.join(map(str, beyond))} not in the clip's {n} "
                                                 "frames: not traced", level=rr.TextLogLevel.WARN), static=True)
            self._set_traced([t for t in self._trace_requested if t < n])

    def _on_input(self, stamp: Stamp, frame: Frame) -> None:
        self._trace(stamp, "input", frame.rgb)
        if self.level == "full":
            self._set_time(stamp)
            self.rec.log(ent.INPUT_FRAME, self._image(frame.rgb))

    def _on_warp(self, stamp: Stamp, result: WarpResult) -> None:
        self._trace(stamp, "stabilized", result.frame)
        if self.level == "full":
            self._set_time(stamp)
            self.rec.log(ent.STABILIZED_FRAME, self._image(result.frame))
            self.rec.log(ent.STABILIZED_MISSING, rr.SegmentationImage(result.missing.astype(np.uint8) * MISSING_CLASS))

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
        self.rec.log(ent.COMPLETION_FRAME, self._image(result.frame))
        self.rec.log(ent.COMPLETION_VARIANCE, rr.DepthImage(visual.finite_or_nan(result.mosaic.variance),
                                                            colormap="turbo"))
        self.rec.log(ent.COMPLETION_ACCEPTED, rr.SegmentationImage(
            np.where(result.mosaic.accepted, 2, np.where(result.missing, 1, 0)).astype(np.uint8)))
        self.rec.log(ent.COMPLETION_FILLED_BY, rr.SegmentationImage(self._filled_by_classes(result)))
        self.rec.log(ent.COMPLETION_FALLBACK, rr.SegmentationImage(result.fallback.astype(np.uint8)))
        if result.fills:
            first = result.fills[0]
            self.rec.log(ent.COMPLETION_FLOW_IMAGE, self._image(visual.flow_to_rgb(first.inpainted.flow)))
            origins, vectors = visual.sparse_arrows(first.inpainted.flow)
            self.rec.log(ent.COMPLETION_FLOW_ARROWS, rr.Arrows2D(origins=origins, vectors=vectors))
            order = first.inpainted.order.astype(np.float32)
            order[order < 0] = np.nan
            self.rec.log(ent.COMPLETION_FMM_ORDER, rr.DepthImage(order, colormap="viridis"))
            self.rec.log(ent.COMPLETION_FMM_ARRIVAL, rr.DepthImage(visual.finite_or_nan(first.inpainted.arrival),
                                                                   colormap="magma"))

    def _filled_by_classes(self, result: CompletionResult) -> np.ndarray:
        """Class per pixel: 0 original, 1 mosaic, 2 fallback, FILLED_BY_BASE + offset for local warps."""
        classes = np.zeros(result.source.shape, np.uint8)
        classes[result.source == SOURCE_MOSAIC] = 1
        classes[result.source == SOURCE_FALLBACK] = 2
        warped = result.source == SOURCE_LOCAL_WARP
        classes[warped] = (FILLED_BY_BASE + result.filled_by[warped]).astype(np.uint8)
        return classes

    def _on_deblur(self, stamp: Stamp, result: Any) -> None:
        """A deblurring result (duck-typed: frame, before, blurriness, neighbours, weights)."""
        self._trace(stamp, "deblurred", result.frame)
        self._set_time(stamp)
        neighbours = tuple(getattr(result, "neighbours", None) or ())
        self.rec.log(ent.DEBLUR_BLURRINESS, rr.Scalars(float(result.blurriness)))
        self.rec.log(ent.DEBLUR_NEIGHBOURS, rr.Scalars(len(neighbours)))
        refused = getattr(result, "refused", None)
        self.rec.log(ent.DEBLUR_REFUSED, rr.Scalars(float(refused.mean()) if refused is not None else 0.0))
        if self.level != "full":
            return
        # Where each pixel came from, and where a sharper neighbour was refused (shown even when none was used).
        classes = self._deblur_source_classes(result)
        self.rec.log(ent.DEBLUR_SOURCE, rr.SegmentationImage(classes) if classes.any() else rr.Clear(recursive=False))
        if not neighbours:  # nothing was sharpened: clear, so the viewer shows no stale frame from earlier
            for entity in (ent.DEBLUR_BEFORE, ent.DEBLUR_AFTER, ent.DEBLUR_WEIGHTS):
                self.rec.log(entity, rr.Clear(recursive=False))
            return
        self.rec.log(ent.DEBLUR_BEFORE, self._image(result.before))
        self.rec.log(ent.DEBLUR_AFTER, self._image(result.frame))
        weights = getattr(result, "weights", None)
        if weights is not None:
            # uint8 (255 = 1): a float32 map is 4x the bytes and does not compress; 1/255 is plenty to look at.
            quantised = np.clip(np.asarray(weights, np.float32) * ent.DEBLUR_WEIGHTS_SCALE + 0.5, 0, 255).astype(np.uint8)
            self.rec.log(ent.DEBLUR_WEIGHTS, rr.DepthImage(quantised, meter=ent.DEBLUR_WEIGHTS_SCALE, colormap="viridis",
                                                           depth_range=(0.0, ent.DEBLUR_WEIGHTS_SCALE)))

    def _on_output(self, stamp: Stamp, rgb: np.ndarray) -> None:
        self._trace(stamp, "output", rgb)
        self._set_time(stamp)
        self.rec.log(ent.OUTPUT_FRAME, self._image(rgb))

    # -- stage stepping ---------------------------------------------------------------------------

    def _set_traced(self, frames: Sequence[int]) -> None:
        self.traced = tuple(frames)
        self._send_blueprint()

    def _send_blueprint(self) -> None:
        if not self._blueprint_sent:
            self._blueprint_sent = True
            # Active too: it arrives after data, and the viewer would otherwise keep the layout it guessed from that.
            self.rec.send_blueprint(default_blueprint(self.traced), make_active=True, make_default=True)

    def _trace(self, stamp: Stamp, stage: str, rgb: np.ndarray) -> None:
        """Log a traced frame's image after ``stage`` on the ``stage`` timeline (frame = the traced frame)."""
        if stamp.index not in self.traced:
            return
        step = ent.TRACE_STAGES.index(stage)
        self._set_time(stamp)
        self.rec.set_time(ent.STAGE_TIMELINE, sequence=step)
        height, width = rgb.shape[:2]
        self.rec.log(ent.trace_image(stamp.index), self._image(rgb))
        self.rec.log(ent.trace_label(stamp.index), rr.Boxes2D(
            array=[0, 0, width, height], array_format=rr.Box2DFormat.XYWH, colors=[(255, 255, 255, 60)],
            labels=[trace.stage_label(stamp.index, step)], show_labels=True))
        self.rec.disable_timeline(ent.STAGE_TIMELINE)

    def _trace_completion(self, stamp: Stamp, result: CompletionResult) -> None:
        """Mosaic and local-warp stages, and the first neighbour's Fast Marching band (Fig. 18)."""
        self._trace(stamp, "mosaic", result.mosaic.frame)
        self._trace(stamp, "motion-inpainted", trace.local_warp_frame(result.mosaic.frame, result.frame,
                                                                       result.source == SOURCE_LOCAL_WARP))
        if not result.fills:
            return
        inpainted = result.fills[0].inpainted
        stabilized = np.where(result.missing[..., None], np.uint8(0), result.mosaic.frame)
        self._set_time(stamp)
        height, width = result.missing.shape
        for step, filled, total, image in trace.fmm_band_images(stabilized, inpainted.flow, inpainted.order):
            self.rec.set_time(ent.FMM_STEP_TIMELINE, sequence=step)
            self.rec.log(ent.trace_fmm(stamp.index), self._image(image))
            self.rec.log(ent.trace_fmm_label(stamp.index), rr.Boxes2D(
                array=[0, 0, width, height], array_format=rr.Box2DFormat.XYWH, colors=[(255, 255, 255, 60)],
                labels=[f"frame {stamp.index}: Fast Marching, {filled} of {total} pixels filled "
                        f"(neighbour {result.fills[0].offset:+d})"], show_labels=True))
        self.rec.disable_timeline(ent.FMM_STEP_TIMELINE)

    # -- helpers ----------------------------------------------------------------------------------

    def _set_time(self, stamp: Stamp) -> None:
        self.rec.set_time(ent.FRAME_TIMELINE, sequence=stamp.index)
        self.rec.set_time(ent.VIDEO_TIME_TIMELINE, duration=stamp.time_s)

    def _image(self, rgb: np.ndarray) -> Any:
        if self.jpeg_quality is None:
            return rr.Image(np.ascontiguousarray(rgb), color_model="RGB")
        # OpenCV's encoder: 2-3x faster than Image.compress (Pillow) on 640x360, the same JPEG quality scale.
        ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        return rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg")

    @staticmethod
    def _filled_by_legend(max_offset: int = 30) -> list:
        legend = [(0, "original", (0, 0, 0, 0)), (1, "mosaic", (40, 200, 90, 170)), (2, "fallback", (255, 200, 0, 200))]
        for offset in range(-max_offset, max_offset + 1):
            if offset:
                hue = (offset + max_offset) / (2 * max_offset)
                colour = tuple(int(255 * c) for c in (hue, 0.3, 1.0 - hue)) + (190,)
                legend.append((FILLED_BY_BASE + offset, f"neighbour {offset:+d}", colour))
        return legend

    @staticmethod
    def _deblur_source_classes(result: Any) -> np.ndarray:
        """Class per pixel: 0 the frame's own, 1 refused, FILLED_BY_BASE + offset the neighbour that gave most."""
        shape = result.frame.shape[:2]
        classes = np.zeros(shape, np.uint8)
        source = getattr(result, "main_source", None)
        if source is not None:
            taken = source != 0
            classes[taken] = (FILLED_BY_BASE + source[taken].astype(np.int16)).astype(np.uint8)
        refused = getattr(result, "refused", None)
        if refused is not None:
            classes[refused] = 1
        return classes

    @staticmethod
    def _deblur_source_legend(max_offset: int = 30) -> list:
        legend = [(0, "own frame", (0, 0, 0, 0)), (1, "refused: other content", (230, 40, 60, 200))]
        for offset in range(-max_offset, max_offset + 1):
            if offset:
                hue = (offset + max_offset) / (2 * max_offset)
                colour = tuple(int(255 * c) for c in (hue, 0.3, 1.0 - hue)) + (170,)
                legend.append((FILLED_BY_BASE + offset, f"from neighbour {offset:+d}", colour))
        return legend

    @staticmethod
    def _meta_markdown(info: Any, config: Any) -> str:
        return (f"# ffviz recording\n\n- ffviz {ffviz.__version__}\n- rerun-sdk {rr.__version__}\n"
                f"- input: `{info.path}` ({info.width}x{info.height}, {float(info.fps):.3f} fps, "
                f"{info.frame_count} frames)\n- config: `{config}`\n")

    def close(self) -> None:
        """Finish the file and move it into place."""
        if self._closed:
            return
        self._closed = True
        self._send_blueprint()
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
        self._closed = True
        self.rec.disconnect()
        self._tmp_path.unlink(missing_ok=True)
