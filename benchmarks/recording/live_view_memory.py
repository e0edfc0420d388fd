"""`ffviz stabilize --view` (the live view) at phone sizes: peak memory of the run and of the viewer's server, and
whether the .rrd holds every frame (the live view may drop display updates, never data in the file).

Runs `ffviz stabilize CLIP -o OUT --view` in its own session, samples the resident memory of the ffviz process and of
the web viewer's server (the `rerun` process it starts) every 0.2 s, stops the server once the run has written its
files, and counts the recording's output frames. Writes its section of docs/benchmarks-recording.md (--no-report:
print only).

Usage: python -m benchmarks.recording.live_view_memory CLIP [CLIP ...] [--work bench_out/live]
       [--report PATH | --no-report]
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil

from benchmarks import common
from ffviz import entities as ent
from ffviz.rrd import Recording
from pipeline.runtime.video_reader import probe_video


def run(clip: Path, work: Path) -> str:
    out, rrd = work / f"{clip.stem}.live.mp4", work / f"{clip.stem}.live.rrd"
    command = [sys.executable, "-m", "ffviz.cli", "stabilize", str(clip), "-o", str(out), "--rrd", str(rrd), "--view",
               "--web-port", "9190", "--grpc-port", "9976", "--overwrite"]
    log = (work / f"{clip.stem}.live.log").open("w")
    child = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    peaks = {"ffviz": 0, "viewer server": 0}
    started = time.perf_counter()
    try:
        while child.poll() is None and "still serving" not in (work / f"{clip.stem}.live.log").read_text():
            for name, process in _processes(child.pid).items():
                peaks[name] = max(peaks[name], process.memory_info().rss)
            time.sleep(0.2)
        seconds = time.perf_counter() - started
    finally:
        os.killpg(child.pid, signal.SIGINT)
        child.wait(timeout=60)
    frames = len(Recording.load(rrd).indices(ent.OUTPUT_FRAME))
    info = probe_video(clip)
    return (f"| {clip.name} | {info.width}x{info.height} | {info.frame_count} | {seconds:.0f} | "
            f"{peaks['ffviz'] / 2**20:.0f} | {peaks['viewer server'] / 2**20:.0f} | {frames} |")


def _processes(pid: int) -> dict[str, psutil.Process]:
    """The ffviz process and the viewer server among its children."""
    found = {}
    try:
        root = psutil.Process(pid)
        found["ffviz"] = root
        for child in root.children(recursive=True):
            if "rerun" in child.name():
                found["viewer server"] = child
    except psutil.Error:
        pass
    return found


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    parser.add_argument("clips", type=Path, nargs="+")
    common.add_work(parser, Path("bench_out/live"))
    common.add_report(parser, common.RECORDING_REPORT)
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    lines = ["## live_view_memory.py: `ffviz stabilize --view`, peak memory of the run and of the viewer's server", "",
             f"{common.machine_line()}; no browser attached (the server keeps what it was sent, up to its 1 GiB limit, for "
             "a page that connects later).", "",
             "| clip | size | frames | run s | ffviz peak MB | viewer server peak MB | .rrd output frames |",
             "|---|---|---|---|---|---|---|"]
    for clip in args.clips:
        lines.append(run(clip, args.work))
        print(lines[-1], flush=True)
    common.save("live_view_memory", lines, common.report_path(args), common.RECORDING_HEADER)
    return 0


if __name__ == "__main__":
    sys.exit(main())
