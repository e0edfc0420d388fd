"""The what-if debugger's speed: opening a video (pass 1 and the path plan) against `ffviz stabilize`'s pass 1, and one
frame re-rendered with new settings, at 640x360 and at 1080p (issue 40's targets: at most 2 s and 10 s a frame,
opening at most pass 1's time).

Each clip is opened once with no cache (the open's wall seconds; pass 1 alone timed by the same function a run uses),
then frames spread over it are rendered as the default and as variants (a completion setting, a deblurring setting,
a path setting that re-plans), each render timed whole (decoding its window, rendering, recording it). Prints the
medians and the worst, and writes docs/benchmarks-debugger.md (--no-report: print only).

Usage: python -m benchmarks.speed.debugger_speed [--clips ../shared/videos/vplab_C.avi,PHONE_CLIP] [--frames 4]
       [--report PATH | --no-report]
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import common
from ffviz.debugger import Debugger
from pipeline import settings as named
from pipeline.config import StabilizeConfig
from pipeline.runtime import parallel
from pipeline.runtime.observer import NullObserver, null_progress
from pipeline.runtime.source import FileSource
from pipeline.stabilize import estimate_motion

REPORT = common.DOCS / "benchmarks-debugger.md"
HEADER = """# Debugger benchmarks (issue 40)

Each section is written by the benchmark script it names; rerun it to regenerate the section.
"""
VARIANTS = ({}, {"completion.neighbour_frames": "3"}, {"deblur.alpha": "4"}, {"smoothing.radius_frames": "90"})
TARGETS_S = {360: 2.0, 1080: 10.0}  # by the frame's short side


def pass_1_seconds(clip: Path) -> float:
    source = FileSource(clip)
    started = time.perf_counter()
    estimate_motion(source, StabilizeConfig().motion, observer=NullObserver(), progress=null_progress,
                    total=source.info.frame_count or None, workers=parallel.default_workers())
    return time.perf_counter() - started


def measure(clip: Path, frames: int) -> list[str]:
    with tempfile.TemporaryDirectory(prefix="ffviz-debugger-") as tmp:
        alone = pass_1_seconds(clip)
        started = time.perf_counter()
        debugger = Debugger(clip, rrd=Path(tmp) / "debug.rrd")
        opened = time.perf_counter() - started
        picks = [round(i * (debugger.n_frames - 1) / max(frames - 1, 1)) for i in range(frames)]
        with debugger:
            for t in picks:
                for settings in VARIANTS:
                    debugger.frame(t, settings)
        info = debugger.session.info
    short = min(info.width, info.height)
    target = TARGETS_S[1080 if short > 720 else 360]
    lines = [f"| {clip.name} | {info.width}x{info.height} | {debugger.n_frames} | {alone:.1f} | {opened:.1f} |"]
    for settings in VARIANTS:
        name = named.label(settings)
        seconds = [s for _, variant, s in debugger.rendered if variant == name]
        verdict = "met" if statistics.median(seconds) <= target else "NOT MET"
        lines.append(f"|  | {name} | | | | {statistics.median(seconds):.2f} | {max(seconds):.2f} | {target:g} ({verdict}) |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    parser.add_argument("--clips", default=str(common.VIDEOS / "vplab_C.avi"),
                        help="comma-separated clips (add a 1080p phone clip: ../shared/tools/phone-clips.sh)")
    common.add_frames(parser, 4, "frames rendered per clip and variant")
    common.add_report(parser, REPORT)
    args = parser.parse_args(argv)
    lines = ["## debugger_speed.py: opening a video, and one frame re-rendered with new settings", "",
             f"{common.machine_line()}; wall seconds; {args.frames} frames spread over each clip, each as every variant.", "",
             "| clip | size / variant | frames | pass 1 alone s | open s | render s (median) | render s (worst) | "
             "target s |", "|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for clip in (Path(c) for c in args.clips.split(",") if c):
        rows = measure(clip, args.frames)
        lines += rows
        print("\n".join(rows), flush=True)
    common.save("debugger_speed", lines, common.report_path(args), HEADER)
    return 0


if __name__ == "__main__":
    sys.exit(main())
