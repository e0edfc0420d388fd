"""Benchmark: PSNR of the synthesized pixels (ours vs OpenCV's CPU chain vs Telea) and full-mode speed.

Ground truth (pipeline/evaluation.py):
- synthetic worlds (skimage photographs) with hand-held jitter and a textured object crossing the borders;
- jittered 80 % crops of the real clips in ../shared/videos (skipped when absent): the wide frame is the truth.
Then frames per second of full mode at 640x360 (synthetic, in memory: no decode/encode) with the time per stage.

Usage: python benchmarks/completion_psnr.py [--frames 48] [--clips a.mp4,b.avi] [--skip-real] [--skip-speed]
"""

from __future__ import annotations

import argparse
import cProfile
import itertools
import pstats
import sys
import time
from pathlib import Path

from pipeline.evaluation import METHODS, CompletionScores, completion_scores, crop_completion_scores, jittered_crop
from pipeline.smoothing import SmoothingConfig
from pipeline.source import ArraySource, FileSource, one_pass
from pipeline.stabilize import StabilizeConfig, stabilize_source
from pipeline.synthetic import SyntheticConfig, generate

VIDEOS = Path(__file__).resolve().parents[2] / "shared" / "videos"
SYNTHETIC = (("coffee", 1), ("coffee", 2), ("astronaut", 3), ("chelsea", 4), ("rocket", 5))
REAL = ("linyihaolyh_shaky.mp4", "vplab_C.avi", "selh_tasc.mp4", "sudheerachary_small-shaky-5.avi")


def _row(name: str, scores: CompletionScores, seconds: float) -> str:
    ours = scores.psnr("ours")
    cells = " ".join(f"{scores.psnr(m):>12.2f}" for m in METHODS)
    return (f"{name:34} {cells} {ours - scores.psnr('mosaic+telea'):>+8.2f} {ours - scores.psnr('telea'):>+8.2f} "
            f"{scores.pixels / max(scores.frames, 1) / 1000:>8.1f} {seconds:>6.0f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--clips", default=",".join(REAL))
    parser.add_argument("--skip-real", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    args = parser.parse_args(argv)

    print(f"{'scene':34} " + " ".join(f"{m:>12}" for m in METHODS)
          + f" {'vs m+t':>8} {'vs telea':>8} {'kpx/frm':>8} {'s':>6}")
    full_synthetic = StabilizeConfig(mode="full", smoothing=SmoothingConfig(radius=50))
    for image, seed in SYNTHETIC:
        video = generate(SyntheticConfig(n_frames=args.frames, jitter_px=10.0, object_sweep=1.3, image=image, seed=seed,
                                         blurred_frames=()))
        started = time.perf_counter()
        scores = completion_scores(video, full_synthetic)
        print(_row(f"synthetic {image} seed {seed}", scores, time.perf_counter() - started), flush=True)
    if not args.skip_real:
        for name in filter(None, args.clips.split(",")):
            path = VIDEOS / name
            if not path.is_file():
                print(f"{name:34} (absent)")
                continue
            with one_pass(FileSource(path)) as frames:
                wide = [f.rgb for f in itertools.islice(frames, args.frames)]
            crop = jittered_crop(len(wide), (wide[0].shape[1], wide[0].shape[0]), crop_fraction=0.8, jitter_px=8.0,
                                 seed=1)
            started = time.perf_counter()
            scores = crop_completion_scores(wide, crop, config=StabilizeConfig(mode="full"))
            print(_row(f"crop of {name}", scores, time.perf_counter() - started), flush=True)
    if not args.skip_speed:
        _speed(args.frames)
    return 0


def _speed(n_frames: int) -> None:
    """Full mode at 640x360 in memory, then a profile of the same run: where the time goes."""
    video = generate(SyntheticConfig(n_frames=n_frames, blurred_frames=()))
    source = ArraySource(video.frames, fps=30.0, name="synthetic 640x360")
    for mode in ("none", "full"):
        stabilize_source(source, None, StabilizeConfig(mode=mode))  # warm-up: numba compile, caches
        started = time.perf_counter()
        report = stabilize_source(source, None, StabilizeConfig(mode=mode))
        seconds = time.perf_counter() - started
        print(f"\nmode {mode} at 640x360: {n_frames / seconds:.2f} frames/s ({seconds:.1f} s for {n_frames} frames; "
              f"motion {report.seconds_motion:.1f} s, render {report.seconds_render:.1f} s)")
    profile = cProfile.Profile()
    profile.runcall(stabilize_source, source, None, StabilizeConfig(mode="full"))
    print("\nwhere full mode spends its time (cumulative, top 25):")
    pstats.Stats(profile, stream=sys.stdout).sort_stats("cumulative").print_stats(r"pipeline|cv2|fmm", 25)


if __name__ == "__main__":
    sys.exit(main())
