"""What `ffviz bench` compares: ffviz's modes (each `ffviz stabilize` as a child process) and the peer stabilizers,
each a ``Method`` whose passes are the commands it runs, and ``run_method``, which measures them.

Peers (skipped with a one-line note when absent): ffmpeg's two-pass vid.stab and one-pass deshake (defaults), and
OpenCV's videostab sample program built by benchmarks/peers/build_opencv_videostab.sh. One reference that stabilizes
nothing: "x264 only", ffmpeg decoding the clip and encoding it with the x264 settings ffviz and the ffmpeg peers use,
the cost every method writing H.264 pays whatever it does.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from ffviz.bench.measure import ChildRun, add_ticks, run_measured
from ffviz.bench.report import X264_ONLY

REPO = Path(__file__).resolve().parents[2]
OPENCV_VIDEOSTAB = REPO / ".cache" / "peers" / "videostab" / "videostab"  # where the build script puts it
BUILD_SCRIPT = "benchmarks/peers/build_opencv_videostab.sh"
MODES = ("full", "crop", "none")
# A mode with "-mpeg4" writes the OpenCV sample's codec (--codec mpeg4): its chain compared without x264's cost.
MPEG4_MODES = tuple(f"{mode}-mpeg4" for mode in MODES)
# A mode with "-l1" plans the L1-optimal path (--path l1) instead of the mode's default.
L1_MODES = ("full-l1", "crop-l1")
DEFAULT_MODES = (*MODES, "full-mpeg4")
PEERS = ("vidstab", "deshake", "opencv", "x264")


Passes = Callable[[Path, Path, Path], list[list[str]]]  # (input, output, work dir) -> commands, run in order


@dataclass(frozen=True)
class Method:
    name: str  # as in the table: "ffviz full", "vidstab", ...
    output_suffix: str
    passes: Passes

    def output_path(self, clip: Path, work: Path) -> Path:
        return work / f"{clip.name}.{self.name.replace(' ', '-')}{self.output_suffix}"  # a.mp4, a.avi: apart


def mode_options(mode: str) -> tuple[str, list[str]]:
    """(--mode, the other `ffviz stabilize` options) of a bench mode: one of MODES, MPEG4_MODES or L1_MODES."""
    base, _, variant = mode.partition("-")
    options = {"": [], "mpeg4": ["--codec", "mpeg4"], "l1": ["--path", "l1"]}[variant]
    return base, options


def ffviz_command(clip: Path, output: Path, mode: str) -> list[str]:
    """``mode``: one of MODES, MPEG4_MODES or L1_MODES."""
    base, options = mode_options(mode)
    return [sys.executable, "-m", "ffviz.cli", "stabilize", str(clip), "-o", str(output), "--mode", base,
            "--overwrite", *options]


def ffviz_method(mode: str) -> Method:
    return Method(f"ffviz {mode.replace('-', ' ')}", ".mp4", lambda clip, out, work: [ffviz_command(clip, out, mode)])


# Peers encode as ffviz does (x264 CRF 18, one output frame per input frame at the input's timestamps).
_X264 = ["-fps_mode", "passthrough", "-c:v", "libx264", "-crf", "18", "-c:a", "copy"]


def _vidstab_passes(clip: Path, out: Path, work: Path) -> list[list[str]]:
    transforms = work / f"{clip.name}.trf"
    # format=yuv420p first: vidstabdetect aborts on yuvj444p input.
    return [["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf",
             f"format=yuv420p,vidstabdetect=result={transforms}", "-f", "null", "-"],
            ["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf",
             f"format=yuv420p,vidstabtransform=input={transforms},format=yuv420p", *_X264, str(out)]]


def _deshake_passes(clip: Path, out: Path, work: Path) -> list[list[str]]:
    return [["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf", "format=yuv420p,deshake", *_X264, str(out)]]


def _x264_passes(clip: Path, out: Path, work: Path) -> list[list[str]]:
    return [["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-vf", "format=yuv420p", *_X264, str(out)]]


def _opencv_passes(clip: Path, out: Path, work: Path) -> list[list[str]]:
    # One-pass stabilizer (-et=no), no trimming (-t=0): borders filled by consistent mosaicing, then
    # Telea inpainting, plus its deblurring: the sample's closest match to ffviz --mode full.
    # It writes XVID (FFmpeg's mpeg4) through cv::VideoWriter, hence .avi.
    return [[str(OPENCV_VIDEOSTAB), str(clip), f"-o={out}", "-q", "--mosaic=yes", "-ci=telea", "--deblur=yes",
             "-t=0", "-et=no"]]


def _ffmpeg_lists(kind: str, name: str) -> bool:
    """Whether the installed ffmpeg lists ``name`` among its ``kind`` ("filters", "encoders")."""
    if shutil.which("ffmpeg") is None:
        return False
    listing = subprocess.run(["ffmpeg", "-hide_banner", f"-{kind}"], capture_output=True, text=True).stdout
    return any(line.split()[1:2] == [name] for line in listing.splitlines())


def peer_methods(names: Sequence[str]) -> tuple[list[Method], list[str]]:
    """The peers that can run here, and a one-line note for each that cannot."""
    methods: list[Method] = []
    notes: list[str] = []
    for name in names:
        if name == "vidstab":
            if _ffmpeg_lists("filters", "vidstabdetect"):
                methods.append(Method("vidstab", ".mp4", _vidstab_passes))
            else:
                notes.append("vidstab skipped: no ffmpeg with vidstabdetect (apt-get install ffmpeg)")
        elif name == "deshake":
            if _ffmpeg_lists("filters", "deshake"):
                methods.append(Method("deshake", ".mp4", _deshake_passes))
            else:
                notes.append("deshake skipped: no ffmpeg with deshake (apt-get install ffmpeg)")
        elif name == "opencv":
            if os.access(OPENCV_VIDEOSTAB, os.X_OK):
                methods.append(Method("opencv", ".avi", _opencv_passes))
            else:
                notes.append(f"opencv skipped: {OPENCV_VIDEOSTAB} not built (run {BUILD_SCRIPT})")
        elif name == "x264":
            if _ffmpeg_lists("encoders", "libx264"):
                methods.append(Method(X264_ONLY, ".mp4", _x264_passes))
            else:
                notes.append("x264 skipped: no ffmpeg with libx264 (apt-get install ffmpeg)")
    return methods, notes


class MethodFailed(Exception):
    pass


def run_method(method: Method, clip: Path, output: Path, work: Path) -> ChildRun:
    """All passes of a method: seconds, CPU seconds and machine ticks summed, peak memory the largest of any pass."""
    output.unlink(missing_ok=True)  # a stale output must not pass for this run's
    seconds, cpu_seconds, peak, ticks = 0.0, 0.0, 0, (0, 0)
    for command in method.passes(clip, output, work):
        run = run_measured(command)
        seconds += run.seconds
        cpu_seconds += run.cpu_seconds
        peak = max(peak, run.peak_rss_bytes)
        ticks = add_ticks(ticks, run.machine_ticks)
        if run.returncode != 0:
            raise MethodFailed(f"exit {run.returncode}: {run.output_tail or '(no output)'}")
    if not output.is_file():
        raise MethodFailed(f"exit 0 but no output at {output}")
    return ChildRun(seconds=seconds, cpu_seconds=cpu_seconds, peak_rss_bytes=peak, returncode=0, output_tail="",
                    machine_ticks=ticks)
