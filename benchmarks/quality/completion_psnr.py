"""Benchmark: PSNR of the synthesized pixels (ours vs OpenCV's CPU chain vs Telea) and full-mode speed.

Ground truth (pipeline/evaluation/completion.py):
- synthetic worlds (skimage photographs) with hand-held jitter and a textured object crossing the borders;
- jittered 80 % crops of the real clips in ../shared/videos (skipped when absent): the wide frame is the truth.
Then frames per second of full mode at 640x360 (synthetic, in memory: no decode/encode) with the time per stage.

With --flicker CLIP: instead, the temporal change of the completed pixels of CLIP's full-mode run by what filled
them in the previous and the current frame (CompletionResult.source), against the real pixels' change. Frame t-1's
completed frame is carried onto frame t by the stabilizer's own transforms (S_{t-1}^-1 M_t^-1 S_t, no estimation
error); pixels within 2 px of either frame's missing-area outline count as neither, as in pipeline.evaluation.metrics.

With --split, each row is followed by the same PSNRs over the pixels our chain filled by each stage (mosaic, local
warp, fallback: which stage's pixels lose) and the frames where ours loses most against mosaic+telea (a few frames
usually hold the whole difference). --cases keeps the rows whose name holds one of the given words.

Usage: python -m benchmarks.quality.completion_psnr [--frames 48] [--clips a.mp4,b.avi] [--skip-real] [--skip-speed]
                                                   [--cases astronaut,chelsea] [--split]
       python -m benchmarks.quality.completion_psnr --flicker ../shared/videos/selh_asb_1.mp4
"""

from __future__ import annotations

import cProfile
import itertools
import pstats
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks import common
from pipeline import geometry
from pipeline.stages import completion
from pipeline.runtime.observer import NullObserver
from pipeline.stabilize import stabilize

from pipeline.evaluation.completion import METHODS, CompletionScores, completion_scores, crop_completion_scores, jittered_crop
from pipeline.stages.smoothing import SmoothingConfig
from pipeline.runtime.source import ArraySource, FileSource, one_pass
from pipeline.stabilize import StabilizeConfig, stabilize_source
from pipeline.evaluation.synthetic import SyntheticConfig, generate

VIDEOS = common.VIDEOS
SYNTHETIC = (("coffee", 1), ("coffee", 2), ("astronaut", 3), ("chelsea", 4), ("rocket", 5))
REAL = ("linyihaolyh_shaky.mp4", "vplab_C.avi", "selh_tasc.mp4", "sudheerachary_small-shaky-5.avi")


