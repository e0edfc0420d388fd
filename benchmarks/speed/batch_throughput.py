"""Batch throughput of `ffviz batch` on Ray: videos per minute at 1, 2, ... workers on this machine.

    .venv/bin/python -m benchmarks.speed.batch_throughput [--clips 4] [--frames 30] [--size 320x180] [--mode full]
                                                           [--workers 1,2] [--address ADDR]

Synthetic clips are generated once into a temp folder; each worker count gets a fresh local Ray
instance with that many CPUs (or, with --address, the cluster with --jobs capping concurrency) and a fresh
output folder. Ray's start-up is not counted; each figure is the wall time of run_batch.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from benchmarks import common
from ffviz import batch
from pipeline import stabilize as stab
from pipeline.evaluation import synthetic


def main() -> None:
    parser = common.parser(__doc__)
    parser.add_argument("--clips", type=int, default=4, help="synthetic clips made (default: %(default)s)")
    common.add_frames(parser, 30, "frames of each clip")
    parser.add_argument("--size", default="320x180")
    parser.add_argument("--mode", choices=stab.OUTPUT_MODES, default="full")
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    parser.add_argument("--address", default=None, help="a Ray cluster instead of a local instance")
    args = parser.parse_args()
    import ray

    width, height = map(int, args.size.split("x"))
    config = stab.StabilizeConfig(mode=args.mode)
    with tempfile.TemporaryDirectory(prefix="ffviz-batch-bench-") as tmp:
        folder = Path(tmp)
        inputs = []
        for seed in range(args.clips):
            clip = folder / "in" / f"clip{seed}.mp4"
            clip.parent.mkdir(exist_ok=True)
            synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(
                width=width, height=height, n_frames=args.frames, seed=seed)), clip)
            inputs.append(clip)
        print(f"{args.clips} clips of {args.frames} frames at {width}x{height}, --mode {args.mode}")
        print(f"{'workers':>7}  {'seconds':>8}  {'videos/min':>10}  {'frames/s':>8}")
        for workers in map(int, args.workers.split(",")):
            outdir = folder / f"out{workers}"
            outdir.mkdir()
            jobs = [batch.VideoJob(i, o, config) for i, o in zip(inputs, batch.output_paths(inputs, outdir))]
            batch.connect(args.address, workers)
            started = time.perf_counter()
            results = batch.run_batch(jobs, jobs=workers)
            seconds = time.perf_counter() - started
            ray.shutdown()
            failed = [r for r in results if r.status != "done"]
            if failed:
                raise SystemExit(f"{len(failed)} video(s) failed: {failed[0].message}")
            frames = sum(r.n_frames for r in results)
            print(f"{workers:>7}  {seconds:>8.1f}  {60 * len(results) / seconds:>10.2f}  {frames / seconds:>8.1f}")


if __name__ == "__main__":
    main()
