"""The `ffviz` command: a thin layer over pipeline/ and the recorder.

Expected failures (pipeline.errors.FFVizError) print one line and exit non-zero; Ctrl-C and SIGTERM
leave no partial output (writers abort on any exception) and exit 130/143.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import traceback
from pathlib import Path
from typing import Sequence

from pipeline import deblur, motion, smoothing, stabilize as stab, video_io
from pipeline.errors import ConfigError, FFVizError
from pipeline.observer import Observer, Observers

DEFAULT_RECORDINGS = Path("recordings")


class Terminated(BaseException):
    """Raised in the main thread on SIGTERM so the same cleanup as Ctrl-C runs.

    A BaseException, like KeyboardInterrupt, so that no `except Exception` on the way swallows it."""


def _on_sigterm(signum, frame) -> None:
    raise Terminated()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ffviz", description=__doc__.splitlines()[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = commands.add_parser("stabilize", help="stabilize a video")
    p.add_argument("input", type=Path)
    p.add_argument("-o", "--output", type=Path, required=True, help="output video (.mp4, .mov or .mkv)")
    _add_stabilize_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace OUTPUT if it exists")

    p = commands.add_parser("demo", help="generate a synthetic shaky video with ground truth and stabilize it")
    p.add_argument("-o", "--output-dir", type=Path, default=Path("ffviz-demo"), help="where to write (default: %(default)s)")
    p.add_argument("--frames", type=int, default=120, help="number of frames to generate (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0)
    _add_stabilize_options(p, default_rrd=DEFAULT_RECORDINGS / "demo.rrd")

    p = commands.add_parser("metrics", help="stabilization metrics of OUTPUT against INPUT (Liu et al. 2013)")
    p.add_argument("input", type=Path)
    p.add_argument("output", type=Path)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")

    p = commands.add_parser("view", help="open a recording in the Rerun viewer (web viewer on 127.0.0.1)")
    p.add_argument("recording", type=Path)
    p.add_argument("--native", action="store_true", help="use the desktop viewer instead of the web viewer")
    p.add_argument("--web-port", type=int, default=9090)
    p.add_argument("--grpc-port", type=int, default=9876)

    p = commands.add_parser("figures", help="render the thesis-style figures from a recording (PNG, PDF or SVG)")
    p.add_argument("recording", type=Path)
    p.add_argument("-o", "--output-dir", type=Path, required=True, help="directory to write the figures to")
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png", help="(default: %(default)s)")
    p.add_argument("--frames", type=_frame_list, default=None, metavar="T1,T2,...",
                   help="frames to show in the frame comparisons (default: the traced frames, else a few spread out)")

    from ffviz.batch import add_parser as add_batch_parser  # imports no Ray: that happens when a batch runs

    add_batch_parser(commands, _add_stabilize_options)
    from ffviz.bench import add_parser as add_bench_parser  # imports no pipeline stage: the runs are children

    add_bench_parser(commands)
    return parser


def _frame_list(text: str) -> tuple[int, ...] | None:
    from ffviz.trace import parse_frame_list

    try:
        return parse_frame_list(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _add_stabilize_options(p: argparse.ArgumentParser, default_rrd: Path | None = None) -> None:
    p.add_argument("--mode", choices=stab.OUTPUT_MODES, default="full",
                   help="full: missing areas completed from neighbouring frames (full frame, no crop); "
                        "crop: largest window valid in every frame, scaled back to full size; "
                        "none: missing areas left black (default: %(default)s)")
    p.add_argument("--smoothing-radius", "-k", type=int, default=smoothing.DEFAULT_RADIUS, metavar="K",
                   help="neighbours on each side in the Gaussian of eq. 18 (default: %(default)s)")
    p.add_argument("--smoothing-sigma", type=float, default=None, metavar="SIGMA",
                   help="Gaussian sigma in frames (default: sqrt(K))")
    p.add_argument("--motion-model", choices=motion.MOTION_MODELS, default="affine")
    p.add_argument("--refine", choices=motion.REFINEMENTS, default="none",
                   help="ecc: hierarchical coarse-to-fine direct refinement of each estimate (slower)")
    p.add_argument("--no-deblur", dest="deblur", action="store_false",
                   help="leave motion-blurred frames as they are (default: sharpen them with the pixels of sharper "
                        "neighbouring frames, thesis ch. 5)")
    p.add_argument("--deblur-alpha", type=float, default=deblur.DEBLUR_ALPHA, metavar="ALPHA",
                   help="eq. 31 sensitivity to the alignment error, in intensity levels 0-255: larger lets "
                        "less well aligned neighbours contribute more (default: %(default)s)")
    p.add_argument("--rrd", type=Path, nargs="?", const=Path("AUTO"), default=default_rrd, metavar="PATH",
                   help="write a Rerun recording (default place: recordings/<input name>.rrd)")
    p.add_argument("--record", choices=("summary", "full"), default="full",
                   help="recording detail: summary (series, output frames) or full (every intermediate)")
    p.add_argument("--lossless", action="store_true", help="record images losslessly instead of JPEG")
    p.add_argument("--trace-frames", type=_frame_list, default=None, metavar="T1,T2,...",
                   help="frames to step through every stage in the recording (timelines 'stage' and 'fmm_step'); "
                        "'none' for none (default: 3 frames with missing area at --record full, none at summary)")
    p.add_argument("--codec", choices=video_io.VIDEO_CODECS, default="h264",
                   help="output video: h264 (x264; --crf, --preset) or mpeg4 (MPEG-4 Part 2, what OpenCV's XVID "
                        "writer uses; --qscale): a tenth of x264's CPU for about twice the bits (default: %(default)s)")
    p.add_argument("--crf", type=int, default=None,
                   help="h264 quality, 0-51 (lower is better; default: %d)" % video_io.Encoding.crf)
    p.add_argument("--preset", choices=video_io.X264_PRESETS, default=None,
                   help="h264 speed against file size at the same --crf quality: faster presets encode sooner into "
                        "larger files (default: %s)" % video_io.Encoding.preset)
    p.add_argument("--qscale", type=int, default=None,
                   help="mpeg4 quantiser, 2-31 (lower is better; default: %d)" % video_io.Encoding.qscale)
    p.add_argument("--workers", "-j", type=int, default=None, metavar="N",
                   help="frames processed at once, on threads (default: one per CPU core); the frames written are the same")


MAX_RADIUS = 100_000  # frames; the smoothing kernel is allocated at 2k+1 taps
MIN_SIGMA, MAX_SIGMA = 1e-6, 1e6  # frames


def _check_options(args: argparse.Namespace) -> None:
    """What the configs cannot check: values argparse parses but the run or the kernel cannot use (the
    encoder's values are video_io.Encoding's to check)."""
    if getattr(args, "workers", None) is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, not {args.workers}")
    if args.smoothing_radius > MAX_RADIUS:
        raise ConfigError(f"-k must be at most {MAX_RADIUS}, not {args.smoothing_radius}")
    # Outside these the kernel's sigma**2 underflows (0/0) or overflows; the ends already mean none/uniform.
    if args.smoothing_sigma is not None and not MIN_SIGMA <= args.smoothing_sigma <= MAX_SIGMA:  # False for nan
        raise ConfigError(f"--smoothing-sigma must be between {MIN_SIGMA:g} and {MAX_SIGMA:g} frames, "
                          f"not {args.smoothing_sigma}")


def _stabilize_config(args: argparse.Namespace) -> stab.StabilizeConfig:
    _check_options(args)
    try:
        return stab.StabilizeConfig(
            mode=args.mode,
            motion=motion.MotionConfig(model=args.motion_model, refine=args.refine),
            smoothing=smoothing.SmoothingConfig(radius=args.smoothing_radius, sigma=args.smoothing_sigma),
            deblur=deblur.DeblurConfig(enabled=args.deblur, alpha=args.deblur_alpha),
        )
    except ValueError as error:  # the configs validate their own values
        raise ConfigError(str(error)) from None


def output_encoding(args: argparse.Namespace) -> video_io.Encoding:
    """--codec and the quality options that belong to it (one that belongs to another codec is an error)."""
    own = video_io.CODEC_OPTIONS[args.codec]
    every = [name for names in video_io.CODEC_OPTIONS.values() for name in names]
    given = {name: getattr(args, name) for name in every if getattr(args, name) is not None}
    stray = [f"--{name}" for name in given if name not in own]
    if stray:
        raise ConfigError(f"{' and '.join(stray)} {'does' if len(stray) == 1 else 'do'} not apply to --codec "
                          f"{args.codec} (its options: {', '.join('--' + n for n in own)})")
    try:
        return video_io.Encoding(codec=args.codec, **given)
    except ConfigError as error:
        raise ConfigError(f"--{error}") from None


def _recording_path(args: argparse.Namespace, input_path: Path) -> Path | None:
    if args.rrd is None:
        return None
    if args.rrd == Path("AUTO"):
        return DEFAULT_RECORDINGS / f"{input_path.stem}.rrd"
    return args.rrd


def run_stabilize(input_path: Path, output_path: Path, args: argparse.Namespace, *, overwrite: bool,
                  observers: Sequence[Observer] = ()) -> stab.StabilizeReport:
    from ffviz.progress import tqdm_progress

    config = _stabilize_config(args)
    encoding = output_encoding(args)
    rrd_path = _recording_path(args, input_path)
    recorder = None
    if rrd_path is not None:
        from ffviz.recorder import RerunRecorder

        recorder = RerunRecorder(rrd_path, level=args.record, jpeg_quality=None if args.lossless else 80,
                                 trace_frames=args.trace_frames)
    try:
        report = stab.stabilize(input_path, output_path, config, observer=Observers(recorder, *observers),
                                progress=tqdm_progress, overwrite=overwrite, encoding=encoding,
                                workers=getattr(args, "workers", None))
    except BaseException:
        if recorder is not None:
            recorder.abort()
        raise
    _print_report(report, rrd_path)
    return report


def _print_report(report: stab.StabilizeReport, rrd_path: Path | None) -> None:
    lines = [f"stabilized {report.n_frames} frames in {report.seconds:.1f} s "
             f"({report.n_frames / max(report.seconds, 1e-9):.1f} frames/s) -> {report.output_path}"]
    if report.crop is not None:
        lines.append(f"crop: kept {report.crop.cropping_ratio:.1%} of the frame area (scale {report.crop.scale:.3f})")
    if report.cuts:
        lines.append(f"scene cuts at frames {', '.join(map(str, report.cuts))}")
    if report.warnings:
        lines.append(f"{len(report.warnings)} warning(s), listed on stderr")
    if rrd_path is not None:
        lines.append(f"recording: {rrd_path}  (open with: ffviz view {rrd_path})")
    print("\n".join(lines))
    _print_warnings(report.warnings)


def _print_warnings(warnings: Sequence[tuple[int | None, str]], limit: int = 5) -> None:
    for frame, message in warnings[:limit]:
        print(f"ffviz: warning: {message}" + (f" (frame {frame})" if frame is not None else ""), file=sys.stderr)
    if len(warnings) > limit:
        print(f"ffviz: warning: ... and {len(warnings) - limit} more", file=sys.stderr)


def cmd_stabilize(args: argparse.Namespace) -> int:
    run_stabilize(args.input, args.output, args, overwrite=args.overwrite)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from ffviz.demo import run_demo

    return run_demo(args)


def cmd_metrics(args: argparse.Namespace) -> int:
    from pipeline import metrics

    result = metrics.compare(args.input, args.output)
    data = result.to_dict()
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    rows = [("", "input", "output")]
    for key, label, fmt in (("residual_jitter_px", "residual jitter (px)", "{:.3f}"),
                            ("residual_jitter_deg", "residual jitter (deg)", "{:.4f}"),
                            ("stability_translation", "stability, translation", "{:.3f}"),
                            ("stability_rotation", "stability, rotation", "{:.3f}")):
        rows.append((label, fmt.format(data["input"][key]), fmt.format(data[key])))
    for key, label in (("cropping_ratio", "cropping ratio"), ("distortion", "distortion (worst frame)"),
                       ("black_fraction", "black pixels (fraction)")):
        rows.append((label, "", f"{data[key]:.3f}"))
    width = max(len(r[0]) for r in rows)
    print("\n".join(f"{a:<{width}}  {b:>8}  {c:>8}" for a, b, c in rows))
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from ffviz.viewer import serve

    return serve(args.recording, web_port=args.web_port, grpc_port=args.grpc_port, native=args.native)


def cmd_figures(args: argparse.Namespace) -> int:
    from ffviz.figures import render_figures

    render_figures(args.recording, args.output_dir, fmt=args.format, frames=args.frames)
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from ffviz.batch import cmd_batch as run_batch

    return run_batch(args, _stabilize_config(args), output_encoding(args))


def cmd_bench(args: argparse.Namespace) -> int:
    from ffviz.bench import cmd_bench as run_bench

    return run_bench(args)


COMMANDS = {"stabilize": cmd_stabilize, "demo": cmd_demo, "metrics": cmd_metrics, "view": cmd_view,
            "figures": cmd_figures, "batch": cmd_batch, "bench": cmd_bench}


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return COMMANDS[args.command](args)
    except FFVizError as error:
        print(f"ffviz: error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:
        print("ffviz: interrupted; no output written", file=sys.stderr)
        return 130
    except Terminated:
        print("ffviz: terminated; no output written", file=sys.stderr)
        return 143
    except Exception as error:  # noqa: BLE001 - the last line of defence: one line, not a traceback
        if args.debug:
            traceback.print_exc()
        print(f"ffviz: internal error: {type(error).__name__}: {error} (rerun with --debug for details)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
