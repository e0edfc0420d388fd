"""`ffviz snapshot`: a picture of what the viewer shows for a recording at a frame, on a tab, rendered headless.

The native viewer runs without a window (`rerun --headless`, software Vulkan on these machines) with the
recording and a blueprint file (.rbl) that is the recording's own layout with the asked tab active; it is
driven over its control API (rerun.experimental.ViewerClient): wait for the load, move the time cursor, then
take screenshots until two in a row are the same (the video frames have been decoded and drawn).
The native viewer decodes H.264 frame streams with the `ffmpeg` executable: it must be on PATH.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

from ffviz import entities as ent
from ffviz.blueprint import TAB_ORDER, debug_blueprint, debug_tabs, default_blueprint
from ffviz.recording import variants
from ffviz.viewer import check_recording, rerun_executable, stop_process_group
from pipeline.errors import ConfigError, InputError

DEFAULT_SIZE = (1280, 800)  # logical points; the PNG is at the viewer's pixel scale
APPLICATION_ID = "ffviz"


def tab_index(name: str, tabs: tuple[str, ...] = TAB_ORDER) -> int:
    """The tab a name (or an unambiguous prefix of one, any case) means."""
    wanted = name.strip().lower()
    exact = [i for i, tab in enumerate(tabs) if tab == wanted]
    matches = exact or [i for i, tab in enumerate(tabs) if tab.startswith(wanted)]
    if len(matches) != 1:
        raise ConfigError(f"--tab {name!r}: choose one of {', '.join(repr(t) for t in tabs)}")
    return matches[0]


def recording_layout(recording: Path) -> tuple[Any, tuple[str, ...], str]:
    """The layout ``recording`` opens with, its tabs' names and its application id: a run's, or the debugger's
    (one column per variant, named in the recording)."""
    from ffviz.rrd import Recording

    loaded = Recording.load(recording)
    if variants.NAMES in loaded.entities:
        names = loaded.texts(variants.NAMES, "TextDocument:text")[-1].split("\n")
        paths = any(entity.startswith(f"{variants.VARIANTS}/") and "/path/" in entity for entity in loaded.entities)
        return debug_blueprint(names, paths=paths), debug_tabs(paths), variants.DEBUG_APPLICATION_ID
    traced, flags = layout_facts(recording)
    return default_blueprint(traced, **flags), TAB_ORDER, APPLICATION_ID


def layout_facts(recording: Path) -> tuple[list[int], dict[str, bool]]:
    """What the layout depends on: the frames the recording traced (a view each), and default_blueprint's flags
    for the options the run used and its log (told by data only those runs have: a crop scale, a rolling-shutter
    skew, log lines) and for the frames' aspect (the input's size)."""
    from rerun.chunk import RrdReader

    found, flags = set(), {"crop": False, "rolling_shutter": False, "log": False, "portrait": False}
    for chunk in RrdReader(str(recording)).stream().to_chunks():
        path = str(chunk.entity_path).strip("/")
        if path == ent.SIZES:
            size = chunk.to_record_batch().column("input_size").to_pylist()[-1]
            flags["portrait"] = bool(size) and size[1] > size[0]
        parts = path.split("/")
        if len(parts) >= 2 and parts[0] == ent.TRACE and parts[1].isdigit():
            found.add(int(parts[1]))
        flags["crop"] = flags["crop"] or path == ent.CROP_SCALE  # (CROP_ROOM has a style in every recording)
        flags["rolling_shutter"] = flags["rolling_shutter"] or path.startswith(ent.ROLLING_SHUTTER_SKEW + "/")
        flags["log"] = flags["log"] or path == ent.LOG
    return sorted(found), flags


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def snapshot(recording: Path, output: Path, *, frame: int = 0, tab: str = "overview",
             size: tuple[int, int] = DEFAULT_SIZE, timeout_s: float = 120.0) -> Path:
    """Render ``recording`` at ``frame`` on ``tab`` to ``output`` (.png, or .jpg); returns ``output``."""
    from rerun.experimental import ViewerClient

    check_recording(recording)
    if frame < 0:
        raise ConfigError(f"--frame must be 0 or more, not {frame}")
    if output.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise ConfigError(f"{output}: the snapshot is a PNG or a JPEG; name it .png or .jpg")
    if shutil.which("ffmpeg") is None:
        print("ffviz: warning: no `ffmpeg` on PATH: the native viewer cannot decode the recording's H.264 frame "
              "streams (Debian: apt-get install ffmpeg); they will show an error", flush=True)
    layout, tabs, application_id = recording_layout(recording)
    index = tab_index(tab, tabs)
    output.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ffviz-snapshot-") as folder:
        layout.root_container.active_tab = index
        rbl = Path(folder) / "layout.rbl"
        layout.save(application_id, str(rbl))
        port = _free_port()
        env = dict(os.environ, RERUN_ANALYTICS="0")
        log = Path(folder) / "viewer.log"
        with open(log, "wb") as log_file:
            viewer = subprocess.Popen(
                [rerun_executable(), "--headless", "--bind", "127.0.0.1", "--port", str(port), "--window-size",
                 f"{size[0]}x{size[1]}", str(recording), str(rbl)],
                env=env, stdout=subprocess.DEVNULL, stderr=log_file, start_new_session=True)
        try:
            png = _drive(ViewerClient, port, viewer, frame, time.monotonic() + timeout_s,
                         tabs=str(layout.root_container.id), tab=str(layout.root_container.contents[index].id))
        except Exception as error:  # noqa: BLE001 - the viewer's own account first, where it stopped
            if _wait_stopped(viewer):
                raise InputError(viewer_stopped(viewer.returncode, log.read_text(errors="replace"))) from None
            raise error
        finally:
            stop_process_group(viewer)
    if output.suffix.lower() == ".png":
        output.write_bytes(png)
    else:  # JPEG, for docs: a fifth of the PNG's bytes
        import cv2
        import numpy as np

        image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        cv2.imwrite(str(output), image, [cv2.IMWRITE_JPEG_QUALITY, 88])
    return output


def _wait_stopped(viewer: subprocess.Popen, seconds: float = 2.0) -> bool:
    """Whether the viewer has exited, or does within ``seconds`` (a connection error can come first)."""
    try:
        viewer.wait(seconds)
    except subprocess.TimeoutExpired:
        return False
    return True


def viewer_stopped(returncode: int | None, log: str) -> str:
    """One line on why the headless viewer stopped, from its exit status and its stderr (a Rust panic names its
    cause: 'Failed to get render context' where neither Vulkan nor OpenGL can render)."""
    panic = re.search(r"panicked at '([^']+)'", log) or re.search(r"panicked at [^\n]*\n([^\n]+)", log)
    reason = f": {panic.group(1).strip()}" if panic else ""
    hint = ""
    if "render context" in reason:
        hint = (" (no renderer: the headless viewer draws with software Vulkan; Debian: apt-get install "
                "mesa-vulkan-drivers; ./run test installs it)")
    return f"the headless viewer stopped (exit {returncode}){reason}{hint}"


def shows_tab(blueprint: dict, tabs: str, tab: str) -> bool:
    """Whether a blueprint, as the viewer reports it, is ours (its root tab container ``tabs`` is there) with
    ``tab`` active."""
    container = blueprint.get(f"/container/{tabs}", {}).get("ContainerBlueprint", {})
    return container.get("active_tab") == f"container/{tab}"


def _drive(client_type, port: int, viewer: subprocess.Popen, frame: int, deadline: float, *, tabs: str,
           tab: str) -> bytes:
    """Wait for the viewer to load the recording and the layout, move it to ``frame``, and screenshot it once
    two screenshots a second apart agree.

    The viewer opens the recording with its embedded blueprint and activates the layout file (ours, with the
    asked tab ``tab`` of root container ``tabs`` active) only when that file has loaded too; on a loaded machine
    that can come after the recording has drawn. So the screenshot waits until the active blueprint is ours.
    """
    client = None
    while client is None:
        if viewer.poll() is not None:
            raise InputError(f"the headless viewer exited ({viewer.returncode}) before it could be driven")
        try:
            client = client_type.connect(f"rerun+http://127.0.0.1:{port}/proxy")
            state = client.get_state()
        except Exception:  # noqa: BLE001 - not listening yet
            client = None
            if time.monotonic() > deadline:
                raise InputError("the headless viewer did not answer") from None
            time.sleep(0.3)
    while state.loading or not state.recordings or not any(
            t.name == ent.FRAME_TIMELINE for r in state.recordings for t in r.timelines):
        if time.monotonic() > deadline:
            raise InputError("the headless viewer did not finish loading the recording")
        time.sleep(0.3)
        state = client.get_state()
    last = max((t.end for r in state.recordings for t in r.timelines if t.name == ent.FRAME_TIMELINE), default=0)
    if frame > last:
        raise ConfigError(f"--frame {frame}: the recording's frames are 0 to {last}")
    while not shows_tab(client.get_blueprint().blueprint, tabs, tab):
        if time.monotonic() > deadline:
            raise InputError("the headless viewer did not take the snapshot's layout")
        time.sleep(0.3)
    client.set_time(ent.FRAME_TIMELINE, sequence=frame, play_state="paused")
    previous, shot = None, None
    time.sleep(1.0)
    while time.monotonic() < deadline:
        shot = client.take_screenshot()
        if shot == previous:
            return shot
        previous = shot
        time.sleep(1.0)
    if shot is None:
        raise InputError("no screenshot from the headless viewer")
    return shot
