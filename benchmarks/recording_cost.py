"""What a Rerun recording costs: run time with --record summary and --record full against no recording, and
the .rrd's size per 100 frames, on a synthetic 640x360 clip (pipeline.evaluation.synthetic), in --mode none and full.

Each configuration runs the whole library call (both passes, the output video written), interleaved
(none, summary, full, none, ...) so that load on a shared machine spreads over all of them. Columns: wall
seconds (the minimum over the runs, the estimate least disturbed by other jobs, and every run), the overhead
of that minimum against no recording, CPU seconds of the process (all threads), and the recorder's time on
the pipeline's thread: seconds spent inside its observer calls (handing results to its own thread, waiting
when that one is behind, and closing, which waits for it and the SDK's writer), and its share of the run. On a loaded machine the wall-clock overhead swings by +-20 % from run to
run; the recorder's own time does not. Summary recording should add at most 15 % (issue 5).
Usage: python benchmarks/recording_cost.py [--frames 100] [--repeats 3] [--full-repeats 2] [--modes none,full]
       [--clip ../shared/videos/vplab_C.avi]  (a real clip instead of the synthetic one)
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")

from ffviz.recorder import RerunRecorder  # noqa: E402
from pipeline.evaluation import synthetic  # noqa: E402
from pipeline.stabilize import StabilizeConfig, stabilize  # noqa: E402

LEVELS = (None, "summary", "full")
SUMMARY_BUDGET = 0.15


class TimedRecorder(RerunRecorder):
    """The recorder, counting the seconds its observer calls take."""

    seconds = 0.0

    def _timed(self, method, *args) -> None:
        started = time.perf_counter()
        try:
            method(*args)
        finally:
            self.seconds += time.perf_counter() - started

    def on_start(self, info, config) -> None:
        self._timed(super().on_start, info, config)

    def on_motion(self, stamp, estimate) -> None:
        self._timed(super().on_motion, stamp, estimate)

    def on_path(self, plan) -> None:
        self._timed(super().on_path, plan)

    def on_frame(self, result) -> None:
        self._timed(super().on_frame, result)

    def on_warning(self, stamp, message) -> None:
        self._timed(super().on_warning, stamp, message)

    def on_finish(self, report) -> None:
        self._timed(super().on_finish, report)


CPU_SECONDS: dict[tuple[str, str | None], list[float]] = {}


def run_once(clip: Path, folder: Path, mode: str, level: str | None) -> tuple[float, float, int]:
    """Wall seconds of one run, seconds inside the recorder, and the recording's size in bytes (CPU seconds of
    the process, all threads, go to CPU_SECONDS)."""
    rrd = folder / f"{mode}_{level}.rrd"
    recorder = TimedRecorder(rrd, level=level) if level else None
    started, cpu_started = time.perf_counter(), time.process_time()
    stabilize(clip, folder / f"{mode}.mp4", StabilizeConfig(mode=mode), observer=recorder, overwrite=True)
    seconds = time.perf_counter() - started
    CPU_SECONDS.setdefault((mode, level), []).append(time.process_time() - cpu_started)
    return seconds, recorder.seconds if recorder else 0.0, rrd.stat().st_size if level else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration in --mode none")
    parser.add_argument("--full-repeats", type=int, default=2, help="runs per configuration in --mode full (slow)")
    parser.add_argument("--modes", default="none,full")
    parser.add_argument("--clip", type=Path, default=None, help="a real clip instead of the synthetic one")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="ffviz-recording-cost-") as tmp:
        folder = Path(tmp)
        if args.clip is not None:
            from pipeline.runtime.video_reader import count_frames

            clip = args.clip
            args.frames = count_frames(clip)
            print(f"clip {clip}: {args.frames} frames; os.cpu_count() = {os.cpu_count()}, "
                  f"load average {os.getloadavg()[0]:.1f}")
        else:
            clip = folder / "shaky.mp4"
            synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(n_frames=args.frames, seed=0)), clip)
            print(f"synthetic clip: {args.frames} frames of 640x360; os.cpu_count() = {os.cpu_count()}, "
                  f"load average {os.getloadavg()[0]:.1f}")
        run_once(clip, folder, "none", None)  # warm-up: numba compilation, codec start-up
        print("| mode | recording | wall s: min (runs) | overhead | CPU s: min | recorder s (share of run) | "
              ".rrd MB per frame |")
        print("|---|---|---|---|---|---|---|")
        for mode in args.modes.split(","):
            repeats = args.repeats if mode != "full" else args.full_repeats
            wall: dict[str | None, list[float]] = {level: [] for level in LEVELS}
            inside: dict[str | None, list[tuple[float, float]]] = {level: [] for level in LEVELS}
            sizes: dict[str | None, int] = {}
            for _ in range(repeats):
                for level in LEVELS:
                    seconds, recorder_seconds, sizes[level] = run_once(clip, folder, mode, level)
                    wall[level].append(seconds)
                    inside[level].append((recorder_seconds, seconds))
            base = min(wall[None])
            for level in LEVELS:
                fastest = min(wall[level])
                runs = ", ".join(f"{s:.1f}" for s in wall[level])
                overhead = "-" if level is None else f"{fastest / base - 1:+.1%}"
                own_seconds, run_seconds = max(inside[level], key=lambda pair: pair[0] / pair[1])  # the worst run
                own = "-" if level is None else f"{own_seconds:.2f} ({own_seconds / run_seconds:.1%})"
                size = "-" if level is None else f"{sizes[level] / 1e6 / args.frames:.3f}"
                cpu = min(CPU_SECONDS[mode, level])
                print(f"| {mode} | {level or 'no recording'} | {fastest:.1f} ({runs}) | {overhead} | {cpu:.1f} | {own} "
                      f"| {size} |", flush=True)
            share = max(own / run for own, run in inside["summary"])
            wall_overhead = min(wall["summary"]) / base - 1
            verdict = "within" if share <= SUMMARY_BUDGET else "OVER"
            print(f"  mode {mode}: the summary recorder takes {share:.1%} of the run ({verdict} the "
                  f"{SUMMARY_BUDGET:.0%} budget); wall-clock overhead of the fastest runs {wall_overhead:+.1%}")


if __name__ == "__main__":
    main()
