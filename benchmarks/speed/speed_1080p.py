"""Benchmark: 1080p (issue 24, target 4): ffviz full, crop and none against a plain x264 transcode at the same settings.

The clip: the first --frames frames of a shared 640x360 clip upscaled to 1920x1080 by ffmpeg (Lanczos, x264 CRF 16
preset fast), and a second one --frames x 3 long, so that peak memory can be compared across lengths (x264's
lookahead, 40 frames at preset medium, and ffviz's frame window fill up over the first few dozen frames). Each command
runs as its own child process, measured from outside as `ffviz bench` measures (ffviz/bench/measure.py run_measured:
wall and CPU seconds of the process tree, peak RSS from wait4), --repeat times, medians, after one unmeasured run of
each on the shorter clip (numba's kernels compiled into their cache, the clips in the page cache). The transcode: ffmpeg
decoding the clip and encoding it with libx264 CRF 18 preset medium, ffviz's default encoder settings. Then each mode's
CPU ms a frame per stage on the shorter clip (`ffviz bench --profile`'s measurement, ffviz/bench/profile.py,
without the recording run).

Usage: python -m benchmarks.speed.speed_1080p [--clip ../shared/videos/vplab_C.avi] [--frames 40] [--repeat 1]
       [--modes full,crop,none] [--report docs/benchmarks-speed.md | --no-report]
"""

from __future__ import annotations

import shutil
import statistics
import subprocess
import tempfile
from pathlib import Path

from benchmarks import common
from ffviz.bench import profile as bench_profile
from ffviz.bench.measure import run_measured
from ffviz.bench.methods import ffviz_command

VIDEOS = common.VIDEOS
X264 = ["-fps_mode", "passthrough", "-c:v", "libx264", "-preset", "medium", "-crf", "18"]


def upscaled(clip: Path, frames: int, out: Path) -> Path:
    """The first ``frames`` frames of ``clip`` at 1920x1080 (H.264 CRF 16: close to the source, cheap to decode)."""
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-frames:v", str(frames), "-an",
                    "-vf", "scale=1920:1080:flags=lanczos", "-c:v", "libx264", "-crf", "16", "-preset", "fast",
                    "-pix_fmt", "yuv420p", str(out)], check=True)
    return out


