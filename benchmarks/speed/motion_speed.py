"""Benchmark: CPU of the motion pass (thesis 3.2) against the residual jitter of the output it leads to (issue 24).

For each variant of MotionConfig and each clip: CPU milliseconds a frame of motion.prepare + motion.estimate over
the clip's frames decoded once into memory (the median of --repeat runs; decoding is not counted), then the clip
stabilized in `--mode none` with that motion config and the output's residual jitter measured as `ffviz metrics`
does (metrics.video_motion_stats; written as MPEG-4 at qscale 2 so the encoder stays cheap and near-lossless).
A variant is kept only where the jitter on every clip stays within the noise: the spread of the default's jitter
between two encodings of the same frames (MPEG-4 q2 and q4), or 1 %, whichever is larger.

Usage: python -m benchmarks.speed.motion_speed [--clips a.avi,b.avi] [--variants default,corners300] [--repeat 3]
       [--report docs/benchmarks-speed.md | --no-report]
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

from benchmarks import common
from pipeline.evaluation import metrics
from pipeline.runtime.encoding import Encoding
from pipeline.runtime import video_reader
from pipeline.stabilize import StabilizeConfig, stabilize
from pipeline.stages import motion

VIDEOS = common.VIDEOS
CLIPS = ("vplab_C.avi", "sudheerachary_shaky-5.avi", "zhangyilang_03_input.avi")
VARIANTS: dict[str, dict] = {  # changes to MotionConfig's defaults
    "default": {},
    "before": dict(max_corners=600, hist_step=1),  # the defaults until issue 24
    "corners200": dict(max_corners=200),
    "side480": dict(max_side=480),  # estimation on frames downscaled to 480 px on their longest side
    "side320": dict(max_side=320),
    "one_lk_pass": dict(lk_passes=1),
}


def motion_cpu_ms(frames: list, config: motion.MotionConfig, repeat: int) -> float:
    """Median over ``repeat`` runs of the CPU ms a frame of prepare + estimate (this process, all its threads)."""
    runs = []
    for _ in range(repeat):
        started = time.process_time()
        previous = None
        for rgb in frames:
            prepared = motion.prepare(rgb, config)
            if previous is not None:
                motion.estimate(previous, prepared, config)
            previous = prepared
        runs.append((time.process_time() - started) * 1000 / len(frames))
    return statistics.median(runs)


def output_jitter(clip: Path, config: motion.MotionConfig, workdir: Path, qscale: int = 2) -> float:
    output = workdir / f"{clip.stem}.mp4"
    stabilize(clip, output, StabilizeConfig(mode="none", motion=config), overwrite=True,
              encoding=Encoding(codec="mpeg4", qscale=qscale))
    return metrics.video_motion_stats(output).residual_jitter_px


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    parser.add_argument("--clips", default=",".join(CLIPS), help="shared clips, comma-separated (default: %(default)s)")
    parser.add_argument("--variants", default=",".join(VARIANTS), help="of VARIANTS (default: %(default)s)")
    common.add_repeat(parser, 3)
    common.add_report(parser, common.SPEED_REPORT)
    args = parser.parse_args(argv)
    clips = [VIDEOS / name for name in args.clips.split(",")]
    clips = [clip for clip in clips if clip.is_file()]
    if not clips:
        print(f"no clips found in {VIDEOS}: nothing measured")
        return 0
    names = args.variants.split(",")
    started = common.machine_line()
    cpu: dict[tuple[str, str], float] = {}
    jitter: dict[tuple[str, str], float] = {}
    noise: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for clip in clips:
            frames = [frame.rgb for frame in video_reader.VideoReader(clip)]
            q2 = output_jitter(clip, motion.MotionConfig(), Path(tmp))
            q4 = output_jitter(clip, motion.MotionConfig(), Path(tmp), qscale=4)
            noise[clip.name] = max(abs(q2 - q4), 0.01 * q2)
            for name in names:
                config = motion.MotionConfig(**VARIANTS[name])
                cpu[name, clip.name] = motion_cpu_ms(frames, config, args.repeat)
                jitter[name, clip.name] = q2 if name == "default" else output_jitter(clip, config, Path(tmp))
                print(f"{clip.name:28s} {name:28s} {cpu[name, clip.name]:6.1f} ms/frame CPU  "
                      f"jitter {jitter[name, clip.name]:.3f} px (noise {noise[clip.name]:.3f})", flush=True)
            del frames
    lines = ["## Motion estimation: CPU a frame against output jitter", "",
             f"Written by `benchmarks/speed/motion_speed.py` ({started}; --repeat {args.repeat}). CPU ms a frame of "
             "motion.prepare + motion.estimate on frames decoded once (median of the repeats); jitter: residual "
             "jitter (px) of the `--mode none` output with that motion config (`ffviz metrics`); noise: the default's "
             "jitter between MPEG-4 q2 and q4 encodings of the same frames, or 1 %. A variant is within noise "
             "when |its jitter - the default's| <= the noise on every clip.", "",
             "| variant | " + " | ".join(f"{c.name} CPU ms | jitter px" for c in clips) + " | within noise |",
             "|---|" + "---|---|" * len(clips) + "---|"]
    for name in names:
        ok = all(abs(jitter[name, c.name] - jitter["default", c.name]) <= noise[c.name] for c in clips) \
            if "default" in names else None
        cells = " | ".join(f"{cpu[name, c.name]:.1f} | {jitter[name, c.name]:.3f}" for c in clips)
        lines.append(f"| {name} ({', '.join(f'{k}={v}' for k, v in VARIANTS[name].items()) or 'as shipped'}) "
                     f"| {cells} | {'-' if ok is None else 'yes' if ok else 'no'} |")
    lines += ["", "Noise (px): " + ", ".join(f"{c.name} {noise[c.name]:.3f}" for c in clips) + "."]
    common.publish("motion", lines, common.report_path(args), common.SPEED_HEADER)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
