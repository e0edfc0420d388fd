"""ffviz: full-frame video stabilization (Matsushita et al. 2006) that records every step for the Rerun viewer.

Expected failures (pipeline.errors.FFVizError) print one line and exit non-zero; Ctrl-C and SIGTERM
leave no partial output (writers abort on any exception) and exit 130/143.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import traceback
from pathlib import Path
from typing import Sequence

from ffviz.recording.view import RECORD_SIZE, parse_record_size
from ffviz.runner import DEFAULT_RECORDINGS, output_encoding, run_stabilize, stabilize_config
from ffviz.runner import view_command  # noqa: F401 - part of cli's interface (tests call cli.view_command)
from pipeline.stages import adaptive_crop, deblur, motion, smoothing
from pipeline import presets
from pipeline import stabilize as stab
from pipeline.runtime.encoding import Encoding, VIDEO_CODECS, X264_PRESETS
from pipeline.runtime import memory
from pipeline.errors import ConfigError, FFVizError

_stabilize_config = stabilize_config  # the name tests/test_deblur.py uses


class Terminated(BaseException):
    """Raised in the main thread on SIGTERM so the same cleanup as Ctrl-C runs.

    A BaseException, like KeyboardInterrupt, so that no `except Exception` on the way swallows it."""


def _on_sigterm(signum, frame) -> None:
    raise Terminated()


DESCRIPTION = """\
ffviz turns a shaky video into a steady one of the same size: no crop, no black borders (Matsushita et al.
2006: motion smoothing, full-frame completion from neighbouring frames, deblurring). With --rrd it records
every step (motion, trajectories, masks, flow, each stage of chosen frames) to a Rerun recording (.rrd)
that `ffviz view` opens.

Start with `ffviz demo`, then `ffviz stabilize INPUT -o OUTPUT.mp4 --rrd`. `ffviz COMMAND --help` for more.
Output paths: -o/--output names a file, --output-dir a folder."""

STABILIZE_EXAMPLES = """\
examples:
  ffviz stabilize shaky.mp4 -o steady.mp4
      full-frame output (the default --mode full), H.264, audio copied
  ffviz stabilize shaky.mp4 -o steady.mp4 --rrd
      also record every step to recordings/shaky.rrd; then: ffviz view recordings/shaky.rrd
  ffviz stabilize shaky.mp4 -o steady.mp4 --mode crop --crop-fill 0
      faster: crop to a window inside every frame, nothing synthesized
  ffviz stabilize shaky.mp4 -o steady.mp4 --rrd runs/a.rrd --frames 10,40
      record to runs/a.rrd and follow frames 10 and 40 through every stage
  ffviz stabilize big.mov -o steady.mp4 --codec mpeg4 --workers 1
      cheaper encoder, one thread
  ffviz stabilize long.mp4 -o try.mp4 --preview 5 --start 60 --compare try_sbs.mp4
      try settings on 5 s from 1:00 only, and write it beside the input (ffviz compare) to look at

