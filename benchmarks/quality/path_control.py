"""Path control side by side with ffmpeg vid.stab's matching options, crop mode, on the shared clips.

Each ffviz setting runs `ffviz stabilize --mode crop --no-deblur` (deblurring changes no path) with the options
shown; vid.stab runs its two passes (vidstabdetect, vidstabtransform) with the options shown (its defaults
otherwise: smoothing=10, optzoom=1). Every output is compared with its input by pipeline.evaluation.metrics:
residual jitter (px, deg; lower is steadier), the cropping ratio (Liu et al.: the output's scale against the
input, 1/s, averaged over the frames; 0.9 is a 10 % crop each way, 81 % of the area) and the share of black
pixels. ffviz's rows also print the area its plan kept (the crop window's scale squared, averaged).

Usage: nice -n 10 python -m benchmarks.quality.path_control [CLIP ...] [--frames N]
       [--report [docs/benchmarks-path-control.md]]   (--report: also write the table as its section of the report)
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import common
from pipeline.evaluation import metrics

SHARED = common.VIDEOS
REPORT = common.DOCS / "benchmarks-path-control.md"
DEFAULT_CLIPS = ("sudheerachary_small-shaky-5.avi", "vplab_C.avi", "zhangyilang_03_input.avi")

# (label, ffviz options, the vid.stab options that match it or None)
# Windows inside every frame (--crop-fill 0, as --crop adaptive's always is), eq. 18's path at k = 30 unless named:
# the path controls compared with vid.stab's matching options on the same footing.
HARD = ["--path", "gaussian", "--crop-fill", "0"]
FFVIZ = (
    ("gaussian, fixed crop", HARD, None),
    ("gaussian, --crop adaptive", ["--path", "gaussian", "-k", "30", "--crop", "adaptive"], None),
    ("gaussian, --crop adaptive --zoom-speed 0.25", ["--path", "gaussian", "-k", "30", "--crop", "adaptive",
                                                     "--zoom-speed", "0.25"], None),
    ("gaussian, --smoothness 25", [*HARD, "--smoothness", "25"], None),
    ("gaussian, --smoothness 75", [*HARD, "--smoothness", "75"], None),
    ("gaussian, --smoothness t=75,r=100,z=100", [*HARD, "--smoothness", "t=75,r=100,z=100"], None),
    ("gaussian, --max-shift 8 --max-angle 1", [*HARD, "--max-shift", "8", "--max-angle", "1"], None),
    ("l1, fixed crop", ["--path", "l1"], None),
    ("l1, --crop adaptive", ["--path", "l1", "--crop", "adaptive"], None),
    ("tripod", ["--tripod"], None),
    ("tripod 0-3 s, then gaussian", [*HARD, "--path-segment", "0-3:tripod"], None),
)
VIDSTAB = (
    ("vid.stab optzoom=1 (default)", "", ""),
    ("vid.stab optzoom=0", "", ":optzoom=0"),
    ("vid.stab optzoom=2 (adaptive)", "", ":optzoom=2"),
    ("vid.stab tripod", ":tripod=1", ":tripod=1"),
    ("vid.stab maxshift=8:maxangle=0.017", "", ":maxshift=8:maxangle=0.017"),
)
X264 = ["-fps_mode", "passthrough", "-c:v", "libx264", "-crf", "18", "-an"]


def trimmed(clip: Path, frames: int | None, folder: Path) -> Path:
    """The clip itself, or its first ``frames`` frames re-encoded near-losslessly (both tools then read the same)."""
    if frames is None:
        return clip
    out = folder / f"{clip.stem}-{frames}.mp4"
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-frames:v", str(frames), "-fps_mode",
                    "passthrough", "-c:v", "libx264", "-crf", "10", "-an", str(out)], check=True)
    return out


def run_ffviz(clip: Path, out: Path, options: list[str]) -> str:
    result = subprocess.run([sys.executable, "-m", "ffviz.cli", "stabilize", str(clip), "-o", str(out), "--mode",
                             "crop", "--no-deblur", "--overwrite", *options], capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(result.stderr.strip().splitlines()[-1])
    kept = [line for line in result.stdout.splitlines() if line.startswith("crop: kept")]
    return kept[0].split()[2] if kept else ""


def run_vidstab(clip: Path, out: Path, detect: str, transform: str, work: Path) -> None:
    transforms = work / f"{out.stem}.trf"
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf",
                    f"format=yuv420p,vidstabdetect=result={transforms}{detect}", "-f", "null", "-"], check=True)
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf",
                    f"format=yuv420p,vidstabtransform=input={transforms}{transform},format=yuv420p", *X264,
                    str(out)], check=True)


def main() -> None:
    parser = common.parser(__doc__)
    parser.add_argument("clips", nargs="*", type=Path, help="videos (default: three shared clips)")
    common.add_frames(parser, None)
    common.add_report(parser, REPORT, by_default=False)
    args = parser.parse_args()
    clips = args.clips or [SHARED / name for name in DEFAULT_CLIPS if (SHARED / name).exists()]
    header = ["| clip | method | jitter px | jitter deg | cropping | black | planned area | run s |",
              "|---|---|---|---|---|---|---|---|"]
    lines = list(header)
    for line in header:
        print(line, flush=True)
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        for clip in clips:
            source = trimmed(clip, args.frames, work)
            base = metrics.compare(source, source)
            rows = [(f"| {clip.name} | input | {base.residual_jitter_px:.2f} | {base.residual_jitter_deg:.3f} | 1.000 "
                     f"| {base.black_fraction:.3f} | | |")]
            print(rows[0], flush=True)
            runs = [("ffviz " + label, lambda out, o=options: run_ffviz(source, out, o)) for label, options, _ in FFVIZ]
            runs += [(label, lambda out, d=detect, t=transform: run_vidstab(source, out, d, t, work) or "")
                     for label, detect, transform in VIDSTAB]
            for index, (label, run) in enumerate(runs):
                out = work / f"{clip.stem}-{index}.mp4"
                started = time.perf_counter()
                try:
                    planned = run(out)
                except (RuntimeError, subprocess.CalledProcessError) as error:
                    rows.append(f"| {clip.name} | {label} | failed: {error} | | | | | |")
                    print(rows[-1], flush=True)
                    continue
                seconds = time.perf_counter() - started
                m = metrics.compare(source, out)
                rows.append(f"| {clip.name} | {label} | {m.residual_jitter_px:.2f} | {m.residual_jitter_deg:.3f} "
                            f"| {m.cropping_ratio:.3f} | {m.black_fraction:.3f} | {planned} | {seconds:.0f} |")
                print(rows[-1], flush=True)
            lines += rows
    report = common.report_path(args)
    if report is not None:
        note = f" (first {args.frames} frames of each clip)" if args.frames else ""
        body = ("# Path control beside vid.stab\n\nWritten by `benchmarks/quality/path_control.py`" + note + ". Crop "
                "mode (`--mode crop --no-deblur`); vid.stab two-pass with the options shown. Jitter: residual "
                "high-frequency motion of the frame centre (docs/metrics.md; lower is steadier; a zoom about the "
                "centre does not move it). Cropping: Liu et al.'s cropping ratio, the output's scale against the input "
                "measured from the videos (1: nothing cropped; 0.9: 10 % each way). Black: share of black pixels (none "
                "anywhere: vid.stab's default crop=keep fills the borders optzoom=0 uncovers with earlier frames' "
                "pixels). Planned area: the share of the frame area ffviz's crop windows kept, averaged over the "
                "frames. Run s: wall seconds on a shared 2-core machine (noisy; not a speed comparison).\n\n"
                + "\n".join(lines))
        print(f"wrote {common.write_section('path_control', body, report)}")


if __name__ == "__main__":
    main()
