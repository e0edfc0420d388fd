"""The debugger's recording: frames rendered alone, each a named variant (``default``, ``alpha=4``, ...), recorded
at their frame's time under ``variants/<name>/`` with the run recording's entity layout below that (``completion/
source``, ``output/frame``, ...), so the same stage of two variants sits side by side with the same colour keys.

Each variant but the default also gets its difference from the default at the same frame: ``diff/output`` (the
largest change of a colour channel per pixel, 0-64 levels in the key's colour map), ``diff/source`` (pixels whose
way of filling changed) and ``diff/stats`` (PSNR against the default, share of pixels that changed source). A
variant whose settings shape the path has its planned path under ``variants/<name>/path``. Frames are recorded as
PNG (exact at the recorded size), not as video: a variant is one frame.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import cv2
import numpy as np
import rerun as rr

from ffviz import entities as ent, visual
from ffviz.recording import digest, encoders, legends
from ffviz.recording.sink import RecordingFile
from ffviz.recording.view import ViewSize
from pipeline.results import FrameResult, PathPlan
from pipeline.runtime.colour import ColourDescription

DEBUG_APPLICATION_ID = "ffviz-debug"  # the debugger's recordings (their layout is their own)
VARIANTS = "variants"
NAMES = f"{VARIANTS}/names"  # static text: the variants' names, one a line, in order
DIFF_RANGE = (0.0, 64.0)  # intensity levels: the output difference's colour range
PSNR_CAP = 99.0  # dB: an output identical to the default's
BATCHER = rr.ChunkBatcherConfig(flush_tick=0.5, flush_num_bytes=4 << 20, flush_num_rows=4096)  # live: shows at once
CHANGED_LEGEND = [(0, "same", (0, 0, 0, 0)), (1, "filled another way than the default", (255, 60, 160, 210))]


def entity_name(name: str) -> str:
    """A variant's name as one entity path part (its letters, digits, '.', '-', the rest '_')."""
    return re.sub(r"[^A-Za-z0-9.\-]+", "_", name).strip("_") or "variant"


def variant_entity(name: str, entity: str) -> str:
    return f"{VARIANTS}/{entity_name(name)}/{entity}"


@dataclass
class _Default:
    """The default variant's output and fill at a frame, at the recorded size (what the others are compared with)."""

    output: np.ndarray
    source: np.ndarray | None