exit status: 0 done, 2 bad input or option, 3 output problem, 130 interrupted, 143 terminated."""


def _deprecated(parser: argparse.ArgumentParser, old: str, new: str, **kwargs) -> None:
    """An old spelling that still works, hidden from --help; it warns once used."""
    parser.add_argument(old, help=argparse.SUPPRESS, action=_DeprecatedAlias, new=new, **kwargs)


class _DeprecatedAlias(argparse.Action):
    def __init__(self, *args, new: str, **kwargs) -> None:
        self.new = new
        super().__init__(*args, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(f"ffviz: warning: {option_string} is deprecated here; use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ffviz", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--debug", action="store_true", help="show the traceback of an internal error")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_command in (_add_stabilize_command, _add_demo_command, _add_metrics_command, _add_view_command,
                        _add_snapshot_command, _add_figures_command):
        add_command(commands)
    from ffviz.batch import add_parser as add_batch_parser  # imports no Ray: that happens when a batch runs

    add_batch_parser(commands, _add_stabilize_options)
    from ffviz.compare import add_parser as add_compare_parser

    add_compare_parser(commands)
    from ffviz.bench.command import add_parser as add_bench_parser  # imports no pipeline stage: the runs are children

    add_bench_parser(commands)
    from ffviz.debug_command import add_parser as add_debug_parser  # imports no recorder: that happens when it runs

    add_debug_parser(commands, _record_size, RECORD_SIZE)
    return parser


def _add_stabilize_command(commands: argparse._SubParsersAction) -> None:
    """`ffviz stabilize INPUT -o OUTPUT`: one video, with --preview, --start and --compare."""
    p = commands.add_parser("stabilize", help="stabilize a video", description="Stabilize a video file.",
                            epilog=STABILIZE_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", type=Path, metavar="INPUT",
                   help="video to stabilize (any container and codec FFmpeg reads: .mp4, .mov, .mkv, .avi, ...)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUTPUT",
                   help="video file to write: .mp4, .mov or .mkv (same frame count, rate and timestamps; audio copied)")
    _add_stabilize_options(p)
    p.add_argument("--preview", type=float, default=None, metavar="SECONDS",
                   help="stabilize only SECONDS of INPUT, from --start, to try settings before a long run: OUTPUT "
                        "(and --compare) hold just that stretch, starting at 0 s, with its audio (default: all of it)")
    p.add_argument("--start", type=float, default=None, metavar="SECONDS",
                   help="begin at this time of INPUT, in seconds; with --preview, the stretch previewed "
                        "(default: 0, the beginning)")
    p.add_argument("--compare", type=Path, default=None, metavar="FILE",
                   help="also write INPUT and OUTPUT side by side to FILE, with their camera paths, as "
                        "`ffviz compare` does (default: none)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace OUTPUT (and --compare FILE) if it exists (default: refuse)")


def _add_demo_command(commands: argparse._SubParsersAction) -> None:
    """`ffviz demo`: a synthetic shaky video with known motion, stabilized and checked."""
    p = commands.add_parser("demo", help="make a synthetic shaky video with known camera motion, stabilize it, "
                                         "check against the truth",
                            description="Generate a synthetic shaky video with known camera motion (no input "
                                        "needed), stabilize it with a recording, and compare the estimated motion "
                                        "with the truth.")
    p.add_argument("--output-dir", type=Path, default=Path("ffviz-demo"), metavar="DIR",
                   help="folder for the input and stabilized videos (default: %(default)s)")
    _deprecated(p, "-o", "--output-dir", dest="output_dir", type=Path)
    p.add_argument("--num-frames", type=int, default=120, metavar="N",
                   help="length of the synthetic video, in frames at 30 frames/s (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the synthetic camera shake and scene; the same seed gives the same video "
                        "(default: %(default)s)")
    _add_stabilize_options(p, rrd_default=DEFAULT_RECORDINGS / "demo.rrd")


def _add_metrics_command(commands: argparse._SubParsersAction) -> None:
    """`ffviz metrics INPUT OUTPUT`: how steady OUTPUT is."""
    p = commands.add_parser("metrics", help="how steady OUTPUT is compared with INPUT (Liu et al. 2013 + residual "
                                            "jitter)",
                            description="Stabilization measures of OUTPUT against INPUT: residual jitter, "
                                        "stability, cropping ratio, distortion, black pixels (docs/metrics.md).")
    p.add_argument("input", type=Path, metavar="INPUT", help="the original (shaky) video")
    p.add_argument("output", type=Path, metavar="OUTPUT",
                   help="the stabilized video, with the same number of frames as INPUT")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table (default: a table)")


def _add_view_command(commands: argparse._SubParsersAction) -> None:
    """`ffviz view RECORDING`: the Rerun viewer, on the web or the desktop."""
    p = commands.add_parser("view", help="open a recording (.rrd) in the Rerun viewer",
                            description="Serve a recording to Rerun's web viewer on 127.0.0.1 (offline; open the "
                                        "printed URL in a browser) or open it in the desktop viewer. Ctrl-C stops.")
    p.add_argument("recording", type=Path, metavar="RECORDING", help="a .rrd file written by ffviz")
    p.add_argument("--native", action="store_true",
                   help="open the desktop viewer instead of serving the web viewer (needs a display)")
    p.add_argument("--web-port", type=int, default=9090, metavar="PORT",
                   help="TCP port of the web viewer page on 127.0.0.1 (default: %(default)s)")
    p.add_argument("--grpc-port", type=int, default=9876, metavar="PORT",
                   help="TCP port on 127.0.0.1 from which the page streams the recording (default: %(default)s)")


def _add_snapshot_command(commands: argparse._SubParsersAction) -> None:
    """`ffviz snapshot RECORDING`: a PNG of one tab at one frame, rendered headless."""
    p = commands.add_parser("snapshot", help="a PNG of what the viewer shows for a recording at a frame, on a tab",
                            description="Render what the Rerun viewer shows for RECORDING at --frame on --tab, "
                                        "headless (the native viewer without a window; needs `ffmpeg` on PATH to "
                                        "decode the frame streams), to a PNG for reviews, docs and tests.")
    p.add_argument("recording", type=Path, metavar="RECORDING", help="a .rrd file written by ffviz")
    p.add_argument("--frame", type=int, default=0, metavar="N",
                   help="frame number (from 0) to show (default: %(default)s)")
    p.add_argument("--tab", default="overview", metavar="NAME",
                   help="tab to show: overview, motion, smoothing, mosaic, local flow + motion inpainting, "
                        "deblurring, stage stepping or about; a unique prefix is enough (default: %(default)s)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="PNG",
                   help="image file to write, .png or .jpg (required)")
    p.add_argument("--size", default="1280x800", metavar="WxH",
                   help="viewer window size in points; the PNG may be at twice that (default: %(default)s)")


def _add_figures_command(commands: argparse._SubParsersAction) -> None:
    """`ffviz figures RECORDING`: the thesis-style figures from a recording."""
    p = commands.add_parser("figures", help="render the thesis-style figures from a recording (PNG, PDF or SVG)",
                            description="Render figures (trajectories, stabilized vs original, completion, motion "
                                        "inpainting, deblurring, blurriness, mosaic variance) from a recording "
                                        "alone. A figure the recording lacks data for is skipped with a note.")
    p.add_argument("recording", type=Path, metavar="RECORDING", help="a .rrd file written by ffviz")
    p.add_argument("--output-dir", type=Path, default=None, metavar="DIR",
                   help="folder to write the figures to, created if missing (required)")
    _deprecated(p, "-o", "--output-dir", dest="output_dir", type=Path)
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png",
                   help="file format of the figures (default: %(default)s)")
    p.add_argument("--frames", type=_frame_list, default=None, metavar="T1,T2,...",
                   help="frame numbers (from 0) to show in the frame comparisons (default: the frames the "
                        "recording traced, else a few spread over the video)")


def _record_size(text: str) -> int | None:
    try:
        return parse_record_size(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _frame_list(text: str) -> tuple[int, ...] | None:
    from ffviz.trace import parse_frame_list

    try:
        return parse_frame_list(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _add_stabilize_options(p: argparse.ArgumentParser, rrd_default: Path | None = None, *,
                           rrd_folder: bool = False) -> None:
    """The options of one stabilization, shared by stabilize, demo and batch. ``rrd_folder``: --rrd names a
    folder of recordings, one per video, and there is no --workers (batch: one thread per Ray task)."""
    _add_path_options(p)
    _add_crop_options(p)
    _add_motion_options(p)
    _add_completion_options(p)
    _add_recording_options(p, rrd_default, rrd_folder=rrd_folder)
    _add_encoding_options(p)
    if rrd_folder:
        return
    p.add_argument("--workers", "-j", type=int, default=None, metavar="N",
                   help="frames processed at once, on threads; the frames written are the same for any N "
                        "(default: one per CPU core, here %d)" % (os.cpu_count() or 1))


def _add_path_options(p: argparse.ArgumentParser) -> None:
    """--mode and how the camera path is planned: its smoothing, its planner and the bounds it keeps."""
    p.add_argument("--mode", choices=stab.OUTPUT_MODES, default="full",
                   help="full: missing areas completed from neighbouring frames (full frame, no crop); "
                        "crop: a window scaled back to full size, valid in every frame but for a small share "
                        "completed (--crop-fill); "
                        "none: missing areas left black (default: %(default)s)")
    p.add_argument("--smoothing-radius", "-k", type=int, default=None, metavar="K",
                   help="smoothing radius: frames on each side averaged into each frame's camera path (eq. 18); "
                        "larger is steadier but needs more completion or crop (default: "
                        f"{stab.DEFAULT_RADIUS}; {stab.HARD_CROP_RADIUS} in crop mode with a window inside every frame)")
    p.add_argument("--smoothing-sigma", type=float, default=None, metavar="SIGMA",
                   help="width of that Gaussian, in frames (default: sqrt(K))")
    p.add_argument("--path", choices=smoothing.PATHS, default=None,
                   help="camera path planner: gaussian (eq. 18, with -k); l1 (L1-optimal path of still, "
                        "constant-velocity and constant-acceleration pieces, each frame within 3%% of the frame's "
                        "longer side, 2 degrees and 4%% zoom of its input, or in crop mode inside the crop window); "
                        "tripod (see --tripod); auto (crop mode: l1 that also prices the path's shake over half a second, in "
                        "the widest window where it is as steady as gaussian, else gaussian; other modes: gaussian) "
                        "(default: gaussian; auto in crop mode with a window inside every frame: --crop-fill 0, "
                        "--crop-scale or --crop adaptive)")
    p.add_argument("--tripod", action="store_true",
                   help="hold the camera still (same as --path tripod): the output does not move while a still "
                        "view stays within 10%% of the frame, 4 degrees and 8%% zoom of every input frame; where the "
                        "camera went further the view follows it as little as it can, and a warning says where")
    p.add_argument("--horizon-lock", action="store_true",
                   help="keep the output's rotation at that of each shot's first frame, with any --path "
                        "(the turned frames' corners are completed, or cropped with --mode crop)")
    p.add_argument("--smoothness", default=None, metavar="S|t=S,r=S,z=S",
                   help="how smooth the camera path is, 0-100: 0 follows the input, 50 is the default path, 100 the "
                        "smoothest; one S for every axis or per axis (t translation, r rotation, z zoom; left out: "
                        "50); gaussian: radius K (S/50)^2 per axis, K the mode's default -k; l1: its margins times S/50 "
                        "(default: -k, or l1's margins)")
    p.add_argument("--max-shift", type=float, default=None, metavar="PX",
                   help="no output frame's centre lies further than PX pixels (x and y each) from its input frame's, "
                        "with any --path (default: no bound)")
    p.add_argument("--max-angle", type=float, default=None, metavar="DEG",
                   help="no output frame turns more than DEG degrees from its input frame, with any --path "
                        "(default: no bound)")
    p.add_argument("--path-segment", action="append", default=[], metavar="T0-T1:PATH[:S]",
                   help="plan the seconds T0-T1 with their own path and smoothness, e.g. 0-5:tripod or "
                        "5-:gaussian:80 (either end may be left out; the rest of the clip follows --path); the path "
                        "eases from one setting into the next over a second, without a jump; may be given several "
                        "times (default: none)")


def _add_crop_options(p: argparse.ArgumentParser) -> None:
    """The crop window of --mode crop: fixed or adaptive, its size, and the share of it that may be completed."""
    p.add_argument("--crop", choices=adaptive_crop.CROPS, default="fixed",
                   help="with --mode crop: fixed, one window valid in every frame; adaptive, a window whose zoom "
                        "follows the path (wider where the camera is calm), never showing black (default: "
                        "%(default)s)")
    p.add_argument("--zoom-speed", type=float, default=adaptive_crop.DEFAULT_ZOOM_SPEED, metavar="PCT",
                   help="with --crop adaptive: how fast the zoom may change, in %% of the frame a frame "
                        "(default: %(default)s)")
    p.add_argument("--crop-scale", type=float, default=None, metavar="Z",
                   help="with --mode crop and --path l1 or tripod: the crop window's size as a share of the frame "
                        "each way (0.9 keeps 81%% of the area); the path is planned to keep this window inside "
                        "every input frame (default: the window the path keeps without that constraint)")
    p.add_argument("--crop-fill", type=float, default=None, metavar="SHARE",
                   help="with --mode crop on eq. 18's path: the window is the largest whose parts outside the input "
                        "frames are at most SHARE of the output's pixels over the clip, completed from neighbouring "
                        "frames as in full mode; 0: a window inside every frame, nothing synthesized, on the auto "
                        f"path at -k {stab.HARD_CROP_RADIUS} (default: {stab.DEFAULT_CROP_FILL:g})")


def _add_motion_options(p: argparse.ArgumentParser) -> None:
    """How the camera motion between frames is estimated: the model, what it ignores, rolling shutter, ECC."""
    p.add_argument("--motion-model", choices=motion.MOTION_MODELS, default="affine",
                   help="camera motion fitted between frames: similarity (shift, rotation, zoom), affine (also "
                        "shear) or homography (also perspective) (default: %(default)s)")
    p.add_argument("--ignore", action="append", default=[], metavar="X,Y,W,H[@T0-T1]",
                   help="a box (px: left, top, width, height) whose features motion estimation does not use, e.g. "
                        "a logo or a person in front of the camera; @T0-T1 limits it to that time (seconds; "
                        "either end may be left out: @5- or @-2.5); may be given several times (default: none)")
    p.add_argument("--ignore-mask", metavar="IMAGE_OR_VIDEO", default=None,
                   help="image (for every frame) or video (frame by frame) of the input's size: white pixels' "
                        "features are not used by motion estimation (default: none)")
    p.add_argument("--rolling-shutter", default=None, metavar="auto|READOUT",
                   help="undo rolling-shutter wobble (phones, action cameras: rows exposed one after another): "
                        "READOUT is the time the sensor takes to read a frame, as a fraction of the frame interval "
                        "(0-1, e.g. 0.9), or auto to fit it from the video's motion (default: off)")
    p.add_argument("--refine", choices=motion.REFINEMENTS, default="none",
                   help="ecc: refine each motion estimate by hierarchical coarse-to-fine direct alignment "
                        "(slower) (default: %(default)s)")


def _add_completion_options(p: argparse.ArgumentParser) -> None:
    """Deblurring and the effort of full mode's completion."""
    p.add_argument("--no-deblur", dest="deblur", action="store_false",
                   help="leave motion-blurred frames as they are (default: sharpen them with the pixels of sharper "
                        "neighbouring frames, thesis ch. 5)")
    p.add_argument("--deblur-alpha", type=float, default=deblur.DEBLUR_ALPHA, metavar="ALPHA",
                   help="eq. 31 sensitivity to the alignment error, in intensity levels 0-255: larger lets "
                        "less well aligned neighbours contribute more (default: %(default)s)")
    p.add_argument("--quality", choices=presets.QUALITIES, default="default",
                   help="full mode's completion and deblurring effort: default (the thesis's chain) or fast (local "
                        "warp from two neighbours at half the flow resolution, no local registration, deblurring over "
                        "+-3 frames: less CPU "
                        "for some PSNR in the filled borders; docs/benchmarks-speed.md) (default: %(default)s)")