def commands(clip: Path, modes: list[str], work: Path) -> dict[str, list[str]]:
    found = {f"ffviz {mode}": ffviz_command(clip, work / f"{clip.stem}.{mode}.mp4", mode) for mode in modes}
    found["x264 transcode"] = ["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf", "format=yuv420p", *X264,
                               str(work / f"{clip.stem}.x264.mp4")]
    return found


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    common.add_clip(parser, VIDEOS / "vplab_C.avi")
    common.add_frames(parser, 40, "the shorter clip's frames (the longer one has three times as many)")
    common.add_repeat(parser, 1)
    parser.add_argument("--modes", default="full,crop,none", help="ffviz modes, comma-separated (default: %(default)s)")
    parser.add_argument("--no-profile", action="store_true", help="leave out the per-stage table")
    common.add_report(parser, common.SPEED_REPORT)
    args = parser.parse_args(argv)
    if not args.clip.is_file() or shutil.which("ffmpeg") is None:
        print(f"{args.clip} or ffmpeg not found: nothing measured")
        return 0
    started = common.machine_line()
    modes = args.modes.split(",")
    lengths = (args.frames, 3 * args.frames)
    runs: dict[tuple[str, int], list] = {}
    profiles = []
    with tempfile.TemporaryDirectory(prefix="ffviz-1080p-") as tmp:
        work = Path(tmp)
        clips = {n: upscaled(args.clip, n, work / f"{args.clip.stem}_1080p_{n}.mp4") for n in lengths}
        # One unmeasured run of each command first: the first run in a fresh checkout compiles the numba kernels
        # into their on-disk cache, seconds of CPU that would land in the short clip's run only and so shrink the
        # difference the per-frame figure is taken from.
        for name, command in commands(clips[args.frames], modes, work).items():
            run_measured(command)
        for _ in range(args.repeat):
            for n, clip in clips.items():
                for name, command in commands(clip, modes, work).items():
                    run = run_measured(command)
                    if run.returncode != 0:
                        raise SystemExit(f"{name} on {clip.name} failed: {run.output_tail}")
                    runs.setdefault((name, n), []).append(run)
                    print(f"{name}, {n} frames: wall {run.seconds:.1f} s, CPU {run.cpu_seconds:.1f} s, peak RSS "
                          f"{run.peak_rss_bytes / 2**20:.0f} MiB", flush=True)
        if not args.no_profile:
            profiles = [bench_profile.profile_stages(clips[args.frames], mode, recording=False) for mode in modes]

    def med(name: str, n: int, field: str) -> float:
        return statistics.median(getattr(run, field) for run in runs[(name, n)])

    names = [*(f"ffviz {mode}" for mode in modes), "x264 transcode"]
    short, long = lengths

    def marginal_ms(name: str) -> float:
        """CPU ms a frame from the difference between the two lengths: start-up (imports, x264's set-up) cancels."""
        return 1000 * (med(name, long, "cpu_seconds") - med(name, short, "cpu_seconds")) / (long - short)

    x264_ms = marginal_ms("x264 transcode")
    lines = ["## 1080p: ffviz against the x264 transcode (target 4)", "",
             f"Written by `benchmarks/speed/speed_1080p.py` ({started}; --repeat {args.repeat}, medians). The clip: "
             "the "
             f"first {short} and {long} frames of {args.clip.name} upscaled to 1920x1080. Whole commands "
             "as `ffviz bench` measures them (wall and CPU s of the process tree, peak RSS); the transcode is "
             "ffmpeg's decode + libx264 CRF 18 preset medium, ffviz's default encoder settings. CPU a frame: the "
             f"difference between the {long}- and {short}-frame runs over the {long - short} frames between, so that "
             "start-up cancels. Target: ffviz full's CPU a frame <= 2x the transcode's; memory flat in the video's "
             "length.", "",
             "| method | wall s | CPU s | peak RSS MiB | CPU ms a frame | x the transcode's |",
             "|---|---|---|---|---|---|"]
    for name in names:
        lines.append(f"| {name} | " + " / ".join(f"{med(name, n, 'seconds'):.1f}" for n in lengths) + " | "
                     + " / ".join(f"{med(name, n, 'cpu_seconds'):.1f}" for n in lengths) + " | "
                     + " / ".join(f"{med(name, n, 'peak_rss_bytes') / 2**20:.0f}" for n in lengths)
                     + f" | {marginal_ms(name):.0f} | {marginal_ms(name) / x264_ms:.2f} |")
    lines += ["", f"(wall, CPU and peak RSS: {short} / {long} frames.)"]
    if "full" in modes:
        ratio = marginal_ms("ffviz full") / x264_ms
        lines += ["", f"Full mode: {ratio:.2f}x the transcode's CPU a frame (target <= 2x: "
                      f"{'met' if ratio <= 2 else 'missed'})."]
    growth = [med(f"ffviz {mode}", long, "peak_rss_bytes") / med(f"ffviz {mode}", short, "peak_rss_bytes")
              for mode in modes]
    lines += [f"Peak RSS at {long} frames over {short}: "
              + ", ".join(f"{mode} {g:.2f}x" for mode, g in zip(modes, growth)) + " (flat: about 1x)."]
    if profiles:
        lines += ["", f"Each stage's CPU ms a frame at 1080p ({short} frames; ffviz/bench/profile.py: one worker "
                      "in process, OpenCV's threads off, no recording run):", "", bench_profile.table_header(),
                  *(profile.line() for profile in profiles)]
    common.publish("1080p", lines, common.report_path(args), common.SPEED_HEADER)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
