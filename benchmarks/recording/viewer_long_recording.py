"""Does a 1000-frame 640x360 full recording open whole in the web viewer? (issue 22)

Builds a 1000-frame clip from vplab_C (forward, backward, forward, forward), stabilizes it in full mode with a
full recording, serves it with `ffviz view` and drives headless Chromium over DevTools (tests/test_browser.py's
helpers): frame 0 on screen at open, the last frame after stepping back from frame 0 (the time line wraps
round) once the stream has loaded, and frame 0 again after stepping forward from the last (nothing dropped).
Prints the recording's size per frame and the times. Needs chromium and ../shared/videos/vplab_C.avi.
Usage: python -m benchmarks.recording.viewer_long_recording [--load-wait 150]
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import av

os.environ.setdefault("RERUN_ANALYTICS", "0")

from benchmarks import common  # noqa: E402
from ffviz.recorder import RerunRecorder  # noqa: E402
from pipeline.stabilize import StabilizeConfig, stabilize  # noqa: E402
from pipeline.runtime.video_reader import VideoReader  # noqa: E402

browser = common.from_tests("test_browser")  # its DevTools helpers: screenshots, key presses, the viewer's page
CLIP = common.VIDEOS / "vplab_C.avi"


def wait_for(devtools, wanted, other, timeout_s: float, key: tuple[str, int] | None = None) -> tuple[float, float]:
    """Screenshots until ``wanted`` is on screen (better than ``other``); (its score, seconds)."""
    started = time.monotonic()
    while True:
        time.sleep(3)
        shot = browser.screenshot(devtools)
        score, score_other = browser.match_score(shot, wanted), browser.match_score(shot, other)
        if (score >= browser.MATCH_SCORE and score > score_other) or time.monotonic() - started > timeout_s:
            return score, time.monotonic() - started
        if key is not None and int(time.monotonic() - started) % 30 < 3:
            browser.press(devtools, *key)  # a key pressed while the viewer was busy ingesting may be lost


def main() -> None:
    parser = common.parser(__doc__)
    parser.add_argument("--load-wait", type=float, default=150.0, help="seconds to let the stream load (default 150)")
    args = parser.parse_args()
    frames = [f.rgb for f in VideoReader(CLIP)]
    sequence = frames + frames[::-1] + frames + frames
    with tempfile.TemporaryDirectory(prefix="ffviz-viewer-long-") as tmp:
        folder = Path(tmp)
        clip = folder / "long.mp4"
        with av.open(str(clip), "w") as out:
            stream = out.add_stream("libx264", rate=30)
            stream.width, stream.height, stream.pix_fmt = 640, 360, "yuv420p"
            stream.options = {"crf": "16", "preset": "veryfast"}
            for rgb in sequence:
                out.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
            out.mux(stream.encode(None))
        rrd = folder / "long.rrd"
        started, cpu = time.perf_counter(), time.process_time()
        stabilize(clip, None, StabilizeConfig(mode="full"), observer=RerunRecorder(rrd, level="full"))
        print(f"{len(sequence)} frames: recorded in {time.perf_counter() - started:.0f} s wall, "
              f"{time.process_time() - cpu:.0f} s CPU; {rrd.stat().st_size / 1e6:.1f} MB, "
              f"{rrd.stat().st_size / 1e6 / len(sequence):.3f} MB a frame", flush=True)
        first, last = sequence[0], sequence[-1]
        with browser.web_viewer_page(rrd, folder / "profile") as (devtools, url, navigated):
            score, seconds = wait_for(devtools, first, last, 300)
            print(f"frame 0 on screen: score {score:.3f}, {time.monotonic() - navigated:.0f} s after navigation",
                  flush=True)
            time.sleep(args.load_wait)
            width, height = browser.WINDOW
            devtools.call("Input.dispatchMouseEvent", type="mouseMoved", x=width // 2, y=height // 2)
            browser.press(devtools, "ArrowLeft", 37)
            score, seconds = wait_for(devtools, last, first, 240, key=("ArrowLeft", 37))
            print(f"last frame after stepping back from frame 0: score {score:.3f} ({seconds:.0f} s)", flush=True)
            browser.press(devtools, "ArrowRight", 39)
            score, seconds = wait_for(devtools, first, last, 90)
            print(f"frame 0 again after stepping forward from the last: score {score:.3f} ({seconds:.0f} s)",
                  flush=True)


if __name__ == "__main__":
    main()
