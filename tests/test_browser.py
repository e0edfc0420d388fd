"""A real browser shows a recording served by `ffviz view` (headless Chromium, WebGL on SwiftShader).

Plain `chromium --screenshot` captures the viewer's loading screen (the viewer is WebAssembly that keeps
loading after the page's load event), so the page is driven over the DevTools protocol instead: navigate,
then take screenshots until the viewer has drawn the recording's frames, or time out. The DevTools client
is a minimal WebSocket client on the standard library (no extra dependency for one test).
Skipped when neither `chromium` nor `chromium-browser` is on PATH (Debian: apt-get install chromium).
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
import urllib.parse
import urllib.request

import cv2
import numpy as np
import pytest

from ffviz.recorder import RerunRecorder
from pipeline import synthetic
from pipeline.stabilize import StabilizeConfig, stabilize

pytestmark = pytest.mark.slow

WINDOW = (1280, 800)
RENDER_TIMEOUT_S = 150  # SwiftShader on 2 loaded cores: the viewer has taken 20-60 s to draw
# The synthetic clip is a photograph of an orange-brown coffee cup on red-brown saucer; the viewer's chrome
# is grey/dark. A page showing the clip's frames has many such warm, saturated pixels; the loading screen,
# a blank page or an empty viewer has (almost) none.
MIN_PHOTO_FRACTION = 0.05


def chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    pytest.skip("chromium not installed (Debian: apt-get update && apt-get install -y chromium)")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_http(url: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=2):
                return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)


def stop(process: subprocess.Popen) -> None:
    """Stop a process started in its own session, and everything it started."""
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGTERM)
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=15)
        except ProcessLookupError:
            pass


class DevTools:
    """Just enough of the Chrome DevTools protocol over one WebSocket: send a command, wait for its answer."""

    def __init__(self, ws_url: str) -> None:
        url = urllib.parse.urlparse(ws_url)
        self.sock = socket.create_connection((url.hostname, url.port), timeout=60)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET {url.path} HTTP/1.1\r\nHost: {url.hostname}:{url.port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
        self.buffer = b""
        while b"\r\n\r\n" not in self.buffer:
            self.buffer += self._recv()
        head, self.buffer = self.buffer.split(b"\r\n\r\n", 1)
        assert b" 101 " in head.split(b"\r\n")[0], head
        self.last_id = 0

    def _recv(self) -> bytes:
        data = self.sock.recv(1 << 16)
        if not data:
            raise ConnectionError("DevTools closed the connection")
        return data

    def _read(self, n: int) -> bytes:
        while len(self.buffer) < n:
            self.buffer += self._recv()
        data, self.buffer = self.buffer[:n], self.buffer[n:]
        return data

    def _send(self, text: str) -> None:
        payload = text.encode()
        header = bytearray([0x81])  # FIN, text frame
        if len(payload) < 126:
            header.append(0x80 | len(payload))
        elif len(payload) < 1 << 16:
            header += bytes([0x80 | 126]) + struct.pack(">H", len(payload))
        else:
            header += bytes([0x80 | 127]) + struct.pack(">Q", len(payload))
        mask = os.urandom(4)  # clients must mask
        masked = (np.frombuffer(payload, np.uint8) ^ np.resize(np.frombuffer(mask, np.uint8), len(payload))).tobytes()
        self.sock.sendall(bytes(header) + mask + masked)

    def _message(self) -> dict:
        parts = []
        while True:
            first, second = self._read(2)
            length = second & 0x7F
            if length == 126:
                length = struct.unpack(">H", self._read(2))[0]
            elif length == 127:
                length = struct.unpack(">Q", self._read(8))[0]
            data = self._read(length)
            opcode = first & 0x0F
            if opcode == 0x8:
                raise ConnectionError("DevTools closed the WebSocket")
            if opcode in (0x1, 0x2, 0x0):
                parts.append(data)
                if first & 0x80:
                    return json.loads(b"".join(parts))

    def call(self, method: str, **params) -> dict:
        self.last_id += 1
        self._send(json.dumps({"id": self.last_id, "method": method, "params": params}))
        while True:
            message = self._message()
            if message.get("id") == self.last_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    def close(self) -> None:
        self.sock.close()


def photo_fraction(rgb: np.ndarray) -> float:
    """Share of warm, saturated pixels (the clip's coffee-cup photograph; the viewer's UI is grey)."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    hue, saturation, value = hsv[..., 0].astype(int), hsv[..., 1], hsv[..., 2]
    warm = (hue <= 25) | (hue >= 170)  # red, orange, brown (OpenCV hue 0..179)
    return float(np.mean(warm & (saturation > 90) & (value > 60)))


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("browser")
    video = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=12, seed=4))
    clip = folder / "clip.mp4"
    synthetic.write_video(video, clip)
    rrd = folder / "clip.rrd"
    stabilize(clip, None, StabilizeConfig(mode="none"), observer=RerunRecorder(rrd, level="full"))
    return rrd


