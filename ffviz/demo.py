"""`ffviz demo`: a synthetic shaky video with known camera path, stabilized, checked against the truth."""

from __future__ import annotations

import argparse
import time

import numpy as np

from ffviz.runner import recording_path, run_stabilize, written_line
from pipeline import geometry
from pipeline.evaluation import metrics, synthetic
from pipeline.runtime.observer import StageCollector


def run_demo(args: argparse.Namespace) -> int:
    out_dir = args.output_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    config = synthetic.SyntheticConfig(n_frames=args.num_frames, seed=args.seed)
    step(f"1/3 generating {config.n_frames} frames of {config.width}x{config.height} over skimage's "
         f"'{config.image}' photograph (seed {config.seed})")
    started = time.perf_counter()
    video = synthetic.generate(config)
    input_path = out_dir / "demo_input.mp4"
    output_path = out_dir / f"demo_stabilized_{args.mode}.mp4"
    synthetic.write_video(video, input_path)
    step(f"    done in {time.perf_counter() - started:.1f} s")

    step(f"2/3 stabilizing (--mode {args.mode})")
    collector = StageCollector("motion")
    run_stabilize(input_path, output_path, args, overwrite=True, observers=[collector], final_line=False)

    step("3/3 checking against the known camera motion")
    errors = [geometry.corner_error(estimate.curr_from_prev, video.curr_from_prev[stamp.index], config.width, config.height)
              for stamp, estimate in collector.results["motion"] if stamp.index > 0]
    print(f"global motion vs ground truth: median corner error {np.median(errors):.3f} px, "
          f"95th percentile {np.percentile(errors, 95):.3f} px over {len(errors)} frame pairs")
    before = metrics.video_motion_stats(input_path)
    after = metrics.video_motion_stats(output_path)
    print(f"residual jitter: input {before.residual_jitter_px:.2f} px -> output {after.residual_jitter_px:.2f} px; "
          f"stability (translation): {before.stability_translation:.3f} -> {after.stability_translation:.3f}")
    print(written_line([(input_path, "shaky input"), (output_path, "stabilized")], recording_path(args, input_path)),
          flush=True)
    return 0


def step(message: str) -> None:
    """What the demo is doing now (stdout, in order with the results)."""
    print(message, flush=True)
