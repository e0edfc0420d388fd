"""`ffviz figures`: the thesis's figures, rendered from a recording alone (matplotlib, no display needed).

Figures are built on matplotlib.figure.Figure directly (no pyplot, no global backend state) and saved
with the Agg/PDF/SVG canvases. A figure whose entities the recording lacks (a summary recording, no
deblurring, no traced frame) is skipped with a note.

| file | thesis | shows |
|---|---|---|
| trajectories | Figs. 12, 13, 15 | camera path x, y, angle: original vs smoothed |
| stabilized_vs_original | Figs. 14, 16 | input frames over their 2D-stabilized versions |
| completed_vs_stabilized | Figs. 20, 21 | 2D-stabilized frames over the completed ones |
| motion_inpainting | Fig. 18 | the Fast Marching band filling the flow into the missing area, step by step |
| deblurring | Figs. 22, 23 | the most blurred frames before and after deblurring, and the neighbours' weights |
| blurriness | eq. 28 | relative blurriness b_t over time |
| mosaic_variance | eq. 20 | the mosaic's variance over the missing area |
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np
from matplotlib.figure import Figure

from ffviz import entities as ent, visual
from ffviz.rrd import Recording
from pipeline.errors import InputError

FORMATS = ("png", "pdf", "svg")
DEFAULT_FRAME_COUNT = 3
FMM_COLUMNS = 5  # pictures of the Fast Marching progression per traced frame
FMM_ZOOM = 3  # they show a window 1/3 of the frame's width and height around the thickest filled area
MAX_FMM_ROWS = 3
MAX_DEBLUR_FRAMES = 2
PANEL_WIDTH_IN = 3.2
DPI = 150


class Skip(Exception):
    """The recording lacks what a figure needs; the message says what."""


@dataclass(frozen=True)
class FigureResult:
    name: str
    figure: Figure | None
    note: str | None = None  # why it was skipped


# -- choosing frames --------------------------------------------------------------------------------


def traced_frames(recording: Recording) -> list[int]:
    prefix = f"{ent.TRACE}/"
    return sorted({int(e.split("/")[1]) for e in recording.entities
                   if e.startswith(prefix) and e.split("/")[1].isdigit()})


def pick_frames(recording: Recording, entities: Sequence[str], requested: Sequence[int] | None,
                count: int = DEFAULT_FRAME_COUNT) -> list[int]:
    """Frames that have an image in every one of ``entities``: the requested ones, else the traced ones,
    else ``count`` spread over the clip. Raises Skip when none is left."""
    available = set(recording.indices(entities[0]))
    for entity in entities[1:]:
        available &= set(recording.indices(entity))
    if not available:
        raise Skip(f"the recording has no {' + '.join(entities)} images (recorded with --record summary?)")
    if requested:
        chosen = [t for t in requested if t in available]
        if not chosen:
            raise Skip(f"none of frames {', '.join(map(str, requested))} has {' + '.join(entities)} images")
        return chosen
    chosen = [t for t in traced_frames(recording) if t in available]
    if chosen:
        return chosen[:count]
    ordered = sorted(available)
    return [ordered[i] for i in np.unique(np.linspace(0, len(ordered) - 1, min(count, len(ordered))).round().astype(int))]


# -- drawing helpers ------------------------------------------------------------------------------


def _image_grid(rows: Sequence[tuple[str, Sequence[np.ndarray]]], column_titles: Sequence[str], title: str,
                ) -> tuple[Figure, np.ndarray]:
    """A grid of images, one labelled row per entry; returns the figure and its axes (rows x columns)."""
    n_rows, n_cols = len(rows), max(len(images) for _, images in rows)
    height, width = rows[0][1][0].shape[:2]
    panel_h = PANEL_WIDTH_IN * height / width
    fig = Figure(figsize=(PANEL_WIDTH_IN * n_cols + 0.6, panel_h * n_rows + 0.9), dpi=DPI, layout="constrained")
    axes = np.atleast_2d(fig.subplots(n_rows, n_cols, squeeze=False))
    for r, (label, images) in enumerate(rows):
        for c in range(n_cols):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            if c < len(images):
                ax.imshow(images[c], interpolation="nearest")
            else:
                ax.set_visible(False)
            if c == 0:
                ax.set_ylabel(label)
            if r == 0 and c < len(column_titles):
                ax.set_title(column_titles[c], fontsize=9)
    fig.suptitle(title)
    return fig, axes


def _pair_figure(recording: Recording, top: tuple[str, str], bottom: tuple[str, str], title: str,
                 requested: Sequence[int] | None) -> Figure:
    frames = pick_frames(recording, [top[1], bottom[1]], requested)
    rows = [(label, [recording.image(entity, t) for t in frames]) for label, entity in (top, bottom)]
    fig, _ = _image_grid(rows, [f"frame {t}" for t in frames], title)
    return fig


def _series(recording: Recording, entity: str) -> tuple[np.ndarray, np.ndarray]:
    frames, values = recording.scalars(entity)
    if len(frames) == 0:
        raise Skip(f"the recording has no {entity} series")
    return frames, values


# -- the figures ----------------------------------------------------------------------------------


def trajectories(recording: Recording, requested: Sequence[int] | None = None) -> Figure:
    """The camera path per axis, original against smoothed, with eq. 18's and the L1 path on the same motion where
    recorded; where path settings change (--path-segment) each stretch is shaded and labelled with its setting."""
    units = {"x": "x (px)", "y": "y (px)", "angle": "angle (deg)", "zoom": "zoom (%)"}
    axis_names = [a for a in ent.TRAJECTORY_AXES if len(recording.scalars(f"{ent.TRAJECTORY_ORIGINAL}/{a}")[0])]
    fig = Figure(figsize=(8, 1.9 * len(axis_names) + 0.8), dpi=DPI, layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(axis_names), 1, sharex=True))
    stretches = _setting_stretches(recording)
    for ax, axis in zip(axes, axis_names):
        frames, original = _series(recording, f"{ent.TRAJECTORY_ORIGINAL}/{axis}")
        smoothed_frames, smoothed = _series(recording, f"{ent.TRAJECTORY_SMOOTHED}/{axis}")
        # The viewer's colours (visual.TRAJECTORY_COLOURS): original warm, smoothed cool.
        ax.plot(frames, original, color=visual.hex_colour(visual.TRAJECTORY_COLOURS["original", axis]), linewidth=1.0,
                label="original")
        ax.plot(smoothed_frames, smoothed, color=visual.hex_colour(visual.TRAJECTORY_COLOURS["smoothed", axis]),
                linewidth=1.6, label="smoothed (the run's)")
        # Both planners on the same motion (PathComparison), in the recording's colours, dashed over the run's.
        for root, kind, label in ((ent.TRAJECTORY_GAUSSIAN, "gaussian", "eq. 18 (gaussian)"),
                                  (ent.TRAJECTORY_L1, "l1", "L1")):
            other_frames, other = recording.scalars(f"{root}/{axis}")
            if len(other_frames):
                ax.plot(other_frames, other, color=visual.hex_colour(visual.TRAJECTORY_COLOURS[kind, axis]),
                        linewidth=1.0, linestyle="--", label=label)
        for k, (first, last, _) in enumerate(stretches):
            if k % 2:
                ax.axvspan(first - 0.5, last + 0.5, color="0.5", alpha=0.12, linewidth=0)
        ax.set_ylabel(units[axis])
        ax.grid(alpha=0.3)
    for first, last, label in stretches if len(stretches) > 1 else ():
        axes[0].annotate(label, xy=((first + last) / 2, 1.0), xycoords=("data", "axes fraction"), ha="center",
                         va="bottom", fontsize=7)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("frame")
    settings = sorted({label for _, _, label in stretches})
    fig.suptitle("Camera trajectory: original and smoothed" + (f" ({settings[0]})" if len(settings) == 1 else ""))
    return fig


def _setting_stretches(recording: Recording) -> list[tuple[int, int, str]]:
    """(first frame, last frame, setting) of each stretch planned with one path setting; [] when not recorded."""
    frames, index = recording.scalars(ent.PATH_SETTING)
    texts = recording.texts(ent.PATH_SETTINGS, "TextDocument:text")
    labels = texts[-1].split("\n") if texts else []
    if len(frames) == 0 or not labels:
        return []
    index = index.astype(int)
    starts = [0, *np.flatnonzero(np.diff(index)) + 1]
    ends = [*(s - 1 for s in starts[1:]), len(index) - 1]
    return [(int(frames[a]), int(frames[b]), labels[index[a]] if index[a] < len(labels) else "?")
            for a, b in zip(starts, ends)]


def stabilized_vs_original(recording: Recording, requested: Sequence[int] | None = None) -> Figure:
    return _pair_figure(recording, ("original", ent.INPUT_FRAME), ("2D stabilized", ent.STABILIZED_FRAME),
                        "Original frames and 2D-stabilized frames (missing areas black)", requested)


def completed_vs_stabilized(recording: Recording, requested: Sequence[int] | None = None) -> Figure:
    return _pair_figure(recording, ("2D stabilized", ent.STABILIZED_FRAME), ("completed", ent.COMPLETION_FRAME),
                        "2D-stabilized frames and the frames after video completion", requested)


def _zoom_box(first: np.ndarray, last: np.ndarray, zoom: int = FMM_ZOOM) -> tuple[slice, slice]:
    """A window 1/zoom of the frame's size centred on the deepest point of the area that changed between the
    first and the last Fast Marching picture: where the filled region is thickest, the band shows best."""
    changed = (np.abs(first.astype(np.int16) - last.astype(np.int16)).max(axis=-1) > 40).astype(np.uint8)
    height, width = changed.shape
    if not changed.any():
        return slice(0, height), slice(0, width)
    depth = cv2.distanceTransform(changed, cv2.DIST_L2, 3)
    cy, cx = np.unravel_index(int(np.argmax(depth)), depth.shape)
    h, w = height // zoom, width // zoom
    y0, x0 = int(np.clip(cy - h // 2, 0, height - h)), int(np.clip(cx - w // 2, 0, width - w))
    return slice(y0, y0 + h), slice(x0, x0 + w)


def motion_inpainting(recording: Recording, requested: Sequence[int] | None = None) -> Figure:
    traced = [t for t in traced_frames(recording) if recording.indices(ent.trace_fmm(t), ent.FMM_STEP_TIMELINE)]
    if not traced:
        raise Skip("the recording has no traced frame with a Fast Marching fill (record with --mode full and "
                   "--trace-frames on frames with missing area)")
    if requested:
        traced = [t for t in traced if t in requested] or traced
    rows, titles = [], []
    for t in traced[:MAX_FMM_ROWS]:
        entity = ent.trace_fmm(t)
        steps = recording.indices(entity, ent.FMM_STEP_TIMELINE)
        shown = [steps[i] for i in np.unique(np.linspace(0, len(steps) - 1, FMM_COLUMNS).round().astype(int))]
        images = [recording.image(entity, s, ent.FMM_STEP_TIMELINE) for s in shown]
        box = _zoom_box(images[0], images[-1])
        rows.append((f"frame {t}", [image[box] for image in images]))
        titles = [f"step {s}/{steps[-1]}" for s in shown]
    fig, _ = _image_grid(rows, titles, "Motion inpainting: Fast Marching propagates the local flow (colour-coded) "
                                       f"into the missing area\n(zoomed {FMM_ZOOM}x; dark blue: still to fill; "
                                       "amber: the band)")
    return fig


def deblurring(recording: Recording, requested: Sequence[int] | None = None) -> Figure:
    available = sorted(set(recording.indices(ent.DEBLUR_BEFORE)) & set(recording.indices(ent.DEBLUR_AFTER)))
    if not available:
        raise Skip("the recording has no deblurred frames (no deblurring stage, --record summary, or no frame "
                   "had a sharper neighbour)")
    frames = [t for t in requested or () if t in available]
    if not frames:  # the most blurred of the sharpened frames
        blur_frames, blurriness = recording.scalars(ent.DEBLUR_BLURRINESS)
        by_frame = dict(zip(blur_frames.tolist(), blurriness.tolist()))
        frames = sorted(sorted(available, key=lambda t: -by_frame.get(t, 0.0))[:MAX_DEBLUR_FRAMES])
    has_weights = set(frames) <= set(recording.indices(ent.DEBLUR_WEIGHTS))
    rows = []
    for t in frames:
        images = [recording.image(ent.DEBLUR_BEFORE, t), recording.image(ent.DEBLUR_AFTER, t)]
        if has_weights:
            images.append(recording.image(ent.map_values(ent.DEBLUR_WEIGHTS), t) / ent.DEBLUR_WEIGHTS_SCALE)
        rows.append((f"frame {t}", images))
    titles = ["before", "after (eq. 30)"] + (["share from the neighbours"] if has_weights else [])
    fig, axes = _image_grid(rows, titles, "Deblurring by interpolating sharper neighbours")
    if has_weights:
        for r in range(len(rows)):
            image = axes[r, 2].images[0]
            image.set_cmap("viridis")
            image.set_clim(0.0, 1.0)
        fig.colorbar(axes[0, 2].images[0], ax=axes[:, 2].tolist(), shrink=0.8, label="sum w / (1 + sum w)")
    return fig


def blurriness(recording: Recording, requested: Sequence[int] | None = None) -> Figure:
    frames, values = _series(recording, ent.DEBLUR_BLURRINESS)
    fig = Figure(figsize=(8, 3), dpi=DPI, layout="constrained")
    ax = fig.subplots()
    ax.plot(frames, values, color="#b450c8", linewidth=1.2, label="b_t")
    sharpened = recording.indices(ent.DEBLUR_AFTER)
    if sharpened:
        lookup = dict(zip(frames.tolist(), values.tolist()))
        ax.plot(sharpened, [lookup.get(t, np.nan) for t in sharpened], "o", color="#202020", markersize=3,
                label="deblurred")
    ax.set_xlabel("frame")
    ax.set_ylabel("relative blurriness b_t")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.suptitle("Blurriness over time (eq. 28: 1 / sum of squared gradients)")
    return fig


def mosaic_variance(recording: Recording, requested: Sequence[int] | None = None) -> Figure:
    frames = pick_frames(recording, [ent.STABILIZED_FRAME, ent.COMPLETION_VARIANCE], requested)
    first = recording.image(ent.STABILIZED_FRAME, frames[0])
    height, width = first.shape[:2]
    fig = Figure(figsize=(2 * PANEL_WIDTH_IN + 1.2, PANEL_WIDTH_IN * height / width * len(frames) + 0.9), dpi=DPI,
                 layout="constrained")
    axes = fig.subplots(len(frames), 2, squeeze=False)
    variances = [recording.map(ent.COMPLETION_VARIANCE, t) for t in frames]
    vmax = visual.VARIANCE_RANGE[1]  # the viewer's colour bar (keys/variance): turbo, 0 to 400 intensity^2
    for r, (t, variance) in enumerate(zip(frames, variances)):
        stabilized = recording.image(ent.STABILIZED_FRAME, t)
        axes[r, 0].imshow(stabilized)
        axes[r, 1].imshow((stabilized * 0.35).astype(np.uint8))
        shown = axes[r, 1].imshow(np.ma.masked_invalid(variance), cmap="turbo", vmin=0.0, vmax=max(vmax, 1e-6))
        axes[r, 0].set_ylabel(f"frame {t}")
        for ax in axes[r]:
            ax.set_xticks([])
            ax.set_yticks([])
    axes[0, 0].set_title("2D stabilized", fontsize=9)
    axes[0, 1].set_title("mosaic variance v_t (eq. 20)", fontsize=9)
    fig.colorbar(shown, ax=axes[:, 1].tolist(), shrink=0.8, label="intensity^2 (0-255 scale)")
    fig.suptitle("Consistent mosaicing: variance of the neighbours over the missing area")
    return fig


FIGURES: dict[str, Callable[[Recording, Sequence[int] | None], Figure]] = {
    "trajectories": trajectories,
    "stabilized_vs_original": stabilized_vs_original,
    "completed_vs_stabilized": completed_vs_stabilized,
    "motion_inpainting": motion_inpainting,
    "deblurring": deblurring,
    "blurriness": blurriness,
    "mosaic_variance": mosaic_variance,
}


def build_figures(recording: Recording, frames: Sequence[int] | None = None) -> list[FigureResult]:
    results = []
    for name, build in FIGURES.items():
        try:
            results.append(FigureResult(name, build(recording, frames)))
        except Skip as reason:
            results.append(FigureResult(name, None, str(reason)))
    return results


def panel_count(fig: Figure) -> int:
    """Visible axes that are not colour bars."""
    return sum(1 for ax in fig.axes if ax.get_visible() and ax.get_label() != "<colorbar>")


def load_recording(path: Path) -> Recording:
    from ffviz.viewer import check_recording, version_note

    check_recording(path)
    try:
        return Recording.load(path)
    except Exception as error:  # the reader's errors name no file; say which and why it may fail
        note = version_note(path) or f"could not read {path}"
        raise InputError(f"{note} ({type(error).__name__}: {error})") from None


def render_figures(path: Path | str, out_dir: Path | str, *, fmt: str = "png", frames: Sequence[int] | None = None,
                   ) -> list[Path]:
    """Write every figure the recording allows to ``out_dir`` as NAME.FMT; print what was written or skipped."""
    if fmt not in FORMATS:
        raise InputError(f"figure format must be one of {', '.join(FORMATS)}, not {fmt!r}")
    path, out_dir = Path(path), Path(out_dir)
    recording = load_recording(path)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for result in build_figures(recording, frames):
        if result.figure is None:
            print(f"skipped {result.name}: {result.note}")
            continue
        target = out_dir / f"{result.name}.{fmt}"
        result.figure.savefig(target, format=fmt)
        written.append(target)
        print(f"wrote {target} ({panel_count(result.figure)} panels)")
    return written
