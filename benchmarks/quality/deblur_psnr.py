"""Deblurring (pipeline/stages/deblur.py) on synthetic ground truth: PSNR gain, ghosting, and the time it adds.

Cases: pipeline.evaluation.synthetic clips (640x360, 30 frames, hand-held jitter, a moving textured disc, frames t % 10 in
{2, 5, 8} blurred by a 12 px linear kernel) over several photographs and seeds. Frames 8..21 are judged (full
windows of 6 neighbours either side). Each frame is placed as the orchestrator places it, in its stabilized view
(here the intended, jitter-free one, from the exact transforms), with neighbours warped there by the exact
transforms; the truth is the world rendered through that view (sharp). PSNR over the pixels frame t covers.

Printed per configuration (blurred / sharp frames separately):
  gain     PSNR after - before over the frame (dB), mean and worst frame
  ghost    PSNR change where some neighbour shows the moving object and frame t does not (a ghost would land here)
  object   PSNR change on the object's interior in frame t (neighbours show it elsewhere: any transfer there ghosts)
  share    mean share of the output taken from neighbours (eq. 30) on the object's interior / on static background
  ms       median time of deblurring one frame: with the neighbours completion already warped (full mode), and
           warping its sharper neighbours itself (--mode none/crop); blurriness over the window included

Usage: python -m benchmarks.quality.deblur_psnr [--sweep] [--placement] [--images coffee,astronaut] [--seeds 0,1]
  --sweep      the alpha / rejection / min-ratio tables the defaults were chosen from
  --placement  deblurring after completion (what the orchestrator does) vs before it, on the completed frame
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, replace

import cv2
import numpy as np

from benchmarks import common
from pipeline.stages import completion, deblur, warping
from pipeline.evaluation import synthetic
from pipeline.stages.neighbours import WarpedNeighbour, warp_neighbours
from pipeline.evaluation.synthetic import psnr

WIDTH, HEIGHT, N_FRAMES = 640, 360, 30
JUDGED = range(8, 22)


@dataclass
class Case:
    """Frame t of a clip, ready for deblurring, with its truth and the masks the scores use."""

    video: synthetic.SyntheticVideo
    t: int
    frames: dict[int, np.ndarray]
    orig_from_stab: np.ndarray
    stabilized: warping.WarpResult
    neighbours: list[WarpedNeighbour]
    truth: np.ndarray
    judged: np.ndarray  # pixels frame t covers whose truth is inside the world canvas
    ghost_zone: np.ndarray  # a neighbour shows the object there, frame t does not (object grown by 12 px)
    object_inner: np.ndarray  # frame t's object footprint shrunk by 4 px

    @property
    def blurred(self) -> bool:
        return self.video.is_blurred(self.t)


def make_case(video: synthetic.SyntheticVideo, t: int, radius: int = 6) -> Case:
    frames = {i: video.frames[i] for i in range(max(t - radius, 0), min(t + radius + 1, video.n_frames))}
    stab_from_orig = video.intended_from_frame[t]
    orig_from_stab = np.linalg.inv(stab_from_orig)
    stabilized = warping.warp_frame(video.frames[t], orig_from_stab)
    others = {i: rgb for i, rgb in frames.items() if i != t}
    neighbours = warp_neighbours(others, t, video.curr_from_prev, orig_from_stab)
    truth = video.render_view(t, stab_from_orig)
    judged = ~stabilized.missing & video.view_coverage(t, stab_from_orig)

    def object_in_view(i: int) -> np.ndarray:
        i_from_t = video.frame_from_world[i] @ np.linalg.inv(video.frame_from_world[t])
        return warping.warp(video.object_mask[i].astype(np.uint8) * 255, i_from_t @ orig_from_stab) > 127

    own = object_in_view(t)
    elsewhere = np.zeros_like(own)
    for i in others:
        elsewhere |= object_in_view(i)
    grown = cv2.dilate(own.astype(np.uint8), np.ones((25, 25), np.uint8)) > 0
    inner = cv2.erode(own.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    return Case(video, t, frames, orig_from_stab, stabilized, neighbours, truth, judged,
                elsewhere & ~grown & judged, inner & judged)


def cases(images: list[str], seeds: list[int]) -> list[Case]:
    out = []
    for image in images:
        for seed in seeds:
            video = synthetic.generate(synthetic.SyntheticConfig(width=WIDTH, height=HEIGHT, n_frames=N_FRAMES,
                                                                 image=image, seed=seed))
            out += [make_case(video, t) for t in JUDGED]
    return out


@dataclass
class Score:
    blurred: bool
    gain: float
    ghost: float
    object: float
    object_share: float
    static_share: float
    ms_reused: float
    ms_warping: float


def streaming_cache(case: Case) -> deblur.EnergyCache:
    """The orchestrator's cache as it stands when frame t is deblurred: only the newest frame is new."""
    cache = deblur.EnergyCache()
    for i, rgb in case.frames.items():
        if i != max(case.frames):
            cache.get(i, rgb)
    return cache