class VariantRecording:
    """Writes variants to ``path`` (and to a viewer at ``live_url``, or to ``stream``); ``names`` in the order they
    came."""

    def __init__(self, path: Path, *, width: int, height: int, fps: float, colour: ColourDescription | None,
                 record_size: int | None, live_url: str | None = None, stream: bool = False) -> None:
        self._out = RecordingFile(path, application_id=DEBUG_APPLICATION_ID, batcher=BATCHER, live_url=live_url,
                                  stream=stream)
        self.rec = self._out.rec
        self.stream = self._out.stream  # with ``stream``: what was recorded, to forward (BinaryStream.read)
        self.view = ViewSize.of(width, height, record_size)
        self.spec = digest.Spec("full", 90, self.view, colour or ColourDescription(), ())
        self.fps = fps
        self.names: list[str] = []
        self.settings: dict[str, Mapping[str, Any]] = {}
        self._defaults: dict[int, _Default] = {}
        self._log_keys()

    def _log_keys(self) -> None:
        for name, image in legends.colour_keys().items():
            self.rec.log(ent.key_entity(name), rr.EncodedImage(contents=encoders.png(image), media_type="image/png"),
                         static=True)
        self.rec.log(ent.key_entity("diff"), rr.EncodedImage(contents=encoders.png(visual.colour_bar(
            "magma", *DIFF_RANGE, "largest channel difference from the default (0-255 levels)",
            "difference from the default")), media_type="image/png"), static=True)

    def _add(self, name: str, settings: Mapping[str, Any]) -> None:
        if name in self.names:
            return
        self.names.append(name)
        self.settings[name] = dict(settings)
        self.rec.log(NAMES, rr.TextDocument("\n".join(self.names)), static=True)  # for the layout, read back
        for entity, (legend, _) in legends.class_legends().items():
            self.rec.log(variant_entity(name, entity), rr.AnnotationContext(legend), static=True)
        self.rec.log(variant_entity(name, "diff/source"), rr.AnnotationContext(CHANGED_LEGEND), static=True)

    def log_variant(self, t: int, name: str, settings: Mapping[str, Any], result: FrameResult, seconds: float) -> None:
        """Frame ``t`` rendered as variant ``name`` (``settings``: what differs from the default) in ``seconds``."""
        self._add(name, settings)
        view = digest.finish(digest.digest(result, self.spec), result, self.spec)
        self.rec.set_time(ent.FRAME_TIMELINE, sequence=t)
        self.rec.set_time(ent.VIDEO_TIME_TIMELINE, duration=result.stamp.time_s)
        for item in view.logged:
            self.rec.log(variant_entity(name, item.entity), item.loggable)
        for entity, rgb in view.streams:
            self.rec.log(variant_entity(name, entity), rr.EncodedImage(contents=encoders.png(rgb),
                                                                       media_type="image/png"))
        shown = dict(view.streams)[ent.OUTPUT_FRAME]
        source = self.view.classes(result.completion.source) if result.completion is not None else None
        if name == "default":
            self._defaults[t] = _Default(shown, source)
        elif t in self._defaults:
            self._log_difference(name, self._defaults[t], shown, source)
        described = ", ".join(f"`{k} = {v}`" for k, v in settings.items()) or "the session's settings"
        self.rec.log(variant_entity(name, "about"), rr.TextDocument(
            f"**{name}** at frame {t}: {described}; rendered in {seconds:.1f} s", media_type=rr.MediaType.MARKDOWN))

    def _log_difference(self, name: str, default: _Default, output: np.ndarray, source: np.ndarray | None) -> None:
        """Where and by how much the variant's output differs from the default's, and where it filled otherwise."""
        change = np.abs(output.astype(np.int16) - default.output.astype(np.int16)).max(axis=-1).astype(np.float32)
        picture = encoders.indexed_png(visual.map_indices(change, DIFF_RANGE), visual.map_palette("magma"))
        self.rec.log(variant_entity(name, "diff/output"), rr.EncodedImage(contents=picture, media_type="image/png"))
        psnr = cv2.PSNR(output, default.output) if change.any() else float("inf")
        self.rec.log(variant_entity(name, "diff/stats/psnr_db"), rr.Scalars(min(psnr, PSNR_CAP)))
        if source is not None and default.source is not None:
            changed = (source != default.source).astype(np.uint8)
            self.rec.log(variant_entity(name, "diff/source"), rr.EncodedImage(
                contents=encoders.palette_png(changed, CHANGED_LEGEND), media_type="image/png",
                opacity=digest.SEE_THROUGH, draw_order=digest.MASK_DRAW_ORDER))
            self.rec.log(variant_entity(name, "diff/stats/changed_source"), rr.Scalars(float(changed.mean())))

    def log_path(self, name: str, plan: PathPlan, settings: Mapping[str, Any] | None = None) -> None:
        """The path variant ``name`` plans (and, once, the original path), for the whole video."""
        self._add(name, settings or {})
        frames = np.arange(len(plan.smoothing.smoothed_trajectory))
        indexes = [rr.TimeColumn(ent.FRAME_TIMELINE, sequence=frames)]
        for root, trajectory in ((f"{VARIANTS}/original_path", plan.smoothing.original_trajectory),
                                 (variant_entity(name, "path"), plan.smoothing.smoothed_trajectory)):
            for column, axis in enumerate(ent.TRAJECTORY_AXES):
                self.rec.send_columns(f"{root}/{axis}", indexes=indexes,
                                      columns=rr.Scalars.columns(scalars=trajectory[:, column]))

    @property
    def error(self) -> OSError | None:
        return self._out.error

    def send_blueprint(self, blueprint: Any) -> None:
        self.rec.send_blueprint(blueprint, make_active=True, make_default=True)

    def finish(self) -> None:
        self._out.finish()

    def drop(self) -> None:
        self._out.drop()
