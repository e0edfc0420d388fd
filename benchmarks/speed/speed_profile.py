"""Benchmark: CPU ms a frame of each stage (`ffviz bench --profile`, ffviz/bench/profile.py) into the speed report,
and of each thread of a default run (both cores: frame workers, the decoder thread, x264's threads, the main
thread that converts and writes), from the kernel's per-thread accounting (/proc/self/task, Linux).

Usage: python -m benchmarks.speed.speed_profile [--clip ../shared/videos/vplab_C.avi] [--modes none,full]
       [--no-recording] [--report docs/benchmarks-speed.md | --no-report]
"""

from __future__ import annotations

import os
import tempfile
import threading
from pathlib import Path

from benchmarks import common
from ffviz.bench import profile as bench_profile
from pipeline.runtime import memory

VIDEOS = common.VIDEOS
THREAD_GROUPS = (("ffviz-frame", "frame workers (motion, warp, completion, deblur)"),
                 ("ffviz-decode", "decoding + RGB conversion (both passes)"),
                 ("MainThread", "main (RGB -> YUV, muxing, orchestration)"),
                 ("av:", "FFmpeg's decoder threads"))
OTHER_THREADS = "x264's threads (and any other)"


def _task_cpu() -> dict[int, tuple[str, float]]:
    """tid -> (name the kernel gives it, CPU seconds so far) of this process's threads."""
    tick = os.sysconf("SC_CLK_TCK")
    found = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            stat = Path(f"/proc/self/task/{tid}/stat").read_text()
            name = Path(f"/proc/self/task/{tid}/comm").read_text().strip()
        except OSError:  # ended meanwhile
            continue
        fields = stat.rsplit(")", 1)[1].split()
        found[int(tid)] = (name, (int(fields[11]) + int(fields[12])) / tick)  # utime + stime
    return found


def thread_profile(clip: Path, mode: str) -> tuple[dict[str, float], int]:
    """CPU ms a frame of each THREAD_GROUPS group in a default `ffviz stabilize` run (threads sampled every 0.1 s,
    so a thread that ends counts up to its last sample; a short warm-up first, as bench_profile's)."""
    from pipeline.config import StabilizeConfig
    from pipeline.stabilize import stabilize

    names: dict[int, str] = {}
    latest: dict[int, tuple[str, float]] = {}
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            names.update({t.native_id: t.name for t in threading.enumerate() if t.native_id})
            latest.update(_task_cpu())
            stop.wait(0.1)

    with tempfile.TemporaryDirectory() as tmp:
        bench_profile._warm_up(mode, Path(tmp), "auto")
        before = _task_cpu()
        sampler = threading.Thread(target=sample, name="sampler", daemon=True)
        sampler.start()
        try:
            report = stabilize(clip, Path(tmp) / "out.mp4", StabilizeConfig(mode=mode), overwrite=True)
        finally:
            stop.set()
            sampler.join()
        latest.update(_task_cpu())
    groups: dict[str, float] = {}
    for tid, (comm, cpu) in latest.items():
        if tid == sampler.native_id:
            continue
        name = names.get(tid, comm)
        label = next((label for prefix, label in THREAD_GROUPS if name.startswith(prefix)), OTHER_THREADS)
        groups[label] = groups.get(label, 0.0) + cpu - before.get(tid, (comm, 0.0))[1]
    return {label: 1000 * cpu / report.n_frames for label, cpu in groups.items()}, report.n_frames


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    common.add_clip(parser, VIDEOS / "vplab_C.avi")
    parser.add_argument("--modes", default="none,full", help="ffviz modes, comma-separated (default: %(default)s)")
    parser.add_argument("--no-recording", action="store_true", help="leave out the recording's column")
    common.add_report(parser, common.SPEED_REPORT)
    args = parser.parse_args(argv)
    if not args.clip.is_file():
        print(f"{args.clip} not found: nothing measured")
        return 0
    memory.reuse_freed_memory()  # as `ffviz` does at its start (pipeline/runtime/memory.py)
    started = common.machine_line()
    rows = [bench_profile.profile_stages(args.clip, mode, recording=not args.no_recording).line()
            for mode in args.modes.split(",")]
    lines = ["## Where the CPU goes: each stage's CPU ms a frame", "",
             f"Written by `benchmarks/speed/speed_profile.py` ({started}) with `ffviz bench --profile`'s measurement "
             "(ffviz/bench/profile.py: one worker in process, OpenCV's threads off, after a short warm-up; total: the "
             "run without recording, every thread; recording: a second run's extra CPU with a full .rrd).", "",
             bench_profile.table_header(), *rows]
    labels = [label for _, label in THREAD_GROUPS] + [OTHER_THREADS]
    lines += ["", "The same clip run as `ffviz stabilize` runs it (a worker per core, OpenCV's threads on): CPU ms a "
              "frame of each thread group.", "", "| mode | " + " | ".join(labels) + " | total |",
              "|---|" + "---|" * (len(labels) + 1)]
    for mode in args.modes.split(","):
        groups, _ = thread_profile(args.clip, mode)
        lines.append(f"| {mode} | " + " | ".join(f"{groups.get(label, 0.0):.1f}" for label in labels)
                     + f" | {sum(groups.values()):.1f} |")
    common.publish("profile", lines, common.report_path(args), common.SPEED_HEADER)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
