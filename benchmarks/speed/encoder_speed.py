"""Benchmark: the encoder's share of `--mode none`/`crop` against ffmpeg at the same x264 settings (issue 24).

1. The encoder alone: a clip's frames, decoded once into memory, encoded by PyAV's libx264 as VideoWriter does
   (CRF 18, preset medium) with PyAV's default slice threads and with frame threads (thread_type AUTO, what
   VideoWriter asks for): wall and CPU seconds of this process, medians of --repeat.
2. Whole commands, interleaved, medians of --repeat (wall s / CPU s of the process tree): `ffviz stabilize --mode
   none` and `--mode crop`, vid.stab's two passes and a plain x264 transcode, all at x264 CRF 18 preset medium
   (ffviz's default and `ffviz bench`'s peers), ffviz none against the transcode at CRF 23, and none and crop
   with --no-deblur (vid.stab does not deblur: what the rest of ffviz's chain costs).

Usage: python -m benchmarks.speed.encoder_speed [--clip ../shared/videos/vplab_C.avi] [--repeat 3]
       [--report docs/benchmarks-speed.md | --no-report]
"""

from __future__ import annotations

import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import av

from benchmarks import common
from pipeline.runtime import video_reader

VIDEOS = common.VIDEOS


def _cpu(who: int) -> float:
    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


def encode_only(frames: list, fps: int, thread_type: str | None, path: Path) -> tuple[float, float]:
    """(wall s, CPU s) of encoding ``frames`` to H.264 CRF 18 medium; ``thread_type`` None: PyAV's default."""
    cpu, started = _cpu(resource.RUSAGE_SELF), time.perf_counter()
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps, options={"crf": "18", "preset": "medium"})
        stream.width, stream.height, stream.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
        if thread_type is not None:
            stream.codec_context.thread_type = thread_type
        for rgb in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
        container.mux(stream.encode())
    return time.perf_counter() - started, _cpu(resource.RUSAGE_SELF) - cpu


def timed(commands: list[list[str]]) -> tuple[float, float]:
    """(wall s, CPU s of the children) of running ``commands`` one after the other."""
    cpu, started = _cpu(resource.RUSAGE_CHILDREN), time.perf_counter()
    for command in commands:
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started, _cpu(resource.RUSAGE_CHILDREN) - cpu


