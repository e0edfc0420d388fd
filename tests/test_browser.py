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
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest

from ffviz.recorder import RerunRecorder
from pipeline.evaluation import synthetic
from pipeline.runtime.video_reader import VideoReader
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
        chrome, devtools = _start_chromium(browser, profile)
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


# -- a real clip's full recording, >= 250 frames: open on frame 0, step to the last ------------------------------

REAL_CLIP = "vplab_C.avi"
OPEN_TIMEOUT_S = 300  # the whole recording streams in and frame 0's video is decoded in software
MATCH_SCORE = 0.7  # normalised cross-correlation of the frame with the best-matching screen region


@contextmanager
def web_viewer_page(rrd: Path, profile: Path):
    """`ffviz view rrd` and headless Chromium on it: yields (DevTools session, page URL, navigation time)."""
    browser = chromium()
    web, grpc = free_port(), free_port()
    env = dict(os.environ, RERUN_ANALYTICS="0")
    viewer = subprocess.Popen([sys.executable, "-m", "ffviz.cli", "view", str(rrd), "--web-port", str(web),
                               "--grpc-port", str(grpc)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                              env=env, start_new_session=True)
    chrome = devtools = None
    try:
        url = re.search(r"http://\S+", viewer.stdout.readline()).group(0)
        wait_http(f"http://127.0.0.1:{web}/", 30)
        chrome, devtools = _open_page(browser, url, profile)
        yield devtools, url, time.monotonic()
    finally:
        if devtools is not None:
            devtools.close()
        if chrome is not None:
            stop(chrome)
        stop(viewer)


def screenshot(devtools: DevTools) -> np.ndarray:
    return decode_png(devtools.call("Page.captureScreenshot", format="png")["data"])


def match_score(screen: np.ndarray, frame: np.ndarray) -> float:
    """How well ``frame``, at any scale from a quarter to 2.5x, matches a region of ``screen`` (best
    normalised cross-correlation, grey levels; both halved first, for speed)."""
    screen_grey = cv2.resize(cv2.cvtColor(screen, cv2.COLOR_RGB2GRAY), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    frame_grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    best = -1.0
    for scale in np.geomspace(0.125, 1.25, 48):
        template = cv2.resize(frame_grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        if template.shape[0] > screen_grey.shape[0] or template.shape[1] > screen_grey.shape[1]:
            continue
        best = max(best, float(cv2.matchTemplate(screen_grey, template, cv2.TM_CCOEFF_NORMED).max()))
    return best


def press(devtools: DevTools, key: str, code: int) -> None:
    for kind in ("rawKeyDown", "keyUp"):
        devtools.call("Input.dispatchKeyEvent", type=kind, key=key, code=key, windowsVirtualKeyCode=code,
                      nativeVirtualKeyCode=code)


@pytest.fixture(scope="module")
def real_recording(tmp_path_factory):
    from tests.conftest import real_clip

    clip = real_clip(REAL_CLIP)
    with VideoReader(clip) as reader:
        frames = [f.rgb for f in reader]
    assert len(frames) >= 250
    rrd = tmp_path_factory.mktemp("real") / "vplab_C.rrd"
    stabilize(clip, None, StabilizeConfig(mode="full"), observer=RerunRecorder(rrd, level="full"))
    return rrd, frames[0], frames[-1], len(frames)


@pytest.mark.real_video
def test_a_real_full_recording_opens_on_frame_0_and_steps_to_the_last(real_recording, tmp_path):
    rrd, first, last, n_frames = real_recording
    with web_viewer_page(rrd, tmp_path / "profile") as (devtools, url, navigated):
        deadline = navigated + OPEN_TIMEOUT_S
        scores = []
        while True:
            time.sleep(5)
            shot = screenshot(devtools)
            scores.append((round(match_score(shot, first), 3), round(match_score(shot, last), 3)))
            if scores[-1][0] >= MATCH_SCORE or time.monotonic() > deadline:
                break
        opened_s = time.monotonic() - navigated
        cv2.imwrite(str(tmp_path / "open.png"), cv2.cvtColor(shot, cv2.COLOR_RGB2BGR))
        print(f"{n_frames}-frame recording ({rrd.stat().st_size / 1e6:.1f} MB): frame 0 on screen after {opened_s:.0f} s")
        assert scores[-1][0] >= MATCH_SCORE, f"frame 0 not on screen (scores frame 0 / last: {scores}); {tmp_path}/open.png"
        # Paused on frame 0: it stays.
        time.sleep(5)
        assert match_score(screenshot(devtools), first) >= MATCH_SCORE
        # Step back from frame 0: the time line wraps round to the last frame.
        devtools.call("Input.dispatchMouseEvent", type="mouseMoved", x=WINDOW[0] // 2, y=WINDOW[1] // 2)
        press(devtools, "ArrowLeft", 37)
        deadline = time.monotonic() + 120
        while True:
            time.sleep(3)
            shot = screenshot(devtools)
            on_last, on_first = match_score(shot, last), match_score(shot, first)
            if (on_last >= MATCH_SCORE and on_last > on_first) or time.monotonic() > deadline:
                break
        cv2.imwrite(str(tmp_path / "last.png"), cv2.cvtColor(shot, cv2.COLOR_RGB2BGR))
        assert on_last >= MATCH_SCORE and on_last > on_first, (
            f"last frame not on screen after stepping (scores last / first: {on_last:.3f} / {on_first:.3f}); "
            f"{tmp_path}/last.png")


@pytest.mark.parametrize("clip, recorded", [("uhd_recording", (540, 960)), ("portrait_recording", (960, 540))])
def test_a_phone_sized_recording_opens_on_frame_0_in_the_browser(clip, recorded, request, tmp_path):
    """Recorded at the viewing size, a 3840x2160 clip's and a 1080x1920 portrait clip's recordings open in the web
    viewer on frame 0 (the portrait one in its side-by-side layout)."""
    from ffviz import entities as ent
    from ffviz.rrd import Recording

    rrd, recorder = request.getfixturevalue(clip)
    recording = Recording.load(rrd)
    first, last = recording.image(ent.INPUT_FRAME, 0), recording.image(ent.INPUT_FRAME, 7)
    assert first.shape[:2] == (recorder.view.height, recorder.view.width) == recorded
    with web_viewer_page(rrd, tmp_path / "profile") as (devtools, url, navigated):
        scores = []

        def on_frame_0(shot: np.ndarray) -> bool:
            scores.append(round(match_score(shot, first), 3))
            return scores[-1] >= MATCH_SCORE and match_score(shot, first) > match_score(shot, last) - 0.05

        assert _until(devtools, on_frame_0, tmp_path / "open.png"), \
            f"frame 0 not on screen (scores: {scores}); {tmp_path}/open.png"


# -- ffviz snapshot: the native viewer, headless ----------------------------------------------------------------

def vulkan_drivers() -> list[str]:
    """The Vulkan drivers the loader can find (the headless viewer renders with lavapipe, Mesa's CPU driver)."""
    return [str(p) for folder in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d") for p in Path(folder).glob("*.json")]


def test_snapshot_shows_the_asked_frame_on_the_asked_tab(tmp_path):
    if shutil.which("ffmpeg") is None:
        pytest.skip("the native viewer decodes H.264 with the ffmpeg executable (apt-get install ffmpeg)")
    if not vulkan_drivers():
        pytest.skip("no Vulkan driver for the headless viewer (apt-get install mesa-vulkan-drivers)")
    video = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=12, seed=4, jitter_px=8.0))
    clip = tmp_path / "clip.mp4"
    synthetic.write_video(video, clip)
    rrd = tmp_path / "clip.rrd"
    stabilize(clip, None, StabilizeConfig(mode="none"), observer=RerunRecorder(rrd, level="full"))
    with VideoReader(clip) as reader:
        inputs = [f.rgb for f in reader]
    env = dict(os.environ, RERUN_ANALYTICS="0")
    shots = {}
    for frame, tab in ((9, "overview"), (2, "about")):
        png = tmp_path / f"{tab}-{frame}.png"
        subprocess.run([sys.executable, "-m", "ffviz.cli", "snapshot", str(rrd), "--frame", str(frame), "--tab", tab,
                        "-o", str(png)], check=True, env=env, capture_output=True, timeout=300)
        shots[tab] = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
    overview = shots["overview"]
    assert match_score(overview, inputs[9]) >= MATCH_SCORE
    assert match_score(overview, inputs[9]) > match_score(overview, inputs[0])
    assert match_score(shots["about"], inputs[2]) < MATCH_SCORE  # the about tab shows text, not frames
    result = subprocess.run([sys.executable, "-m", "ffviz.cli", "snapshot", str(rrd), "--tab", "nope", "-o",
                             str(tmp_path / "x.png")], env=env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "overview" in result.stderr


def test_a_viewer_that_cannot_render_is_told_in_one_line_with_its_remedy():
    """What `ffviz snapshot` says when the headless viewer stops: its exit status, the cause its panic names,
    and for a missing renderer the package that brings one (it once printed 'internal error: ConnectionError')."""
    from ffviz.snapshot import viewer_stopped

    old_style = "INFO listening\nthread 'main' panicked at 'Failed to get render context'\nre_viewer/src/app/mod.rs:1425\n"
    new_style = "thread 'main' panicked at re_viewer/src/app/mod.rs:1425:9:\nFailed to get render context\nnote: ...\n"
    for log in (old_style, new_style):
        line = viewer_stopped(102, log)
        assert "\n" not in line and "exit 102" in line and "Failed to get render context" in line
        assert "mesa-vulkan-drivers" in line
    assert viewer_stopped(1, "nothing useful") == "the headless viewer stopped (exit 1)"


def test_the_snapshot_waits_for_its_own_layout_before_the_screenshot():
    """The viewer shows the recording's embedded layout (overview tab) until the snapshot's layout file has
    loaded; on a loaded CI machine that once came after two agreeing screenshots, and `--tab about` returned the
    overview. The screenshot is taken only once the active blueprint is the snapshot's, with the asked tab."""
    from types import SimpleNamespace

    from ffviz import entities as ent
    from ffviz.snapshot import _drive

    ours = {"/container/ROOT": {"ContainerBlueprint": {"active_tab": "container/ABOUT"}}}
    embedded = {"/container/OTHER": {"ContainerBlueprint": {"active_tab": "container/OVERVIEW"}}}

    class Viewer:
        def poll(self):
            return None

    class Client:
        calls = 0

        @classmethod
        def connect(cls, url):
            return cls()

        def get_state(self):
            timeline = SimpleNamespace(name=ent.FRAME_TIMELINE, end=11)
            return SimpleNamespace(loading=[], recordings=[SimpleNamespace(timelines=[timeline])])

        def get_blueprint(self):
            Client.calls += 1
            return SimpleNamespace(blueprint=ours if Client.calls > 3 else embedded)

        def set_time(self, *args, **kwargs):
            pass

        def take_screenshot(self):
            return b"about" if Client.calls > 3 else b"overview"

    shot = _drive(Client, 0, Viewer(), 2, time.monotonic() + 30, tabs="ROOT", tab="ABOUT")
    assert shot == b"about" and Client.calls == 4


# -- ffviz debug: the what-if debugger's page ---------------------------------------------------------------------

DEBUG_CLIP = "sudheerachary_small-shaky-5.avi"


def _evaluate(devtools: DevTools, expression: str):
    return devtools.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")


def _ctrl_c_as_at_a_terminal() -> None:
    """A child's SIGINT as a terminal's Ctrl-C delivers it: a run started in the background (CI) ignores SIGINT, and
    its children would inherit that, so Python would never raise KeyboardInterrupt in them."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.real_video
def test_the_debugger_page_shows_a_new_variant_after_apply(tmp_path):
    """`ffviz debug CLIP`: the page opens on frame 0's default render; moving to frame 150, changing a setting and
    pressing apply renders frame 150 with it, and that variant's frame comes on screen; Ctrl-C leaves the recording
    with both variants."""
    from ffviz import entities as ent
    from ffviz.recording.variants import variant_entity
    from ffviz.rrd import Recording
    from pipeline import settings as named
    from pipeline.frame_session import FrameSession
    from tests.conftest import real_clip

    browser = chromium()
    clip = real_clip(DEBUG_CLIP)
    session = FrameSession(clip)
    double = lambda rgb: cv2.resize(rgb, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)  # noqa: E731 (shown large)
    first = double(session.render(0).output)
    later = double(session.render(150, named.with_settings(session.config, {"deblur.alpha": "4"})).output)
    port, rrd = free_port(), tmp_path / "debug.rrd"
    debug = subprocess.Popen([sys.executable, "-m", "ffviz.cli", "debug", str(clip), "--port", str(port), "--rrd",
                              str(rrd)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                             env=dict(os.environ, RERUN_ANALYTICS="0"), start_new_session=True,
                             preexec_fn=_ctrl_c_as_at_a_terminal)
    chrome = devtools = None
    try:
        url = re.search(r"http://\S+", debug.stdout.readline()).group(0)
        chrome, devtools = _open_page(browser, url, tmp_path / "profile")
        assert _until(devtools, lambda shot: match_score(shot, first) >= MATCH_SCORE, tmp_path / "open.png"), \
            f"frame 0's default render not on screen; {tmp_path}/open.png"
        _evaluate(devtools, "const f = document.getElementById('frame'); f.value = 150; "
                            "f.dispatchEvent(new Event('change'));")
        _evaluate(devtools, "document.querySelector('[data-setting=\"deblur.alpha\"]').value = '4'; "
                            "document.getElementById('apply').click();")
        deadline = time.monotonic() + 120
        while "rendered" not in (_evaluate(devtools, "window.ffviz.status") or "") and time.monotonic() < deadline:
            time.sleep(1)
        assert "variant 'alpha=4' rendered" in _evaluate(devtools, "window.ffviz.status")
        assert _until(devtools, lambda shot: match_score(shot, later) >= MATCH_SCORE
                      and match_score(shot, later) > match_score(shot, first), tmp_path / "applied.png"), \
            f"frame 150's new variant not on screen; {tmp_path}/applied.png"
    finally:
        if devtools is not None:
            devtools.close()
        if chrome is not None:
            stop(chrome)
        if debug.poll() is None:
            os.killpg(debug.pid, signal.SIGINT)
            try:
                debug.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(debug.pid, signal.SIGKILL)
                raise
    recording = Recording.load(rrd)
    assert recording.indices(variant_entity("default", ent.OUTPUT_FRAME)) == [0, 150]  # the default beside it
    assert recording.indices(variant_entity("alpha=4", ent.OUTPUT_FRAME)) == [150]


def _start_chromium(browser: str, profile: Path) -> tuple[subprocess.Popen, DevTools]:
    """Headless Chromium on a blank page at WINDOW's size, and a DevTools session with it."""
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
    return chrome, devtools


def _open_page(browser: str, url: str, profile: Path) -> tuple[subprocess.Popen, DevTools]:
    chrome, devtools = _start_chromium(browser, profile)
    devtools.call("Page.navigate", url=url)
    return chrome, devtools


def _until(devtools: DevTools, seen, picture: Path, timeout_s: float = OPEN_TIMEOUT_S) -> bool:
    """Screenshots every 5 s until ``seen(shot)`` or the time is up; the last one saved to ``picture``."""
    deadline = time.monotonic() + timeout_s
    while True:
        time.sleep(5)
        shot = screenshot(devtools)
        if seen(shot) or time.monotonic() > deadline:
            cv2.imwrite(str(picture), cv2.cvtColor(shot, cv2.COLOR_RGB2BGR))
            return bool(seen(shot))
