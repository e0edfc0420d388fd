"""What a recording keeps of one frame, made on the rendering thread as soon as the frame is (RerunRecorder.keep):
the pictures at the recorded size (``view.ViewSize``), masks and maps already encoded, statistics from the full-
resolution results. The recorder's thread then only encodes the frame streams, in order, and logs.

So a run holds each frame's intermediates only while this digest is made, never in a queue, and the digest's size
depends on the recorded size, not on the input's.
"""

from __future__ import annotations

import time
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator, Sequence

import cv2
import numpy as np
import rerun as rr

from ffviz import entities as ent, trace, visual
from ffviz.recording import encoders, legends
from ffviz.recording.columns import Row
from ffviz.recording.view import ViewSize
from pipeline.results import FrameResult, Stamp
from pipeline.runtime.colour import ColourDescription, display_rgb
from pipeline.stages.completion import SOURCE_FALLBACK, SOURCE_MOSAIC, SOURCE_NAMES, CompletionResult, from_a_neighbour
from pipeline.stages.local_warp import claims as flow_piece_claims
from pipeline.stages.deblur import DeblurResult

# An RGBA image's alpha is used by the viewer (rerun 0.41) only when the image's opacity is below 1: at the default
# 1 it is drawn opaque, its transparent pixels black (checked headless). 0.99 changes the colours by 1 %.
SEE_THROUGH = 0.99
MASK_DRAW_ORDER = 10.0  # masks above the frame streams they are drawn over
WEIGHTS_STEP = 8  # deblur/weights in the compact recording: multiples of 8/255 (--lossless: of 1/255)
FLOW_ARROW_STEP_PX = 16  # one flow arrow per this many recorded pixels


@dataclass(frozen=True)
class Spec:
    """How the recorder records: the level, lossless or not, the recorded size, the input's colour, traced frames."""

    level: str
    jpeg_quality: int | None
    view: ViewSize
    colour: ColourDescription
    traced: tuple[int, ...] = ()

    @property
    def lossless(self) -> bool:
        return self.jpeg_quality is None

    @property
    def full(self) -> bool:
        return self.level == "full"


@dataclass(frozen=True)
class Logged:
    """One log call: ``archetype`` at ``entity``, at the frame's time and at ``times`` on other timelines. A ``Row``
    (its fields only) is sent with the entity's rows of the next few frames, as columns (recording/columns.py)."""

    entity: str
    archetype: Any
    times: tuple[tuple[str, int], ...] = ()
    nbytes: int = 0  # the pictures' bytes it holds

    @property
    def loggable(self) -> Any:
        """What one ``log`` call takes."""
        return self.archetype.archetype() if isinstance(self.archetype, Row) else self.archetype


@dataclass
class FrameView:
    """A frame as the recording keeps it: frame streams (display RGB at the recorded size, H.264-encoded in frame
    order by the recorder's thread) and everything else ready to log; the CPU seconds each entity family took."""

    stamp: Stamp
    streams: list[tuple[str, np.ndarray]] = field(default_factory=list)
    logged: list[Logged] = field(default_factory=list)
    cpu: Counter = field(default_factory=Counter)
    synthesized_pixels: int | None = None  # where completion ran: how many pixels it synthesized (full resolution)

    @property
    def nbytes(self) -> int:
        """Bytes held (the pictures and encoded blobs; the small rest is not counted)."""
        return sum(rgb.nbytes for _, rgb in self.streams) + sum(item.nbytes for item in self.logged)


def family(entity: str) -> str:
    """The entity family a cost is counted under: a traced frame's pictures as 'trace', pass 1's entities as
    'motion', else the first two parts."""
    root = entity.split("/")[0]
    return root if root in (ent.TRACE, MOTION_FAMILY) else "/".join(entity.split("/")[:2])


MOTION_FAMILY = ent.MOTION_PARAMS.split("/")[0]


