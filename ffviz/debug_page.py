"""The debugger's page: rerun-notebook's viewer bundle (its ``widget.js`` and wasm, served from the installed package)
under a row of controls, talking to Python over plain HTTP on 127.0.0.1.

Python -> page: a long-polled stream of messages (``GET /api/msgs?after=N``): the recording's bytes as it grows (kept
and replayed to a page that opens later), time-control commands, and status lines for the controls. Page -> Python:
the viewer's events (``POST /api/event``: the time cursor), ``apply`` (``POST /api/apply``: settings to render the
frame with) and a typed frame (``POST /api/goto``). The viewer is driven through the few calls of the anywidget model
its bundle uses (``get``, ``on``, ``send``); that protocol is rerun-notebook's own, hence the pinned version.
"""

from __future__ import annotations

import html
import importlib.util
import json
import struct
import threading
from http.server import BaseHTTPRequestHandler
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from ffviz import entities as ent
from ffviz.debug_session import MAIN_SETTINGS, current_value

POLL_SECONDS = 25.0  # a long poll answers at the latest after this, empty
NO_BUFFER = 0xFFFFFFFF


def viewer_assets() -> dict[str, tuple[str, Path]]:
    """URL -> (content type, file) of rerun-notebook's viewer bundle, found without importing the package (its
    import loads Jupyter's widget machinery)."""
    spec = importlib.util.find_spec("rerun_notebook")
    if spec is None or not spec.submodule_search_locations:
        from pipeline.errors import ConfigError

        raise ConfigError('the debugger page needs rerun-notebook: pip install -e ".[notebook]"')
    static = Path(next(iter(spec.submodule_search_locations))) / "static"
    return {"/static/widget.js": ("text/javascript", static / "widget.js"),
            "/static/re_viewer_bg.wasm": ("application/wasm", static / "re_viewer_bg.wasm"),
            "/static/widget.css": ("text/css", static / "widget.css")}


class Hub:
    """Messages to the page, in order; the recording's bytes are kept and replayed to a page that opens later."""

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._items: list[tuple[int, dict, bytes | None]] = []
        self._kept: list[tuple[int, dict, bytes | None]] = []
        self.seq = 0

    def send(self, content: dict, buffer: bytes | None = None, *, keep: bool = False) -> None:
        with self._changed:
            self.seq += 1
            item = (self.seq, content, buffer)
            (self._kept if keep else self._items).append(item)
            self._items = [i for i in self._items if i[0] > self.seq - 256]  # a live page is never that far behind
            self._changed.notify_all()

    def since(self, after: int, timeout: float = POLL_SECONDS) -> tuple[int, bytes]:
        """(the latest number, the packed messages after ``after``; a new page, after=0, gets the kept ones)."""
        with self._changed:
            self._changed.wait_for(lambda: self.seq > after, timeout=timeout)
            items = sorted(i for i in self._kept + ([] if after == 0 else self._items) if i[0] > after)
            return self.seq, b"".join(_packed(content, buffer) for _, content, buffer in items)


def _packed(content: dict, buffer: bytes | None) -> bytes:
    """One message: u32 JSON length, JSON, u32 buffer length (NO_BUFFER: none), buffer; little-endian."""
    text = json.dumps(content).encode()
    head = struct.pack("<I", len(text)) + text
    return head + (struct.pack("<I", NO_BUFFER) if buffer is None else struct.pack("<I", len(buffer)) + buffer)