def _add_recording_options(p: argparse.ArgumentParser, rrd_default: Path | None, *, rrd_folder: bool) -> None:
    """The Rerun recording: where it goes (a file, or a folder for batch), live viewing, and its detail."""
    if rrd_folder:
        p.add_argument("--rrd", type=Path, nargs="?", const=Path("AUTO"), default=rrd_default, metavar="DIR",
                       help="write one Rerun recording per video, DIR/<input name>.rrd; --rrd alone: "
                            "OUTDIR/recordings/ (default: no recordings)")
    else:
        p.add_argument("--rrd", type=Path, nargs="?", const=Path("AUTO"), default=rrd_default, metavar="FILE",
                       help="also write a Rerun recording of every step to FILE; --rrd alone: "
                            "recordings/<input name>.rrd (default: %s)"
                            % (rrd_default if rrd_default is not None else "no recording"))
    if not rrd_folder:
        p.add_argument("--view", action="store_true",
                       help="watch the run live in Rerun's web viewer on 127.0.0.1 (the URL is printed) while "
                            "it also writes the recording (--rrd, default recordings/<input name>.rrd); keeps "
                            "serving after the run until Ctrl-C (default: off)")
        p.add_argument("--web-port", type=int, default=9090, metavar="PORT",
                       help="with --view: TCP port of the web viewer page on 127.0.0.1 (default: %(default)s)")
        p.add_argument("--grpc-port", type=int, default=9876, metavar="PORT",
                       help="with --view: TCP port on 127.0.0.1 the run streams to and the page reads from "
                            "(default: %(default)s)")
    p.add_argument("--record", choices=("summary", "full"), default="full",
                   help="recording detail: summary (series and output frames) or full (every intermediate) "
                        "(default: %(default)s)")
    p.add_argument("--lossless", action="store_true",
                   help="record images losslessly (larger files) (default: JPEG at quality 80)")
    p.add_argument("--record-size", type=_record_size, default=RECORD_SIZE, metavar="PX|full",
                   help="long side in pixels of the recorded frames, masks and maps (the traced frames' too), or "
                        "'full' for the input's size; statistics and charts come from full resolution either way "
                        "(default: %(default)s)")
    p.add_argument("--frames", type=_frame_list, default=None, metavar="T1,T2,...",
                   help="frame numbers (from 0) to follow through every stage in the recording (timelines 'stage' "
                        "and 'fmm_step'), or 'none' (default: 3 frames with missing area at --record full, none "
                        "at summary)")
    _deprecated(p, "--trace-frames", "--frames", dest="frames", type=_frame_list)


