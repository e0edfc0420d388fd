"""The one definition of what happens to the whole path and to each frame, used by every runner (single process,
segment-parallel, batch): ``plan_path`` turns pass 1's estimates into the path plan (eq. 18 or L1 smoothing,
the output transform, the crop window), and ``FrameChain`` turns one frame and its window of neighbours into
one FrameResult: warp (eq. 19) -> completion (chapter 4: full mode, and crop mode where its window leaves the frame)
-> deblurring (chapter 5) -> output.

Invariants: a frame's result depends only on the plan and the frames within ``config.window_frames`` of it
(never on other frames' results), so frames can be rendered in any order, on threads or in segments, and come
out identical; neighbours are taken from the frame's own shot only (nothing crosses a scene cut).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import threading
import time
from typing import Callable, Iterable, Iterator

from pipeline.config import StabilizeConfig
from pipeline import geometry
from pipeline.results import FrameResult, MotionPass, PathComparison, PathPlan, Stamp
from pipeline.frames import Frame
from pipeline.runtime import parallel
from pipeline.runtime.source import FrameSource, one_pass
from pipeline.runtime.window import RENDER_SLACK_FRAMES, Windowed, sliding_window
from pipeline.stages import adaptive_crop, completion, deblur, neighbours, rolling_shutter, smoothing, temporal, warping
from pipeline.stages.per_frame import PerFrame

import numpy as np

SINGLE_FRAME_WARNING = "only one frame: there is no motion to smooth, written as it is"
NO_CROP_WARNING = "no area is common to all stabilized frames: crop disabled, borders left black"
CROP_FILL_WARNING = ("the crop window leaves the frames by more than --crop-fill even at {scale:.2f} of the frame: "
                     "{share:.1%} of the output is completed, not {fill:.1%} (a smaller -k keeps the path nearer its "
                     "frames)")
# Crop mode's L1 window without --crop-scale is first tried at the one eq. 18's path at this radius keeps. --path l1:
# the room the shake within about half a second needs, about what vid.stab's defaults keep (docs/decisions.md D26).
# --path auto (crop mode's default with its window inside every frame) also prices the path's shake
# (l1_path.L1PathConfig.shake_weight) at AUTO_SHAKE_WEIGHT, five times Grundmann et al.'s weight of jerk, and so needs
# less room, that of a third of a second: on most shared clips its path in that wider window is steadier than the L1
# path without the term in the narrower one (D33).
L1_WINDOW_RADIUS_FRAMES = 15
AUTO_WINDOW_RADIUS_FRAMES = 10
AUTO_SHAKE_WEIGHT = 500.0


def plan_path(motion_pass: MotionPass, config: StabilizeConfig, width: int, height: int) -> PathPlan:
    """Smooth the whole path (it is tiny: one 3x3 matrix a frame) and choose each output frame's transform, with
    the other planner's path beside it for display made on request (``PathPlan.paths()``: a second solve, which
    only recordings and figures want).
    With rolling-shutter correction, the path is that of the corrected views (each frame's middle row's)."""
    plan = _plan(motion_pass, config, width, height)
    return dataclasses.replace(plan, paths=functools.partial(_compare_paths, plan, config, width, height))


def _compare_paths(plan: PathPlan, config: StabilizeConfig, width: int, height: int) -> PathComparison:
    """Eq. 18's and the L1 path's trajectories on the same motion (the run's own where it follows one of them
    alone; for crop mode's auto, the one it chose) and, in crop mode, where each output frame's corners lie in its
    input frame."""
    curr_from_prev = (plan.motion.curr_from_prev if plan.rolling_shutter is None
                      else plan.rolling_shutter.curr_from_prev)
    own = config.smoothing
    trajectories = {}
    for path in ("gaussian", "l1"):
        if plan.smoothing.planner == path and not own.segments:
            trajectories[path] = plan.smoothing.smoothed_trajectory
        else:
            other = dataclasses.replace(own, path=path, segments=())
            trajectories[path] = smoothing.smooth(curr_from_prev, other, cuts=plan.motion.cuts, width=width,
                                                  height=height).smoothed_trajectory
    corners = room = None
    if config.mode == "crop":
        outline = geometry.frame_corners(width, height)
        corners = np.stack([geometry.apply(m, outline) for m in plan.orig_from_out])
        room = np.minimum(np.minimum(corners[..., 0], width - 1 - corners[..., 0]),
                          np.minimum(corners[..., 1], height - 1 - corners[..., 1])).min(axis=1)
    return PathComparison(trajectories["gaussian"], trajectories["l1"], corners, room)


def _plan(motion_pass: MotionPass, config: StabilizeConfig, width: int, height: int) -> PathPlan:
    """plan_path without the comparison."""
    if config.rolling_shutter is None or motion_pass.tracks is None:
        return _plan_views(motion_pass, config, width, height)
    correction = rolling_shutter.estimate(motion_pass.curr_from_prev, motion_pass.tracks, config.rolling_shutter,
                                          height, config.motion.model)
    corrected = dataclasses.replace(motion_pass, curr_from_prev=correction.curr_from_prev)
    plan = _plan_views(corrected, config, width, height)
    if plan.crop is not None and config.crop_fill == 0:  # the window must also avoid what the rows' views leave
        # uncovered (a window that may leave the frames has what they leave uncovered completed)
        valid = np.stack([rows.valid_box(width) for rows in correction.rows])
        crop = warping.largest_crop(plan.smoothing.orig_from_stab, width, height, valid=valid)
        stab = plan.smoothing.orig_from_stab
        warnings = plan.warnings + ([NO_CROP_WARNING] if crop is None else [])
        plan = dataclasses.replace(plan, crop=crop, orig_from_out=stab if crop is None else stab @ crop.stab_from_out,
                                   warnings=warnings)
    if plan.adaptive_crop is not None:  # the same for each frame's window
        valid = np.stack([rows.valid_box(width) for rows in correction.rows])
        adaptive = adaptive_crop.adaptive_crop(plan.smoothing.orig_from_stab, width, height,
                                               zoom_speed=config.crop.zoom_speed,
                                               segment_starts=plan.smoothing.segment_starts, valid=valid)
        stab = plan.smoothing.orig_from_stab
        plan = dataclasses.replace(plan, adaptive_crop=adaptive,
                                   orig_from_out=stab if adaptive is None else stab @ adaptive.stab_from_out)
    return dataclasses.replace(plan, motion=motion_pass, rolling_shutter=correction)


def _plan_views(motion_pass: MotionPass, config: StabilizeConfig, width: int, height: int) -> PathPlan:
    """plan_path for frames each seen from one camera position."""
    smoothed = smoothing.smooth(motion_pass.curr_from_prev, config.smoothing, cuts=motion_pass.cuts,
                                width=width, height=height, times_s=motion_pass.times_s)
    if config.mode == "crop" and config.smoothing.uses_l1:
        smoothed = _l1_in_crop_window(motion_pass, config, width, height, smoothed)
    warnings = [SINGLE_FRAME_WARNING] if motion_pass.n_frames == 1 else []
    warnings += smoothing.path_warnings(smoothed, config.smoothing)
    orig_from_out, crop = smoothed.orig_from_stab, None
    if config.mode == "crop" and config.crop.kind == "adaptive":
        adaptive = adaptive_crop.adaptive_crop(smoothed.orig_from_stab, width, height,
                                               zoom_speed=config.crop.zoom_speed,
                                               segment_starts=smoothed.segment_starts)
        if adaptive is None:
            warnings.append(NO_CROP_WARNING)
            return PathPlan(motion_pass, smoothed, orig_from_out, None, warnings)
        return PathPlan(motion_pass, smoothed, smoothed.orig_from_stab @ adaptive.stab_from_out, None, warnings,
                        adaptive_crop=adaptive)
    if config.crop_fill > 0:  # a window that may leave the frames by the fill, completed there
        crop, share = warping.window_for_fill(smoothed.orig_from_stab, width, height, config.crop_fill)
        orig_from_out = smoothed.orig_from_stab @ crop.stab_from_out
        if share > config.crop_fill:  # the path departs from its frames by more than the smallest window
            warnings.append(CROP_FILL_WARNING.format(scale=crop.scale, share=share, fill=config.crop_fill))
    elif config.mode == "crop":
        crop = warping.largest_crop(smoothed.orig_from_stab, width, height)
        if crop is None:
            warnings.append(NO_CROP_WARNING)
        else:
            orig_from_out = smoothed.orig_from_stab @ crop.stab_from_out
    return PathPlan(motion_pass, smoothed, orig_from_out, crop, warnings)


def _l1_in_crop_window(motion_pass: MotionPass, config: StabilizeConfig, width: int, height: int,
                       free: smoothing.SmoothingResult) -> smoothing.SmoothingResult:
    """The L1 program with Grundmann et al.'s crop-window constraint: a window stays inside every input frame and
    within it the path is as smooth as the program can make it (for auto, with the shake priced at
    AUTO_SHAKE_WEIGHT over the jitter measure's half second). The window: the centred one of --crop-scale, or
    the widest that leaves the path at least as steady as eq. 18's at the run's radius (by ``_shake_px``), tried
    from the window eq. 18's path at L1_WINDOW_RADIUS_FRAMES (auto: AUTO_WINDOW_RADIUS_FRAMES) keeps to eq. 18's
    own. Where none does, the l1 path takes eq. 18's window and the auto path is eq. 18's.
    ``free``: the run's path without the window (eq. 18's for auto; returned if no window fits)."""
    auto = config.smoothing.path == "auto"
    l1_config = dataclasses.replace(config.smoothing, path="l1") if auto else config.smoothing
    if auto:  # the shake over the jitter measure's half second, in frames
        l1_config = dataclasses.replace(l1_config, l1=dataclasses.replace(
            l1_config.l1, shake_weight=AUTO_SHAKE_WEIGHT, shake_sigma_frames=_fps(motion_pass.times_s) / 2.0))

    def solve(window: tuple[float, tuple[float, float]], zoom_in: float = 0.0) -> smoothing.SmoothingResult:
        l1 = dataclasses.replace(l1_config.l1, crop_scale=window[0], crop_offset=window[1], crop_zoom_in=zoom_in)
        return smoothing.smooth(motion_pass.curr_from_prev, dataclasses.replace(l1_config, l1=l1),
                                cuts=motion_pass.cuts, width=width, height=height, times_s=motion_pass.times_s)

    if config.crop.scale is not None:
        return solve((config.crop.scale, (0.0, 0.0)))
    windows, reference = [], None  # (scale, offset, how far eq. 18's path zooms in)
    run_radius = config.smoothing.radius_frames
    first = AUTO_WINDOW_RADIUS_FRAMES if auto else L1_WINDOW_RADIUS_FRAMES
    for radius in dict.fromkeys((first, (first + run_radius) // 2, run_radius)):
        eq18 = smoothing.smooth(motion_pass.curr_from_prev, dataclasses.replace(
            config.smoothing, path="gaussian", radius_frames=radius, sigma=None, smoothness=None, segments=()),
            cuts=motion_pass.cuts, width=width, height=height)
        needed = warping.largest_crop(eq18.orig_from_stab, width, height)
        if needed is not None:
            cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
            zoom_in = -float(np.log(np.sqrt(np.abs(np.linalg.det(eq18.orig_from_stab[:, :2, :2])))).min())
            windows.append((needed.scale, (needed.x0 + needed.scale * cx - cx, needed.y0 + needed.scale * cy - cy),
                            max(zoom_in, 0.0)))
        reference = eq18
    if not windows:
        return free
    steadiness = _shake_px(reference.smoothed_trajectory, motion_pass.times_s)
    for scale, offset, zoom_in in sorted(windows, reverse=True)[:None if auto else -1]:
        planned = solve((scale, offset), zoom_in)
        if _shake_px(planned.smoothed_trajectory, motion_pass.times_s) <= steadiness:
            return planned
    if auto:  # eq. 18's path, labelled as such in the recording
        return dataclasses.replace(free, settings=(dataclasses.replace(config.smoothing, path="gaussian").label(),
                                                   *free.settings[1:]))
    scale, offset, zoom_in = min(windows)
    return solve((scale, offset), zoom_in)


def _shake_px(trajectory: np.ndarray, times_s: list[float]) -> float:
    """RMS of a trajectory's x and y (px) above a Gaussian low-pass of half a second: the shake left in a path
    (the high-pass pipeline.evaluation.metrics' residual jitter takes of a video's motion)."""
    from scipy.ndimage import gaussian_filter1d

    xy = np.asarray(trajectory, np.float64)[:, :2]
    return float(np.sqrt(np.mean(np.sum((xy - gaussian_filter1d(xy, _fps(times_s) / 2.0, axis=0, mode="nearest"))
                                        ** 2, axis=1)))) if len(xy) > 1 else 0.0


def _fps(times_s: list[float]) -> float:
    """Frames a second from the frames' times (30 when they do not tell)."""
    return (len(times_s) - 1) / (times_s[-1] - times_s[0]) if len(times_s) > 1 and times_s[-1] > times_s[0] else 30.0


def temporal_radius(config: StabilizeConfig) -> int:
    """Frames on each side whose completed frames temporal consistency averages into a frame (0: it does not run)."""
    return config.completion.temporal.radius if config.completing else 0


def frames_read(config: StabilizeConfig, frames: range, n_frames: int) -> range:
    """The input frames render_frames reads to make ``frames`` of an ``n_frames`` video: the frames temporal
    consistency averages in are rendered too, each with its window."""
    margin = temporal_radius(config) + config.window_frames
    return range(max(frames.start - margin, 0), min(frames.stop + margin, n_frames))


class FrameChain:
    """One frame and its window -> one FrameResult. Safe to call from several threads at once: it only reads the
    window and the plan (the caches it keeps are locked)."""

    def __init__(self, plan: PathPlan, config: StabilizeConfig, *,
                 keep: Callable[[FrameResult], FrameResult] | None) -> None:
        self.config = config
        self.rows = plan.rolling_shutter.rows if plan.rolling_shutter is not None else None
        self.curr_from_prev = (plan.motion.curr_from_prev if plan.rolling_shutter is None
                               else plan.rolling_shutter.curr_from_prev)
        # Crop mode with a fill completes in its window's coordinates: its output frames are the stabilized frames.
        self.orig_from_stab = plan.orig_from_out if config.crop_fill > 0 else plan.smoothing.orig_from_stab
        self.orig_from_out = plan.orig_from_out
        # Crop mode with a fill keeps (for recordings) the stabilized frame its window is cut from, not the window.
        self.orig_from_uncropped = plan.smoothing.orig_from_stab if config.crop_fill > 0 else None
        self.shot_of = np.searchsorted(plan.smoothing.segment_starts, np.arange(len(self.orig_from_stab)),
                                       side="right") - 1
        # None: each frame's result holds only what the run needs; else a frame's full result goes through keep (an
        # observer's Observer.keep) as soon as it is made, and the run holds what that returns
        self.keep = keep
        # completion's temporal consistency (smoothed_stream) holds each frame's completed frame and mask (FrameResult.
        # completed) until the frames next to it are made, whether intermediates are kept or not
        self.temporal_radius = temporal_radius(config)
        self.energy_cache = deblur.EnergyCache()  # each frame's gradients computed once while it is in the window
        self.downscaled: neighbours.Downscaled | None = None  # frames at completion's flow resolution
        # --rolling-shutter: completion and deblurring draw on frames corrected to their middle rows' views
        self.middle_row_views = PerFrame(lambda item: rolling_shutter.middle_row_view(item[1], self.rows[item[0]]))
        self._downscaled_lock = threading.Lock()

    def _downscaled(self, shape: tuple[int, int], t: int) -> neighbours.Downscaled | None:
        """The frames at local flow's working resolution (each shrunk once for all the frames it is a neighbour
        of); None when that is full resolution."""
        scale = completion.flow_scale(shape, self.config.completion)
        if scale >= 1.0:
            return None
        size = (max(round(shape[1] * scale), 1), max(round(shape[0] * scale), 1))
        with self._downscaled_lock:
            if self.downscaled is None or self.downscaled.size != size:
                self.downscaled = neighbours.Downscaled(size)
            downscaled = self.downscaled
        downscaled.forget_before(t - self.config.completion_frames - RENDER_SLACK_FRAMES)
        return downscaled

    def __call__(self, window: Windowed[Frame]) -> FrameResult:
        config = self.config
        frame = window.centre
        t = min(frame.index, len(self.orig_from_stab) - 1)  # decoding is deterministic: pass 2 sees pass 1's frames
        cpu: dict[str, float] = {}
        clock = time.thread_time()

        def lap(stage: str) -> None:
            nonlocal clock
            now = time.thread_time()
            cpu[stage] = cpu.get(stage, 0.0) + now - clock
            clock = now

        # Crop mode with its window inside every frame writes its own warp (by orig_from_out): the stabilized frame is
        # made there only to be kept.
        stabilized = None
        rows = self.rows[t] if self.rows is not None else None
        if config.mode != "crop" or config.completing or self.keep:
            stabilized = rolling_shutter.warp_frame(frame.rgb, self.orig_from_stab[t], rows)
        same_shot = {n.index: n.rgb for n in window.neighbours.values()
                     if n.index < len(self.shot_of) and self.shot_of[n.index] == self.shot_of[t]}
        original = frame.rgb  # what completion and deblurring see of frame t (and same_shot of its neighbours)
        if self.rows is not None and (config.completing or config.deblurring):
            self.middle_row_views.forget_before(t - config.window_frames - RENDER_SLACK_FRAMES)
            same_shot = {i: self.middle_row_views.get(i, (i, rgb)) for i, rgb in same_shot.items()}
            original = self.middle_row_views.get(t, (t, frame.rgb))
        warped: list[neighbours.WarpedNeighbour] = []
        completed = None
        if config.completing and (config.mode == "full" or stabilized.missing.any()):
            near = {i: rgb for i, rgb in same_shot.items() if abs(i - t) <= config.completion_frames}
            downscaled = self._downscaled(frame.rgb.shape[:2], t)
            warped = neighbours.warp_neighbours(near, t, self.curr_from_prev, self.orig_from_stab[t],
                                                downscaled=downscaled)
            itself = neighbours.warp_neighbours({t: original}, t, self.curr_from_prev, self.orig_from_stab[t],
                                                downscaled=downscaled)[0]
            lap("warp")
            completed = completion.complete(stabilized.frame, stabilized.missing, warped, config.completion,
                                            target_original=itself)
            lap("completion")
            output, output_valid = completed.frame, None
        elif config.completing:  # crop mode's window inside this frame: nothing to complete
            output, output_valid = stabilized.frame, None
            lap("warp")
        elif config.mode == "crop":
            output = (warping.warp(frame.rgb, self.orig_from_out[t]) if rows is None
                      else rolling_shutter.warp_frame(frame.rgb, self.orig_from_out[t], rows).frame)
            output_valid = None
            lap("warp")
        else:
            output, output_valid = stabilized.frame, ~stabilized.missing
            lap("warp")
        deblurred = None
        if config.deblurring:
            # Last, on the frame as it will be written: completion's warped neighbours are reused, completed pixels
            # are sharpened like the rest, missing pixels of --mode none stay missing (docs/deblurring.md).
            self.energy_cache.forget_before(t - config.deblur.neighbour_frames - RENDER_SLACK_FRAMES)
            deblurred = deblur.deblur_frame(output, output_valid, t, {**same_shot, t: original},
                                            self.curr_from_prev, self.orig_from_out[t], config.deblur,
                                            warped=warped, cache=self.energy_cache)
            lap("deblur")
            output = deblurred.frame
        stamp = Stamp(frame.index, frame.time_s)
        held = (temporal.CompletedFrame(completed.frame, completed.missing)
                if self.temporal_radius and completed is not None else None)
        if self.keep is None:
            return FrameResult(stamp, frame.pts, output, cpu_seconds=cpu, completed=held)
        if self.orig_from_uncropped is not None:
            stabilized = rolling_shutter.warp_frame(frame.rgb, self.orig_from_uncropped[t], rows)
        kept = self.keep(FrameResult(stamp, frame.pts, output, input=frame, warp=stabilized, completion=completed,
                                     deblur=deblurred, cpu_seconds=cpu, completed=held))
        lap("observers")  # the observers' digests (the same dict as kept.cpu_seconds)
        return kept

    def smoothed_stream(self, results: Iterable[FrameResult]) -> Iterator[FrameResult]:
        """Completion's last step over the frames in order: each frame's synthesized pixels averaged with its
        neighbours' completed frames (pipeline/stages/temporal.py), deblurring's change to them kept."""
        for window in sliding_window(results, self.temporal_radius):
            yield self._smoothed(window)

    def _smoothed(self, window: Windowed[FrameResult]) -> FrameResult:
        result = window.centre
        completed, t = result.completed, result.stamp.index
        if completed is None or t >= len(self.shot_of):  # (a frame pass 1 did not see has no path to be smoothed on)
            return dataclasses.replace(result, completed=None)
        clock = time.thread_time()
        others = {n.stamp.index: n.completed for n in window.neighbours.values()
                  if n.completed is not None and n.stamp.index < len(self.shot_of)
                  and self.shot_of[n.stamp.index] == self.shot_of[t]}
        completed_neighbours = []
        if others:
            t_from = geometry.neighbour_transforms(self.curr_from_prev, t, min(min(others), t), max(max(others), t))
            stab_t = self.orig_from_stab[t]
            completed_neighbours = [
                temporal.CompletedNeighbour(j - t, others[j].frame,
                                            np.linalg.inv(self.orig_from_stab[j]) @ np.linalg.inv(t_from[j]) @ stab_t,
                                            others[j].synthesized)
                for j in sorted(others, key=lambda j: (abs(j - t), j))]
        smoothed = temporal.smooth(completed.frame, completed.synthesized, completed_neighbours,
                                   self.config.completion.temporal)
        output = result.output
        if smoothed.neighbours:
            # The output is the completed frame after deblurring: the synthesized pixels take the average plus
            # deblurring's change to them (none where deblurring did not run).
            synthesized = np.flatnonzero(completed.synthesized)  # (flat indices: a boolean mask is read per use)
            change = (smoothed.frame.reshape(-1, 3)[synthesized].astype(np.int16)
                      - completed.frame.reshape(-1, 3)[synthesized])
            output = output.copy()
            output.reshape(-1, 3)[synthesized] = np.clip(result.output.reshape(-1, 3)[synthesized] + change, 0,
                                                         255).astype(np.uint8)
        cpu = {**result.cpu_seconds, "temporal": time.thread_time() - clock}
        if self.keep is None:
            return FrameResult(result.stamp, result.pts, output, cpu_seconds=cpu)
        return dataclasses.replace(result, output=output, temporal=smoothed, cpu_seconds=cpu, completed=None)


def render_frames(source: FrameSource, plan: PathPlan, config: StabilizeConfig, *,
                  keep: Callable[[FrameResult], FrameResult] | None, frames: range | None = None,
                  workers: int = 1) -> Iterator[FrameResult]:
    """Pass 2: every frame's result, in frame order (``workers`` frames at once on threads; identical either way).
    ``keep``: what of each frame's intermediates the run holds (FrameChain); None: none.

    ``frames``: only these (a segment); the window still reads ``config.window_frames`` frames either side of the
    range, and the frames temporal consistency averages in are rendered too (not returned), so each frame is what
    it is in a whole-video run."""
    chain = FrameChain(plan, config, keep=keep)
    margin = chain.temporal_radius
    with one_pass(source) as decoded:
        windows: Iterable[Windowed[Frame]] = sliding_window(decoded, config.window_frames)
        if frames is not None:
            first, stop = frames.start - margin, frames.stop + margin
            windows = (w for w in itertools.takewhile(lambda w: w.centre.index < stop, windows)
                       if w.centre.index >= first)
        results: Iterable[FrameResult] = parallel.ordered_map(chain, windows, workers)
        if margin:
            results = chain.smoothed_stream(results)
            if frames is not None:
                results = (r for r in results if frames.start <= r.stamp.index < frames.stop)
        yield from results
