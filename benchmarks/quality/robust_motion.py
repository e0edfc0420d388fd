"""Robust camera motion on the shared clips: jitter with and without --ignore and --rolling-shutter.

For each clip (first two synthetic ones with known truth: a rolling shutter of readout 0.9 and a global shutter,
under the same shake), `ffviz stabilize --mode crop` runs plain, with --rolling-shutter auto, and, where a moving person
can be boxed for the whole clip, with --ignore around them; pipeline.evaluation.metrics compares each output with
its input. Printed: residual jitter (px, deg; lower is steadier), cropping ratio (share of the frame kept), the
fitted readout time (auto), and the output's wobble: the mean squared residual (px^2, input pixels) of a
similarity fitted to the inlier tracks between consecutive output frames (rolling_shutter.readout_misfit at
readout 0: what no global-shutter camera motion explains; parallax and moving things add to it too).

Usage: nice -n 10 python -m benchmarks.quality.robust_motion [CLIP ...] [--report [docs/benchmarks-robust-motion.md]]
(CLIPs given: those only, no synthetic ones; --report: also write the table as its section of the report)
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from benchmarks import common
from pipeline.evaluation import metrics, synthetic
from pipeline.runtime.observer import NullObserver, null_progress
from pipeline.runtime.source import FileSource
from pipeline.stabilize import StabilizeConfig, estimate_motion, stabilize
from pipeline.stages import motion, rolling_shutter

SHARED = common.VIDEOS
REPORT = common.DOCS / "benchmarks-robust-motion.md"
DEFAULT_CLIPS = ("vplab_C.avi", "zhangyilang_03_input.avi", "selh_asb_1.mp4", "lohoi_test_eric_vid_original.mp4",
                 "selh_tasc.mp4")
# A box (x, y, w, h, full-resolution px) around the moving person for the whole clip, read off frames 0, 120, 240
# (vplab_C: the dancing woman the camera follows; lohoi: the man waving on the sofa).
PERSON_BOXES = {"vplab_C.avi": motion.IgnoreRegion(220, 100, 240, 260),
                "lohoi_test_eric_vid_original.mp4": motion.IgnoreRegion(380, 140, 440, 580)}


class _Plan(NullObserver):
    def __init__(self) -> None:
        self.plan = None

    def on_path(self, plan) -> None:
        self.plan = plan


def wobble(video: Path) -> float:
    """Mean squared similarity residual (px^2) of the inlier tracks between consecutive frames of ``video``."""
    source = FileSource(video)
    found = estimate_motion(source, motion.MotionConfig(), observer=NullObserver(), progress=null_progress,
                            total=None, keep_tracks=True)
    return rolling_shutter.readout_misfit(found.curr_from_prev, found.tracks, 0.0, source.info.height)


def synthetic_clips(folder: Path) -> list[Path]:
    """The two synthetic clips (90 frames, 640x360, the same shake): readout 0.9, and a global shutter."""
    paths = []
    for name, readout in (("synthetic_readout_0.9.mp4", 0.9), ("synthetic_global_shutter.mp4", 0.0)):
        path = folder / name
        synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(
            n_frames=90, moving_object=False, blurred_frames=(), readout=readout, seed=3)), path)
        paths.append(path)
    return paths


def main() -> None:
    parser = common.parser(__doc__)
    parser.add_argument("clips", nargs="*", type=Path, help="videos (default: two synthetic and the shared clips)")
    common.add_report(parser, REPORT, by_default=False)
    args = parser.parse_args()
    lines = ["| clip | option | jitter px | jitter deg | kept | readout | wobble px² |",
             "|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    with tempfile.TemporaryDirectory() as folder:
        clips = args.clips or (synthetic_clips(Path(folder))
                               + [SHARED / name for name in DEFAULT_CLIPS if (SHARED / name).exists()])
        for clip in clips:
            options = {"plain": StabilizeConfig(mode="crop"),
                       "--rolling-shutter auto": StabilizeConfig(mode="crop", rolling_shutter="auto")}
            if clip.name == "synthetic_readout_0.9.mp4":
                options["--rolling-shutter 0.9"] = StabilizeConfig(mode="crop", rolling_shutter=0.9)
            box = PERSON_BOXES.get(clip.name)
            if box is not None:
                options[f"--ignore {box.x},{box.y},{box.width},{box.height}"] = StabilizeConfig(
                    mode="crop", motion=motion.MotionConfig(ignore=(box,)))
            for name, config in options.items():
                output = Path(folder) / f"{clip.stem}-{len(lines)}.mp4"
                observer = _Plan()
                stabilize(clip, output, config, observer=observer)
                m = metrics.compare(clip, output)
                correction = observer.plan.rolling_shutter
                readout = f"{correction.readout:.2f}" if correction is not None else "-"
                # Output pixels are input pixels enlarged by 1 / scale: the wobble is given in input pixels.
                scale_sq = m.cropping_ratio if m.cropping_ratio and m.cropping_ratio > 0 else 1.0
                line = (f"| {clip.name} | {name} | {m.residual_jitter_px:.2f} | {m.residual_jitter_deg:.3f} "
                        f"| {m.cropping_ratio:.3f} | {readout} | {wobble(output) * scale_sq:.3f} |")
                lines.append(line)
                print(line, flush=True)
            lines.append(f"| {clip.name} | (input) | | | | | {wobble(clip):.3f} |")
            print(lines[-1], flush=True)
    report = common.report_path(args)
    if report is not None:
        body = ("# Robust camera motion: --ignore and --rolling-shutter on the shared clips\n\n"
                "Written by `benchmarks/quality/robust_motion.py` (--mode crop). Jitter: "
                "pipeline/evaluation/metrics.py (docs/metrics.md); kept: the crop's share of the frame; readout: the "
                "fitted readout time (fraction of the frame interval); wobble: mean squared residual of a similarity "
                "on the inlier tracks between consecutive frames, in input px² (what no global-shutter camera motion "
                "explains; parallax and moving objects add to it), the input's on its own row. The synthetic clips "
                "are rendered by pipeline/evaluation/synthetic.py under the same shake, row by row with readout 0.9 "
                "and all at once.\n\n" + "\n".join(lines))
        print(f"wrote {common.write_section('robust_motion', body, report)}")


if __name__ == "__main__":
    main()
