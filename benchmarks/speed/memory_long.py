"""Peak memory of `ffviz stabilize` on long video: synthetic 1080p clips of 30 s and 5 min (not a test; prints a table).

    .venv/bin/python -m benchmarks.speed.memory_long [--modes crop,none] [--seconds 30,300] [--size 1920x1080]
                                                     [--fps 30] [--work DIR]

Each clip is rendered frame by frame (pipeline.evaluation.synthetic.stream_frames) straight into an H.264 MP4, so
the generator never holds the video; clips are kept in --work and reused. Each run of `ffviz stabilize`
is a child process measured as `ffviz bench` measures (ffviz.bench.measure.run_measured: wall and CPU seconds,
peak RSS from wait4). Streaming should make the peak independent of the length: the verdict printed
at the end says whether the longest clip's peak is within 10 % of the shortest's and under 1.5 GiB.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Iterator

import numpy as np

from benchmarks import common
from ffviz.bench.measure import run_measured
from ffviz.bench.methods import ffviz_command
from pipeline.evaluation import synthetic

PEAK_GROWTH_LIMIT = 1.10  # the long clip's peak may exceed the short one's by at most 10 %
PEAK_LIMIT_BYTES = int(1.5 * 2**30)


def write_long_clip(path: Path, width: int, height: int, fps: int, seconds: float) -> None:
    """Render and encode one frame at a time; written to a temp name and renamed when complete."""
    config = synthetic.SyntheticConfig(
        width=width, height=height, n_frames=round(seconds * fps), fps=fps,
        pan_px_per_frame=0.0, moving_object=False, blurred_frames=(),
        jitter_px=6.0 * height / 360)  # the demo's shake, scaled to the frame size
    temp = path.with_name(f".{path.name}.tmp.mp4")
    started = time.perf_counter()
    step = max(1, config.n_frames // 10)

    def with_progress() -> Iterator[np.ndarray]:
        for i, rgb in enumerate(synthetic.stream_frames(config)):
            yield rgb
            if (i + 1) % step == 0:
                print(f"  {path.name}: {i + 1}/{config.n_frames} frames, {time.perf_counter() - started:.0f} s",
                      flush=True)

    synthetic.write_video(with_progress(), temp, fps=fps, crf=20, preset="veryfast")
    temp.replace(path)


def main(argv: list[str]) -> int:
    parser = common.parser(__doc__)
    parser.add_argument("--modes", default="crop,none", help="ffviz modes, comma-separated (default: %(default)s)")
    parser.add_argument("--seconds", default="30,300", help="clip durations, comma-separated (default: %(default)s)")
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--fps", type=int, default=30)
    common.add_work(parser, Path("bench_out/memory_long"))  # and memory_long.json
    args = parser.parse_args(argv)
    width, height = map(int, args.size.split("x"))
    durations = sorted(float(s) for s in args.seconds.split(","))
    modes = [m for m in args.modes.split(",") if m]
    args.work.mkdir(parents=True, exist_ok=True)

    clips = {}
    for seconds in durations:
        clip = args.work / f"shaky_{width}x{height}_{args.fps}fps_{seconds:g}s.mp4"
        if not clip.is_file():
            print(f"generating {clip} ...", flush=True)
            write_long_clip(clip, width, height, args.fps, seconds)
        clips[seconds] = clip

    print("| mode | clip seconds | frames | wall s | frames/s | cpu s | peak MiB |\n|---|---|---|---|---|---|---|",
          flush=True)
    results = []
    for mode in modes:
        for seconds, clip in clips.items():
            output = args.work / f"{clip.stem}.ffviz-{mode}.mp4"
            run = run_measured(ffviz_command(clip, output, mode))
            frames = round(seconds * args.fps)
            if run.returncode != 0:
                print(f"{clip.name}: ffviz {mode} failed (exit {run.returncode}): {run.output_tail}", file=sys.stderr)
                continue
            results.append(dict(mode=mode, clip_seconds=seconds, frames=frames, wall_seconds=run.seconds,
                                cpu_seconds=run.cpu_seconds, peak_rss_bytes=run.peak_rss_bytes))
            print(f"| {mode} | {seconds:g} | {frames} | {run.seconds:.1f} | {frames / run.seconds:.2f} | "
                  f"{run.cpu_seconds:.1f} | {run.peak_rss_bytes / 2**20:.0f} |", flush=True)

    print()
    for mode in modes:
        runs = sorted((r for r in results if r["mode"] == mode), key=lambda r: r["clip_seconds"])
        if len(runs) < 2:
            print(f"{mode}: fewer than two durations measured, no verdict")
            continue
        short, long = runs[0], runs[-1]
        growth = long["peak_rss_bytes"] / short["peak_rss_bytes"]
        within = growth <= PEAK_GROWTH_LIMIT
        under = long["peak_rss_bytes"] < PEAK_LIMIT_BYTES
        print(f"{mode}: peak {long['peak_rss_bytes'] / 2**20:.0f} MiB at {long['clip_seconds']:g} s vs "
              f"{short['peak_rss_bytes'] / 2**20:.0f} MiB at {short['clip_seconds']:g} s = {growth:.3f}x "
              f"({'within' if within else 'NOT within'} 10 %); "
              f"{'under' if under else 'NOT under'} 1.5 GiB")
    (args.work / "memory_long.json").write_text(json.dumps(results, indent=2))
    print(f"results: {args.work / 'memory_long.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
