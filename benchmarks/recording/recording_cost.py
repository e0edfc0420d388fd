"""What recording costs at the sizes phones record: `ffviz stabilize` with and without `--rrd`, CPU seconds and peak
memory, side by side, at 640x360, 1080x1920 and 2160x3840 (and, with --long, 1000 frames of 1920x1080).

The inputs are a shared clip centre-cropped to each of --sizes and scaled with Lanczos (as
../shared/tools/phone-clips.sh makes them), made once into --work; a clip shorter than --frames (or than the 1000
frames of --long) is played forwards, backwards, forwards... until it has them (no cut where it turns). --input adds
videos measured as they are (e.g. phone-clips.sh's portrait clips, with the frame counts of issue 39's table). Each
run is its own child process measured from outside as `ffviz bench` measures (ffviz.bench.measure.run_measured: CPU
seconds of the process tree, peak RSS from wait4), plain and recorded in turn, --repeat times; the table shows
medians, and the CPU ratio's median and range over the pairs (each recorded run against the plain run just before
it). The project's modules are byte-compiled first, as an installed package's are: where PYTHONDONTWRITEBYTECODE is
set, each run would compile them again, the recorded run more of them. The bounds are issue 39's: the recording
adds at most 30 % CPU at 640x360 and 1080p, and at most max(25 %, 600 MB) to the peak at every size. Writes its section of docs/benchmarks-recording.md (--no-report: print
only).

Usage: python -m benchmarks.recording.recording_cost [--clip ../shared/videos/dfkimera_shaky.mp4] [--frames 120]
       [--sizes 640x360,1080x1920,2160x3840] [--input VIDEO [--input VIDEO ...]] [--long] [--long-repeat N]
       [--repeat 1] [--record-size 960] [--work bench_out/recording] [--report docs/benchmarks-recording.md | --no-report]
"""

from __future__ import annotations

import compileall
import os
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


def back_and_forth(count: int, frames: int) -> list[int]:
    """Indices of ``frames`` frames of a clip of ``count``: forwards, then backwards, ... (no frame twice in a row)."""
    if count <= 1:
        return [0] * frames
    period = 2 * (count - 1)
    return [k % period if k % period < count else period - k % period for k in range(frames)]


def scaled_clip(source: Path, out: Path, width: int, height: int, frames: int) -> Path:
    """``frames`` frames of ``source`` (played back and forth where it has fewer), centre-cropped to width:height
    and scaled (Lanczos), H.264. A longer clip holds its decoded frames at its own size meanwhile."""
    if out.is_file():
        return out
    temp = out.with_name(f".{out.name}.tmp.mp4")
    with av.open(str(source)) as reader, av.open(str(temp), "w") as writer:
        rate = reader.streams.video[0].average_rate or Fraction(30)
        stream = writer.add_stream("libx264", rate=rate)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": "18", "preset": "veryfast"}
        decoded = []
        for frame in reader.decode(video=0):
            if len(decoded) >= frames:
                break
            decoded.append(frame.to_ndarray(format="rgb24"))
        for index in back_and_forth(len(decoded), frames):
            rgb = decoded[index]
            h, w = rgb.shape[:2]
            crop_w, crop_h = min(w, round(h * width / height)), min(h, round(w * height / width))
            x0, y0 = (w - crop_w) // 2, (h - crop_h) // 2
            resized = cv2.resize(rgb[y0:y0 + crop_h, x0:x0 + crop_w], (width, height), interpolation=cv2.INTER_LANCZOS4)
            writer.mux(stream.encode(av.VideoFrame.from_ndarray(resized, format="rgb24")))
        writer.mux(stream.encode(None))
    temp.replace(out)
    return out


def clip_shape(clip: Path) -> tuple[int, int, int]:
    """(width, height, frames) of a video, its frames counted by decoding."""
    with av.open(str(clip)) as reader:
        video = reader.streams.video[0]
        frames = sum(1 for _ in reader.decode(video=0))
        return video.codec_context.width, video.codec_context.height, frames


