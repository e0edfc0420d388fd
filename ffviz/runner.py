"""One stabilization as the command line runs it: options to configs, the recorder, progress, the printed report
and the last line saying what was written and how to look at it.

Shared by `ffviz stabilize` (cli.py) and `ffviz demo` (demo.py), which is why it is neither of them: cli.py
imports demo.py to dispatch, so demo.py must not import cli.py.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import sys
from pathlib import Path
from typing import Sequence

from pipeline.stages import adaptive_crop, deblur, motion, path_control, smoothing
from pipeline import presets
from pipeline import stabilize as stab
from pipeline.runtime.encoding import CODEC_OPTIONS, Encoding
from pipeline.runtime import video_writer
from pipeline.errors import ConfigError, OutputError
from pipeline.runtime.observer import Observer, Observers
from pipeline.runtime.source import FileSource

DEFAULT_RECORDINGS = Path("recordings")  # where --rrd without a path writes INPUT_STEM.rrd
MAX_RADIUS = 100_000  # frames; the smoothing kernel is allocated at 2k+1 taps
MIN_SIGMA, MAX_SIGMA = 1e-6, 1e6  # frames


def _check_options(args: argparse.Namespace) -> None:
    """What the configs cannot check: values argparse parses but the run or the kernel cannot use (the
    encoder's values are Encoding's to check)."""
    if getattr(args, "workers", None) is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, not {args.workers}")
    if getattr(args, "tripod", False) and getattr(args, "path", None) not in (None, "gaussian", "tripod"):
        raise ConfigError(f"--tripod holds the camera still; it cannot be combined with --path {args.path}")
    if args.smoothing_radius is not None and args.smoothing_radius > MAX_RADIUS:
        raise ConfigError(f"-k must be at most {MAX_RADIUS}, not {args.smoothing_radius}")
    # Outside these the kernel's sigma**2 underflows (0/0) or overflows; the ends already mean none/uniform.
    if args.smoothing_sigma is not None and not MIN_SIGMA <= args.smoothing_sigma <= MAX_SIGMA:  # False for nan
        raise ConfigError(f"--smoothing-sigma must be between {MIN_SIGMA:g} and {MAX_SIGMA:g} frames, "
                          f"not {args.smoothing_sigma}")
    if getattr(args, "smoothness", None) is not None and (args.smoothing_radius is not None
                                                          or args.smoothing_sigma is not None):
        raise ConfigError("--smoothness sets eq. 18's radius per axis: give it or -k/--smoothing-sigma, not both")
    if getattr(args, "crop", "fixed") != "fixed" and args.mode != "crop":
        raise ConfigError(f"--crop {args.crop} chooses --mode crop's window; it does not apply to --mode {args.mode}")


def parse_ignore(text: str) -> motion.IgnoreRegion:
    """--ignore X,Y,W,H[@T0-T1] as a motion.IgnoreRegion; ConfigError naming the option when malformed."""
    box, _, times = text.partition("@")
    try:
        x, y, width, height = (int(v) for v in box.split(","))
        start = end = None
        if times:
            first, dash, last = times.partition("-")
            if not dash:
                raise ValueError
            start = float(first) if first else None
            end = float(last) if last else None
    except ValueError:
        raise ConfigError(f"--ignore {text!r}: expected X,Y,W,H or X,Y,W,H@T0-T1 (integers px, seconds)") from None
    return motion.IgnoreRegion(x, y, width, height, start, end)


def stabilize_config(args: argparse.Namespace) -> stab.StabilizeConfig:
    _check_options(args)
    try:
        crop = adaptive_crop.CropConfig(kind=getattr(args, "crop", "fixed"),
                                        zoom_speed=getattr(args, "zoom_speed", adaptive_crop.DEFAULT_ZOOM_SPEED),
                                        scale=getattr(args, "crop_scale", None), fill=getattr(args, "crop_fill", None))
        segments = tuple(path_control.PathSegment.parse(text) for text in getattr(args, "path_segment", []))
        l1_segments = any(segment.path != "gaussian" for segment in segments)
        path = "tripod" if getattr(args, "tripod", False) else (getattr(args, "path", None)
                                                                 or stab.default_path(args.mode, crop,
                                                                                      l1_segments=l1_segments))
        return presets.with_quality(stab.StabilizeConfig(
            mode=args.mode,
            motion=motion.MotionConfig(model=args.motion_model, refine=args.refine,
                                       ignore=tuple(parse_ignore(text) for text in getattr(args, "ignore", [])),
                                       ignore_mask=getattr(args, "ignore_mask", None)),
            smoothing=smoothing.SmoothingConfig(
                radius_frames=(stab.default_radius(args.mode, path, crop, l1_segments=l1_segments)
                               if args.smoothing_radius is None
                               else args.smoothing_radius), sigma=args.smoothing_sigma, path=path,
                horizon_lock=getattr(args, "horizon_lock", False),
                smoothness=(path_control.Smoothness.parse(args.smoothness)
                            if getattr(args, "smoothness", None) is not None else None),
                max_shift=getattr(args, "max_shift", None), max_angle=getattr(args, "max_angle", None),
                segments=segments),
            deblur=deblur.DeblurConfig(enabled=args.deblur, alpha=args.deblur_alpha),
            crop=crop,
            rolling_shutter=getattr(args, "rolling_shutter", None),
        ), getattr(args, "quality", "default"))
    except ValueError as error:  # the configs validate their own values
        raise ConfigError(str(error)) from None


def output_encoding(args: argparse.Namespace) -> Encoding:
    """--codec and the quality options that belong to it (one that belongs to another codec is an error)."""
    own = CODEC_OPTIONS[args.codec]
    every = [name for names in CODEC_OPTIONS.values() for name in names]
    given = {name: getattr(args, name) for name in every if getattr(args, name) is not None}
    stray = [f"--{name}" for name in given if name not in own]
    if stray:
        raise ConfigError(f"{' and '.join(stray)} {'does' if len(stray) == 1 else 'do'} not apply to --codec "
                          f"{args.codec} (its options: {', '.join('--' + n for n in own)})")
    try:
        return Encoding(codec=args.codec, **given)
    except ConfigError as error:
        raise ConfigError(f"--{error}") from None


def recording_path(args: argparse.Namespace, input_path: Path) -> Path | None:
    if args.rrd is None:
        return None
    if args.rrd == Path("AUTO"):
        return DEFAULT_RECORDINGS / f"{input_path.stem}.rrd"
    return args.rrd


def view_command(recording: Path) -> str:
    """A command that opens ``recording``, runnable as printed in the shell the user started ffviz from.

    Under ./run (which exports FFVIZ_LAUNCHER, the script as the user typed it, and FFVIZ_USER_CWD): that script's
    `view` verb and the path from the user's folder. Otherwise `ffviz` when the one on PATH is this one, else the
    path of the script that is running (e.g. .venv/bin/ffviz), else `python -m ffviz.cli`."""
    launcher, user_cwd = os.environ.get("FFVIZ_LAUNCHER"), os.environ.get("FFVIZ_USER_CWD")
    if launcher and user_cwd:
        return f"{shlex.quote(launcher)} view {shlex.quote(os.path.relpath(recording.absolute(), user_cwd))}"
    script = Path(sys.argv[0]) if sys.argv and sys.argv[0] else None
    if script is not None and script.name == "ffviz" and script.is_file():
        on_path = shutil.which("ffviz")
        if on_path is not None and Path(on_path).resolve() == script.resolve():
            program = "ffviz"
        else:
            relative = os.path.relpath(script.absolute())
            program = shlex.quote(relative if relative.startswith("../") is False and "/" in relative
                                  else str(script.absolute()))
    else:
        program = f"{shlex.quote(sys.executable)} -m ffviz.cli"
    return f"{program} view {shlex.quote(str(recording))}"


def run_stabilize(input_path: Path, output_path: Path, args: argparse.Namespace, *, overwrite: bool,
                  observers: Sequence[Observer] = (), final_line: bool = True) -> stab.StabilizeReport:
    """Stabilize with the CLI's options and print the report; ``final_line``: end with what was written where
    and how to look at it (the demo prints its own)."""
    from ffviz.progress import tqdm_progress

    config = stabilize_config(args)
    encoding = output_encoding(args)
    rrd_path = recording_path(args, input_path)
    live = None
    if getattr(args, "view", False):  # --view: a web viewer the run streams into, and the .rrd as well
        from ffviz.viewer import LiveViewer

        rrd_path = rrd_path or DEFAULT_RECORDINGS / f"{input_path.stem}.rrd"
        live = LiveViewer(web_port=args.web_port, grpc_port=args.grpc_port)
        print(f"live view: {live.url}", flush=True)
    recorder = None
    if rrd_path is not None:
        from ffviz.recorder import RerunRecorder

        recorder = RerunRecorder(rrd_path, level=args.record, jpeg_quality=None if args.lossless else 80,
                                 record_size=args.record_size, trace_frames=args.frames,
                                 live_url=live.grpc_url if live else None)
    from ffviz import compare

    start_s, end_s = compare.preview_range(args)
    compare_path = getattr(args, "compare", None)
    try:
        if compare_path is not None:  # refused before the long run, not after it
            compare.check_compare_path(compare_path, input_path, output_path, overwrite=overwrite)
        if start_s is None:
            report = stab.stabilize(input_path, output_path, config, observer=Observers(recorder, *observers),
                                    progress=tqdm_progress, overwrite=overwrite, encoding=encoding,
                                    workers=getattr(args, "workers", None))
        else:  # --preview / --start: only that stretch of the input is read, and written from 0 s on
            source = FileSource(input_path, start_s=start_s, end_s=end_s)
            video_writer.check_output_path(output_path, input_path, overwrite=overwrite)
            report = stab.stabilize_source(source, output_path, config, observer=Observers(recorder, *observers),
                                           progress=tqdm_progress, encoding=encoding,
                                           workers=getattr(args, "workers", None))
    except BaseException as error:
        if recorder is not None:
            recorder.abort()
        if live is not None:
            live.stop()
        if isinstance(error, OutputError) and recorder is not None and recorder.started and not recorder.failed:
            # The video could not be written (a full disk) once the run was under way: the recording is dropped
            # with it; say so.
            raise OutputError(f"{error}; the recording {rrd_path} was not written either") from error
        raise
    _print_report(report, rrd_path)
    written = [(report.output_path, "stabilized video")]
    if compare_path is not None:
        compare.stabilize_comparison(input_path, output_path, compare_path, start_s, end_s, overwrite=overwrite)
        written.append((compare_path, "side by side"))
    if final_line:
        print(written_line(written, rrd_path), flush=True)
    if live is not None:
        print(f"live view still serving at {live.url} (Ctrl-C to stop)", flush=True)
        live.wait()
    return report


def written_line(files: Sequence[tuple[Path, str]], rrd_path: Path | None) -> str:
    """The last line of a run: what was written where, and how to look at it."""
    what = [f"{path} ({label})" for path, label in files]
    if rrd_path is not None:
        what.append(f"{rrd_path} (recording)")
        look = f"to look inside: {view_command(rrd_path)}"
    else:
        look = "play it in any video player (add --rrd to record every step for the viewer)"
    return f"wrote {', '.join(what[:-1]) + ' and ' + what[-1] if len(what) > 1 else what[0]}; {look}"


def _print_report(report: stab.StabilizeReport, rrd_path: Path | None) -> None:
    lines = [f"stabilized {report.n_frames} frames in {report.seconds:.1f} s "
             f"({report.n_frames / max(report.seconds, 1e-9):.1f} frames/s) -> {report.output_path}"]
    if report.crop is not None and hasattr(report.crop, "scales"):  # --crop adaptive
        lines.append(f"crop: kept {report.crop.cropping_ratio:.1%} of the frame area on average (scale "
                     f"{report.crop.scales.min():.3f}-{report.crop.scales.max():.3f})")
    elif report.crop is not None:
        lines.append(f"crop: kept {report.crop.cropping_ratio:.1%} of the frame area (scale {report.crop.scale:.3f})")
    if report.cuts:
        lines.append(f"scene cuts at frames {', '.join(map(str, report.cuts))}")
    if report.warnings:
        lines.append(f"{len(report.warnings)} warning(s), listed on stderr")
    print("\n".join(lines), flush=True)
    _print_warnings(report.warnings)


def _print_warnings(warnings: Sequence[tuple[int | None, str]], limit: int = 5) -> None:
    for frame, message in warnings[:limit]:
        print(f"ffviz: warning: {message}" + (f" (frame {frame})" if frame is not None else ""), file=sys.stderr)
    if len(warnings) > limit:
        print(f"ffviz: warning: ... and {len(warnings) - limit} more", file=sys.stderr)
