"""The Rerun observer: records a run to a .rrd in the entity layout of ``ffviz.entities``, with the default
blueprint embedded. The file is written beside the target and renamed on success, like videos.

Each frame's intermediates are digested on the rendering thread as soon as the frame is made (``keep``,
ffviz/recording/digest.py): pictures at the recorded size (``--record-size``), masks and maps encoded, statistics
from full resolution. The recorder's own thread (ffviz/recording/backlog.py, bounded in bytes) encodes the frame
streams in order and logs. Traced frames (``trace_frames``; by default a few with missing area, chosen once the
path is smoothed) are also logged stage by stage on the ``stage`` timeline.
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from pathlib import Path
from typing import Any, Literal, Sequence

import cv2
import numpy as np
import rerun as rr

from ffviz import entities as ent, trace
from ffviz.blueprint import TAB_NOTES, default_blueprint
from ffviz.recording import about, digest, legends
from ffviz.recording.backlog import BUDGET_BYTES, Backlog
from ffviz.recording.columns import ColumnBuffer, Row
from ffviz.recording.encoders import VideoTrack, png
from ffviz.recording.sink import RecordingFile
from ffviz.recording.view import RECORD_SIZE, ViewSize
from pipeline import geometry
from pipeline.errors import OutputError
from pipeline.results import FrameResult, PathComparison, PathPlan, Stamp
from pipeline.runtime.colour import ColourDescription
from pipeline.stages.adaptive_crop import AdaptiveCrop
from pipeline.stages.motion import MotionEstimate
from pipeline.stages.rolling_shutter import Correction
from pipeline.stages.smoothing import SmoothingResult
from pipeline.stages.warping import CropWindow

RecordLevel = Literal["summary", "full"]
RECORD_LEVELS: tuple[str, ...] = ("summary", "full")
MAX_FEATURE_ARROWS = 300  # enough to read the motion, few enough to keep files small
ROLLING_SHUTTER_GAIN = 5.0  # the bands' arrows are drawn this many times their length (shifts are a few px)
ROLLING_SHUTTER_BANDS = 8
# Chunks of up to 4 MB / 4096 rows. A file-only recording has no tick (it would make the file's size depend on the
# machine's speed: every flush writes each entity's schema again); a live view flushes every 2 s so that the viewer
# follows the run.
BATCHER = rr.ChunkBatcherConfig(flush_tick=3600.0, flush_num_bytes=4 << 20, flush_num_rows=4096)
LIVE_BATCHER = rr.ChunkBatcherConfig(flush_tick=2.0, flush_num_bytes=4 << 20, flush_num_rows=4096)
# The SDK holds what it was given until a flush (rerun 0.41: its batcher's byte limit does not bound it), so the
# recorder flushes each time this much was logged since the last: the SDK's part of the memory stays bounded.
FLUSH_BYTES = 8 << 20  # each flush adds a few kB of schemas per entity to the file: about 1 % at this size
# Per-frame rows (scalars, encoded pictures, video samples) are held and sent as one column per entity every this
# many frames (recording/columns.py): a log call's fixed cost paid once for them all; half a second behind live.
COLUMN_FRAMES = 16


class RerunRecorder:
    """Observer that records a run to ``path`` (.rrd).

    ``level``: "summary" records series and output frames; "full" adds every frame-sized intermediate.
    ``jpeg_quality``: None records images losslessly (raw frames, float maps); otherwise the frame streams are H.264
    video streams, float maps' values 16-bit steps, and the sparse pictures (flow, traced frames) JPEGs at this
    quality. Masks are lossless either way. ``record_size``: the recorded pictures' long side in pixels (None: the
    input's size). ``trace_frames``: frames to follow through every stage; None:
    ``trace.DEFAULT_TRACED`` frames with missing area at level "full", none at "summary". ``threaded``: log on a
    thread of the recorder's own, holding at most ``backlog_bytes`` of work; an error there surfaces at the next call
    or at ``close()``.
    """

    def __init__(self, path: Path | str, *, level: RecordLevel = "full", jpeg_quality: int | None = 80,
                 record_size: int | None = RECORD_SIZE, trace_frames: Sequence[int] | None = None,
                 application_id: str = "ffviz", live_url: str | None = None, threaded: bool = True,
                 backlog_bytes: int = BUDGET_BYTES) -> None:
        if level not in RECORD_LEVELS:
            raise ValueError(f"record level must be one of {', '.join(RECORD_LEVELS)}, not {level!r}")
        self.path = Path(path)
        self.level, self.jpeg_quality, self.record_size, self.live_url = level, jpeg_quality, record_size, live_url
        # Rows batched into chunks (BATCHER): a chunk per log call costs its schema (a few kB) each time. The default
        # blueprint follows once the traced frames are known.
        self._out = RecordingFile(self.path, application_id=application_id, live_url=live_url,
                                  batcher=BATCHER if live_url is None else LIVE_BATCHER)
        self.rec = self._out.rec
        self._key = f"rerun:{id(self)}"  # this recorder's digest in FrameResult.digests
        self._trace_requested = None if trace_frames is None else tuple(sorted({int(t) for t in trace_frames}))
        self.traced: tuple[int, ...] = self._trace_requested or ()
        self._spec = digest.Spec(level, jpeg_quality, ViewSize(0, 0, 1.0), ColourDescription(), self.traced)
        self._info: Any = None
        self._config: Any = None
        self._size = (0, 0)
        self._fps = 30.0
        self._times: dict[int, float] = {}
        self._tracks: dict[str, VideoTrack] = {}
        self._crop: Any = None
        self._adaptive: AdaptiveCrop | None = None
        self._planned: tuple[str, str] | None = None  # (planner, setting label) of the path the plan followed
        self._foreground_shown = False
        self._ignored_drawn: bytes | None = None  # the ignore mask last outlined (redrawn only when it changes)
        self._warnings = 0
        self._log_lines = 0  # lines logged to ent.LOG: the about tab shows their table only when there are any
        self._blueprint_sent = False
        self._closed = False
        self.seconds_logging = 0.0  # wall time the recorder's thread spent encoding and logging
        self.cpu_by_family: Counter = Counter()  # CPU seconds by entity family: digests and the recorder's thread
        self._backlog = Backlog(backlog_bytes) if threaded else None
        self.flush_bytes = FLUSH_BYTES
        self._unflushed = 0  # bytes logged since the SDK was last flushed
        self._columns = ColumnBuffer(self.rec, self._sent)  # per-frame rows, sent as columns every few frames
        self._frames_unsent = 0
        self._frames_planned: int | None = None  # the frames the path plan has (on_path)
        self._frames_handed = 0  # frames handed to on_frame so far
        self._video_done = False  # every frame handed over and the run past its frame loop: the video was written
        self.failed = False  # the recording could not be written (its OutputError raised)

    @property
    def lossless(self) -> bool:
        return self.jpeg_quality is None

    @property
    def started(self) -> bool:
        """The run has started (on_start): anything it failed on after that loses the recording too."""
        return self._info is not None

    @property
    def view(self) -> ViewSize:
        """The recorded pictures' size (known from on_start)."""
        return self._spec.view

    # -- handing work to the recorder's thread ----------------------------------------------------

    def _submit(self, nbytes: int, work, *args) -> None:
        if self._backlog is None:
            self._timed(work, *args)
            return
        try:
            self._backlog.put(nbytes, self._timed, work, *args)
        except Exception as error:  # noqa: BLE001 - the writer's failure, said in one line
            # The writer's thread may fail while the run is already past its last frame (the backlog still held
            # frames): the error surfaces at on_warning or on_finish, after the video was written.
            raise self._failure(error, during_run=not self._video_done) from error

    def _timed(self, work, *args) -> None:
        started = time.perf_counter()
        work(*args)
        self.seconds_logging += time.perf_counter() - started

    def _failure(self, error: BaseException, *, during_run: bool) -> OutputError:
        """The one-line error of a recording that could not be written (the temporary file is removed)."""
        self.failed = True
        self._abort_stream()
        reason = error.strerror if isinstance(error, OSError) and error.strerror else f"{type(error).__name__}: {error}"
        video = "the video was not written either" if during_run else "the video was written"
        return OutputError(f"cannot write the recording {self.path}: {reason}; {video}")

    def _check_file(self) -> None:
        """Stop at the first failed write to the file (a full disk), not at the end of the run."""
        if self._out.error is not None:
            raise self._out.error

    # -- Observer ---------------------------------------------------------------------------------

    def on_start(self, info: Any, config: Any) -> None:
        self._info, self._config = info, config
        self._size = (info.width, info.height)
        try:
            self._fps = float(info.fps) or 30.0
        except (TypeError, ValueError, AttributeError):
            self._fps = 30.0
        view = ViewSize.of(info.width, info.height, self.record_size)
        colour = getattr(info, "colour", None) or ColourDescription()
        self._spec = dataclasses.replace(self._spec, view=view, colour=colour)
        self._submit(0, self._log_start)

    def on_motion(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        self._times[stamp.index] = stamp.time_s
        self._submit(0, self._on_motion, stamp, estimate)

    def on_path(self, plan: PathPlan) -> None:
        self._frames_planned = len(plan.orig_from_out)
        self._choose_traced(plan.smoothing)  # here: the rendering threads' digests need them
        self._submit(0, self._on_path, plan)

    def keep(self, result: FrameResult) -> FrameResult:
        """On a rendering thread: the frame's digest at the recorded size, instead of its intermediates."""
        view = digest.digest(result, self._spec)
        return dataclasses.replace(result.without_intermediates(), digests={**result.digests, self._key: view})

    def on_frame(self, result: FrameResult) -> None:
        view = result.digests.get(self._key)
        if view is None:  # handed a result without going through keep (a single frame, a test)
            view = self.keep(result).digests[self._key]
        digest.finish(view, result, self._spec)
        self._submit(view.nbytes, self._write_frame, view)
        self._frames_handed += 1

    def on_warning(self, stamp: Stamp | None, message: str) -> None:
        # A warning once every frame was handed over comes after the video was closed (stabilize.run_passes).
        self._video_done = self._video_done or (self._frames_planned is not None
                                                and self._frames_handed >= self._frames_planned)
        self._submit(0, self._log_warning, stamp, message)

    def on_finish(self, report: Any) -> None:
        self._video_done = True  # run_passes closes the video before on_finish
        self._submit(0, self._log_meta, report)
        self.close()

    # -- the recorder's thread --------------------------------------------------------------------

    def _write_frame(self, view: digest.FrameView) -> None:
        """A frame's digest into the stream: its items at its time, its frame streams through their encoders."""
        self._check_file()
        self._adaptive_window(view.stamp)
        self.cpu_by_family.update(view.cpu)
        self._set_time(view.stamp)
        for item in view.logged:
            started = time.thread_time()
            if isinstance(item.archetype, Row):
                self._columns.add(item.entity, item.archetype, view.stamp.index, view.stamp.time_s, item.times)
            else:
                for timeline, sequence in item.times:
                    self.rec.set_time(timeline, sequence=sequence)
                self.rec.log(item.entity, item.loggable)
                for timeline, _ in item.times:
                    self.rec.disable_timeline(timeline)
            self.cpu_by_family[digest.family(item.entity)] += time.thread_time() - started
        self._unflushed += sum(item.nbytes for item in view.logged)
        for entity, rgb in view.streams:
            started = time.thread_time()
            track = self._tracks.get(entity)
            if track is None:
                track = self._tracks[entity] = VideoTrack(self.rec, entity, self._fps, self._columns)
            sent = track.bytes
            track.add(view.stamp, rgb)
            self._unflushed += track.bytes - sent
            self.cpu_by_family[entity] += time.thread_time() - started
        self._flush_when_due()

    def _flush_when_due(self) -> None:
        """Send the held rows every COLUMN_FRAMES frames, and hand the SDK's held data to the file once
        ``flush_bytes`` were logged since the last flush."""
        self._frames_unsent += 1
        if self._frames_unsent >= COLUMN_FRAMES or self._unflushed >= self.flush_bytes:
            self._send_columns()
        if self._unflushed >= self.flush_bytes:
            self.rec.flush()
            self._unflushed = 0

    def _send_columns(self) -> None:
        self._columns.send()
        self._frames_unsent = 0

    def _sent(self, entity: str, seconds: float) -> None:
        self.cpu_by_family[digest.family(entity)] += seconds

    def _log_start(self) -> None:
        self._log_meta()
        self.rec.log(ent.SIZES, rr.AnyValues(input_size=np.array(self._size, np.int32),
                                             recorded_size=np.array([self.view.width, self.view.height], np.int32)),
                     static=True)
        if self.live_url is not None:  # the layout from the first frame on; again once the traced frames are known
            self.rec.send_blueprint(default_blueprint(self._trace_requested or (), **self._layout_flags),
                                    make_active=True, make_default=True)
        for entity, (legend, _) in legends.class_legends().items():
            self.rec.log(entity, rr.AnnotationContext(legend), static=True)
        for name, image in legends.colour_keys().items():
            self.rec.log(ent.key_entity(name), rr.EncodedImage(contents=png(image), media_type="image/png"),
                         static=True)
        for tab, text in TAB_NOTES.items():
            self.rec.log(ent.note_entity(tab), rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
        for entity, (name, colour, width) in legends.SERIES_STYLES.items():
            self.rec.log(entity, rr.SeriesLines(names=name, colors=[colour], widths=width), static=True)

    def _log_line(self, line: rr.TextLog, static: bool = False) -> None:
        self._log_lines += 1
        self.rec.log(ent.LOG, line, static=static)

    def _log_warning(self, stamp: Stamp | None, message: str) -> None:
        self._warnings += 1
        if stamp is not None:
            self._set_time(stamp)
        self._log_line(rr.TextLog(message, level=rr.TextLogLevel.WARN), static=stamp is None)

    # -- pass 1: motion ---------------------------------------------------------------------------

    def _on_motion(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        started = time.thread_time()
        self._set_time(stamp)
        width, height = self._size
        dx, dy, angle, scale = geometry.decompose(estimate.curr_from_prev, width, height)
        for name, value in zip(ent.MOTION_PARAM_NAMES, (dx, dy, angle, scale)):
            self._scalar(stamp, f"{ent.MOTION_PARAMS}/{name}", value)
        self._scalar(stamp, ent.MOTION_INLIERS, estimate.n_inliers)
        self._scalar(stamp, ent.MOTION_INLIER_RATIO, estimate.inlier_ratio)
        self._scalar(stamp, ent.MOTION_RESIDUAL, estimate.residual_px)
        self._columns.add(ent.MOTION_STATUS, Row(rr.TextLog, {"text": estimate.status}), stamp.index, stamp.time_s)
        if self.level == "full" and len(estimate.curr_points):
            self._features(estimate)
        elif self.level == "full":  # no tracks (none found): none left from the frame before
            for child in ("points", "arrows"):
                self.rec.log(f"{ent.MOTION_FEATURES}/{child}", rr.Clear(recursive=False))
        self._on_foreground(estimate)
        self._on_camera_choice(stamp, estimate)
        self._on_ignored(estimate.ignored)
        self.cpu_by_family[digest.MOTION_FAMILY] += time.thread_time() - started
        self._flush_when_due()  # its sending counted under each entity's family

    def _scalar(self, stamp: Stamp, entity: str, value: float) -> None:
        self._columns.add(entity, Row(rr.Scalars, {"scalars": float(value)}), stamp.index, stamp.time_s)

    def _features(self, estimate: MotionEstimate) -> None:
        """Tracked corners (green inliers, red outliers) and prev -> curr arrows, in recorded pixels."""
        colours = np.where(estimate.inliers[:, None], [[60, 220, 90]], [[240, 60, 60]]).astype(np.uint8)
        curr = self.view.points(estimate.curr_points)
        self.rec.log(f"{ent.MOTION_FEATURES}/points", rr.Points2D(curr, colors=colours, radii=1.5))
        step = max(1, len(curr) // MAX_FEATURE_ARROWS)
        prev = self.view.points(estimate.prev_points[::step])
        self.rec.log(f"{ent.MOTION_FEATURES}/arrows", rr.Arrows2D(
            origins=prev, vectors=curr[::step] - prev, colors=colours[::step]))

    def _on_foreground(self, estimate: MotionEstimate) -> None:
        """The other motions' tracks (moving figures', or RANSAC's winner's when that was a figure), orange over the
        green and red ones (full level), and a log line where the camera took another motion than RANSAC's."""
        if estimate.chose_other:
            self._log_line(rr.TextLog("the tracks most agree on move with a foreground figure: the camera "
                                      "follows another motion (orange: the figures')", level=rr.TextLogLevel.INFO))
        if self.level != "full":
            return
        points = [other.curr_points for other in estimate.others if len(other.curr_points)]
        if points:
            self.rec.log(ent.MOTION_FOREGROUND, rr.Points2D(self.view.points(np.concatenate(points)),
                                                            colors=legends.FOREGROUND_COLOUR, radii=2.5))
            self._foreground_shown = True
        elif self._foreground_shown:
            self.rec.log(ent.MOTION_FOREGROUND, rr.Clear(recursive=False))
            self._foreground_shown = False

    def _on_camera_choice(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        """Which motion the camera took and why (pipeline/stages/background.py): the evidence for it against the best
        other motion in log-odds, charted, and a line naming the motion and what weighed most."""
        choice = estimate.camera
        if choice is None:
            return
        for name in ent.MOTION_CAMERA_EVIDENCE:
            self._scalar(stamp, f"{ent.MOTION_CAMERA}/{name}", getattr(choice, name))
        if choice.rule == "one motion":
            line = "one motion found: the camera's"
        else:
            count = len(choice.behind)
            taken = f"motion {choice.taken + 1} of {count} ({'RANSAC' if choice.taken == 0 else 'another'}'s; " \
                    "orange: the others')"
            carried = choice.carried or (0,) * count
            votes = ", ".join(f"{b} behind/{f} in front" + (f" (tracked on {k} pair{'s' * (k > 1)})" if k else "")
                              for b, f, k in zip(choice.behind, choice.in_front, carried))
            line = (f"camera: {taken}; decided by {choice.rule} (log-odds for it: occlusion {choice.occlusion:+.1f}, "
                    f"the frames around it {choice.linked:+.1f}; occlusion px of each motion: {votes})")
            if choice.lost:
                line += "; the camera's layer of the frame before goes on as no motion here (lost): a switch of layer"
        self._columns.add(ent.MOTION_CAMERA_RULE, Row(rr.TextLog, {"text": line}), stamp.index, stamp.time_s)

    def _on_ignored(self, ignored: np.ndarray | None) -> None:
        """Outline of where features were not used (--ignore boxes, --ignore-mask), logged when it changes."""
        key = None if ignored is None or not ignored.any() else np.packbits(ignored).tobytes()
        if key == self._ignored_drawn:
            return
        self._ignored_drawn = key
        if key is None:
            self.rec.log(ent.MOTION_IGNORED, rr.Clear(recursive=False))
            return
        mask = cv2.resize(ignored.view(np.uint8), (self.view.width, self.view.height), interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        strips = [np.vstack([c.reshape(-1, 2), c.reshape(-1, 2)[:1]]).astype(np.float32) for c in contours]
        self.rec.log(ent.MOTION_IGNORED, rr.LineStrips2D(strips, colors=legends.IGNORED_COLOUR, radii=1.5))

    # -- the path ---------------------------------------------------------------------------------

    def _choose_traced(self, smoothing: SmoothingResult) -> None:
        n = len(smoothing.orig_from_stab)
        if self._trace_requested is None:
            count = trace.DEFAULT_TRACED if self.level == "full" else 0
            traced = trace.default_trace_frames(smoothing.orig_from_stab, *self._size, count=count)
        else:
            traced = [t for t in self._trace_requested if t < n]
        self.traced = tuple(traced)
        self._spec = dataclasses.replace(self._spec, traced=self.traced)

    def _on_path(self, plan: PathPlan) -> None:
        self._send_columns()  # the motion pass's rows
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
        if self.live_url is not None:  # a file is read whole: its layout is sent once, at the end
            self._send_blueprint()

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
        beyond = [t for t in self._trace_requested or () if t >= n]
        if beyond:
            self._log_line(rr.TextLog(f"traced frame(s) {', '.join(map(str, beyond))} not in the clip's {n} "
                                      "frames: not traced", level=rr.TextLogLevel.WARN), static=True)

    def _on_paths(self, paths: PathComparison) -> None:
        """Eq. 18's and the L1 path beside the run's own (the trajectory views), and in crop mode each frame's
        crop-window constraint: the output's corners on the input frame, and their room inside it (px)."""
        indexes = self._frame_indexes(len(paths.gaussian))
        self._send_trajectories(indexes, (ent.TRAJECTORY_GAUSSIAN, paths.gaussian), (ent.TRAJECTORY_L1, paths.l1))
        if paths.crop_room_px is not None:
            self.rec.send_columns(ent.CROP_ROOM, indexes=indexes, columns=rr.Scalars.columns(scalars=paths.crop_room_px))
        if paths.crop_corners is not None:
            for t, corners in enumerate(self.view.points(paths.crop_corners)):
                self._set_time(Stamp(t, self._times.get(t, 0.0)))
                self.rec.log(ent.CROP_CONSTRAINT, rr.LineStrips2D([np.vstack([corners, corners[:1]])],
                                                                  colors=[legends.CROP_COLOUR], radii=1.0))

    def _on_rolling_shutter(self, correction: Correction) -> None:
        """--rolling-shutter: the readout time (log), each frame's bottom band shifted against its top band (series)
        and, at full level, arrows from every band's middle-row position to where its rows saw it (x5)."""
        width, height = self._size
        self._log_line(rr.TextLog(f"rolling shutter: readout {correction.readout:.2f} of the frame interval",
                                  level=rr.TextLogLevel.INFO), static=True)
        xs = np.linspace(0.1, 0.9, 5) * (width - 1)
        skew = []
        for t, rows in enumerate(correction.rows):
            centres, bands = rows.bands(ROLLING_SHUTTER_BANDS)
            origins = np.array([(x, y) for y in centres for x in xs])
            moved = np.concatenate([geometry.apply(band, [(x, y) for x in xs]) for band, y in zip(bands, centres)])
            skew.append(moved[-3] - moved[2] - (origins[-3] - origins[2]))  # centre column, last band - first
            if self.level == "full":
                self._set_time(Stamp(t, self._times.get(t, 0.0)))
                self.rec.log(ent.ROLLING_SHUTTER_BANDS, rr.Arrows2D(
                    origins=self.view.points(origins), vectors=self.view.points(moved - origins) * ROLLING_SHUTTER_GAIN,
                    colors=legends.ROLLING_SHUTTER_COLOUR))
        indexes = self._frame_indexes(len(correction.rows))
        for column, (axis, colour) in enumerate((("dx", (0, 220, 255)), ("dy", (255, 110, 200)))):
            entity = f"{ent.ROLLING_SHUTTER_SKEW}/{axis}"
            self.rec.log(entity, rr.SeriesLines(names=f"bottom - top, {axis[1]} (px)", colors=[colour], widths=2.0),
                         static=True)
            self.rec.send_columns(entity, indexes=indexes, columns=rr.Scalars.columns(scalars=np.array(skew)[:, column]))

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

    # -- crop mode --------------------------------------------------------------------------------

    def _on_crop(self, crop: CropWindow) -> None:
        """--mode crop: the window of the stabilized frame that becomes the output (static, drawn over it)."""
        self._crop = crop
        width, height = self._size
        box = self.view.points([crop.x0, crop.y0, crop.scale * width, crop.scale * height])
        self.rec.log(ent.CROP_WINDOW, rr.Boxes2D(
            array=box, array_format=rr.Box2DFormat.XYWH, colors=[legends.CROP_COLOUR], radii=1.5,
            labels=[f"crop window: {crop.cropping_ratio:.0%} of the area, scaled x{1 / crop.scale:.3f} to the output"],
            show_labels=True), static=True)
        self._log_meta()

    def _on_crop_scales(self, scales: np.ndarray) -> None:
        """--mode crop: the window's scale per frame (constant for one window; --crop adaptive's follows the path)."""
        self.rec.send_columns(ent.CROP_SCALE, indexes=self._frame_indexes(len(scales)),
                              columns=rr.Scalars.columns(scalars=scales))

    def _adaptive_window(self, stamp: Stamp) -> None:
        """--crop adaptive: this frame's window of the stabilized frame, drawn over it."""
        crop = self._adaptive
        if crop is None:
            return
        width, height = self._size
        scale = float(crop.scales[min(stamp.index, len(crop.scales) - 1)])
        x0, y0 = crop.anchor[0] - scale * (width - 1) / 2.0, crop.anchor[1] - scale * (height - 1) / 2.0
        self._set_time(stamp)
        self.rec.log(ent.CROP_WINDOW, rr.Boxes2D(
            array=self.view.points([x0, y0, scale * width, scale * height]), array_format=rr.Box2DFormat.XYWH,
            colors=[legends.CROP_COLOUR], radii=1.5, labels=[f"crop window: {scale ** 2:.0%} of the area (adaptive)"],
            show_labels=True))

    # -- layout, about tab, closing ---------------------------------------------------------------

    @property
    def _layout_flags(self) -> dict[str, bool]:
        """The run's options that add views to the layout (blueprint.default_blueprint's flags)."""
        width, height = self._size
        return {"crop": getattr(self._config, "mode", None) == "crop",
                "rolling_shutter": getattr(self._config, "rolling_shutter", None) is not None,
                "log": self._log_lines > 0 or not self._closed,  # while running, lines may still come
                "portrait": height > width}

    def _send_blueprint(self) -> None:
        """The layout, once the traced frames are known (live) and again, final, at the end."""
        if self._closed or not self._blueprint_sent:
            self._blueprint_sent = True
            # Active too: it arrives after data, and the viewer would otherwise keep the layout it guessed from that.
            self.rec.send_blueprint(default_blueprint(self.traced, **self._layout_flags), make_active=True,
                                    make_default=True)

    def _set_time(self, stamp: Stamp) -> None:
        self.rec.set_time(ent.FRAME_TIMELINE, sequence=stamp.index)
        self.rec.set_time(ent.VIDEO_TIME_TIMELINE, duration=stamp.time_s)

    def _recording_words(self) -> str:
        stored = ("lossless images (`--lossless`)" if self.lossless else "frame streams as H.264 video, masks as "
                  "lossless PNG, maps as colour-mapped PNG with their values in 16-bit steps")
        width, height = self._size
        size = self.view.describe(width, height) if width else "at the input's size"
        return (f"`--record {self.level}`, {stored}; pictures {size} (`--record-size`; statistics and charts from "
                "the full-resolution results)")

    def _log_meta(self, report: Any = None) -> None:
        """The about tab: a readable summary of the run, rewritten (static) as more becomes known."""
        text = about.about_markdown(self._info, self._config, report=report, crop=self._crop, warnings=self._warnings,
                                    recording=self._recording_words(), seconds_logging=self.seconds_logging,
                                    planned=self._planned)
        self.rec.log(ent.META, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)

    def close(self) -> None:
        """Finish the file and move it into place. A failure to write it raises OutputError (one line; the
        temporary file removed)."""
        if self._closed:
            return
        try:
            if self._backlog is not None:
                self._backlog.close()
            self._closed = True
            self._send_blueprint()
            for track in self._tracks.values():
                track.close()
            self._send_columns()
            self._out.finish()
        except Exception as error:  # noqa: BLE001 - the writer's failure, said in one line
            raise self._failure(error, during_run=False) from error

    def abort(self) -> None:
        """Drop the recording: nothing half-written is left behind."""
        if self._backlog is not None:
            self._backlog.close(drop=True)
        self._abort_stream()

    def _abort_stream(self) -> None:
        self._closed = True
        self._out.drop()
