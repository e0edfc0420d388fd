"""Camera paths side by side: eq. 18 (Gaussian) against the L1 program at several full-mode margins, crop mode
against ffmpeg vid.stab, and on ground truth; writes docs/benchmarks-paths.md.

Real clips (../shared/videos): one motion pass a clip, then each path is planned from it (plan CPU seconds, and
the share of output pixels no input pixel covers: the missing area full mode completes, from the plan's geometry)
and rendered by `ffviz stabilize` (full-frame rows as --mode none: the same warp without completion, whose
motion is full mode's; crop rows as --mode crop). pipeline.evaluation.metrics measures every output against its
input: residual jitter (px, deg; lower is steadier), cropping ratio (1: nothing cropped), black share. vid.stab
runs its two passes with its defaults (crop, optzoom=1), as `ffviz bench` does.
Ground truth (pipeline.evaluation.synthetic, full mode): the output centre's residual jitter in the world, the
missing share and the completion PSNR of the synthesized pixels. Then the L1 program's CPU seconds on a
1000-frame shaken camera (median of 3), full and crop.

Usage: nice -n 10 python -m benchmarks.quality.path_choice [--clips a.mp4,b.avi] [--frames N] [--skip-real]
       [--skip-truth] [--only TEXT] [--cache FILE] [--merge FILE ...] [--report [docs/benchmarks-paths.md]]
(docs/benchmarks-paths.md: --frames 150, the clips split over two runs at once and merged with --merge.)
"""

from __future__ import annotations

import dataclasses
import json
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks import common
from benchmarks.quality.path_control import trimmed
from pipeline.chain import plan_path
from pipeline.config import StabilizeConfig
from pipeline.evaluation import metrics
from pipeline.evaluation.completion import completion_scores
from pipeline.evaluation.synthetic import SyntheticConfig, generate
from pipeline.results import MotionPass
from pipeline.runtime.observer import NullObserver, null_progress
from pipeline.runtime.source import FileSource
from pipeline.stabilize import estimate_motion, stabilize
from pipeline.stages import l1_path, smoothing
from pipeline.stages.adaptive_crop import CropConfig

SHARED = common.VIDEOS
REPORT = common.DOCS / "benchmarks-paths.md"
DEFAULT_CLIPS = ("linyihaolyh_shaky.mp4", "sudheerachary_small-shaky-5.avi", "selh_asb_1.mp4", "vplab_C.avi",
                 "zhangyilang_03_input.avi", "selh_tasc.mp4")
MARGINS = (0.03, 0.04, 0.05)  # full mode on the real clips: the L1 translation margin, fraction of the longer side
TRUTH_MARGINS = (0.02, 0.03, 0.04, 0.05)  # and on ground truth
X264 = ["-fps_mode", "passthrough", "-c:v", "libx264", "-crf", "18", "-an"]


def l1(margin: float) -> smoothing.SmoothingConfig:
    return smoothing.SmoothingConfig(path="l1", l1=l1_path.L1PathConfig(margin_fraction=margin))


# (label, mode rendered, path, crop scale): the full-frame rows are rendered as --mode none (see the docstring).
VARIANTS = (("gaussian k=30", "none", smoothing.SmoothingConfig(), None),
            *((f"l1 margin {m:.0%}", "none", l1(m), None) for m in MARGINS),
            ("crop gaussian k=30", "crop", smoothing.SmoothingConfig(), None),
            ("crop auto (--crop-fill 0)", "crop", smoothing.SmoothingConfig(path="auto"), None),
            ("crop l1", "crop", l1(0.03), None),
            ("crop l1 --crop-scale 0.9", "crop", l1(0.03), 0.9),
            ("crop l1 --crop-scale 0.95", "crop", l1(0.03), 0.95))


def missing_share(orig_from_out: np.ndarray, width: int, height: int) -> float:
    """Mean share of output pixels outside the input frame (the input's outline mapped into the output)."""
    frame = np.array([[0, 0], [width, 0], [width, height], [0, height]], np.float32)
    shares = []
    for m in orig_from_out:
        quad = cv2.perspectiveTransform(frame[None], np.linalg.inv(m))[0].astype(np.float32)
        area, _ = cv2.intersectConvexConvex(frame, quad)
        shares.append(1.0 - area / (width * height))
    return float(np.mean(shares))


def plan_seconds(motion_pass: MotionPass, config: StabilizeConfig, width: int, height: int):
    start = time.process_time()
    plan = plan_path(motion_pass, config, width, height)
    return plan, time.process_time() - start