def methods(clip: Path, tmp: str) -> dict[str, list[list[str]]]:
    ffviz = [sys.executable, "-m", "ffviz.cli", "stabilize", str(clip), "--overwrite"]
    x264 = ["-fps_mode", "passthrough", "-c:v", "libx264", "-preset", "medium"]
    ffmpeg = ["ffmpeg", "-v", "error", "-y", "-i", str(clip)]
    found = {
        "ffviz none (CRF 18)": [ffviz + ["-o", f"{tmp}/none.mp4", "--mode", "none"]],
        "ffviz crop (CRF 18)": [ffviz + ["-o", f"{tmp}/crop.mp4", "--mode", "crop"]],
        "ffviz none (CRF 23)": [ffviz + ["-o", f"{tmp}/none23.mp4", "--mode", "none", "--crf", "23"]],
        # what deblurring (which vid.stab does not do) costs of the two modes
        "ffviz none --no-deblur (CRF 18)": [ffviz + ["-o", f"{tmp}/none_nd.mp4", "--mode", "none", "--no-deblur"]],
        "ffviz crop --no-deblur (CRF 18)": [ffviz + ["-o", f"{tmp}/crop_nd.mp4", "--mode", "crop", "--no-deblur"]],
    }
    if shutil.which("ffmpeg"):
        found["vid.stab two passes (CRF 18)"] = [
            ffmpeg + ["-vf", f"format=yuv420p,vidstabdetect=result={tmp}/t.trf", "-f", "null", "-"],
            ffmpeg + ["-vf", f"format=yuv420p,vidstabtransform=input={tmp}/t.trf,format=yuv420p", *x264, "-crf", "18",
                      f"{tmp}/vidstab.mp4"]]
        found["x264 transcode (CRF 18)"] = [ffmpeg + ["-vf", "format=yuv420p", *x264, "-crf", "18", f"{tmp}/x18.mp4"]]
        found["x264 transcode (CRF 23)"] = [ffmpeg + ["-vf", "format=yuv420p", *x264, "-crf", "23", f"{tmp}/x23.mp4"]]
    return found


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    common.add_clip(parser, VIDEOS / "vplab_C.avi")
    common.add_repeat(parser, 3)
    common.add_report(parser, common.SPEED_REPORT)
    args = parser.parse_args(argv)
    if not args.clip.is_file():
        print(f"{args.clip} not found: nothing measured")
        return 0
    started = common.machine_line()
    frames = [frame.rgb for frame in video_reader.VideoReader(args.clip)]
    fps = round(video_reader.probe_video(args.clip).fps)
    encoder: dict[str, list[tuple[float, float]]] = {"PyAV default (slice threads)": [], "frame threads (AUTO)": []}
    commands_runs: dict[str, list[tuple[float, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):
            for name, thread_type in (("PyAV default (slice threads)", None), ("frame threads (AUTO)", "AUTO")):
                encoder[name].append(encode_only(frames, fps, thread_type, Path(tmp) / "encoded.mp4"))
                print(f"encoder alone, {name}: wall {encoder[name][-1][0]:.1f} s CPU {encoder[name][-1][1]:.1f} s",
                      flush=True)
        del frames
        for _ in range(args.repeat):
            for name, commands in methods(args.clip, tmp).items():
                commands_runs.setdefault(name, []).append(timed(commands))
                print(f"{name}: wall {commands_runs[name][-1][0]:.1f} s CPU {commands_runs[name][-1][1]:.1f} s",
                      flush=True)

    def med(runs: list[tuple[float, float]]) -> tuple[float, float]:
        return statistics.median(w for w, _ in runs), statistics.median(c for _, c in runs)

    lines = ["## Encoding: ffviz's writer and `--mode none`/`crop` against ffmpeg at the same x264 settings", "",
             f"Written by `benchmarks/speed/encoder_speed.py` ({started}) on {args.clip.name}, medians of "
             f"{args.repeat}.", "",
             "The encoder alone (frames in memory, x264 CRF 18 preset medium, this process):", "",
             "| encoder threads | wall s | CPU s |", "|---|---|---|"]
    lines += [f"| {name} | {med(runs)[0]:.1f} | {med(runs)[1]:.1f} |" for name, runs in encoder.items()]
    lines += ["", "Whole commands, interleaved (wall s / CPU s of the process tree; x264 preset medium):", "",
              "| method | wall s | CPU s |", "|---|---|---|"]
    lines += [f"| {name} | {med(runs)[0]:.1f} | {med(runs)[1]:.1f} |" for name, runs in commands_runs.items()]
    vidstab = commands_runs.get("vid.stab two passes (CRF 18)")
    x264 = commands_runs.get("x264 transcode (CRF 18)")
    if vidstab and x264:
        none, crop = med(commands_runs["ffviz none (CRF 18)"]), med(commands_runs["ffviz crop (CRF 18)"])
        lines += ["", f"Against vid.stab (target: wall <= 1x): none {none[0] / med(vidstab)[0]:.2f}x wall, "
                      f"{none[1] / med(vidstab)[1]:.2f}x CPU; crop {crop[0] / med(vidstab)[0]:.2f}x wall, "
                      f"{crop[1] / med(vidstab)[1]:.2f}x CPU. Against the transcode (moonshot: <= 1.3x): none "
                      f"{none[0] / med(x264)[0]:.2f}x wall, {none[1] / med(x264)[1]:.2f}x CPU."]
        plain = med(commands_runs["ffviz none --no-deblur (CRF 18)"])
        lines += [f"Without deblurring: none {plain[0] / med(vidstab)[0]:.2f}x vid.stab's wall, "
                  f"{plain[1] / med(vidstab)[1]:.2f}x its CPU."]
    common.publish("encoding", lines, common.report_path(args), common.SPEED_HEADER)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
