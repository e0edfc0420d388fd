"""`ffviz compare`: videos side by side (the input, ffviz's output, another stabilizer's...), each labelled, with
every video's camera path plotted under them and a cursor at the moment shown; the audio of the first (the input).

Two streaming passes over every video. The first estimates each video's frame-to-frame motion with the
stabilizer's own estimator (pipeline.stages.motion, similarity model, at most 480 px) and accumulates it into a
camera path: where frame t's centre lies in the first frame (x, y px) and its rotation (degrees), as the trajectory
figures draw it; x and y are scaled to the comparison's common height. A steady video's path is smooth; a tripod
shot's is flat. The second pass composes the frames aligned by time: every output frame is an input frame, shown
beside each other video's latest frame at or before its time (half an input frame's leeway), so videos of
another frame rate line up too. Only the paths (3 numbers a frame) are kept between the passes, and in the second
pass one frame of each video: memory does not grow with the length.

Videos of other sizes are scaled to the input's height (or ``height``); widths are rounded to even numbers, so the
H.264 output (yuv420p) needs no padding. A video that ends before the input by more than half an input frame is
refused unless ``shortest`` is set (the comparison then ends with the shortest video), rather than shown frozen.
The plots and labels are drawn once with matplotlib (Agg); per frame only the cursor and the dots are drawn (cv2).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from pipeline import geometry
from pipeline.errors import ConfigError, InputError
from pipeline.frames import Frame
from pipeline.runtime.encoding import Encoding
from pipeline.runtime.video_info import VideoInfo
from pipeline.runtime import video_reader, video_writer
from pipeline.runtime.observer import ProgressFactory, null_progress
from pipeline.stages import background, motion

# Motion for display: rotation, zoom and shift are what a viewer reads off a path; 480 px is plenty for a plot.
PATH_MOTION = motion.MotionConfig(model="similarity", max_side=480)
# One colour per video, in order: the input warm (as the viewer's "original"), ffviz's output blue (its
# "smoothed"), then green, yellow, violet, grey.
PANEL_COLOURS = ((235, 80, 60), (50, 130, 245), (80, 200, 100), (240, 200, 50), (190, 110, 230), (170, 170, 170))
BACKGROUND = (22, 24, 29)  # around and between the videos
PLOT_BACKGROUND = (34, 37, 44)
TEXT = (225, 228, 235)
GAP_PX = 4  # between two videos
ENCODING = Encoding(codec="h264", preset="veryfast")  # a viewing aid: x264, CRF 18, a third of medium's CPU


@dataclass(frozen=True)
class Panel:
    """One video of the comparison: ``start_s``/``end_s`` read only that part of it (a preview's input)."""

    path: Path
    label: str
    start_s: float | None = None
    end_s: float | None = None


@dataclass
class CameraPath:
    """A video's accumulated camera path, one row per frame (pass 1)."""

    info: VideoInfo
    times: np.ndarray  # (N,) seconds since the video's first frame
    xy_angle: np.ndarray  # (N, 3) frame centre in the first frame (x, y px, the video's own pixels), rotation (deg)
    cuts: int  # pairs the estimator took for scene cuts (the path does not move there)

    @property
    def end_s(self) -> float:
        """Where the video's last frame stops showing: its time plus one frame at the video's rate."""
        return float(self.times[-1]) + 1.0 / float(self.info.fps)


@dataclass(frozen=True)
class PanelSummary:
    label: str
    path: Path
    n_frames: int
    width: int
    height: int
    residual_jitter_px: float  # metrics.residual_jitter of the camera path, in the comparison's pixels
    residual_jitter_deg: float


@dataclass(frozen=True)
class CompareReport:
    output_path: Path
    n_frames: int
    width: int
    height: int
    panels: tuple[PanelSummary, ...]
    warnings: tuple[str, ...]


def _reader(panel: Panel) -> video_reader.VideoReader:
    return video_reader.VideoReader(panel.path, start_s=panel.start_s, end_s=panel.end_s)


def camera_path(panel: Panel, config: motion.MotionConfig = PATH_MOTION, progress=None,
                stop: threading.Event | None = None) -> CameraPath:
    """Pass 1 for one video: its motion frame to frame (pipeline.stages.motion, the camera's chosen as a run
    chooses it: pipeline.stages.background) accumulated into a path.
    ``stop``: set from another thread (Ctrl-C in the main one), it ends the pass at the next frame."""
    layers: list[background.PairLayers] = []
    statuses: list[str] = []
    times: list[float] = []
    sizes: list[tuple[int, int]] = []
    evidence = background.LayerEvidence()
    previous: motion.PreparedFrame | None = None
    before: motion.MotionEstimate | None = None  # the pair before's estimate as motion.continued returned it
    with _reader(panel) as reader:
        info = reader.info
        for frame in reader:
            if stop is not None and stop.is_set():
                raise _Stopped()
            prepared = motion.prepare(frame.rgb, config)
            if previous is None:
                estimate = motion.first_frame_estimate()
            elif prepared.gray.shape != previous.gray.shape:
                estimate = motion.MotionEstimate(geometry.IDENTITY.copy(), "cut")
            else:
                estimate = motion.estimate(previous, prepared, config)
            estimate = before = motion.continued(before, estimate, previous, prepared, config)
            layers.extend(pair for _, pair in evidence.push(estimate, previous, prepared))
            statuses.append(estimate.status)
            previous = prepared
            first_time = frame.time_s if not times else first_time
            times.append(frame.time_s - first_time)
            sizes.append((frame.rgb.shape[1], frame.rgb.shape[0]))
            if progress is not None:
                progress.update()
    if not statuses:
        raise InputError(f"no decodable video frames in {panel.path}")
    layers.extend(pair for _, pair in evidence.finish())
    rows, first_from_t = [], geometry.IDENTITY.copy()
    for pair, choice, (width, height) in zip(layers, background.decide(layers), sizes):
        first_from_t = first_from_t @ np.linalg.inv(pair.motions[choice.taken])
        first_from_t /= first_from_t[2, 2]
        rows.append(geometry.decompose(first_from_t, width, height)[:3])
    return CameraPath(info, np.array(times), np.array(rows, np.float64).reshape(-1, 3), statuses.count("cut"))


class _Stopped(Exception):
    """Pass 1 of a video ended because another thread failed or was interrupted."""


@dataclass(frozen=True)
class _Layout:
    """Where everything goes on the output frame (px): a label row, the videos, the plot strip."""

    width: int
    height: int
    header: int  # height of the label row
    video_height: int
    panel_x: tuple[int, ...]  # left edge of each video
    panel_w: tuple[int, ...]
    strip: int  # height of the plot strip
    font_px: float

    @property
    def video_top(self) -> int:
        return self.header

    @property
    def strip_top(self) -> int:
        return self.header + self.video_height


def _even(value: float) -> int:
    return max(2, int(round(value / 2.0)) * 2)


def layout(sizes: Sequence[tuple[int, int]], height: int) -> _Layout:
    """The output's layout for videos of these (width, height) scaled to ``height`` px (made even)."""
    video_height = _even(height)
    widths = [_even(w * video_height / h) for w, h in sizes]
    xs, x = [], 0
    for w in widths:
        xs.append(x)
        x += w + GAP_PX
    total_width = x - GAP_PX
    header = _even(min(max(video_height * 0.075, 24), 64))
    strip = _even(min(max(video_height * 0.45, 150), 480))
    return _Layout(total_width, header + video_height + strip, header, video_height, tuple(xs), tuple(widths),
                   strip, font_px=header * 0.5)


@dataclass(frozen=True)
class _Axis:
    """An axes' data-to-pixel map on the output frame (image rows grow downwards)."""

    x0: float
    x1: float
    y0: float  # pixel row of the axes' bottom
    y1: float  # ... and top
    t_range: tuple[float, float]
    v_range: tuple[float, float]

    def px(self, t: float) -> int:
        lo, hi = self.t_range
        return int(round(self.x0 + (t - lo) / (hi - lo) * (self.x1 - self.x0)))

    def py(self, v: float) -> int:
        lo, hi = self.v_range
        return int(round(self.y0 + (v - lo) / (hi - lo) * (self.y1 - self.y0)))


def _fitted(label: str, characters: int) -> str:
    """``label`` cut in the middle (the end keeps a file's extension) to at most ``characters``."""
    if len(label) <= characters:
        return label
    keep = max(characters - 1, 2)
    return label[:(keep + 1) // 2] + "\u2026" + label[len(label) - keep // 2:]


def _colour(rgb: tuple[int, int, int]) -> tuple[float, float, float]:
    return tuple(c / 255.0 for c in rgb)


PLOTS = (("horizontal position (px)", 0), ("vertical position (px)", 1), ("rotation (deg)", 2))


def _background(lay: _Layout, labels: Sequence[str], plotted: Sequence[np.ndarray], times: Sequence[np.ndarray],
                duration_s: float) -> tuple[np.ndarray, list[_Axis]]:
    """The output frame without the videos: labels, the three path plots; and the plots' pixel maps."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    dpi = 100.0
    fig = Figure(figsize=(lay.width / dpi, lay.height / dpi), dpi=dpi, facecolor=_colour(BACKGROUND))
    canvas = FigureCanvasAgg(fig)
    points = lay.font_px * 72.0 / dpi  # px to points
    renderer = canvas.get_renderer()
    for i, label in enumerate(labels):
        text = fig.text((lay.panel_x[i] + lay.panel_w[i] / 2.0) / lay.width, 1.0 - lay.header / 2.0 / lay.height,
                        label, ha="center", va="center", fontsize=points, fontweight="bold",
                        color=_colour(PANEL_COLOURS[i % len(PANEL_COLOURS)]))
        room, characters = lay.panel_w[i] - lay.font_px, len(label)
        while text.get_window_extent(renderer).width > room and characters > 3:  # cut to fit its own video
            characters -= 1
            text.set_text(_fitted(label, characters))
    small = points * 0.8
    column = lay.width / len(PLOTS)
    left, right = 4.2 * lay.font_px, 0.6 * lay.font_px  # room for tick labels
    bottom, top = 2.6 * lay.font_px, 1.8 * lay.font_px  # time ticks and label; the title
    axes = []
    for k, (title, column_index) in enumerate(PLOTS):
        x0, x1 = k * column + left, (k + 1) * column - right
        y0, y1 = bottom, lay.strip - top  # from the figure's bottom
        ax = fig.add_axes(((x0) / lay.width, y0 / lay.height, (x1 - x0) / lay.width, (y1 - y0) / lay.height),
                          facecolor=_colour(PLOT_BACKGROUND))
        for i, (path, t) in enumerate(zip(plotted, times)):
            ax.plot(t, path[:, column_index], color=_colour(PANEL_COLOURS[i % len(PANEL_COLOURS)]),
                    linewidth=1.4 if i else 1.0)
        ax.set_xlim(0.0, max(duration_s, 1e-3))
        lo, hi = ax.get_ylim()
        if hi - lo < (2.0 if column_index < 2 else 0.2):  # a flat path: a range that does not magnify noise
            middle = (lo + hi) / 2.0
            half = 1.0 if column_index < 2 else 0.1
            ax.set_ylim(middle - half, middle + half)
        if column_index == 1:
            ax.invert_yaxis()  # image rows grow downwards: up in the plot is up in the picture
        ax.set_title(title, fontsize=small, color=_colour(TEXT), loc="left", pad=2)
        ax.set_xlabel("time (s)", fontsize=small * 0.9, color=_colour(TEXT), labelpad=1)
        ax.tick_params(colors=_colour(TEXT), labelsize=small * 0.85, length=2, pad=1)
        ax.grid(alpha=0.2, color=_colour(TEXT))
        for spine in ax.spines.values():
            spine.set_color(_colour((90, 95, 105)))
        axes.append(ax)
    canvas.draw()
    rgb = np.asarray(canvas.buffer_rgba())[:, :, :3]
    if rgb.shape[:2] != (lay.height, lay.width):  # figure size rounding: never more than a pixel
        rgb = cv2.resize(np.ascontiguousarray(rgb), (lay.width, lay.height), interpolation=cv2.INTER_AREA)
    maps = []
    for ax in axes:
        box = ax.get_window_extent()  # display px, origin at the bottom left
        maps.append(_Axis(box.x0, box.x1, lay.height - box.y0, lay.height - box.y1, ax.get_xlim(), ax.get_ylim()))
    return np.ascontiguousarray(rgb), maps


def _timed(reader: video_reader.VideoReader) -> Iterator[tuple[float, Frame]]:
    """(seconds since the video's first frame, frame) of each frame."""
    first = None
    for frame in reader:
        first = frame.time_s if first is None else first
        yield frame.time_s - first, frame


class _Follower:
    """Another video in pass 2: its latest frame at or before a time (its first one before it starts)."""

    def __init__(self, frames: Iterator[tuple[float, Frame]]) -> None:
        self._frames = frames
        self.current = next(frames)
        self._next = next(frames, None)

    def at(self, time_s: float) -> Frame:
        while self._next is not None and self._next[0] <= time_s:
            self.current, self._next = self._next, next(self._frames, None)
        return self.current[1]


def _reader_info(panel: Panel) -> VideoInfo:
    info = video_reader.probe_video(panel.path)
    if panel.start_s is not None or panel.end_s is not None:
        info = video_reader.clipped_info(info, panel.start_s, panel.end_s)
    return info


def compose(background: np.ndarray, lay: _Layout, axes: Sequence[_Axis], time_s: float,
            shown: Sequence[Frame], plotted: Sequence[np.ndarray]) -> np.ndarray:
    """One output frame: the videos' frames ``shown`` (scaled to the layout) on the background, and a cursor at
    ``time_s`` on each plot with a dot on each video's path at the frame shown."""
    out = background.copy()
    top = lay.video_top
    for x, width, frame in zip(lay.panel_x, lay.panel_w, shown):
        rgb = frame.rgb
        if rgb.shape[:2] != (lay.video_height, width):
            shrink = rgb.shape[0] > lay.video_height
            rgb = cv2.resize(rgb, (width, lay.video_height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        out[top:top + lay.video_height, x:x + width] = rgb
    radius = max(2, int(round(lay.font_px * 0.3)))
    for ax, (_, column) in zip(axes, PLOTS):
        x = ax.px(time_s)
        cv2.line(out, (x, int(round(ax.y1))), (x, int(round(ax.y0))), TEXT, 1, cv2.LINE_AA)
        for i, (frame, path) in enumerate(zip(shown, plotted)):
            row = min(frame.index, len(path) - 1)
            cv2.circle(out, (x, ax.py(path[row, column])), radius, PANEL_COLOURS[i % len(PANEL_COLOURS)], -1,
                       cv2.LINE_AA)
    return out


def compare(panels: Sequence[Panel], output: Path | str, *, overwrite: bool = False, height: int | None = None,
            shortest: bool = False, progress: ProgressFactory = null_progress,
            encoding: Encoding = ENCODING) -> CompareReport:
    """Write the side-by-side of ``panels`` (the first is the input: its frames, timing and audio lead) to
    ``output``. Raises InputError for a video that cannot be read or is shorter than the input (unless
    ``shortest``), OutputError for an output that is one of the videos or exists (unless ``overwrite``).
    Nothing is written on an error (the writer's temp file is removed)."""
    output = Path(output)
    if len(panels) < 2:
        raise ConfigError("compare needs at least two videos: the input and an output")
    if height is not None and not 16 <= height <= 4320:
        raise ConfigError(f"height must be between 16 and 4320 px, not {height}")
    infos = [_reader_info(panel) for panel in panels]  # every video readable before anything is written
    for panel in panels:  # the output is none of the videos (before saying it exists)
        video_writer.check_output_path(output, panel.path, overwrite=True)
    video_writer.check_output_path(output, panels[0].path, overwrite=overwrite)

    paths = _camera_paths(panels, infos, progress)
    lead = paths[0]
    end_s = _common_end(panels, paths, shortest)
    sizes = [(p.info.width, p.info.height) for p in paths]
    lay = layout(sizes, height or lead.info.height)
    scales = [lay.video_height / h for _, h in sizes]  # each video's px to the comparison's
    plotted = [p.xy_angle * np.array([s, s, 1.0]) for p, s in zip(paths, scales)]
    shown = [p.times < end_s - 0.5 / float(p.info.fps) for p in paths]  # the part of each that is shown
    background, axes = _background(lay, [panel.label for panel in panels], [xy[s] for xy, s in zip(plotted, shown)],
                                   [p.times[s] for p, s in zip(paths, shown)], end_s)
    summaries = _summaries(panels, paths, plotted, shown)
    written, warnings = _write_side_by_side(panels, output, lead, end_s, _Picture(background, lay, axes, plotted),
                                            progress, encoding)
    return CompareReport(output, written, lay.width, lay.height, tuple(summaries), tuple(warnings))


def _camera_paths(panels: Sequence[Panel], infos: Sequence[VideoInfo], progress: ProgressFactory) -> list[CameraPath]:
    """Pass 1: every video's camera path, two videos at a time."""
    bar = progress("compare 1/2: camera paths", sum(info.frame_count for info in infos) or None)
    stop = threading.Event()
    try:
        with ThreadPoolExecutor(max_workers=min(len(panels), 2)) as pool:
            try:
                return list(pool.map(lambda panel: camera_path(panel, progress=bar, stop=stop), panels))
            except BaseException:  # Ctrl-C, SIGTERM or a video's error: the other threads stop at their next frame
                stop.set()
                raise
    finally:
        bar.close()


def _common_end(panels: Sequence[Panel], paths: Sequence[CameraPath], shortest: bool) -> float:
    """Where the comparison ends (seconds): the input's end, or with ``shortest`` the shortest video's; a video
    that ends before the input without ``shortest`` is an InputError."""
    lead = paths[0]
    fps = float(lead.info.fps)
    end_s = lead.end_s
    for panel, path in zip(panels[1:], paths[1:]):
        if path.end_s < lead.end_s - 0.5 / fps:
            if not shortest:
                raise InputError(
                    f"{panel.path} ends at {path.end_s:.2f} s ({len(path.times)} frames), before {panels[0].path} "
                    f"({lead.end_s:.2f} s, {len(lead.times)} frames): pass --shortest to end the comparison with the "
                    f"shortest video")
            end_s = min(end_s, path.end_s)
    return end_s


def _summaries(panels: Sequence[Panel], paths: Sequence[CameraPath], plotted: Sequence[np.ndarray],
               shown: Sequence[np.ndarray]) -> list[PanelSummary]:
    """Each video's line of the report: frames shown, size, and the residual jitter of its path over them."""
    from pipeline.evaluation import metrics  # here: it imports scipy.ndimage, which `ffviz --help` need not

    summaries = []
    for panel, path, xy_angle, part in zip(panels, paths, plotted, shown):
        jitter_px, jitter_deg = metrics.residual_jitter(xy_angle[part] * np.array([1.0, 1.0, math.pi / 180.0]),
                                                        float(path.info.fps))
        summaries.append(PanelSummary(panel.label, panel.path, int(part.sum()), path.info.width,
                                      path.info.height, jitter_px, jitter_deg))
    return summaries


@dataclass(frozen=True)
class _Picture:
    """What every output frame shares: the background with labels and plots, its layout, the plots' axes, and each
    video's path in the comparison's pixels."""
    background: np.ndarray
    lay: _Layout
    axes: list[_Axis]
    plotted: list[np.ndarray]


def _write_side_by_side(panels: Sequence[Panel], output: Path, lead: CameraPath, end_s: float, picture: _Picture,
                        progress: ProgressFactory, encoding: Encoding) -> tuple[int, list[str]]:
    """Pass 2: the input's frames up to ``end_s``, each beside the other videos' frames of its time, written to
    ``output`` with the input's timing and audio. (Frames written, the readers' and the writer's warnings.)"""
    fps = float(lead.info.fps)
    leeway = 0.5 / fps
    # A clip: the output starts at the input's first frame, and the audio ends with the last frame written.
    # 8 bits (the frames are read as uint8; 8-bit H.264 plays everywhere), the input's matrix, range and tags.
    like = dataclasses.replace(lead.info, clip=lead.info.clip or (0.0, end_s),
                               colour=dataclasses.replace(lead.info.colour, bit_depth=8))
    audio_from = panels[0].path if lead.info.has_audio else None
    lay = picture.lay
    bar = progress("compare 2/2: side by side + encode", len(lead.times))
    readers: list[video_reader.VideoReader] = []
    writer = None
    written = 0
    try:
        readers = [_reader(panel) for panel in panels]
        writer = video_writer.VideoWriter(output, like=like, width=lay.width, height=lay.height, audio_from=audio_from,
                                          encoding=encoding)
        followers = [_Follower(_timed(reader)) for reader in readers[1:]]
        for time_s, frame in _timed(readers[0]):
            if time_s >= end_s - leeway:
                break
            shown = [frame] + [follower.at(time_s + leeway) for follower in followers]
            writer.write(compose(picture.background, lay, picture.axes, time_s, shown, picture.plotted),
                         pts=frame.pts, time_s=frame.time_s)
            written += 1
            bar.update()
        writer.close()
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    finally:
        for reader in readers:
            reader.close()
        bar.close()
    return written, [*writer.warnings, *(w for reader in readers for w in reader.warnings)]


# -- the command line: `ffviz compare`, and `ffviz stabilize --compare / --preview / --start` ------------------


def add_parser(commands) -> None:
    p = commands.add_parser(
        "compare", help="videos side by side (input | ffviz | another stabilizer), labelled, with their camera paths",
        description="Write a video of INPUT and its stabilized versions side by side, each labelled, scaled to one\n"
                    "height and aligned by time, with every video's camera path (estimated from its frames) plotted\n"
                    "underneath and a cursor at the moment shown; the audio is INPUT's. People judge stabilizers by\n"
                    "looking. More: docs/usage.md, \"Comparing side by side\".",
        epilog="example:\n  ffviz compare shaky.mp4 steady.mp4 vidstab.mp4 -o sbs.mp4 --labels "
               "original,ffviz,vid.stab",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", type=Path, metavar="INPUT",
                   help="the original video, shown first: its frames set the output's timing, its audio is copied")
    p.add_argument("outputs", type=Path, nargs="+", metavar="OUTPUT",
                   help="stabilized versions of INPUT (ffviz's, another stabilizer's...), shown to its right in this "
                        "order; each as long as INPUT")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FILE",
                   help="side-by-side video to write: .mp4, .mov or .mkv (H.264, even size) (required)")
    p.add_argument("--labels", default=None, metavar="L1,L2,...",
                   help="the videos' labels, in order, comma-separated; an empty one keeps the file name "
                        "(default: the file names)")
    p.add_argument("--height", type=int, default=None, metavar="PX",
                   help="height every video is scaled to, in pixels (default: INPUT's height)")
    p.add_argument("--shortest", action="store_true",
                   help="end the comparison with the shortest video (default: refuse a video that ends before INPUT)")
    p.add_argument("--overwrite", action="store_true", help="replace FILE if it exists (default: refuse)")


def parse_labels(text: str | None, paths: Sequence[Path]) -> list[str]:
    """--labels L1,L2,... as one label per video (an empty entry, or a missing tail: the file name)."""
    names = [path.name for path in paths]
    if text is None:
        return names
    given = [label.strip() for label in text.split(",")]
    if len(given) > len(paths):
        raise ConfigError(f"--labels gives {len(given)} labels for {len(paths)} videos")
    return [label or name for label, name in zip(given + [""] * len(paths), names)]


def cmd_compare(args) -> int:
    from ffviz.progress import tqdm_progress

    paths = [args.input, *args.outputs]
    labels = parse_labels(args.labels, paths)
    if args.height is not None and not 16 <= args.height <= 4320:
        raise ConfigError(f"--height must be between 16 and 4320 px, not {args.height}")
    report = compare([Panel(path, label) for path, label in zip(paths, labels)], args.output,
                     overwrite=args.overwrite, height=args.height, shortest=args.shortest, progress=tqdm_progress)
    print_report(report)
    return 0


def print_report(report: CompareReport) -> None:
    import sys

    width = max(len(panel.label) for panel in report.panels)
    lines = [f"wrote {report.output_path} ({report.n_frames} frames, {report.width}x{report.height}); "
             f"camera path residual jitter (px, deg; lower is steadier):"]
    for panel in report.panels:
        lines.append(f"  {panel.label:<{width}}  {panel.residual_jitter_px:7.3f} px  {panel.residual_jitter_deg:7.4f} deg"
                     f"  ({panel.n_frames} frames, {panel.width}x{panel.height})")
    print("\n".join(lines), flush=True)
    for message in report.warnings[:5]:
        print(f"ffviz: warning: {message}", file=sys.stderr)
    if len(report.warnings) > 5:
        print(f"ffviz: warning: ... and {len(report.warnings) - 5} more", file=sys.stderr)


def preview_range(args) -> tuple[float | None, float | None]:
    """``--start`` / ``--preview`` of `ffviz stabilize` as (start_s, end_s) of the input; (None, None) without."""
    start_s, seconds = getattr(args, "start", None), getattr(args, "preview", None)
    if start_s is not None and not (math.isfinite(start_s) and start_s >= 0):
        raise ConfigError(f"--start must be 0 s or later, not {start_s:g}")
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise ConfigError(f"--preview must be more than 0 seconds, not {seconds:g}")
    if start_s is None and seconds is None:
        return None, None
    start_s = start_s or 0.0
    return start_s, None if seconds is None else start_s + seconds


def check_compare_path(path: Path, input_path: Path, output_path: Path, *, overwrite: bool) -> None:
    """--compare FILE: refused like any output, and it must not be the stabilized output either."""
    video_writer.check_output_path(path, input_path, overwrite=overwrite)
    if Path(path).absolute() == Path(output_path).absolute():
        raise ConfigError(f"--compare {path} is the stabilized output itself: name another file")


def stabilize_comparison(input_path: Path, output_path: Path, compare_path: Path, start_s: float | None,
                         end_s: float | None, *, overwrite: bool) -> CompareReport:
    """`ffviz stabilize --compare FILE`: the input (the part stabilized) beside the output."""
    from ffviz.progress import tqdm_progress

    report = compare([Panel(Path(input_path), Path(input_path).name, start_s, end_s),
                      Panel(Path(output_path), Path(output_path).name)], compare_path, overwrite=overwrite,
                     progress=tqdm_progress)
    print_report(report)
    return report
