"""Render docs/img/demo-before-after.png from `./run demo`'s videos.

Usage: .venv/bin/python docs/img/make_before_after.py [DEMO_DIR]   (default: ffviz-demo)
Top row: the shaky input at three times; bottom row: the stabilized output at the same times. The dashed
lines sit at the same place in every panel, so the input's shake and the output's steadiness show.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from pipeline.runtime.video_reader import VideoReader  # noqa: E402

FRAMES = (20, 55, 90)


def frames_at(path: Path, wanted: tuple[int, ...]) -> list:
    picked = {}
    with VideoReader(path) as reader:
        for frame in reader:
            if frame.index in wanted:
                picked[frame.index] = frame.rgb
            if len(picked) == len(wanted):
                break
    return [picked[i] for i in wanted]


def main() -> None:
    demo = Path(sys.argv[1] if len(sys.argv) > 1 else "ffviz-demo")
    rows = (("input (shaky)", demo / "demo_input.mp4"), ("ffviz --mode full", demo / "demo_stabilized_full.mp4"))
    fig, axes = plt.subplots(2, len(FRAMES), figsize=(12, 4.6))
    for r, (label, path) in enumerate(rows):
        for c, frame in enumerate(frames_at(path, FRAMES)):
            ax = axes[r][c]
            ax.imshow(frame)
            h, w = frame.shape[:2]
            for x in (w / 3, 2 * w / 3):
                ax.axvline(x, color="white", linestyle="--", linewidth=0.8, alpha=0.8)
            ax.axhline(h / 2, color="white", linestyle="--", linewidth=0.8, alpha=0.8)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(f"frame {FRAMES[c]}", fontsize=10)
            if c == 0:
                ax.set_ylabel(label, fontsize=10)
    fig.tight_layout()
    out = Path(__file__).parent / "demo-before-after.png"
    fig.savefig(out, dpi=70)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

# docs/img/viewer.jpg was taken from the same demo recording with Rerun's headless native viewer (needs
# Vulkan: apt-get install mesa-vulkan-drivers): `rerun --headless --bind 127.0.0.1 --port 9878 --window-size
# 1400x800 recordings/demo.rrd`, then `rerun.experimental.ViewerClient.connect("rerun+http://127.0.0.1:9878/proxy")`,
# `.set_time("frame", sequence=60)`, wait ~10 s, `.save_screenshot(path)`.
