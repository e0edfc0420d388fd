"""Serving a recording to the Rerun viewer: the web viewer on 127.0.0.1 (offline), or the native one."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import rerun as rr

from pipeline.errors import InputError

RRD_MAGIC = b"RRF2"


def rerun_executable() -> str:
    """The viewer binary shipped inside the rerun-sdk wheel, else a `rerun` on PATH.

    The binary itself, not the `rerun` console script: that shim runs it as a grandchild, which
    terminating the shim would leave behind.
    """
    try:
        import rerun_cli

        binary = Path(rerun_cli.__file__).parent / "rerun"
        if binary.is_file():
            return str(binary)
    except ImportError:
        pass
    found = shutil.which("rerun")
    if found is None:
        raise InputError("the rerun viewer executable was not found (is rerun-sdk installed in this environment?)")
    return found


def check_recording(path: Path) -> None:
    """A clear one-line error for a missing file or one that is not a Rerun recording."""
    if not path.is_file():
        raise InputError(f"{path}: no such recording")
    with path.open("rb") as f:
        magic = f.read(4)
    if magic != RRD_MAGIC:
        raise InputError(f"{path}: not a Rerun recording (.rrd)")


def recording_sdk_version(path: Path) -> str | None:
    """The rerun-sdk version ffviz wrote into the recording's meta document, if readable by this SDK."""
    from rerun.chunk import RrdReader

    try:
        for chunk in RrdReader(str(path)).stream().to_chunks():
            if str(chunk.entity_path).strip("/") == "meta":
                text = str(chunk.to_record_batch().to_pydict())
                marker = "rerun-sdk "
                if marker in text:
                    return text.split(marker, 1)[1].split("\\n", 1)[0].split()[0]
    except Exception:  # an unreadable file is reported by the caller
        return None
    return None


def version_note(path: Path) -> str | None:
    written_by = recording_sdk_version(path)
    if written_by is None:
        return (f"could not read {path} with rerun-sdk {rr.__version__}: it may have been written by another "
                f"rerun version (a .rrd is only readable by the version that wrote it)")
    if written_by != rr.__version__:
        return f"{path} was written by rerun-sdk {written_by}; this viewer is {rr.__version__}: it may not load"
    return None


def web_viewer_command(path: Path, *, web_port: int, grpc_port: int) -> list[str]:
    return [rerun_executable(), "--web-viewer", "--bind", "127.0.0.1", "--web-viewer-port", str(web_port),
            "--port", str(grpc_port), str(path)]


def serve(path: Path, *, web_port: int = 9090, grpc_port: int = 9876, native: bool = False) -> int:
    """Run the viewer until it exits or the user presses Ctrl-C; returns the viewer's exit status."""
    check_recording(path)
    note = version_note(path)
    if note:
        print(f"ffviz: warning: {note}", file=sys.stderr)
    if native:
        command = [rerun_executable(), str(path)]
    else:
        command = web_viewer_command(path, web_port=web_port, grpc_port=grpc_port)
        url = f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp://127.0.0.1:{grpc_port}/proxy"
        print(f"serving {path} at {url}  (Ctrl-C to stop)", flush=True)
    env = dict(os.environ)
    env.setdefault("RERUN_ANALYTICS", "0")  # offline tool: no first-run analytics banner or calls
    process = subprocess.Popen(command, env=env, start_new_session=True)
    try:
        return process.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        # Whatever ends us (Ctrl-C, SIGTERM via the CLI's handler, an error), the viewer goes too.
        stop_process_group(process)


# What the live view's server keeps for the page: past it, the oldest is dropped (display only; the .rrd has all).
LIVE_SERVER_MEMORY = "1GiB"


class LiveViewer:
    """A web viewer with no recording yet, serving on 127.0.0.1, for a run to stream into (`--view`).

    ``url`` is what the page shows, ``grpc_url`` what the recorder connects to. ``wait()`` keeps it serving
    until Ctrl-C; ``stop()`` ends it (and everything it started)."""

    def __init__(self, *, web_port: int = 9090, grpc_port: int = 9876) -> None:
        command = [rerun_executable(), "--web-viewer", "--bind", "127.0.0.1", "--web-viewer-port", str(web_port),
                   "--port", str(grpc_port), "--server-memory-limit", LIVE_SERVER_MEMORY]
        env = dict(os.environ)
        env.setdefault("RERUN_ANALYTICS", "0")
        self.process = subprocess.Popen(command, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL)
        self.grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
        self.url = f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp://127.0.0.1:{grpc_port}/proxy"
        _wait_listening(grpc_port, self.process)

    def wait(self) -> int:
        try:
            return self.process.wait()
        except KeyboardInterrupt:
            return 0
        finally:
            self.stop()

    def stop(self) -> None:
        stop_process_group(self.process)


def stop_process_group(process: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """End a viewer started in a session of its own and everything it started: SIGTERM, then SIGKILL."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)


def _wait_listening(port: int, process: subprocess.Popen, timeout_s: float = 30.0) -> None:
    import socket
    import time

    deadline = time.monotonic() + timeout_s
    while True:
        if process.poll() is not None:
            raise InputError(f"the web viewer exited ({process.returncode}); is port {port} in use?")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                return
        except OSError:
            if time.monotonic() > deadline:
                raise InputError(f"the web viewer did not listen on 127.0.0.1:{port}") from None
            time.sleep(0.2)


def notebook_live(*, web_port: int = 9090, grpc_port: int = 9876, width: int = 1100, height: int = 700):
    """Jupyter: a viewer server on 127.0.0.1 and rerun's notebook widget reading from it; returns (live, widget).

    Record with ``RerunRecorder(path, live_url=live.grpc_url)``: the run shows in the widget while it runs and
    is saved to ``path`` (both sinks at once). Needs the `rerun-notebook` package (pip install -e ".[notebook]").
    Show the widget as a cell's last expression (or ``widget.display()``); ``live.stop()`` when done."""
    from rerun.notebook import Viewer

    live = LiveViewer(web_port=web_port, grpc_port=grpc_port)
    return live, Viewer(url=live.grpc_url, width=width, height=height)