class _Builder:
    """Collects a FrameView's parts, each timed (this thread's CPU) under its entity family."""

    def __init__(self, spec: Spec, out: FrameView) -> None:
        self.spec, self.view = spec, spec.view
        self.out = out

    @contextmanager
    def timed(self, entity: str) -> Iterator[None]:
        started = time.thread_time()
        try:
            yield
        finally:
            self.out.cpu[family(entity)] += time.thread_time() - started

    def log(self, entity: str, archetype: Any, times: tuple[tuple[str, int], ...] = (), nbytes: int = 0) -> None:
        self.out.logged.append(Logged(entity, archetype, times, nbytes))

    def image(self, entity: str, rgb: np.ndarray, times: tuple[tuple[str, int], ...] = ()) -> None:
        """A picture (not a frame stream): JPEG, or raw with --lossless."""
        if self.spec.lossless:
            self.log(entity, rr.Image(np.ascontiguousarray(rgb), color_model="RGB"), times, rgb.nbytes)
        else:
            data = encoders.jpeg(rgb, self.spec.jpeg_quality)
            self.log(entity, Row(rr.EncodedImage, {"blob": data, "media_type": "image/jpeg"}), times, len(data))

    def png(self, entity: str, data: bytes, **options: Any) -> None:
        self.log(entity, Row(rr.EncodedImage, {"blob": data, "media_type": "image/png", **options}), nbytes=len(data))

    def display(self, rgb: np.ndarray) -> np.ndarray:
        """A frame as a person sees it at the recorded size: 8-bit display RGB by the input's colour description."""
        return display_rgb(self.view.frame(rgb), self.spec.colour)

    def frame(self, entity: str, rgb: np.ndarray) -> None:
        """A frame stream: H.264 by the recorder's thread, or a raw image with --lossless."""
        with self.timed(entity):
            shown = self.display(rgb)
            if self.spec.lossless:
                self.log(entity, rr.Image(np.ascontiguousarray(shown), color_model="RGB"), nbytes=shown.nbytes)
            else:
                self.out.streams.append((entity, shown))

    def classes(self, entity: str, classes: np.ndarray, legend: Sequence[tuple]) -> None:
        """A class map at the recorded size: SegmentationImage with --lossless (hover names), else a paletted PNG."""
        with self.timed(entity):
            classes = self.view.classes(classes)
            if self.spec.lossless:
                self.log(entity, rr.SegmentationImage(classes, draw_order=MASK_DRAW_ORDER), nbytes=classes.nbytes)
            else:
                self.png(entity, encoders.palette_png(classes, legend), opacity=SEE_THROUGH, draw_order=MASK_DRAW_ORDER)

    def map(self, entity: str, values: np.ndarray, colormap: str, value_range: tuple[float, float],
            shown: np.ndarray | None = None) -> None:
        """A float map, twice. At ``entity``, what the views show: a paletted PNG colour-mapped as its key,
        transparent where the map has no value (not finite, or not ``shown``); a depth image would paint those its
        lowest colour. At entities.map_values(entity), the values for reading back: float32 with --lossless, else
        a 16-bit PNG of steps of entities.MAP_STEPS (0: no value; a few kB, where the raw array would hold its
        zeros in the viewer's memory). Both are computed only where the map has a value (mostly the missing area)."""
        with self.timed(entity):
            values = self.view.values(np.asarray(values, np.float32))
            pictured = values if shown is None else self.view.values(np.where(shown, values, np.float32(np.nan)))
            flat, where = _finite(values)
            shown_flat, shown_where = (flat, where) if shown is None else _finite(pictured)
            indices = np.zeros(flat.shape, np.uint8)
            indices[shown_where] = visual.map_indices(shown_flat[shown_where], value_range)
            picture = encoders.indexed_png(indices.reshape(values.shape), visual.map_palette(colormap))
            self.png(entity, picture, opacity=SEE_THROUGH)
            if self.spec.lossless:
                exact = np.full(flat.shape, np.nan, np.float32)
                exact[where] = flat[where]
                self.log(ent.map_values(entity), rr.DepthImage(exact.reshape(values.shape), meter=1.0, colormap=colormap,
                                                               depth_range=value_range), nbytes=exact.nbytes)
                return
            step = ent.MAP_STEPS[entity]
            stored = np.zeros(flat.shape, np.uint16)
            stored[where] = np.clip(np.rint(flat[where] / np.float32(step)) + 1, 1, 65535).astype(np.uint16)
            data = encoders.png16(stored.reshape(values.shape))
            self.log(ent.map_values(entity), Row(rr.EncodedDepthImage, {
                "blob": data, "media_type": "image/png", "meter": 1.0 / step, "colormap": colormap,
                "depth_range": (value_range[0] / step + 1, value_range[1] / step + 1)}), nbytes=len(data))

    def clear(self, *entities: str, recursive: bool = False) -> None:
        for entity in entities:
            self.log(entity, rr.Clear(recursive=recursive))

    def scalar(self, entity: str, value: float) -> None:
        self.log(entity, Row(rr.Scalars, {"scalars": float(value)}))


