"""Profile: frames/s per mode and where full mode spends its time (synthetic, in memory: no decode/encode).

The synthetic clip has the demo's hand-held jitter, a moving object and its default blurred frames, so
completion and deblurring both work as on a real clip. Prints frames/s for each mode with one worker thread and
with one per core (after a warm-up run that compiles the numba kernels), then a cProfile of one full-mode run: the pipeline's own functions by
cumulative time. Used for the before/after figures of issue 6 (docs/benchmarks-history.md).

Usage: python -m benchmarks.archive.profile_render [--size 640x360] [--frames 40] [--modes none,crop,full] [--top 30]
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import time

from benchmarks import common
from pipeline.runtime.parallel import default_workers
from pipeline.runtime.source import ArraySource
from pipeline.stabilize import StabilizeConfig, stabilize_source
from pipeline.evaluation.synthetic import SyntheticConfig, generate


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    parser.add_argument("--size", default="640x360")
    common.add_frames(parser, 40, "frames of the synthetic clip")
    parser.add_argument("--modes", default="none,crop,full")
    parser.add_argument("--top", type=int, default=30)
    parser.add_argument("--no-profile", action="store_true")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    video = generate(SyntheticConfig(n_frames=args.frames, width=width, height=height))
    source = ArraySource(video.frames, fps=30.0, name=f"synthetic {width}x{height}")
    stabilize_source(source, None, StabilizeConfig(mode="full"), workers=1)  # warm-up: numba compile, caches
    for mode in args.modes.split(","):
        for workers in sorted({1, default_workers()}):
            started = time.perf_counter()
            report = stabilize_source(source, None, StabilizeConfig(mode=mode), workers=workers)
            seconds = time.perf_counter() - started
            print(f"mode {mode:5} {width}x{height} {workers} worker(s): {args.frames / seconds:6.2f} frames/s  "
                  f"({seconds:5.1f} s; motion {report.seconds_motion:4.1f} s, render {report.seconds_render:5.1f} s)",
                  flush=True)
    if not args.no_profile:
        profile = cProfile.Profile()  # one worker: cProfile sees only the thread it runs on
        profile.runcall(stabilize_source, source, None, StabilizeConfig(mode="full"), workers=1)
        print(f"\nwhere full mode spends its time (one worker; cumulative, top {args.top}):")
        pstats.Stats(profile, stream=sys.stdout).sort_stats("cumulative").print_stats(r"pipeline|cv2", args.top)
    return 0


if __name__ == "__main__":
    sys.exit(main())
