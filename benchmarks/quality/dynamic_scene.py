"""Moving people on ground truth: does deblurring or completion make them see-through? (issue: dynamic scenes)

Cases: pipeline.evaluation.synthetic clips at 640x360, 30 frames, frames t % 10 in {2, 5, 8} blurred by a 12 px kernel:
"person" clips (a figure a fifth of the frame wide and over half its height, dressed in a crop of the world
photograph, walking 10-25 px a frame; sweep > 1 walks it into the borders completion synthesizes) and the
existing "disc" clips (the textured disc; static background) for reference. Each case runs the real orchestrator
in full mode with deblurring (pipeline.evaluation.completion.dynamic_scores); "no deblur" is what deblurring was handed,
exactly the --no-deblur output. Optionally the same with the colour-only rule (the structure guard off).

Columns:
  obj        PSNR over the object's pixels on blurred frames: deblurred / not deblurred (dB)
  show       show-through: correlation of the high-passed output with the hidden background inside the object,
             deblurred / not deblurred (0: none)
  blur gain  PSNR over blurred frames, deblurred minus not deblurred (dB)
  synth      PSNR over synthesized pixels: ours / mosaic + Telea (OpenCV's CPU chain), and the margin
  synth show show-through inside the object over synthesized pixels
  flicker    (--flicker) pipeline.evaluation.metrics' synthesized-pixel flicker ratio of the output video, when available

--seeds N: instead, the synth margin of each person case over seeds 0..N-1 (its spread: median, min, max), as the
test holds it (a single seed's margin moves by a dB with sub-pixel differences in the blurred pairs' motion).

Usage: python -m benchmarks.quality.dynamic_scene [--colour-only] [--flicker] [--seeds N]
       [--report [docs/benchmarks-dynamic.md]]  (--report: also write the table as its section of the report)
"""

from __future__ import annotations

import datetime
import platform
import statistics
import tempfile
import time
from pathlib import Path

from benchmarks import common
from pipeline.stages import deblur
from pipeline.evaluation.completion import dynamic_scores
from pipeline.stabilize import StabilizeConfig, stabilize
from pipeline.evaluation.synthetic import SyntheticConfig, generate, write_video

REPORT = common.DOCS / "benchmarks-dynamic.md"
CASES = (  # name, image, seed, object kind, sweep
    ("person chelsea", "chelsea", 3, "person", 0.6),
    ("person astronaut border", "astronaut", 2, "person", 1.0),
    ("person coffee", "coffee", 1, "person", 0.6),
    ("person chelsea border", "chelsea", 4, "person", 1.2),
    ("person rocket", "rocket", 6, "person", 0.8),
    ("disc coffee (static bg)", "coffee", 0, "disc", 1.3),
    ("disc astronaut (static bg)", "astronaut", 1, "disc", 1.3),
)


def flicker(video, config: StabilizeConfig) -> float:
    from pipeline.evaluation import metrics

    with tempfile.TemporaryDirectory() as folder:
        source, output = Path(folder) / "in.mp4", Path(folder) / "out.mp4"
        write_video(video, source, crf=0)
        stabilize(source, output, config)
        result = metrics.compare(source, output)
    return float(getattr(result, "synth_flicker_ratio", float("nan")) or float("nan"))


def main() -> None:
    parser = common.parser(__doc__)
    parser.add_argument("--colour-only", action="store_true", help="also run with the structure guard off")
    parser.add_argument("--flicker", action="store_true", help="also write each output and measure its flicker")
    parser.add_argument("--seeds", type=int, default=0, help="the person cases' synth margin over seeds 0..N-1")
    common.add_report(parser, REPORT, by_default=False)
    args = parser.parse_args()
    if args.seeds:
        margin_spread(args.seeds, common.report_path(args))
        return
    configs = [("structure guard (default)", StabilizeConfig())]
    if args.colour_only:
        configs.append(("colour test only", StabilizeConfig(deblur=deblur.DeblurConfig(structure_min=None))))
    header = ("| case | deblurring | obj dB (deblurred / none) | show-through (deblurred / none) | blur gain dB | "
              "synth dB (ours / mosaic+Telea, margin) | synth show | flicker | s |")
    lines = [header, "|---" * (header.count("|") - 1) + "|"]
    for name, image, seed, kind, sweep in CASES:
        video = generate(SyntheticConfig(n_frames=30, object_kind=kind, image=image, seed=seed, object_sweep=sweep))
        for label, config in configs:
            start = time.perf_counter()
            s = dynamic_scores(video, config)
            seconds = time.perf_counter() - start
            flick = flicker(video, config) if args.flicker else float("nan")
            margin = s.synthesized_psnr - s.mosaic_telea_psnr
            line = (f"| {name} | {label} | {s.object_psnr['deblurred']:.2f} / {s.object_psnr['not deblurred']:.2f} | "
                    f"{s.show_through['deblurred']:+.4f} / {s.show_through['not deblurred']:+.4f} | "
                    f"{s.blurred_psnr['deblurred'] - s.blurred_psnr['not deblurred']:+.2f} | "
                    f"{s.synthesized_psnr:.2f} / {s.mosaic_telea_psnr:.2f}, {margin:+.2f} | "
                    f"{s.synthesized_show_through:+.3f} | {flick:.2f} | {seconds:.1f} |")
            lines.append(line)
            print(line, flush=True)
    report = common.report_path(args)
    if report is not None:
        stamp = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
        machine = f"{platform.processor() or platform.machine()}, Python {platform.python_version()}"
        body = (f"# Dynamic scenes: moving objects on ground truth\n\nWritten by `benchmarks/quality/dynamic_scene.py` "
                f"on {stamp} ({machine}). Columns: see the script's docstring. NaN: no object pixels in that set.\n\n"
                + "\n".join(lines))
        print(f"wrote {common.write_section('dynamic_scene', body, report)}")


def margin_spread(n_seeds: int, report: Path | None) -> None:
    """Each person case's synth margin over mosaic + Telea on seeds 0..n_seeds-1, and its spread."""
    header = "| case | sweep | margin dB by seed | median | min | max |"
    lines = [header, "|---" * (header.count("|") - 1) + "|"]
    for name, image, _, kind, sweep in CASES:
        if kind != "person":
            continue
        margins = []
        for seed in range(n_seeds):
            video = generate(SyntheticConfig(n_frames=30, object_kind=kind, image=image, seed=seed, object_sweep=sweep))
            s = dynamic_scores(video)
            margins.append(s.synthesized_psnr - s.mosaic_telea_psnr)
            print(f"{name} seed {seed}: {margins[-1]:+.2f}", flush=True)
        line = (f"| {name} | {sweep} | {' '.join(f'{m:+.2f}' for m in margins)} | "
                f"{statistics.median(margins):+.2f} | {min(margins):+.2f} | {max(margins):+.2f} |")
        lines.append(line)
        print(line, flush=True)
    if report is not None:
        stamp = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
        body = (f"## Completion's margin over mosaic + Telea, by seed\n\nWritten by `benchmarks/quality/dynamic_scene.py "
                f"--seeds {n_seeds}` on {stamp}: ours minus OpenCV's CPU chain over the synthesized pixels (dB), "
                f"default settings, seeds 0-{n_seeds - 1} of each person case.\n\n" + "\n".join(lines))
        print(f"wrote {common.write_section('dynamic_scene_seeds', body, report)}")


if __name__ == "__main__":
    main()
