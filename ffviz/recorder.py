"""The Rerun observer: maps each stage's result to the entity layout in ``ffviz.entities``.

It writes to its own RecordingStream (no global state), saved straight to a .rrd with the default
blueprint embedded. The file is written beside the target and renamed on success, like videos.
"""

from __future__ import annotations

import os
import tempfile
import uuid
from pathlib import Path
from typing import Any, Literal

import numpy as np
import rerun as rr

import ffviz
from ffviz import entities as ent, visual
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
    """

    def __init__(self, path: Path | str, *, level: RecordLevel = "full", jpeg_quality: int | None = 80,
                 application_id: str = "ffviz") -> None:
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
        self.rec.save(self._tmp_path, default_blueprint=default_blueprint())
        self._times: dict[int, float] = {}
        self._size = (0, 0)
        self._closed = False

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

    def _on_input(self, stamp: Stamp, frame: Frame) -> None:
        if self.level == "full":
            self._set_time(stamp)
            self.rec.log(ent.INPUT_FRAME, self._image(frame.rgb))

    def _on_warp(self, stamp: Stamp, result: WarpResult) -> None:
        if self.level == "full":
            self._set_time(stamp)
            self.rec.log(ent.STABILIZED_FRAME, self._image(result.frame))
            self.rec.log(ent.STABILIZED_MISSING, rr.SegmentationImage(result.missing.astype(np.uint8) * MISSING_CLASS))

    def _on_completion(self, stamp: Stamp, result: CompletionResult) -> None:
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

    def _on_output(self, stamp: Stamp, rgb: np.ndarray) -> None:
        self._set_time(stamp)
        self.rec.log(ent.OUTPUT_FRAME, self._image(rgb))

    # -- helpers ----------------------------------------------------------------------------------

    def _set_time(self, stamp: Stamp) -> None:
        self.rec.set_time(ent.FRAME_TIMELINE, sequence=stamp.index)
        self.rec.set_time(ent.VIDEO_TIME_TIMELINE, duration=stamp.time_s)

    def _image(self, rgb: np.ndarray) -> Any:
        image = rr.Image(np.ascontiguousarray(rgb), color_model="RGB")
        return image if self.jpeg_quality is None else image.compress(jpeg_quality=self.jpeg_quality)

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
    def _meta_markdown(info: Any, config: Any) -> str:
        return (f"# ffviz recording\n\n- ffviz {ffviz.__version__}\n- rerun-sdk {rr.__version__}\n"
                f"- input: `{info.path}` ({info.width}x{info.height}, {float(info.fps):.3f} fps, "
                f"{info.frame_count} frames)\n- config: `{config}`\n")

    def close(self) -> None:
        """Finish the file and move it into place."""
        if self._closed:
            return
        self._closed = True
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
