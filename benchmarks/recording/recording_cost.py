"""What recording costs at the sizes phones record: `ffviz stabilize` with and without `--rrd`, CPU seconds and peak
memory, side by side, at 640x360, 1080x1920 and 2160x3840 (and, with --long, 1000 frames of 1920x1080).

The large inputs are a shared clip centre-cropped to the aspect and scaled with Lanczos (as
../shared/tools/phone-clips.sh makes them), made once into --work. Each run is its own child process measured from
outside as `ffviz bench` measures (ffviz.bench.measure.run_measured: CPU seconds of the process tree, peak RSS from
wait4), plain and recorded in turn, --repeat times; the table shows medians. The bounds are issue 39's: the
recording adds at most 30 % CPU at 640x360 and 1080p, and at most max(25 %, 600 MB) to the peak at every size.
Writes its section of docs/benchmarks-recording.md (--no-report: print only).

Usage: python -m benchmarks.recording.recording_cost [--clip ../shared/videos/dfkimera_shaky.mp4] [--frames 120]
       [--sizes 640x360,1080x1920,2160x3840] [--long] [--repeat 1] [--record-size 960] [--work bench_out/recording]
       [--report docs/benchmarks-recording.md | --no-report]
"""

from __future__ import annotations

import statistics
import sys
from fractions import Fraction
from pathlib import Path

import av
import cv2

from benchmarks import common
from ffviz.bench.measure import run_measured
from ffviz.bench.methods import ffviz_command

VIDEOS = common.VIDEOS
CPU_BOUND = 1.30  # at 640x360 and 1080p
PEAK_SHARE, PEAK_FLOOR_MB = 0.25, 600.0
CPU_BOUNDED_PIXELS = 1920 * 1080  # the CPU bound holds up to 1080p


def scaled_clip(source: Path, out: Path, width: int, height: int, frames: int) -> Path:
    """The first ``frames`` frames of ``source``, centre-cropped to width:height and scaled (Lanczos), H.264."""
    if out.is_file():
        return out
    temp = out.with_name(f".{out.name}.tmp.mp4")
    with av.open(str(source)) as reader, av.open(str(temp), "w") as writer:
        rate = reader.streams.video[0].average_rate or Fraction(30)
        stream = writer.add_stream("libx264", rate=rate)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": "18", "preset": "veryfast"}
        for index, frame in enumerate(reader.decode(video=0)):
            if index >= frames:
                break
            rgb = frame.to_ndarray(format="rgb24")
            h, w = rgb.shape[:2]
            crop_w, crop_h = min(w, round(h * width / height)), min(h, round(w * height / width))
            x0, y0 = (w - crop_w) // 2, (h - crop_h) // 2
            resized = cv2.resize(rgb[y0:y0 + crop_h, x0:x0 + crop_w], (width, height), interpolation=cv2.INTER_LANCZOS4)
            writer.mux(stream.encode(av.VideoFrame.from_ndarray(resized, format="rgb24")))
        writer.mux(stream.encode(None))
    temp.replace(out)
    return out


def measure(clip: Path, work: Path, repeat: int, record_size: str) -> dict[str, list]:
    """Plain and recorded runs in turn: {'plain': [ChildRun...], 'rrd': [...]}, and the recording's bytes."""
    runs: dict[str, list] = {"plain": [], "rrd": [], "rrd_bytes": []}
    rrd = work / f"{clip.stem}.rrd"
    for _ in range(repeat):
        for kind in ("plain", "rrd"):
            command = ffviz_command(clip, work / f"{clip.stem}.{kind}.mp4", "full")
            if kind == "rrd":
                command += ["--rrd", str(rrd), "--record-size", record_size]
            run = run_measured(command)
            if run.returncode != 0:
                raise SystemExit(f"{' '.join(command)} failed: {run.output_tail}")
            runs[kind].append(run)
            if kind == "rrd":
                runs["rrd_bytes"].append(rrd.stat().st_size)
    return runs


def row(name: str, frames: int, pixels: int, runs: dict[str, list]) -> tuple[str, bool]:
    med = lambda kind, field: statistics.median(getattr(r, field) for r in runs[kind])  # noqa: E731
    cpu_plain, cpu_rrd = med("plain", "cpu_seconds"), med("rrd", "cpu_seconds")
    peak_plain, peak_rrd = med("plain", "peak_rss_bytes") / 2**20, med("rrd", "peak_rss_bytes") / 2**20
    cpu_ratio = cpu_rrd / cpu_plain
    peak_allowed = max(peak_plain * PEAK_SHARE, PEAK_FLOOR_MB)
    cpu_ok = cpu_ratio <= CPU_BOUND or pixels > CPU_BOUNDED_PIXELS
    peak_ok = peak_rrd - peak_plain <= peak_allowed
    size_mb = statistics.median(runs["rrd_bytes"]) / 1e6
    cpu_note = f"{cpu_ratio:.2f}x" + ("" if pixels <= CPU_BOUNDED_PIXELS else " (no bound)")
    line = (f"| {name} | {frames} | {cpu_plain:.1f} | {cpu_rrd:.1f} | {cpu_note} | {peak_plain:.0f} | {peak_rrd:.0f} | "
            f"{peak_rrd - peak_plain:+.0f} (bound +{peak_allowed:.0f}) | {size_mb:.1f} ({size_mb / frames:.3f}/frame) | "
            f"{'met' if cpu_ok and peak_ok else 'NOT MET'} |")
    return line, cpu_ok and peak_ok


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    common.add_clip(parser, VIDEOS / "dfkimera_shaky.mp4")
    common.add_frames(parser, 120, "frames of each input")
    parser.add_argument("--sizes", default="640x360,1080x1920,2160x3840", help="inputs' sizes (default: %(default)s)")
    parser.add_argument("--long", action="store_true", help="also 1000 frames of 1920x1080")
    common.add_repeat(parser, 1)
    parser.add_argument("--record-size", default="960", help="the recordings' --record-size (default: %(default)s)")
    common.add_work(parser, Path("bench_out/recording"))
    common.add_report(parser, common.RECORDING_REPORT)
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    inputs = [(size, args.frames) for size in args.sizes.split(",") if size]
    if args.long:
        inputs.append(("1920x1080", 1000))
    lines = ["## recording_cost.py: plain against `--rrd`, full mode, CPU and peak memory", "",
             f"{common.machine_line()}; input: {args.clip.name} cropped and scaled; recorded at `--record-size "
             f"{args.record_size}`; medians of {args.repeat} run(s) each, plain and recorded in turn.", "",
             "| input | frames | plain CPU s | --rrd CPU s | CPU ratio (bound 1.30) | plain peak MB | --rrd peak MB | "
             "peak added MB | .rrd MB | bounds |", "|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    all_met = True
    for size, frames in inputs:
        width, height = (int(v) for v in size.split("x"))
        clip = scaled_clip(args.clip, args.work / f"{args.clip.stem}-{size}-{frames}.mp4", width, height, frames)
        line, met = row(size, frames, width * height, measure(clip, args.work, args.repeat, args.record_size))
        all_met &= met
        lines.append(line)
        print(line, flush=True)
    lines += ["", "Every bound met." if all_met else "Some bound NOT met (rows marked)."]
    common.save("recording_cost", lines, common.report_path(args), common.RECORDING_HEADER)
    return 0 if all_met else 1


if __name__ == "__main__":
    sys.exit(main())