def _add_encoding_options(p: argparse.ArgumentParser) -> None:
    """The output video's encoder and its quality settings (pipeline.runtime.encoding.Encoding)."""
    p.add_argument("--codec", choices=VIDEO_CODECS, default="auto",
                   help="output video: auto (h264 for 8-bit input, hevc for 10/12-bit and HDR input), h264 (x264; "
                        "--crf, --preset), hevc (x265; --crf, --preset) or mpeg4 (MPEG-4 Part 2, what OpenCV's XVID "
                        "writer uses; --qscale; 8-bit only): a tenth of x264's CPU for about twice the bits "
                        "(default: %(default)s)")
    p.add_argument("--crf", type=int, default=None,
                   help="h264 quality, 0-51 (lower is better; default: %d)" % Encoding.crf)
    p.add_argument("--preset", choices=X264_PRESETS, default=None,
                   help="h264 speed against file size at the same --crf quality: faster presets encode sooner into "
                        "larger files (default: %s)" % Encoding.preset)
    p.add_argument("--qscale", type=int, default=None,
                   help="mpeg4 quantiser, 2-31 (lower is better; default: %d)" % Encoding.qscale)


def cmd_stabilize(args: argparse.Namespace) -> int:
    run_stabilize(args.input, args.output, args, overwrite=args.overwrite)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from ffviz.demo import run_demo

    return run_demo(args)


