"""The interactive what-if debugger: the viewer's time cursor picks the frame, controls hold the main settings of each
stage, "apply" re-renders that frame with them and the new variant appears beside the others.

``notebook()`` puts it in Jupyter (rerun's notebook widget and ipywidgets); ``serve()`` in a page of our own for
`ffviz debug INPUT` (ffviz/debug_page.py). Both drive an ``ffviz.debug_session.DebugSession``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ffviz import entities as ent
from ffviz.debug_session import MAIN_SETTINGS, DebugSession, current_value
from pipeline.config import StabilizeConfig
from pipeline.errors import FFVizError, InputError


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
