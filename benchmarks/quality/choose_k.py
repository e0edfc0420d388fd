"""Choose the default smoothing radius k from the real clips (docs/how-it-works.md, "Choosing k").

For each clip: one motion pass, then for each k the residual jitter the output would have, measured
exactly as pipeline.evaluation.metrics measures a video (its trajectory() and residual_jitter() applied to the
output's inter-frame motion stab_t <- stab_(t-1) = S_t^-1 T_t S_(t-1)), and the crop it costs (area kept
by the largest window valid in every frame).
Usage: python -m benchmarks.quality.choose_k [--radii 0,6,15] [CLIPS...]   (default: every clip in ../shared/videos)
With --radii 0 it measures a video's own residual jitter, e.g. a peer's output, on the same scale.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from benchmarks import common
from pipeline.evaluation import metrics
from pipeline.stages import motion, smoothing, warping
from pipeline import stabilize
from pipeline.runtime import video_reader
from pipeline.runtime.observer import NullObserver, null_progress
from pipeline.runtime.source import FileSource

RADII = (0, 6, 15, 30, 45, 60, 90)
VIDEOS = common.VIDEOS


def output_jitter(curr_from_prev: np.ndarray, orig_from_stab: np.ndarray, width: int, height: int, fps: float) -> float:
    """Residual jitter (px) of the stabilized video, predicted from the transforms, measured like metrics does."""
    stab_from_orig = np.linalg.inv(orig_from_stab)
    steps = [stab_from_orig[t] @ curr_from_prev[t] @ orig_from_stab[t - 1] for t in range(1, len(curr_from_prev))]
    return metrics.residual_jitter(metrics.trajectory(steps, width, height), fps)[0]


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    parser.add_argument("clips", nargs="*", type=Path, help="videos (default: every clip in ../shared/videos)")
    parser.add_argument("--radii", default=",".join(map(str, RADII)), help="values of k, comma-separated "
                        "(default: %(default)s)")
    args = parser.parse_args(argv)
    radii = tuple(int(k) for k in args.radii.split(","))
    clips = args.clips or sorted(p for p in VIDEOS.iterdir() if p.suffix in (".mp4", ".avi"))
    print(f"{'clip':34s} " + " ".join(f"k={k:<2d} jit/crop" for k in radii))
    table = []
    for clip in clips:
        info = video_reader.probe_video(clip)
        passed = stabilize.estimate_motion(FileSource(clip), motion.MotionConfig(), observer=NullObserver(),
                                           progress=null_progress, total=None)
        row = []
        for k in radii:
            result = smoothing.smooth(passed.curr_from_prev, smoothing.SmoothingConfig(radius_frames=k), cuts=passed.cuts,
                                      width=info.width, height=info.height)
            jitter = output_jitter(passed.curr_from_prev, result.orig_from_stab, info.width, info.height, float(info.fps))
            window = warping.largest_crop(result.orig_from_stab, info.width, info.height)
            row.append((jitter, window.cropping_ratio if window else 0.0))
        table.append(row)
        print(f"{clip.name:34s} " + " ".join(f"{j:5.2f}/{c:4.2f}  " for j, c in row), flush=True)
    jit = np.array([[j for j, _ in row] for row in table])
    crop = np.array([[c for _, c in row] for row in table])
    print(f"{'median':34s} " + " ".join(f"{j:5.2f}/{c:4.2f}  " for j, c in zip(np.median(jit, 0), np.median(crop, 0))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