def cmd_metrics(args: argparse.Namespace) -> int:
    from ffviz.progress import tqdm_callback
    from pipeline.evaluation import metrics

    progress, close = tqdm_callback("measuring both videos")
    try:
        result = metrics.compare(args.input, args.output, progress=progress)
    finally:
        close()
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
    flicker = data["synth_flicker_ratio"]  # None when no frame has synthesized pixels (crop)
    rows.append(("synthesized-pixel flicker (x real)", "", "-" if flicker is None else f"{flicker:.3f}"))
    width = max(len(r[0]) for r in rows)
    print("\n".join(f"{a:<{width}}  {b:>8}  {c:>8}" for a, b, c in rows))
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from ffviz.viewer import serve

    return serve(args.recording, web_port=args.web_port, grpc_port=args.grpc_port, native=args.native)


def cmd_snapshot(args: argparse.Namespace) -> int:
    from ffviz.snapshot import snapshot

    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--size {args.size!r}: expected WIDTHxHEIGHT, e.g. 1280x800") from None
    written = snapshot(args.recording, args.output, frame=args.frame, tab=args.tab, size=(width, height))
    print(f"wrote {written} (frame {args.frame}, tab {args.tab})")
    return 0


def cmd_figures(args: argparse.Namespace) -> int:
    from ffviz.figures import render_figures

    if args.output_dir is None:
        raise ConfigError("figures: --output-dir DIR is required (the folder to write the figures to)")
    written = render_figures(args.recording, args.output_dir, fmt=args.format, frames=args.frames)
    print(f"wrote {len(written)} figure(s) to {args.output_dir}/" if written else
          f"no figure written: {args.recording} lacks the data for every figure")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from ffviz.compare import cmd_compare as run_compare

    return run_compare(args)