def test_the_web_viewer_renders_the_recording_in_chromium(recording, tmp_path):
    browser = chromium()
    web, grpc = free_port(), free_port()
    env = dict(os.environ, RERUN_ANALYTICS="0")
    viewer = subprocess.Popen([sys.executable, "-m", "ffviz.cli", "view", str(recording), "--web-port", str(web),
                               "--grpc-port", str(grpc)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                              env=env, start_new_session=True)
    profile = tmp_path / "profile"
    chrome = None
    devtools = None
    try:
        url = re.search(r"http://\S+", viewer.stdout.readline()).group(0)
        assert url.startswith(f"http://127.0.0.1:{web}/")
        wait_http(f"http://127.0.0.1:{web}/", 30)
        chrome = subprocess.Popen(
            [browser, "--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
             "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
             "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--remote-debugging-address=127.0.0.1",
             "--remote-debugging-port=0", f"--window-size={WINDOW[0]},{WINDOW[1]}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        port_file = profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not (port_file.is_file() and port_file.read_text().strip()):
            assert chrome.poll() is None and time.monotonic() < deadline, "chromium did not start its DevTools server"
            time.sleep(0.3)
        port = int(port_file.read_text().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as response:
            page = next(t for t in json.load(response) if t["type"] == "page")
        devtools = DevTools(page["webSocketDebuggerUrl"])

        devtools.call("Page.enable")
        devtools.call("Emulation.setDeviceMetricsOverride", width=WINDOW[0], height=WINDOW[1], deviceScaleFactor=1,
                      mobile=False)
        blank = decode_png(devtools.call("Page.captureScreenshot", format="png")["data"])
        devtools.call("Page.navigate", url=url)
        deadline = time.monotonic() + RENDER_TIMEOUT_S
        shots = []
        while True:
            time.sleep(5)
            shot = decode_png(devtools.call("Page.captureScreenshot", format="png")["data"])
            shots.append(photo_fraction(shot))
            if shots[-1] >= MIN_PHOTO_FRACTION or time.monotonic() > deadline:
                break
        cv2.imwrite(str(tmp_path / "viewer.png"), cv2.cvtColor(shot, cv2.COLOR_RGB2BGR))
        assert shot.shape[:2] == (WINDOW[1], WINDOW[0])
        assert photo_fraction(blank) < 0.001  # the criterion does not fire on an empty page
        assert shots[-1] >= MIN_PHOTO_FRACTION, (
            f"after {RENDER_TIMEOUT_S} s the page shows no recorded frame (photo pixels per screenshot: {shots}); "
            f"last screenshot: {tmp_path / 'viewer.png'}")
        # The viewer's own UI (panels, time line) surrounds the frames: not just an image on a blank page.
        grey = np.abs(shot.astype(int) - shot.mean(axis=-1, keepdims=True)).max(axis=-1) < 12
        assert grey.mean() > 0.3
    finally:
        if devtools is not None:
            devtools.close()
        if chrome is not None:
            stop(chrome)
        stop(viewer)


def decode_png(data: str) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