def vidstab(clip: Path, out: Path, work: Path) -> None:
    transforms = work / f"{clip.stem}.trf"
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf",
                    f"format=yuv420p,vidstabdetect=result={transforms}", "-f", "null", "-"], check=True)
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf",
                    f"format=yuv420p,vidstabtransform=input={transforms},format=yuv420p", *X264, str(out)],
                   check=True)


def measured(clip: Path, output: Path) -> dict:
    m = metrics.compare(clip, output)
    return dict(jitter_px=m.residual_jitter_px, jitter_deg=m.residual_jitter_deg, cropping=m.cropping_ratio,
                black=m.black_fraction)


def real_rows(clip: Path, frames: int | None, cache: dict, save, only: str = "") -> None:
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        source_path = trimmed(clip, frames, work)
        source = FileSource(source_path)
        width, height = source.info.width, source.info.height
        motion_pass = estimate_motion(source, StabilizeConfig().motion, observer=NullObserver(),
                                      progress=null_progress, total=None, workers=1)
        rows = cache.setdefault(clip.name, {})
        if "input" not in rows:
            own = metrics.video_motion_stats(source_path)
            rows["input"] = dict(jitter_px=own.residual_jitter_px, jitter_deg=own.residual_jitter_deg, cropping=1.0,
                                 black=0.0, frames=motion_pass.n_frames)
        if "vid.stab" not in rows and not only:
            out = work / "vidstab.mp4"
            vidstab(source_path, out, work)
            rows["vid.stab"] = measured(source_path, out)
            print(clip.name, "vid.stab", rows["vid.stab"], flush=True)
        for label, mode, path, scale in VARIANTS:
            if label in rows or only not in label:
                continue
            # crop rows: windows inside every frame (--crop-fill 0), what the L1 program is compared in
            config = StabilizeConfig(mode=mode, smoothing=path, crop=CropConfig(scale=scale, fill=0.0))
            plan, seconds = plan_seconds(motion_pass, config, width, height)
            out = work / f"{label.replace(' ', '_').replace('%', '')}.mp4"
            stabilize(source_path, out, dataclasses.replace(config, deblur=dataclasses.replace(
                config.deblur, enabled=False)), workers=1)
            row = measured(source_path, out)
            row.update(plan_cpu_s=seconds, missing=missing_share(plan.orig_from_out, width, height))
            rows[label] = row
            save()
            print(clip.name, label, row, flush=True)


def truth_rows(cache: dict, n_frames: int = 48, seeds: tuple[int, ...] = (0, 1), only: str = "") -> None:
    rows = cache.setdefault("ground truth", {})
    variants = [("gaussian k=30", smoothing.SmoothingConfig()), *((f"l1 margin {m:.0%}", l1(m)) for m in TRUTH_MARGINS)]
    for label, path in variants:
        if label in rows or only not in label:
            continue
        jitter, missing, error, pixels = [], [], 0.0, 0
        for seed in seeds:
            video = generate(SyntheticConfig(n_frames=n_frames, seed=seed, blurred_frames=()))
            config = StabilizeConfig(mode="full", smoothing=path)
            motion_pass = MotionPass(video.curr_from_prev, ["ok"] * n_frames,
                                     [t / video.config.fps for t in range(n_frames)], [])
            plan = plan_path(motion_pass, config, video.config.width, video.config.height)
            centre = np.array([(video.config.width - 1) / 2.0, (video.config.height - 1) / 2.0, 1.0])
            world = [np.linalg.inv(f) @ s for f, s in zip(video.frame_from_world, plan.smoothing.orig_from_stab)]
            trajectory = np.array([[*(m @ centre)[:2], np.arctan2(m[1, 0] - m[0, 1], m[0, 0] + m[1, 1])]
                                   for m in world])
            jitter.append(metrics.residual_jitter(trajectory, video.config.fps))
            missing.append(missing_share(plan.orig_from_out, video.config.width, video.config.height))
            scores = completion_scores(video, config)
            error += scores.squared_error["ours"]
            pixels += scores.pixels
        mse = error / max(pixels * 3, 1)
        rows[label] = dict(jitter_px=float(np.mean([j[0] for j in jitter])),
                           jitter_deg=float(np.mean([j[1] for j in jitter])), missing=float(np.mean(missing)),
                           psnr=float(10 * np.log10(255.0**2 / mse)) if mse > 0 else float("inf"))
        print("ground truth", label, rows[label], flush=True)


def solve_seconds(cache: dict) -> None:
    if "solve" in cache:
        return
    shaken_camera = common.from_tests("test_l1_path").shaken_camera  # the tests' ground-truth camera, 1000 frames
    _, _, curr_from_prev = shaken_camera(1000, seed=3, piece=333)
    out = {}
    for label, config in (("full", l1_path.L1PathConfig()), ("crop", l1_path.L1PathConfig(crop_scale=0.85))):
        times = []
        for _ in range(3):
            start = time.process_time()
            l1_path.orig_from_stab(curr_from_prev, config, 640, 360)
            times.append(time.process_time() - start)
        out[label] = statistics.median(times)
    cache["solve"] = out
    print("solve", out, flush=True)