def cmd_batch(args: argparse.Namespace) -> int:
    from ffviz.batch import cmd_batch as run_batch

    return run_batch(args, stabilize_config(args), output_encoding(args))


def cmd_bench(args: argparse.Namespace) -> int:
    from ffviz.bench.command import cmd_bench as run_bench

    return run_bench(args)


def cmd_debug(args: argparse.Namespace) -> int:
    from ffviz.debug_command import cmd_debug as run

    return run(args)


COMMANDS = {"stabilize": cmd_stabilize, "demo": cmd_demo, "metrics": cmd_metrics, "view": cmd_view,
            "snapshot": cmd_snapshot, "compare": cmd_compare,
            "figures": cmd_figures, "batch": cmd_batch, "bench": cmd_bench, "debug": cmd_debug}


def _nothing_written(args: argparse.Namespace) -> str:
    return "" if args.command in ("view", "metrics") else "; no output written"


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    signal.signal(signal.SIGTERM, _on_sigterm)
    memory.reuse_freed_memory()  # frame-sized arrays are reused, not faulted in afresh (pipeline/runtime/memory.py)
    try:
        return COMMANDS[args.command](args)
    except FFVizError as error:
        print(f"ffviz: error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:
        print(f"ffviz: interrupted{_nothing_written(args)}", file=sys.stderr)
        return 130
    except Terminated:
        print(f"ffviz: terminated{_nothing_written(args)}", file=sys.stderr)
        return 143
    except Exception as error:  # noqa: BLE001 - the last line of defence: one line, not a traceback
        if args.debug:
            traceback.print_exc()
        print(f"ffviz: internal error: {type(error).__name__}: {error} (rerun with --debug for details)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