def score(case: Case, config: deblur.DeblurConfig, *, timing: bool = True) -> Score:
    target, valid = case.stabilized.frame, ~case.stabilized.missing
    cache = streaming_cache(case)
    started = time.perf_counter()
    result = deblur.deblur_frame(target, valid, case.t, case.frames, case.video.curr_from_prev, case.orig_from_stab,
                                 config, warped=case.neighbours, cache=cache)
    ms_reused = 1000 * (time.perf_counter() - started)
    ms_warping = np.nan
    if timing:
        cache = streaming_cache(case)
        started = time.perf_counter()
        deblur.deblur_frame(target, valid, case.t, case.frames, case.video.curr_from_prev, case.orig_from_stab, config,
                            cache=cache)
        ms_warping = 1000 * (time.perf_counter() - started)

    def change(mask: np.ndarray) -> float:
        if not mask.any():
            return np.nan
        return psnr(result.frame, case.truth, mask) - psnr(target, case.truth, mask)

    static = case.judged & ~(cv2.dilate((case.ghost_zone | case.object_inner).astype(np.uint8),
                                        np.ones((41, 41), np.uint8)) > 0)
    share = lambda mask: float(result.weights[mask].mean()) if mask.any() else np.nan  # noqa: E731
    return Score(case.blurred, change(case.judged), change(case.ghost_zone), change(case.object_inner),
                 share(case.object_inner), share(static), ms_reused, ms_warping)


def summarize(name: str, scores: list[Score]) -> str:
    parts = [f"{name:28s}"]
    blurred = [s for s in scores if s.blurred]
    sharp = [s for s in scores if not s.blurred]
    for label, group in (("blurred", blurred), ("sharp", sharp)):
        if not group:
            continue
        values = lambda field: np.array([getattr(s, field) for s in group], float)  # noqa: E731
        gain = values("gain")
        parts.append(f"{label}: gain {np.mean(gain):+.2f} (worst {np.min(gain):+.2f}) "
                     f"ghost {np.nanmean(values('ghost')):+.2f} object {np.nanmean(values('object')):+.2f} "
                     f"share {np.nanmean(values('object_share')):.2f}/{np.nanmean(values('static_share')):.2f} "
                     f"ms {np.median(values('ms_reused')):.0f}"
                     + ("" if np.isnan(values("ms_warping")).all() else f"/{np.nanmedian(values('ms_warping')):.0f}"))
    return " | ".join(parts)


def sweep(all_cases: list[Case]) -> None:
    base = deblur.DeblurConfig()
    print("\nalpha (eq. 31), rejection at the defaults:")
    for alpha in (1.0, 2.0, 4.0, 8.0, 16.0, 64.0):
        print(summarize(f"alpha {alpha:g}", [score(c, replace(base, alpha=alpha), timing=False) for c in all_cases]))
    print("\nrejection: E threshold / grown by (px at 360 rows); 'eq. 31 only' = no rejection:")
    for reject_error, grow in ((1e9, 0), (16.0, 4), (24.0, 4), (32.0, 4), (32.0, 8), (48.0, 8), (64.0, 8)):
        name = "eq. 31 only" if reject_error >= 1e9 else f"E > {reject_error:g}, grow {grow}"
        config = replace(base, reject_error=reject_error, reject_grow_px=grow)
        print(summarize(name, [score(c, config, timing=False) for c in all_cases]))
    print("\nlow-pass of the error (sigma px at 360 rows; 0 = eq. 29 as written):")
    for sigma in (0.0, 2.0, 4.0, 8.0):
        config = replace(base, error_sigma_px=sigma)
        print(summarize(f"sigma {sigma:g}", [score(c, config, timing=False) for c in all_cases]))
    print("\nmin ratio b_t / b_t' (eq. 31: 1):")
    for min_ratio in (1.0, 1.05, 1.1, 1.25, 1.5):
        config = replace(base, min_ratio=min_ratio)
        print(summarize(f"min ratio {min_ratio:g}", [score(c, config) for c in all_cases]))