ORDER = ("input", "vid.stab", *(label for label, *_ in VARIANTS))


def report(cache: dict, frames: int | None) -> str:
    lines = ["# Camera paths: eq. 18 against the L1 program, and beside vid.stab", "",
             "Written by `benchmarks/quality/path_choice.py` (its docstring says how each figure is measured). Jitter: "
             "residual high-frequency motion of the frame centre (px, deg; docs/metrics.md), lower is steadier; "
             "x vid.stab: jitter px against vid.stab's (two-pass defaults, crop) on the same clip. Missing: the "
             "mean share of output pixels no input pixel covers (what full mode completes). Plan CPU s: planning "
             "the whole clip's path (the run's path and, for display, the other planner's). Full-frame rows are "
             "rendered as --mode none (full mode's warp, without completion: their black is what full mode completes). "
             + (f"First {frames} frames of each clip." if frames else "Whole clips."), "",
             "| clip | method | jitter px | x vid.stab | jitter deg | cropping | black | missing | plan CPU s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for clip, rows in cache.items():
        if clip in ("ground truth", "solve"):
            continue
        reference = rows.get("vid.stab", {}).get("jitter_px")
        for label, row in sorted(rows.items(), key=lambda item: ORDER.index(item[0]) if item[0] in ORDER else 99):
            ratio = f"{row['jitter_px'] / reference:.2f}" if reference and label != "input" else ""
            lines.append(f"| {clip} | {label} | {row['jitter_px']:.2f} | {ratio} | {row['jitter_deg']:.3f} | "
                         f"{row['cropping']:.3f} | {row['black']:.3f} | "
                         f"{row['missing']:.3f} | {row['plan_cpu_s']:.2f} |".replace("| nan |", "| |")
                         if "missing" in row else
                         f"| {clip} | {label} | {row['jitter_px']:.2f} | {ratio} | {row['jitter_deg']:.3f} | "
                         f"{row['cropping']:.3f} | {row['black']:.3f} | | |")
    if "ground truth" in cache:
        lines += ["", "Ground truth (synthetic 640x360 clips, 48 frames, seeds 0 and 1, full mode with completion; "
                  "jitter of the output centre in the world):", "",
                  "| path | jitter px | jitter deg | missing | completion PSNR dB |", "|---|---|---|---|---|"]
        for label, row in sorted(cache["ground truth"].items(), key=lambda item: (item[0] != "gaussian k=30", item[0])):
            lines.append(f"| {label} | {row['jitter_px']:.3f} | {row['jitter_deg']:.4f} | {row['missing']:.4f} | "
                         f"{row['psnr']:.2f} |")
    if "solve" in cache:
        solve = cache["solve"]
        lines += ["", f"L1 program on a 1000-frame shaken camera (640x360), CPU s, median of 3: full mode "
                  f"{solve['full']:.2f}, crop mode {solve['crop']:.2f} (windows of 600 frames, 90 shared)."]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = common.parser(__doc__)
    parser.add_argument("--clips", default=",".join(DEFAULT_CLIPS))
    common.add_frames(parser, None)
    parser.add_argument("--skip-real", action="store_true")
    parser.add_argument("--skip-truth", action="store_true")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "path_choice.json",
                        help="rows measured so far (a rerun measures only what is missing)")
    parser.add_argument("--only", default="", help="measure only the rows whose label holds this text")
    parser.add_argument("--merge", type=Path, nargs="*", default=[], help="other runs' caches to add")
    common.add_report(parser, REPORT, by_default=False)
    args = parser.parse_args()
    cache = json.loads(args.cache.read_text()) if args.cache.exists() else {}
    for extra in args.merge:  # rows measured by other runs of this script (e.g. on other clips at the same time)
        for key, rows in json.loads(extra.read_text()).items():
            cache.setdefault(key, {}).update(rows)

    def save() -> None:
        args.cache.write_text(json.dumps(cache, indent=1))

    if not args.skip_truth:
        solve_seconds(cache)
        save()
    if not args.skip_real:
        for name in args.clips.split(","):
            clip = SHARED / name
            if clip.exists():
                real_rows(clip, args.frames, cache, save, args.only)
                save()
    if not args.skip_truth:
        truth_rows(cache, only=args.only)
        save()
    save()
    text = report(cache, args.frames)
    print(text)
    if common.report_path(args) is not None:
        print(f"wrote {common.write_section('path_choice', text, common.report_path(args))}")


if __name__ == "__main__":
    main()
