"""Benchmark: input vs ffviz vs ffmpeg's two-pass vid.stab on the real clips (not a test; prints a table).

For every clip: the input's own residual jitter and stability; then each method's output measured
against the input with pipeline.metrics (residual jitter px, stability translation/rotation, cropping
ratio, distortion) and its wall-clock seconds. vid.stab runs with its defaults (smoothing=10,
optzoom=1: it zooms to hide borders, comparable to ffviz --mode crop).

Usage: python benchmarks/vidstab_compare.py [--modes crop,none] [--out DIR] [CLIPS...]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pipeline import metrics
from pipeline.errors import FFVizError

VIDEOS = Path(__file__).resolve().parents[2] / "shared" / "videos"
COLUMNS = ("jitter_px", "stab_T", "stab_R", "crop", "distort", "black", "seconds")


def run_ffviz(clip: Path, out: Path, mode: str) -> float:
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "ffviz.cli", "stabilize", str(clip), "-o", str(out), "--mode", mode,
                    "--overwrite"], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - started


def run_vidstab(clip: Path, out: Path, work: Path) -> float:
    transforms = work / f"{clip.stem}.trf"
    started = time.perf_counter()
    # format=yuv420p first: vidstabdetect aborts on yuvj444p input.
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf",
                    f"format=yuv420p,vidstabdetect=result={transforms}", "-f", "null", "-"], check=True)
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf",
                    f"format=yuv420p,vidstabtransform=input={transforms},format=yuv420p",
                    "-fps_mode", "passthrough",  # one output frame per input frame, input timestamps
                    "-c:v", "libx264", "-crf", "18", "-c:a", "copy", str(out)], check=True)
    return time.perf_counter() - started


def row(measured: metrics.StabilizationMetrics, seconds: float) -> dict:
    return dict(jitter_px=measured.residual_jitter_px, stab_T=measured.stability_translation,
                stab_R=measured.stability_rotation, crop=measured.cropping_ratio, distort=measured.distortion,
                black=measured.black_fraction, seconds=seconds)


def format_row(clip: str, method: str, values: dict) -> str:
    cells = [f"{values[c]:.3f}" if isinstance(values.get(c), float) else "-" for c in COLUMNS]
    return f"| {clip} | {method} | " + " | ".join(cells) + " |"


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clips", nargs="*", type=Path)
    parser.add_argument("--modes", default="crop", help="ffviz modes to run, comma-separated (default: crop)")
    parser.add_argument("--out", type=Path, default=None, help="keep outputs and results.json here")
    args = parser.parse_args(argv)
    clips = args.clips or sorted(p for p in VIDEOS.glob("*") if p.suffix in (".mp4", ".avi"))
    if not clips:
        print(f"no clips given and none under {VIDEOS}", file=sys.stderr)
        return 2
    have_vidstab = shutil.which("ffmpeg") is not None
    if not have_vidstab:
        print("ffmpeg not found: vid.stab column skipped (./run bench installs Debian's ffmpeg)", file=sys.stderr)
    work = args.out or Path(tempfile.mkdtemp(prefix="ffviz-bench-"))
    work.mkdir(parents=True, exist_ok=True)

    lines = ["| clip | method | " + " | ".join(COLUMNS) + " |", "|" + "---|" * (len(COLUMNS) + 2)]
    print("\n".join(lines), flush=True)
    results: dict[str, dict] = {}
    wins = 0
    for clip in clips:
        per_clip: dict[str, dict] = {}
        own = metrics.video_motion_stats(clip)
        per_clip["input"] = dict(jitter_px=own.residual_jitter_px, stab_T=own.stability_translation,
                                 stab_R=own.stability_rotation)
        runs = [(f"ffviz {mode}", work / f"{clip.stem}.ffviz-{mode}.mp4", lambda c, o, m=mode: run_ffviz(c, o, m))
                for mode in args.modes.split(",")]
        if have_vidstab:
            runs.append(("vidstab", work / f"{clip.stem}.vidstab.mp4", lambda c, o: run_vidstab(c, o, work)))
        for method, out, run in runs:
            try:
                seconds = run(clip, out)
                per_clip[method] = row(metrics.compare(clip, out), seconds)
            except (subprocess.CalledProcessError, FFVizError) as error:  # one failure must not end the table
                print(f"{clip.name}: {method} failed: {error}", file=sys.stderr)
                per_clip[method] = {}
        for method, values in per_clip.items():
            line = format_row(clip.name, method, values)
            lines.append(line)
            print(line, flush=True)
        first_ffviz = per_clip[f"ffviz {args.modes.split(',')[0]}"]
        if per_clip.get("vidstab") and first_ffviz and first_ffviz["jitter_px"] < per_clip["vidstab"]["jitter_px"]:
            wins += 1
        results[clip.name] = per_clip
    if have_vidstab:
        print(f"\nffviz residual jitter lower than vid.stab's on {wins} of {len(clips)} clips")
    (work / "results.json").write_text(json.dumps(results, indent=2))
    (work / "results.md").write_text("\n".join(lines) + "\n")
    print(f"results: {work / 'results.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