def _row(name: str, scores: CompletionScores, seconds: float, split: bool = False) -> str:
    ours = scores.psnr("ours")
    cells = " ".join(f"{scores.psnr(m):>12.2f}" for m in METHODS)
    line = (f"{name:34} {cells} {ours - scores.psnr('mosaic+telea'):>+8.2f} {ours - scores.psnr('telea'):>+8.2f} "
            f"{scores.pixels / max(scores.frames, 1) / 1000:>8.1f} {seconds:>6.0f}")
    if not split:
        return line
    lines = [line]
    total = {m: max(scores.squared_error[m], 1e-9) for m in METHODS}
    for source, part in scores.by_source.items():
        cells = " ".join(f"{part.psnr(m):>12.2f}" for m in METHODS)
        shares = (part.pixels / max(scores.pixels, 1), part.squared_error["ours"] / total["ours"],
                  part.squared_error["mosaic+telea"] / total["mosaic+telea"])
        lines.append(f"  {source:32} {cells} {part.psnr('ours') - part.psnr('mosaic+telea'):>+8.2f}   share "
                     f"{shares[0]:.3f} of pixels, {shares[1]:.3f} of our error, {shares[2]:.3f} of its")
    # Frames by how much more squared error ours has there than mosaic+telea: where the pooled difference sits.
    worst = sorted(scores.by_frame.items(),
                   key=lambda item: item[1].squared_error["mosaic+telea"] - item[1].squared_error["ours"])[:5]
    lines.append("  worst frames (t: ours / mosaic+telea dB, pixels): " + ", ".join(
        f"{t}: {part.psnr('ours'):.1f} / {part.psnr('mosaic+telea'):.1f}, {part.pixels}" for t, part in worst))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    common.add_frames(parser, 48, "frames of each case")
    parser.add_argument("--clips", default=",".join(REAL))
    parser.add_argument("--skip-real", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    parser.add_argument("--flicker", type=Path, help="only: change of completed pixels by source on this clip")
    parser.add_argument("--cases", default="", help="only the rows whose name holds one of these comma-separated words")
    parser.add_argument("--split", action="store_true", help="also PSNR by filling stage, and the worst frames")
    args = parser.parse_args(argv)
    wanted = [word for word in args.cases.split(",") if word]

    def keep(name: str) -> bool:
        return not wanted or any(word in name for word in wanted)

    if args.flicker is not None:
        _flicker_by_source(args.flicker)
        return 0

    print(f"{'scene':34} " + " ".join(f"{m:>12}" for m in METHODS)
          + f" {'vs m+t':>8} {'vs telea':>8} {'kpx/frm':>8} {'s':>6}")
    full_synthetic = StabilizeConfig(mode="full", smoothing=SmoothingConfig(radius_frames=50))
    for image, seed in SYNTHETIC:
        if not keep(f"synthetic {image} seed {seed}"):
            continue
        video = generate(SyntheticConfig(n_frames=args.frames, jitter_px=10.0, object_sweep=1.3, image=image, seed=seed,
                                         blurred_frames=()))
        started = time.perf_counter()
        scores = completion_scores(video, full_synthetic)
        print(_row(f"synthetic {image} seed {seed}", scores, time.perf_counter() - started, args.split), flush=True)
    if not args.skip_real:
        for name in filter(None, args.clips.split(",")):
            if not keep(f"crop of {name}"):
                continue
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
            print(_row(f"crop of {name}", scores, time.perf_counter() - started, args.split), flush=True)
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


class _Keep(NullObserver):
    """Keeps each frame's completed frame, missing mask and source map, the motion and the smoothed path."""

    def __init__(self) -> None:
        self.completed: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.curr_from_prev: list[np.ndarray] = []
        self.orig_from_stab: np.ndarray | None = None

    def on_motion(self, stamp, estimate) -> None:
        self.curr_from_prev.append(estimate.curr_from_prev)

    def on_path(self, plan) -> None:
        self.orig_from_stab = plan.smoothing.orig_from_stab

    def on_frame(self, result) -> None:
        done = result.completion
        if done is not None:
            self.completed[result.stamp.index] = (cv2.cvtColor(done.frame, cv2.COLOR_RGB2GRAY), done.missing,
                                                  done.source)


def _flicker_by_source(path: Path) -> None:
    """Mean |C_t - carried C_{t-1}| (grey levels) over completed pixels by source transition, and over real ones."""
    kept = _Keep()
    stabilize(path, None, StabilizeConfig(mode="full"), observer=kept)
    curr_from_prev, S = np.array(kept.curr_from_prev), kept.orig_from_stab
    kernel = np.ones((5, 5), np.uint8)

    def band(mask: np.ndarray) -> np.ndarray:  # within 2 px of the outline, either side
        return cv2.dilate(mask.view(np.uint8), kernel).view(bool) & cv2.dilate((~mask).view(np.uint8), kernel).view(bool)

    sums: dict[tuple[int, int], list[float]] = {}
    real = [0.0, 0]
    for t in range(1, len(S)):
        if t not in kept.completed or t - 1 not in kept.completed:
            continue
        grey, missing, source = kept.completed[t]
        prev_grey, prev_missing, prev_source = kept.completed[t - 1]
        t_from = geometry.neighbour_transforms(curr_from_prev, t, t - 1, t)
        prev_from_here = np.linalg.inv(S[t - 1]) @ np.linalg.inv(t_from[t - 1]) @ S[t]
        h, w = missing.shape

        def carry(image: np.ndarray, nearest: bool = False, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
            flags = (cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR) | cv2.WARP_INVERSE_MAP
            return cv2.warpPerspective(image, prev_from_here, (w, h), flags=flags, borderMode=border, borderValue=255)

        inside = carry(np.zeros((h, w), np.uint8), True, cv2.BORDER_CONSTANT) == 0
        change = np.abs(grey.astype(np.float32) - carry(prev_grey).astype(np.float32))
        was_missing = carry(prev_missing.view(np.uint8), True, cv2.BORDER_CONSTANT) == 1
        was = carry(prev_source, True, cv2.BORDER_CONSTANT)
        counted = inside & ~band(missing) & ~band(was_missing)
        real[0] += float(change[counted & ~missing & ~was_missing].sum())
        real[1] += int(np.count_nonzero(counted & ~missing & ~was_missing))
        synthesized = counted & (missing | was_missing)
        for key in set(zip(was[synthesized].tolist(), source[synthesized].tolist())):
            mask = synthesized & (was == key[0]) & (source == key[1])
            entry = sums.setdefault(key, [0.0, 0])
            entry[0] += float(change[mask].sum())
            entry[1] += int(np.count_nonzero(mask))
    total = sum(n for _, n in sums.values())
    synth = sum(v for v, _ in sums.values()) / max(total, 1)
    real_mean = real[0] / max(real[1], 1)
    print(f"{path.name}: completed pixels change {synth:.2f}, real {real_mean:.2f} (x{synth / real_mean:.2f})")
    print(f"{'t-1 -> t':28} {'share':>6} {'change':>7} {'of total':>9}")
    for (a, b), (v, n) in sorted(sums.items(), key=lambda kv: -kv[1][0]):
        names = completion.SOURCE_NAMES
        print(f"{names[a] + ' -> ' + names[b]:28} {n / total:>6.3f} {v / n:>7.2f} {v / max(total, 1) / synth:>9.2f}")


if __name__ == "__main__":
    sys.exit(main())
