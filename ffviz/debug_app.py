"""The interactive what-if debugger: the viewer's time cursor picks the frame, controls hold the main settings of each
stage, "apply" re-renders that frame with them and the new variant appears beside the others.

``DebugSession`` is the controller, the same for every host: it follows the viewer's events (the frame the cursor is
on) and renders variants through an ``ffviz.debugger.Debugger`` that streams into the viewer. ``notebook()`` puts it
in Jupyter (rerun's notebook widget and ipywidgets).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from ffviz import entities as ent
from pipeline import settings as named
from pipeline.config import StabilizeConfig
from pipeline.errors import FFVizError, InputError


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


def notebook(input: Path | str, config: StabilizeConfig = StabilizeConfig(), *, rrd: Path | str | None = None,
             width: int = 1100, height: int = 720) -> Any:
    """Jupyter: the debugger as a widget (controls above rerun's viewer). Show it as a cell's last expression.
    Needs `pip install -e ".[notebook]"`."""
    import ipywidgets as widgets

    from ffviz.debugger import Debugger
    from ffviz.viewer import notebook_live

    input = Path(input)
    live, viewer = notebook_live(width=width, height=height)
    debugger = Debugger(input, config, rrd=rrd or Path("recordings") / f"{input.stem}.debug.rrd",
                        live_url=live.grpc_url)
    session = DebugSession(debugger)
    debugger.frame(0)
    return widgets.VBox([_notebook_panel(session, viewer, widgets), viewer])


def _notebook_panel(session: DebugSession, viewer: Any, widgets: Any) -> Any:
    """The controls (frame, main settings, free settings, apply, status) wired to ``session`` and to ``viewer``'s
    events and time control (shown below them)."""
    config = session.debugger.session.config
    frame = widgets.BoundedIntText(value=session.frame, min=0, max=session.debugger.n_frames - 1, description="frame")
    controls = {c.name: (widgets.Dropdown(options=c.choices, value=current_value(config, c.name), description=c.label)
                         if c.choices else widgets.Text(value=current_value(config, c.name), description=c.label))
                for c in MAIN_SETTINGS}
    extra = widgets.Text(placeholder="any: section.field=value,...", description="more")
    name = widgets.Text(placeholder="(from the settings)", description="variant name")
    apply = widgets.Button(description="apply", button_style="primary")
    status = widgets.Label(value="move the time line to a frame, change settings, apply")

    def follow(t: int) -> None:
        frame.value = t

    def on_frame_typed(change: dict) -> None:
        session.frame = int(change["new"])
        viewer.set_time_ctrl(timeline=ent.FRAME_TIMELINE, sequence=session.frame)

    def on_apply(_: Any) -> None:
        status.value = f"rendering frame {session.frame} ..."
        try:
            settings = session.changed({n: str(c.value) for n, c in controls.items()}, extra.value)
        except FFVizError as error:
            status.value = f"not rendered: {error}"
            return
        status.value = session.apply(settings, name.value.strip() or None)

    session.on_frame.append(follow)
    frame.observe(on_frame_typed, names="value")
    viewer.on_event(session.on_viewer_event)
    apply.on_click(on_apply)
    for control in controls.values():
        control.style = {"description_width": "initial"}
    grid = widgets.GridBox(list(controls.values()), layout=widgets.Layout(grid_template_columns="repeat(3, 1fr)"))
    return widgets.VBox([widgets.HBox([frame, name, apply]), grid, extra, status])


# -- `ffviz debug INPUT`: the same, in a page of our own (ffviz/debug_page.py) -------------------------------------

def serve(input: Path, config: StabilizeConfig, *, rrd: Path, record_size: int | None, port: int,
          workers: int | None = None) -> int:
    """Open ``input``, render frame 0 as the default, serve the debugger page until Ctrl-C; the recording is
    finished then."""
    from http.server import ThreadingHTTPServer

    from ffviz.debug_page import DebugPage
    from ffviz.debugger import Debugger
    from ffviz.progress import tqdm_progress

    debugger = Debugger(input, config, rrd=rrd, stream=True, record_size=record_size, workers=workers,
                        progress=tqdm_progress)
    page = DebugPage(DebugSession(debugger))
    try:
        server = ThreadingHTTPServer(("127.0.0.1", port), page.handler())
    except OSError as error:
        debugger.abort()
        raise InputError(f"cannot serve the debugger on 127.0.0.1:{port}: {error.strerror} (--port)") from None
    page.start()
    print(f"debugger: http://127.0.0.1:{server.server_address[1]}/  (Ctrl-C to stop; the recording: {rrd})",
          flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
        debugger.close()
    print(f"wrote {rrd}", flush=True)
    return 0