def measure(clip: Path, work: Path, repeat: int, record_size: str, *, warmup: bool = False) -> dict[str, list]:
    """Plain and recorded runs in turn: {'plain': [ChildRun...], 'rrd': [...]}, and the recording's bytes.
    ``warmup``: one pair first, not counted (a fresh checkout's first run compiles and caches numba's kernels: a
    12-frame clip's first plain run took 7 s of CPU, the next 1.6 s)."""
    runs: dict[str, list] = {"plain": [], "rrd": [], "rrd_bytes": []}
    rrd = work / f"{clip.stem}.rrd"
    if warmup:
        measure(clip, work, 1, record_size)
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
    ratios = [rrd.cpu_seconds / plain.cpu_seconds for plain, rrd in zip(runs["plain"], runs["rrd"])]
    cpu_ratio = statistics.median(ratios)
    peak_allowed = max(peak_plain * PEAK_SHARE, PEAK_FLOOR_MB)
    cpu_ok = cpu_ratio <= CPU_BOUND or pixels > CPU_BOUNDED_PIXELS
    peak_ok = peak_rrd - peak_plain <= peak_allowed
    size_mb = statistics.median(runs["rrd_bytes"]) / 1e6
    spread = f" ({min(ratios):.2f}-{max(ratios):.2f})" if len(ratios) > 1 else ""
    cpu_note = f"{cpu_ratio:.2f}x{spread}" + ("" if pixels <= CPU_BOUNDED_PIXELS else " (no bound)")
    line = (f"| {name} | {frames} | {len(ratios)} | {cpu_plain:.1f} | {cpu_rrd:.1f} | {cpu_note} | {peak_plain:.0f} | "
            f"{peak_rrd:.0f} | "
            f"{peak_rrd - peak_plain:+.0f} (bound +{peak_allowed:.0f}) | {size_mb:.1f} ({size_mb / frames:.3f}/frame) | "
            f"{'met' if cpu_ok and peak_ok else 'NOT MET'} |")
    return line, cpu_ok and peak_ok


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    common.add_clip(parser, VIDEOS / "dfkimera_shaky.mp4")
    common.add_frames(parser, 120, "frames of each input")
    parser.add_argument("--sizes", default="640x360,1080x1920,2160x3840", help="inputs' sizes (default: %(default)s)")
    parser.add_argument("--input", action="append", type=Path, default=[], metavar="VIDEO",
                        help="also this video, measured as it is (repeatable)")
    parser.add_argument("--long", action="store_true", help="also 1000 frames of 1920x1080")
    common.add_repeat(parser, 1)
    parser.add_argument("--no-warmup", dest="warmup", action="store_false",
                        help="no uncounted first pair (on the first input) to fill numba's and the OS's caches")
    parser.add_argument("--long-repeat", type=int, default=None, metavar="N",
                        help="runs of the --long input (default: --repeat)")
    parser.add_argument("--record-size", default="960", help="the recordings' --record-size (default: %(default)s)")
    common.add_work(parser, Path("bench_out/recording"))
    common.add_report(parser, common.RECORDING_REPORT)
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    for package in ("ffviz", "pipeline"):
        compileall.compile_dir(str(common.ROOT / package), quiet=1)
    inputs = [(size, args.frames, args.repeat) for size in args.sizes.split(",") if size]
    inputs += [(path, None, args.repeat) for path in args.input]
    if args.long:
        inputs.append(("1920x1080", 1000, args.long_repeat or args.repeat))
    made = [size for size, _, _ in inputs if isinstance(size, str)]
    lines = ["## recording_cost.py: plain against `--rrd`, full mode, CPU and peak memory", "",
             f"{common.machine_line()}; inputs: "
             + (f"{args.clip.name} cropped and scaled to {', '.join(made)}" if made else "")
             + ("; " if made and args.input else "") + ", ".join(path.name for path in args.input)
             + f"; recorded at `--record-size {args.record_size}`; plain and recorded runs in turn, `runs` times each: "
             "CPU and peak are medians, the CPU ratio the median (and range) of the pairs' ratios"
             + (" (after one uncounted pair on the first input)." if args.warmup else "."), "",
             "| input | frames | runs | plain CPU s | --rrd CPU s | CPU ratio (bound 1.30) | plain peak MB | --rrd peak MB | "
             "peak added MB | .rrd MB | bounds |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    all_met = True
    for source, frames, repeat in inputs:
        if isinstance(source, Path):
            clip, name = source, source.name
        else:
            width, height = (int(v) for v in source.split("x"))
            clip = scaled_clip(args.clip, args.work / f"{args.clip.stem}-{source}-{frames}.mp4", width, height, frames)
            name = source
        width, height, frames = clip_shape(clip)
        name = name if name == f"{width}x{height}" else f"{name} ({width}x{height})"
        runs = measure(clip, args.work, repeat, args.record_size, warmup=source == inputs[0][0] and args.warmup)
        line, met = row(name, frames, width * height, runs)
        all_met &= met
        lines.append(line)
        print(line, flush=True)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines += ["", f"Load average {load:.1f} at the end.", "",
              "Every bound met." if all_met else "Some bound NOT met (rows marked)."]
    common.save("recording_cost", lines, common.report_path(args), common.RECORDING_HEADER)
    return 0 if all_met else 1


if __name__ == "__main__":
    sys.exit(main())