def _finite(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map flattened, and the flat indices where it has a value."""
    flat = values.ravel()
    return flat, np.flatnonzero(np.isfinite(flat))


def digest(result: FrameResult, spec: Spec) -> FrameView:
    """What the recording keeps of ``result``'s intermediates (its output and temporal parts come later: finish)."""
    builder = _Builder(spec, FrameView(result.stamp))
    if result.completion is not None:  # counted here: the run keeps no completion mask once the digest is made
        builder.out.synthesized_pixels = int(np.count_nonzero(result.completion.missing))
    if result.input is not None:
        _trace(builder, "input", result.input.rgb)
        if spec.full:
            builder.frame(ent.INPUT_FRAME, result.input.rgb)
    if result.warp is not None:
        _trace(builder, "stabilized", result.warp.frame)
        if spec.full:
            builder.frame(ent.STABILIZED_FRAME, result.warp.frame)
            builder.classes(ent.STABILIZED_MISSING, result.warp.missing.view(np.uint8) * np.uint8(legends.MISSING_CLASS),
                            legends.MISSING_LEGEND)
    if result.completion is not None:
        _completion(builder, result.completion)
    if result.deblur is not None:
        _deblur(builder, result.deblur)
    return builder.out


def finish(view: FrameView, result: FrameResult, spec: Spec) -> FrameView:
    """``view`` with the frame's final parts: the output as written and, where temporal consistency ran, the mean
    share of the synthesized pixels averaged in from the frames next to it (the share is 0 on every other pixel)."""
    builder = _Builder(spec, view)
    if result.temporal is not None and view.synthesized_pixels is not None:
        share = float(result.temporal.share.sum()) / max(view.synthesized_pixels, 1)
        builder.scalar(ent.COMPLETION_TEMPORAL, share)
    _trace(builder, "output", result.output)
    builder.frame(ent.OUTPUT_FRAME, result.output)
    return view


def _completion(b: _Builder, result: CompletionResult) -> None:
    if b.out.stamp.index in b.spec.traced:
        _trace_completion(b, result)
    with b.timed(ent.COMPLETION_STATS):
        area = result.missing.size
        counts = class_counts(result.source)
        b.scalar(f"{ent.COMPLETION_STATS}/missing", np.count_nonzero(result.missing) / area)
        for code, name in enumerate(SOURCE_NAMES[1:], start=1):
            b.scalar(f"{ent.COMPLETION_STATS}/{name.replace(' ', '_')}", counts[code] / area)
    if not b.spec.full:
        return
    b.frame(ent.COMPLETION_FRAME, result.frame)
    b.map(ent.COMPLETION_VARIANCE, result.mosaic.variance, "turbo", visual.VARIANCE_RANGE)
    with b.timed(ent.COMPLETION_ACCEPTED):  # 0 known, 1 missing and rejected, 2 missing and accepted
        accepted = np.where(result.mosaic.accepted, np.uint8(2), result.missing.view(np.uint8))
    b.classes(ent.COMPLETION_ACCEPTED, accepted, legends.ACCEPTED_LEGEND)
    with b.timed(ent.COMPLETION_FILLED_BY):
        filled_by = filled_by_classes(result)
    b.classes(ent.COMPLETION_FILLED_BY, filled_by, legends.filled_by_legend())
    b.classes(ent.COMPLETION_SOURCE, result.source, legends.SOURCE_LEGEND)
    b.classes(ent.COMPLETION_FALLBACK, result.fallback.view(np.uint8), legends.FALLBACK_LEGEND)
    if result.fills:
        _first_neighbour_flow(b, result)
    else:  # no stale map from an earlier frame (nor its values)
        b.clear(ent.COMPLETION_FLOW_IMAGE, ent.COMPLETION_FLOW_ARROWS)
        b.clear(ent.COMPLETION_FMM_ORDER, ent.COMPLETION_FMM_ARRIVAL, recursive=True)


def class_counts(classes: np.ndarray) -> np.ndarray:
    """(256,) pixels of each class of a uint8 class map (OpenCV's histogram: a tenth of np.bincount's time)."""
    return cv2.calcHist([np.ascontiguousarray(classes, np.uint8)], [0], None, [256], [0, 256]).ravel().astype(np.int64)


def filled_by_classes(result: CompletionResult) -> np.ndarray:
    """Class per pixel: 0 original, 1 mosaic, 2 fallback, FILLED_BY_BASE + offset where one neighbour filled it
    (local warp, carried on or as is: completion/source tells which)."""
    source = np.ascontiguousarray(result.source, np.uint8)
    classes = cv2.LUT(source, _FILLED_BY_OF_SOURCE)
    warped = cv2.LUT(source, _FROM_A_NEIGHBOUR).view(bool)
    classes[warped] = (legends.FILLED_BY_BASE + result.filled_by[warped]).astype(np.uint8)
    return classes


# completion source -> its filled_by class unless one neighbour filled it; -> whether one did (OpenCV's lookup: a
# tenth of the comparisons' and np.isin's time)
_FROM_A_NEIGHBOUR = from_a_neighbour(np.arange(256, dtype=np.uint8)).astype(np.uint8)
_FILLED_BY_OF_SOURCE = np.zeros(256, np.uint8)
_FILLED_BY_OF_SOURCE[[SOURCE_MOSAIC, SOURCE_FALLBACK]] = (1, 2)


def _first_neighbour_flow(b: _Builder, result: CompletionResult) -> None:
    """The first neighbour's local flow, motion-inpainted (colour-coded and as arrows), and its Fast Marching
    visiting order and arrival time T (the thesis's Fig. 18), at the recorded size."""
    with b.timed(ent.COMPLETION_FLOW_IMAGE):
        flow, order, arrival = inpainted_at(result.fills[0], b.view)
        b.image(ent.COMPLETION_FLOW_IMAGE, visual.flow_to_rgb(flow))
        origins, vectors = visual.sparse_arrows(flow, FLOW_ARROW_STEP_PX)
        b.log(ent.COMPLETION_FLOW_ARROWS, Row(rr.Arrows2D, {"origins": origins, "vectors": vectors}, len(origins)))
    unvisited = order < 0
    visited = order.astype(np.float32)
    visited[unvisited] = np.nan
    top = float(order.max()) if not unvisited.all() else 1.0
    b.map(ent.COMPLETION_FMM_ORDER, visited, "viridis", (0.0, top))
    # Shown over the filled band only: T is 0 on every known pixel by definition.
    b.map(ent.COMPLETION_FMM_ARRIVAL, arrival, "magma", visual.ARRIVAL_RANGE, shown=arrival > 0)


def inpainted_at(fill: Any, view: ViewSize) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A neighbour's motion-inpainted flow (vectors in recorded pixels), Fast Marching visiting order (-1: not
    visited) and arrival time T (input pixels; inf where unreached) at the recorded size, sampled from its flow
    pieces (nearest working pixel) as completion's full-frame view pastes them: one visiting order over all boxes,
    each pixel taking the piece that claims it last."""
    flow = np.full((view.height, view.width, 2), np.nan, np.float32)
    order = np.full((view.height, view.width), -1, np.int32)
    arrival = np.full((view.height, view.width), np.inf, np.float32)
    visited = 0
    boxes = []
    for piece in fill.pieces:  # each box at the recorded size, once
        boxes.append(_box_at(piece, view, visited))
        visited += int(piece.inpainted.order.max(initial=-1)) + 1
    for k, (rows, cols) in flow_piece_claims(fill.pieces):
        (top, left), (box_flow, box_order, box_arrival) = boxes[k]
        y0, y1 = _recorded_span(rows, view.scale, view.height)
        x0, x1 = _recorded_span(cols, view.scale, view.width)
        if y1 <= y0 or x1 <= x0:
            continue
        inside = (slice(y0 - top, y1 - top), slice(x0 - left, x1 - left))
        flow[y0:y1, x0:x1] = box_flow[inside]
        order[y0:y1, x0:x1] = box_order[inside]
        arrival[y0:y1, x0:x1] = box_arrival[inside]
    return flow, order, arrival


def _recorded_span(span: slice, scale: float, limit: int) -> tuple[int, int]:
    """Recorded pixels whose centres fall in the input pixels ``span`` (half-open)."""
    first = min(max(int(np.ceil((span.start + 0.5) * scale - 0.5)), 0), limit)
    stop = min(max(int(np.ceil((span.stop + 0.5) * scale - 0.5)), first), limit)
    return first, stop


def _box_at(piece: Any, view: ViewSize, visited: int) -> tuple[tuple[int, int], tuple[np.ndarray, ...]]:
    """A flow piece's box at the recorded size, from its nearest working pixels: (top, left) and (flow in recorded
    pixels, visiting order continuing after ``visited``, arrival in input pixels)."""
    rows, cols = piece.box
    result = piece.inpainted
    height, width = result.order.shape
    y0, y1 = _recorded_span(rows, view.scale, view.height)
    x0, x1 = _recorded_span(cols, view.scale, view.width)

    def taps(first: int, stop: int, box_start: int, size: int) -> np.ndarray:
        source = (np.arange(first, stop) + 0.5) / view.scale - 0.5  # input pixel coordinates
        return np.clip(np.rint((source - box_start + 0.5) * piece.scale - 0.5).astype(np.int64), 0, size - 1)

    vs, us = taps(y0, y1, rows.start, height), taps(x0, x1, cols.start, width)
    pick = lambda values: values.take(vs, axis=0).take(us, axis=1)  # noqa: E731
    order = pick(result.order).astype(np.int32)
    order = np.where(order >= 0, order + np.int32(visited), np.int32(-1))
    return (y0, x0), (pick(result.flow) * np.float32(view.scale / piece.scale), order,
                      pick(result.arrival) / np.float32(piece.scale))


def _deblur(b: _Builder, result: DeblurResult) -> None:
    _trace(b, "deblurred", result.frame)
    neighbours = tuple(result.neighbours)
    with b.timed(ent.DEBLUR_BLURRINESS):
        b.scalar(ent.DEBLUR_BLURRINESS, result.blurriness)
        b.scalar(ent.DEBLUR_NEIGHBOURS, len(neighbours))
        refused = result.refused
        b.scalar(ent.DEBLUR_REFUSED, np.count_nonzero(refused) / refused.size if refused is not None else 0.0)
    if not b.spec.full:
        return
    # Where each pixel came from, and where a sharper neighbour was refused (shown even when none was used).
    with b.timed(ent.DEBLUR_SOURCE):
        classes = deblur_source_classes(result)
    if classes.any():
        b.classes(ent.DEBLUR_SOURCE, classes, legends.deblur_source_legend())
    else:
        b.clear(ent.DEBLUR_SOURCE)
    if not neighbours:  # nothing was sharpened: clear, so the viewer shows no stale frame from earlier
        b.clear(ent.DEBLUR_BEFORE, ent.DEBLUR_AFTER, ent.DEBLUR_WEIGHTS, ent.map_values(ent.DEBLUR_WEIGHTS))
        return
    # Sparse video streams (only sharpened frames; cleared in between, which hides them there).
    b.frame(ent.DEBLUR_BEFORE, result.before)
    b.frame(ent.DEBLUR_AFTER, result.frame)
    if result.weights is not None:
        _deblur_weights(b, result.weights)


def _deblur_weights(b: _Builder, weights: np.ndarray) -> None:
    """Each pixel's share from the neighbours: a picture in the key's colours (a paletted PNG; as a depth image with
    a colour map, rerun 0.41 drew every weight in the map's lowest colour) and the values, 8 bits (255 = 1), in
    steps of WEIGHTS_STEP unless lossless: plenty to look at, a third of the bytes."""
    with b.timed(ent.DEBLUR_WEIGHTS):
        stored = _stored_weights(b.view.values(weights), b.spec.lossless)
        b.png(ent.DEBLUR_WEIGHTS, encoders.indexed_png(_WEIGHT_INDICES[stored], visual.map_palette("viridis")))
        data = encoders.png16(stored)  # lossless for the stored values, a tenth of the raw bytes
        b.log(ent.map_values(ent.DEBLUR_WEIGHTS), Row(rr.EncodedDepthImage, {
            "blob": data, "media_type": "image/png", "meter": ent.DEBLUR_WEIGHTS_SCALE, "colormap": "viridis",
            "depth_range": (0.0, ent.DEBLUR_WEIGHTS_SCALE)}), nbytes=len(data))


def _stored_weights(weights: np.ndarray, lossless: bool) -> np.ndarray:
    stored = np.clip(np.asarray(weights, np.float32) * np.float32(ent.DEBLUR_WEIGHTS_SCALE) + np.float32(0.5),
                     0, 255).astype(np.uint8)
    return stored if lossless else _WEIGHT_STEPS[stored]


# stored weight -> its multiple of WEIGHTS_STEP; stored weight -> the weights' palette index (visual.map_indices)
_WEIGHT_STEPS = np.minimum(np.rint(np.arange(256) / WEIGHTS_STEP) * WEIGHTS_STEP, 255).astype(np.uint8)
_WEIGHT_INDICES = visual.map_indices(np.arange(256, dtype=np.float32) / np.float32(ent.DEBLUR_WEIGHTS_SCALE),
                                     (0.0, 1.0))


def deblur_source_classes(result: DeblurResult) -> np.ndarray:
    """Class per pixel: FILLED_BY_BASE + offset the neighbour that gave most (5 % or more); 1 where none gave
    and a sharper neighbour was refused (other content: the frame keeps its own pixel for that reason); 0 the
    frame's own. (Marking every pixel where some neighbour was refused painted nearly whole frames red on real
    footage, where a far neighbour is refused almost everywhere while the near ones give most of the pixel.)"""
    shape = result.frame.shape[:2]
    classes = np.zeros(shape, np.uint8)
    source = result.main_source
    taken = np.zeros(shape, bool) if source is None else source != 0
    if taken.any():
        classes[taken] = (legends.FILLED_BY_BASE + source[taken].astype(np.int16)).astype(np.uint8)
    refused = result.refused
    if refused is not None:
        classes[refused & ~taken] = 1
    return classes


# -- stage stepping (traced frames, on the `stage` and `fmm_step` timelines, at the recorded size) -----------------

def _trace(b: _Builder, stage: str, rgb: np.ndarray) -> None:
    """A traced frame's picture after ``stage`` on the ``stage`` timeline (frame = the traced frame)."""
    t = b.out.stamp.index
    if t not in b.spec.traced:
        return
    with b.timed(ent.TRACE):
        step = ent.TRACE_STAGES.index(stage)
        times = ((ent.STAGE_TIMELINE, step),)
        b.image(ent.trace_image(t), b.display(rgb), times)
        b.log(ent.trace_label(t), _label(b.view, trace.stage_label(t, step)), times)