def placement(all_cases: list[Case]) -> None:
    """Full mode: deblur the completed frame (the orchestrator's order) or the stabilized one before completing."""
    config = deblur.DeblurConfig()
    print("\nplacement in full mode (blurred frames): PSNR over the frame / over the completed (missing) pixels")
    rows = []
    for case in (c for c in all_cases if c.blurred):
        stabilized, missing, neighbours = case.stabilized, case.stabilized.missing, case.neighbours
        judged = case.video.view_coverage(case.t, case.video.intended_from_frame[case.t])
        completed = completion.complete(stabilized.frame, missing, neighbours).frame
        after = deblur.deblur_frame(completed, None, case.t, case.frames, case.video.curr_from_prev,
                                    case.orig_from_stab, config, warped=neighbours).frame
        sharpened = deblur.deblur_frame(stabilized.frame, ~missing, case.t, case.frames, case.video.curr_from_prev,
                                        case.orig_from_stab, config, warped=neighbours).frame
        before = completion.complete(sharpened, missing, neighbours).frame
        hole = missing & judged
        rows.append([psnr(image, case.truth, mask) for image in (completed, after, before) for mask in (judged, hole)])
    none, none_hole, after, after_hole, before, before_hole = np.mean(rows, axis=0)
    print(f"  no deblurring        {none:.2f} / {none_hole:.2f}\n  after completion     {after:.2f} / {after_hole:.2f}"
          f"\n  before completion    {before:.2f} / {before_hole:.2f}   ({len(rows)} frames)")


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    parser.add_argument("--images", default="coffee,astronaut,chelsea")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--sweep", action="store_true")
    parser.add_argument("--placement", action="store_true")
    args = parser.parse_args(argv)
    images = args.images.split(",")
    seeds = [int(s) for s in args.seeds.split(",")]
    started = time.perf_counter()
    all_cases = cases(images, seeds)
    print(f"{len(all_cases)} frames ({sum(c.blurred for c in all_cases)} blurred) of {WIDTH}x{HEIGHT} clips over "
          f"{', '.join(images)} x seeds {', '.join(map(str, seeds))}; "
          f"cases built in {time.perf_counter() - started:.0f} s")
    print("PSNR before -> after deblurring (defaults), dB:")
    before_after = {True: [], False: []}
    for case in all_cases:
        result = deblur.deblur_frame(case.stabilized.frame, ~case.stabilized.missing, case.t, case.frames,
                                     case.video.curr_from_prev, case.orig_from_stab, warped=case.neighbours)
        before_after[case.blurred].append((psnr(case.stabilized.frame, case.truth, case.judged),
                                           psnr(result.frame, case.truth, case.judged)))
    for blurred, label in ((True, "blurred frames"), (False, "sharp frames  ")):
        pairs = np.array(before_after[blurred])
        gains = pairs[:, 1] - pairs[:, 0]
        print(f"  {label} {pairs[:, 0].mean():.2f} -> {pairs[:, 1].mean():.2f} (change {gains.mean():+.2f}, "
              f"worst {gains.min():+.2f}, best {gains.max():+.2f}; {len(pairs)} frames)")
    defaults = [score(c, deblur.DeblurConfig()) for c in all_cases]
    print(summarize("defaults", defaults))
    print(f"time added per frame, mean over all {len(defaults)} frames: "
          f"{np.mean([d.ms_reused for d in defaults]):.0f} ms with completion's warps reused (full mode), "
          f"{np.mean([d.ms_warping for d in defaults]):.0f} ms warping the sharper neighbours (none/crop)")
    if args.sweep:
        sweep(all_cases)
    if args.placement:
        placement(all_cases)
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
