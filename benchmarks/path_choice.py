"""eq. 18 (Gaussian) against the L1-optimal path on the shared clips: steadiness, kept area, border flicker.

For each clip and mode (full, crop) and path, `ffviz stabilize` writes the output and pipeline.evaluation.metrics compares it
with the input. Printed: residual jitter (px, deg; lower is steadier), cropping ratio (share of the frame kept;
1 in full mode), synthesized-pixel flicker (full mode), and the path planning time (s).

Usage: python benchmarks/path_choice.py [CLIP ...] [--modes full,crop] [--report FILE]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from pipeline.evaluation import metrics
from pipeline.stages import smoothing
from pipeline.stabilize import StabilizeConfig, estimate_motion, stabilize
from pipeline.runtime.source import FileSource
from pipeline.runtime.observer import NullObserver, null_progress

SHARED = Path(__file__).resolve().parents[2] / "shared" / "videos"
DEFAULT_CLIPS = ("linyihaolyh_shaky.mp4", "sudheerachary_small-shaky-5.avi", "selh_asb_1.mp4", "vplab_C.avi",
                 "zhangyilang_03_input.avi")


def planning_seconds(clip: Path, path: str) -> float:
    source = FileSource(clip)
    motion_pass = estimate_motion(source, StabilizeConfig().motion, observer=NullObserver(), progress=null_progress,
                                  total=None, workers=1)
    start = time.perf_counter()
    smoothing.smooth(motion_pass.curr_from_prev, smoothing.SmoothingConfig(path=path), cuts=motion_pass.cuts,
                     width=source.info.width, height=source.info.height)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clips", nargs="*", type=Path, help="videos (default: five shared clips)")
    parser.add_argument("--modes", default="full,crop", help="comma-separated output modes (default: full,crop)")
    parser.add_argument("--report", type=Path, help="also write the table as markdown here")
    args = parser.parse_args()
    clips = args.clips or [SHARED / name for name in DEFAULT_CLIPS if (SHARED / name).exists()]
    lines = ["| clip | mode | path | jitter px | jitter deg | kept | flicker | plan s |", "|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as folder:
        for clip in clips:
            for mode in args.modes.split(","):
                for path in smoothing.PATHS:
                    output = Path(folder) / f"{clip.stem}-{mode}-{path}.mp4"
                    config = StabilizeConfig(mode=mode, smoothing=smoothing.SmoothingConfig(path=path))
                    stabilize(clip, output, config)
                    m = metrics.compare(clip, output)
                    line = (f"| {clip.name} | {mode} | {path} | {m.residual_jitter_px:.2f} | {m.residual_jitter_deg:.3f} "
                            f"| {m.cropping_ratio:.3f} | {m.synth_flicker_ratio:.2f} | {planning_seconds(clip, path):.2f} |")
                    lines.append(line)
                    print(line, flush=True)
    if args.report:
        args.report.write_text("# Camera paths: eq. 18 against L1\n\nWritten by `benchmarks/path_choice.py`.\n\n"
                               + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