def _label(view: ViewSize, text: str) -> Row:
    """A picture's label: a box around the whole of it, titled."""
    half = (view.width / 2, view.height / 2)
    return Row(rr.Boxes2D, {"centers": half, "half_sizes": half, "colors": _LABEL_RGBA, "labels": text,
                            "show_labels": True})


_LABEL_RGBA = np.uint32(int.from_bytes(bytes(legends.LABEL_COLOUR), "big"))  # packed 0xRRGGBBAA: a row's one colour


def _trace_completion(b: _Builder, result: CompletionResult) -> None:
    """Mosaic and local-warp stages, and the first neighbour's Fast Marching band (Fig. 18)."""
    _trace(b, "mosaic", result.mosaic.frame)
    _trace(b, "motion-inpainted", trace.local_warp_frame(result.mosaic.frame, result.frame,
                                                          from_a_neighbour(result.source)))
    if not result.fills:
        return
    with b.timed(ent.TRACE):
        t, fill = b.out.stamp.index, result.fills[0]
        flow, order, _ = inpainted_at(fill, b.view)
        stabilized = np.where(b.view.mask(result.missing)[..., None], np.uint8(0), b.display(result.mosaic.frame))
        for step, filled, total, image in trace.fmm_band_images(stabilized, flow, order):
            times = ((ent.FMM_STEP_TIMELINE, step),)
            b.image(ent.trace_fmm(t), image, times)
            b.log(ent.trace_fmm_label(t), _label(b.view, f"frame {t}: Fast Marching, {filled} of {total} pixels "
                                                          f"filled (neighbour {fill.offset:+d})"), times)
