"""Benchmark: CPU ms a frame of each stage (`ffviz bench --profile`, ffviz/bench_profile.py) into the speed report.

Usage: python benchmarks/speed_profile.py [--clip ../shared/videos/vplab_C.avi] [--modes none,full] [--no-recording]
       [--report docs/benchmarks-speed.md | --no-report]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ffviz import bench_profile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import speed_report  # noqa: E402  (benchmarks/ is not a package)

VIDEOS = Path(__file__).resolve().parents[2] / "shared" / "videos"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip", type=Path, default=VIDEOS / "vplab_C.avi")
    parser.add_argument("--modes", default="none,full")
    parser.add_argument("--no-recording", action="store_true")
    parser.add_argument("--report", type=Path, default=speed_report.REPORT)
    parser.add_argument("--no-report", action="store_true")
    args = parser.parse_args(argv)
    if not args.clip.is_file():
        print(f"{args.clip} not found: nothing measured")
        return 0
    started = speed_report.machine_line()
    rows = [bench_profile.profile_stages(args.clip, mode, recording=not args.no_recording).line()
            for mode in args.modes.split(",")]
    lines = ["## Where the CPU goes: each stage's CPU ms a frame", "",
             f"Written by `benchmarks/speed_profile.py` ({started}) with `ffviz bench --profile`'s measurement "
             "(ffviz/bench_profile.py: one worker in process, OpenCV's threads off, after a short warm-up; total: the "
             "run without recording, every thread; recording: a second run's extra CPU with a full .rrd).", "",
             bench_profile.table_header(), *rows]
    speed_report.publish("profile", lines, None if args.no_report else args.report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
