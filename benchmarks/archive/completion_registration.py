"""Benchmark: local registration of the neighbours and the static fill (pipeline/stages/completion.py), before/after.

"before": completion from the neighbours' global warps alone, the smooth fallback wherever the mosaic refused and no
local warp reached (``register_model=None``, no "neighbour as is" among the candidates); "after": the defaults (each
neighbour's warp refined by ECC on the band next to the missing area; the covering neighbour's best sample instead of
the fallback).

Columns:
  synth dB      PSNR over the synthesized pixels against ground truth (pipeline/evaluation/completion.py: synthetic
                worlds, and jittered 80 % crops of shared clips whose wide frame is the truth), before / after, and
                OpenCV's CPU chain (consistent mosaic of the global warps + Telea) on the same pixels
  flicker       ``synth_flicker_ratio`` of ``ffviz metrics`` (pipeline/evaluation/metrics.py) on the full-mode output
                (deblurring on, as a user runs it) of the first FRAMES frames of each shared clip, before / after
  CPU s         process CPU seconds of that full-mode run (threads included; the machine is shared, so indicative)

Usage: python -m benchmarks.archive.completion_registration [--frames 240] [--clips a.mp4,...] [--skip-psnr]
       [--report [docs/benchmarks-completion.md]]   (--report: also write the tables as its section of the report)
"""

from __future__ import annotations

import dataclasses
import datetime
import itertools
import platform
import subprocess
import tempfile
import time
from pathlib import Path

from benchmarks import common
from pipeline.config import StabilizeConfig
from pipeline.evaluation import metrics
from pipeline.evaluation.completion import completion_scores, crop_completion_scores, jittered_crop
from pipeline.evaluation.synthetic import SyntheticConfig, generate
from pipeline.runtime.source import FileSource, one_pass
from pipeline.stabilize import stabilize
from pipeline.stages.completion import CompletionConfig
from pipeline.stages.smoothing import SmoothingConfig

VIDEOS = common.VIDEOS
REPORT = common.DOCS / "benchmarks-completion.md"
FLICKER_CLIPS = ("selh_asb_1.mp4", "linyihaolyh_shaky.mp4", "selh_tasc.mp4", "vplab_C.avi", "selh_shaky_1.mp4",
                 "dfkimera_shaky.mp4")
CROP_CLIPS = ("linyihaolyh_shaky.mp4", "vplab_C.avi", "selh_tasc.mp4", "sudheerachary_small-shaky-5.avi")
SYNTHETIC = (("coffee", 1), ("coffee", 2), ("astronaut", 3), ("chelsea", 4), ("rocket", 5))
BEFORE = CompletionConfig(register_model=None,
                          candidates=tuple(name for name in CompletionConfig().candidates if name != "neighbour as is"))
AFTER = CompletionConfig()


def _with(config: StabilizeConfig, completion: CompletionConfig) -> StabilizeConfig:
    return dataclasses.replace(config, completion=completion)


def psnr_rows(n_frames: int, emit) -> None:
    synthetic = StabilizeConfig(mode="full", smoothing=SmoothingConfig(radius_frames=50))
    cases = [(f"synthetic {image} seed {seed}", lambda config, image=image, seed=seed: completion_scores(
        generate(SyntheticConfig(n_frames=n_frames, jitter_px=10.0, object_sweep=1.3, image=image, seed=seed,
                                 blurred_frames=())), config), synthetic) for image, seed in SYNTHETIC]
    for name in CROP_CLIPS:
        path = VIDEOS / name
        if not path.is_file():
            continue
        with one_pass(FileSource(path)) as frames:
            wide = [f.rgb for f in itertools.islice(frames, n_frames)]
        crop = jittered_crop(len(wide), (wide[0].shape[1], wide[0].shape[0]), crop_fraction=0.8, jitter_px=8.0, seed=1)
        cases.append((f"crop of {name}", lambda config, wide=wide, crop=crop: crop_completion_scores(
            wide, crop, config=config), StabilizeConfig(mode="full")))
    for name, score, config in cases:
        before, after = score(_with(config, BEFORE)), score(_with(config, AFTER))
        row = (f"| {name} | {before.psnr('ours'):.2f} / {after.psnr('ours'):.2f} ({after.psnr('ours') - before.psnr('ours'):+.2f}) "
               f"| {before.psnr('mosaic+telea'):.2f} | {after.psnr('ours') - before.psnr('mosaic+telea'):+.2f} |")
        emit(row)


def flicker_rows(clips: list[str], n_frames: int, emit) -> None:
    with tempfile.TemporaryDirectory() as folder:
        for name in clips:
            path = VIDEOS / name
            if not path.is_file():
                continue
            prefix = Path(folder) / f"{path.stem}.mp4"  # the first frames, losslessly (upright, as ffmpeg applies tags)
            subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(path), "-frames:v", str(n_frames), "-an",
                            "-c:v", "libx264", "-crf", "0", "-pix_fmt", "yuv444p", str(prefix)], check=True)
            cells = []
            for completion in (BEFORE, AFTER):
                output = Path(folder) / "out.mp4"
                started = time.process_time()
                stabilize(prefix, output, _with(StabilizeConfig(mode="full"), completion), overwrite=True)
                seconds = time.process_time() - started
                cells.append((metrics.compare(prefix, output).synth_flicker_ratio, seconds))
            row = (f"| {name} | {n_frames} | {cells[0][0]:.2f} / {cells[1][0]:.2f} "
                   f"| {cells[0][1]:.0f} / {cells[1][1]:.0f} |")
            emit(row)


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    common.add_frames(parser, 240, "frames of each shared clip for the flicker runs")
    parser.add_argument("--psnr-frames", type=int, default=32, help="frames of each ground-truth case")
    parser.add_argument("--clips", default=",".join(FLICKER_CLIPS))
    parser.add_argument("--skip-psnr", action="store_true")
    parser.add_argument("--skip-flicker", action="store_true")
    common.add_report(parser, REPORT, by_default=False)
    args = parser.parse_args(argv)
    report = common.report_path(args)
    lines = [f"# Completion: local registration and the static fill, before / after", "",
             f"Written by `benchmarks/archive/completion_registration.py` on "
             f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC ({platform.machine()}, Python "
             f"{platform.python_version()}). Columns: see the script's docstring.", ""]

    def emit(*rows: str) -> None:  # print, and rewrite the report so far (a long run keeps what it measured)
        print("\n".join(rows), flush=True)
        lines.extend(rows)
        if report is not None:
            common.write_section("completion_registration", "\n".join(lines), report)

    if not args.skip_flicker:
        emit("| clip | frames | flicker before / after | CPU s before / after |", "|---|---|---|---|")
        flicker_rows([c for c in args.clips.split(",") if c], args.frames, emit)
        emit("")
    if not args.skip_psnr:
        emit("| ground truth | synth dB before / after (gain) | mosaic+Telea dB | after vs mosaic+Telea |",
             "|---|---|---|---|")
        psnr_rows(args.psnr_frames, emit)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