class DebugPage:
    """Serves ``session`` (an ffviz.debug_app.DebugSession whose debugger records with ``stream=True``)."""

    def __init__(self, session: Any) -> None:
        self.session = session
        self.hub = Hub()
        self._rendering = threading.Lock()
        self.assets = viewer_assets()

    def start(self) -> None:
        """The default at frame 0, so that the page opens on something."""
        self.session.debugger.frame(self.session.frame)
        self.forward()

    def forward(self) -> None:
        """What the recording gained since, to every page."""
        data = self.session.debugger.recording.stream.read(flush=True)
        if data:
            self.hub.send({"type": "rrd"}, bytes(data), keep=True)

    def status(self, text: str) -> None:
        self.hub.send({"type": "ui", "status": text, "frame": self.session.frame})

    def goto(self, frame: int) -> None:
        """The viewer's time cursor to ``frame`` (as rerun.notebook's set_time_ctrl; integers travel as text)."""
        self.session.frame = min(max(int(frame), 0), self.session.debugger.n_frames - 1)
        self.hub.send({"type": "time_ctrl", "timeline": ent.FRAME_TIMELINE, "sequence": str(self.session.frame),
                       "duration_nanos": None, "timestamp_nanos": None, "play": False})

    def on_viewer_event(self, event: dict) -> None:
        before = self.session.frame
        self.session.on_viewer_event(SimpleNamespace(**event))
        if self.session.frame != before:
            self.status(f"frame {self.session.frame}")

    def apply(self, values: dict, extra: str, name: str) -> None:
        """Render the current frame with the controls' settings (one at a time), then tell the page."""
        from pipeline.errors import FFVizError

        with self._rendering:
            self.status(f"rendering frame {self.session.frame} ...")
            try:
                settings = self.session.changed({str(k): str(v) for k, v in values.items()}, extra)
            except FFVizError as error:
                self.status(f"not rendered: {error}")
                return
            line = self.session.apply(settings, name.strip() or None)
            self.forward()
            self.status(line)

    def page(self) -> bytes:
        config = self.session.debugger.session.config
        controls = []
        for control in MAIN_SETTINGS:
            value = current_value(config, control.name)
            label = html.escape(control.label)
            if control.choices:
                options = "".join(f'<option{" selected" if c == value else ""}>{html.escape(c)}</option>'
                                  for c in control.choices)
                field = f'<select data-setting="{control.name}">{options}</select>'
            else:
                field = f'<input data-setting="{control.name}" value="{html.escape(value)}" size="6">'
            controls.append(f"<label>{label} {field}</label>")
        last = self.session.debugger.n_frames - 1
        return (PAGE.replace("{{CONTROLS}}", "\n".join(controls)).replace("{{LAST}}", str(last))
                .replace("{{TITLE}}", html.escape(self.session.debugger.session.path.name)).encode())

    def handler(self) -> type:
        return _handler(self)


def _handler(page: DebugPage) -> type:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args: Any) -> None:  # quiet: the terminal shows the debugger's own lines
            pass

        def _send(self, body: bytes, kind: str, *, code: int = 200, cache: bool = False, seq: int | None = None):
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "max-age=3600" if cache else "no-store")
            if seq is not None:
                self.send_header("X-Seq", str(seq))
            self.end_headers()
            self.wfile.write(body)

        def do_GET(self) -> None:
            path, _, query = self.path.partition("?")
            if path == "/":
                self._send(page.page(), "text/html; charset=utf-8")
            elif path in page.assets:
                kind, file = page.assets[path]
                self._send(file.read_bytes(), kind, cache=True)
            elif path == "/api/msgs":
                after = int(dict(kv.split("=", 1) for kv in query.split("&") if "=" in kv).get("after", 0))
                seq, body = page.hub.since(after)
                self._send(body, "application/octet-stream", seq=seq)
            else:
                self._send(b"not found", "text/plain", code=404)

        def do_POST(self) -> None:
            body = json.loads(self.rfile.read(int(self.headers.get("Content-Length", 0))) or b"{}")
            if self.path == "/api/event":
                page.on_viewer_event(json.loads(body) if isinstance(body, str) else body)
            elif self.path == "/api/ready":
                page.goto(page.session.frame)  # the viewer would open on the last frame otherwise
                page.status(f"frame {page.session.frame}: move the time line to a frame, change settings, apply")
            elif self.path == "/api/goto":
                page.goto(int(body.get("frame", 0)))
            elif self.path == "/api/apply":
                threading.Thread(target=page.apply, args=(body.get("settings", {}), body.get("extra", ""),
                                                          body.get("name", "")), daemon=True).start()
            else:
                self._send(b"not found", "text/plain", code=404)
                return
            self._send(b"{}", "application/json")

    return Handler


