"""The what-if debugger's controller, the same for every host (the notebook, the page): it follows the viewer's
events (the frame the time cursor is on) and renders variants of that frame through an ``ffviz.debugger.Debugger``;
and the main settings of each stage that the hosts offer with a control of their own."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping

from ffviz import entities as ent
from pipeline import settings as named
from pipeline.config import StabilizeConfig
from pipeline.errors import FFVizError


@dataclass(frozen=True)
class Control:
    """A setting offered with a control of its own: its name, a label, and its choices (None: typed in)."""

    name: str
    label: str
    choices: tuple[str, ...] | None = None


MAIN_SETTINGS = (
    Control("mode", "mode", ("full", "crop", "none")),
    Control("smoothing.radius_frames", "smoothing k (frames, eq. 18)"),
    Control("completion.neighbour_frames", "completion neighbours (frames each side)"),
    Control("completion.max_warp_neighbours", "neighbours with a local flow"),
    Control("completion.mosaic.variance_threshold", "mosaic variance threshold (eq. 21)"),
    Control("completion.temporal.radius", "temporal consistency (frames each side)"),
    Control("deblur.enabled", "deblurring", ("true", "false")),
    Control("deblur.alpha", "deblur alpha (eq. 31)"),
    Control("deblur.neighbour_frames", "deblur neighbours (frames each side)"),
)


def current_value(config: StabilizeConfig, name: str) -> str:
    value: Any = config
    for part in name.split("."):
        value = getattr(value, part)
    return str(value).lower() if isinstance(value, bool) else str(value)


class DebugSession:
    """Follows the viewer (``on_viewer_event``) and renders the frame it is on with other settings (``apply``)."""

    def __init__(self, debugger: Any) -> None:
        self.debugger = debugger
        self.frame = 0
        self.timeline = ent.FRAME_TIMELINE
        self.on_frame: list[Callable[[int], None]] = []  # told when the cursor moves to another frame

    def on_viewer_event(self, event: Any) -> None:
        """rerun.notebook's TimelineChangeEvent / TimeUpdateEvent: the frame under the time cursor."""
        timeline = getattr(event, "timeline", None)
        if timeline is not None:
            self.timeline = timeline
        time = getattr(event, "time", None)
        if time is None or self.timeline != ent.FRAME_TIMELINE:
            return
        frame = min(max(int(round(float(time))), 0), self.debugger.n_frames - 1)
        if frame != self.frame:
            self.frame = frame
            for callback in self.on_frame:
                callback(frame)

    def changed(self, values: Mapping[str, str], extra: str = "") -> dict[str, str]:
        """The settings that differ from the session's, from the controls' ``values`` and free text ``extra``."""
        config = self.debugger.session.config
        settings = {name: value.strip() for name, value in values.items()
                    if value.strip() and value.strip() != current_value(config, name)}
        if extra.strip():
            settings.update(named.parse_settings(extra))
        return settings

    def apply(self, settings: Mapping[str, str], name: str | None = None) -> str:
        """Render the current frame with ``settings``; returns a line saying what was done (or what was wrong)."""
        try:
            self.debugger.frame(self.frame, settings, name=name or None)
        except FFVizError as error:
            return f"not rendered: {error}"
        t, variant, seconds = self.debugger.rendered[-1]
        return f"frame {t}: variant {variant!r} rendered in {seconds:.1f} s"