PAGE = r"""<!doctype html>
<html><head><meta charset="utf-8"><title>ffviz debug: {{TITLE}}</title>
<link rel="stylesheet" href="/static/widget.css">
<style>
 body { font-family: sans-serif; margin: 6px; background: #111; color: #ddd; font-size: 13px }
 #controls { display: flex; flex-wrap: wrap; gap: 4px 14px; align-items: center; margin-bottom: 6px }
 input, select, button { background: #222; color: #eee; border: 1px solid #555; padding: 2px 4px }
 button { background: #2a5bd7; border-color: #2a5bd7; padding: 3px 14px; cursor: pointer }
 #status { color: #9cf }
</style></head><body>
<div id="controls">
 <label>frame <input id="frame" type="number" min="0" max="{{LAST}}" value="0" size="5"></label>
 {{CONTROLS}}
 <label>more <input id="extra" placeholder="section.field=value,..." size="28"></label>
 <label>variant name <input id="name" placeholder="(from the settings)" size="14"></label>
 <button id="apply">apply</button>
 <span id="status">loading the viewer ...</span>
</div>
<div id="viewer"></div>
<script type="module">
import widget from "/static/widget.js";
const state = {_url: null, _panel_states: null, _width: "auto", _height: Math.max(window.innerHeight - 90, 400),
               _fallback_token: null, _theme: "dark"};
const listeners = {};
const post = (path, body) => fetch(path, {method: "POST", headers: {"Content-Type": "application/json"},
                                          body: JSON.stringify(body)});
const model = {
  get: (key) => state[key],
  set: (key, value) => { state[key] = value; },
  on: (event, callback) => { (listeners[event] ||= []).push(callback); },
  off: () => {},
  save_changes: () => {},
  // the bundle sends "ready" once, then each viewer event (time cursor, selection, ...) as JSON text
  send: (content) => { if (content === "ready") { post("/api/ready", {}); poll(); } else post("/api/event", content); },
};
window.ffviz = {received: 0, status: ""};
async function poll() {
  let after = 0;
  for (;;) {
    let response;
    try { response = await fetch(`/api/msgs?after=${after}`); }
    catch (error) { await new Promise((wake) => setTimeout(wake, 1000)); continue; }
    after = Number(response.headers.get("X-Seq"));
    const data = await response.arrayBuffer(), view = new DataView(data);
    for (let at = 0; at < data.byteLength;) {
      const length = view.getUint32(at, true); at += 4;
      const message = JSON.parse(new TextDecoder().decode(new Uint8Array(data, at, length))); at += length;
      const size = view.getUint32(at, true); at += 4;
      let buffers = [];
      if (size !== 0xFFFFFFFF) { buffers = [new DataView(data.slice(at, at + size))]; at += size; }
      if (message.type === "ui") {
        document.getElementById("status").textContent = window.ffviz.status = message.status;
        document.getElementById("frame").value = message.frame;
        continue;
      }
      if (message.type === "rrd") window.ffviz.received += size;
      (listeners["msg:custom"] || []).forEach((callback) => callback(message, buffers));
    }
  }
}
document.getElementById("frame").onchange = (e) => post("/api/goto", {frame: Number(e.target.value)});
document.getElementById("apply").onclick = () => {
  const settings = {};
  document.querySelectorAll("[data-setting]").forEach((e) => { settings[e.dataset.setting] = e.value; });
  post("/api/apply", {settings, extra: document.getElementById("extra").value,
                      name: document.getElementById("name").value});
};
widget.render({model, el: document.getElementById("viewer")});
</script></body></html>
"""
