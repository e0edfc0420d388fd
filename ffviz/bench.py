"""`ffviz bench`: ffviz's modes against peer stabilizers on the same clips: speed, peak memory, quality.

Every method runs as its own child process and is measured from outside: wall seconds, and peak
memory from the child's own rusage (os.wait4), so no method pays for the benchmark's Python, and the share
of the machine's CPU time that the hypervisor took meanwhile (steal, /proc/stat): on a virtual machine whose
host is busy, a program on both cores loses more than one on one core, so ratios between methods move with
it. Runs are interleaved: for each repeat, for each clip, the methods in an order rotated by one at every
visit, so a drift in the machine's load falls on all methods alike. Quality is pipeline.metrics.compare of
each output against its input, once per clip and method (outputs do not change between repeats).

Peers (skipped with a one-line note when absent): ffmpeg's two-pass vid.stab and one-pass deshake
(defaults), and OpenCV's videostab sample program built by benchmarks/peers/build_opencv_videostab.sh.
One reference that stabilizes nothing: "x264 only", ffmpeg decoding the clip and encoding it with the
x264 settings ffviz and the ffmpeg peers use, the cost every method writing H.264 pays whatever it does.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from pipeline.errors import ConfigError, FFVizError, InputError

REPO = Path(__file__).resolve().parents[1]
SHARED_VIDEOS = REPO.parent / "shared" / "videos"
OPENCV_VIDEOSTAB = REPO / ".cache" / "peers" / "videostab" / "videostab"  # where the build script puts it
BUILD_SCRIPT = "benchmarks/peers/build_opencv_videostab.sh"
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".m4v", ".webm")
MODES = ("full", "crop", "none")
# A mode with "-mpeg4" writes the OpenCV sample's codec (--codec mpeg4): its chain compared without x264's cost.
MPEG4_MODES = tuple(f"{mode}-mpeg4" for mode in MODES)
DEFAULT_MODES = (*MODES, "full-mpeg4")
PEERS = ("vidstab", "deshake", "opencv", "x264")
X264_ONLY = "x264 only"  # the reference row's method name
DEFAULT_OUT = Path("bench_out")  # git-ignored
DEMO_FRAMES = 120  # the synthetic clip used when no real clips are present (as `ffviz demo`)


# -- one measured child process ------------------------------------------------------------------------------

@dataclass(frozen=True)
class ChildRun:
    seconds: float  # wall clock
    cpu_seconds: float  # user + system, the command and the children it waited for
    peak_rss_bytes: int  # the largest resident set of the command (or of a child it waited for)
    returncode: int
    output_tail: str  # last non-empty line of its stderr (else stdout), for a one-line failure report
    # Clock ticks of the whole machine while it ran (all CPUs): (stolen by the hypervisor, all). None where
    # /proc/stat is not available.
    machine_ticks: tuple[int, int] | None = None

    @property
    def steal(self) -> float | None:
        """Share of the machine's CPU time the hypervisor took while the command ran."""
        return steal_share(self.machine_ticks)


# Linux keeps a process's peak RSS across exec, and at exec counts the pages it still shares with the
# parent it was forked from: a command forked straight from this process would report at least this
# process's own size (`true` forked from a 500 MB Python reads 511 MiB). So a small launcher (Python
# without site, ~6 MB) forks the command, waits for it with wait4 and reports the command's own rusage.
_LAUNCHER = """
import os, sys, time
report, argv = sys.argv[1], sys.argv[2:]
started = time.perf_counter()
pid = os.fork()
if pid == 0:
    try:
        os.execvp(argv[0], argv)
    except OSError as error:
        sys.stderr.write(f"cannot run {argv[0]}: {error.strerror}\\n")
    os._exit(127)
_, status, usage = os.wait4(pid, 0)
with open(report, "w") as f:
    f.write(f"{time.perf_counter() - started} {usage.ru_utime + usage.ru_stime} {usage.ru_maxrss}")
code = os.waitstatus_to_exitcode(status)
sys.exit(code if code >= 0 else 128 - code)
"""


def measured_argv(command: Sequence[str], report: Path) -> list[str]:
    """``command`` run under the measuring launcher, which writes "wall_s cpu_s peak_rss_kib" to ``report``
    and exits with the command's status (128 + N for signal N)."""
    return [sys.executable, "-I", "-S", "-c", _LAUNCHER, str(report), *command]


def read_measurement(report: Path) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds, peak RSS bytes) from a launcher's report."""
    seconds, cpu_seconds, max_rss_kib = report.read_text().split()
    return float(seconds), float(cpu_seconds), int(max_rss_kib) * 1024  # ru_maxrss is in KiB on Linux


def machine_ticks(stat: Path = Path("/proc/stat")) -> tuple[int, int] | None:
    """(steal, total) clock ticks of all CPUs since boot, from the "cpu" line of /proc/stat (Linux); None when it
    cannot be read. Total is user + nice + system + idle + iowait + irq + softirq + steal (guest time is already
    counted in user and nice)."""
    try:
        with stat.open() as f:
            fields = f.readline().split()
        ticks = [int(value) for value in fields[1:9]]
    except (OSError, ValueError):
        return None
    if not fields or fields[0] != "cpu" or len(ticks) < 8:
        return None
    return ticks[7], sum(ticks)


def ticks_between(before: tuple[int, int] | None, after: tuple[int, int] | None) -> tuple[int, int] | None:
    if before is None or after is None:
        return None
    return after[0] - before[0], after[1] - before[1]


def add_ticks(a: tuple[int, int] | None, b: tuple[int, int] | None) -> tuple[int, int] | None:
    return None if a is None or b is None else (a[0] + b[0], a[1] + b[1])


def steal_share(ticks: tuple[int, int] | None) -> float | None:
    """Stolen / all ticks; None when unknown or no tick elapsed."""
    if ticks is None or ticks[1] <= 0:
        return None
    return ticks[0] / ticks[1]


def run_measured(command: Sequence[str], *, cwd: Path | None = None) -> ChildRun:
    """Run a command to its end and measure it: wall and CPU seconds, and peak RSS from its wait4 rusage.

    stdout and stderr go to separate files: written to one file, a child's block-buffered stdout (any program
    whose stdout is not a terminal) lands after the error it wrote unbuffered to stderr, so "the last line"
    would depend on buffering. The one-line report is the last line of stderr, else of stdout."""
    with tempfile.TemporaryDirectory(prefix="ffviz-bench-") as tmp:
        report = Path(tmp) / "rusage"
        out_path, err_path = Path(tmp) / "stdout", Path(tmp) / "stderr"
        with out_path.open("wb") as out, err_path.open("wb") as err:  # files, not pipes: nobody reads meanwhile
            ticks_before = machine_ticks()
            # Own session: Ctrl-C reaches only this process, which then ends the launcher and command together.
            child = subprocess.Popen(measured_argv(command, report), stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                     cwd=cwd, start_new_session=True)
            try:
                returncode = child.wait()
            except BaseException:
                os.killpg(child.pid, signal.SIGKILL)
                child.wait()
                raise
            ticks = ticks_between(ticks_before, machine_ticks())
        stdout, stderr = (path.read_text("utf-8", "replace") for path in (out_path, err_path))
        if not report.is_file():  # the launcher itself failed
            raise RuntimeError(f"measuring launcher failed (exit {returncode}): {(stdout + stderr).strip()[-300:]}")
        seconds, cpu_seconds, peak = read_measurement(report)
    tail = _last_line(stderr) or _last_line(stdout)
    return ChildRun(seconds=seconds, cpu_seconds=cpu_seconds, peak_rss_bytes=peak, returncode=returncode,
                    output_tail=tail, machine_ticks=ticks)


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.replace("\r", "\n").splitlines() if line.strip()]
    return lines[-1] if lines else ""


# -- methods -------------------------------------------------------------------------------------------------

Passes = Callable[[Path, Path, Path], list[list[str]]]  # (input, output, work dir) -> commands, run in order


@dataclass(frozen=True)
class Method:
    name: str  # as in the table: "ffviz full", "vidstab", ...
    output_suffix: str
    passes: Passes

    def output_path(self, clip: Path, work: Path) -> Path:
        return work / f"{clip.name}.{self.name.replace(' ', '-')}{self.output_suffix}"  # a.mp4, a.avi: apart


def ffviz_command(clip: Path, output: Path, mode: str) -> list[str]:
    """``mode``: one of MODES, or of MPEG4_MODES."""
    mode, _, codec = mode.partition("-")
    return [sys.executable, "-m", "ffviz.cli", "stabilize", str(clip), "-o", str(output), "--mode", mode,
            "--overwrite", *(["--codec", codec] if codec else [])]


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


# -- rows ----------------------------------------------------------------------------------------------------

@dataclass
class Quality:
    jitter_px: float | None
    stab_T: float | None
    stab_R: float | None
    crop: float | None = None
    distort: float | None = None
    black: float | None = None


@dataclass
class BenchRow:
    clip: str
    method: str  # "input" for the input's own motion measures
    width: int
    height: int
    frames: int
    seconds_runs: list[float] = field(default_factory=list)
    cpu_seconds_runs: list[float] = field(default_factory=list)
    steal_runs: list[float] = field(default_factory=list)  # share of the machine's CPU time stolen, per run
    peak_rss_bytes: int | None = None  # the largest over repeats
    quality: Quality | None = None
    error: str = ""
    # What the method wrote: its video codec and the file's bitrate (kbit/s over its duration). Encoders cost
    # very different CPU: the OpenCV sample writes XVID (FFmpeg's mpeg4, ~3 ms a 640x360 frame), the others
    # x264 at CRF 18 (~38 ms).
    codec: str | None = None
    kbit_s: float | None = None

    @property
    def seconds(self) -> float | None:
        return statistics.median(self.seconds_runs) if self.seconds_runs else None

    @property
    def cpu_seconds(self) -> float | None:
        return statistics.median(self.cpu_seconds_runs) if self.cpu_seconds_runs else None

    @property
    def steal(self) -> float | None:
        return statistics.median(self.steal_runs) if self.steal_runs else None

    @property
    def fps(self) -> float | None:
        seconds = self.seconds
        return self.frames / seconds if seconds else None

    @property
    def peak_mib(self) -> float | None:
        return self.peak_rss_bytes / 2**20 if self.peak_rss_bytes is not None else None


def schedule(repeats: int, n_clips: int, n_methods: int) -> Iterator[tuple[int, int, list[int]]]:
    """(repeat, clip index, method order): each visit starts one method later than the previous visit."""
    visit = 0
    for repeat in range(repeats):
        for clip in range(n_clips):
            start = visit % n_methods
            yield repeat, clip, [(start + i) % n_methods for i in range(n_methods)]
            visit += 1


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None  # NaN (e.g. every pair failed) reads as "-"


def input_row(clip: Path) -> BenchRow:
    from pipeline import metrics
    from pipeline.video_io import probe_video

    info = probe_video(clip)
    own = metrics.video_motion_stats(clip)
    return BenchRow(clip.name, "input", info.width, info.height, own.n_frames,
                    quality=Quality(_finite(own.residual_jitter_px), _finite(own.stability_translation),
                                    _finite(own.stability_rotation)))


def describe_output(output: Path) -> tuple[str, float | None]:
    """(video codec, kbit/s of the whole file over its duration) of a written output."""
    from pipeline.video_io import probe_video

    info = probe_video(output)
    kbit_s = output.stat().st_size * 8 / 1000 / info.duration_s if info.duration_s > 0 else None
    return info.codec, kbit_s


def measure_quality(clip: Path, output: Path) -> Quality:
    from pipeline import metrics

    m = metrics.compare(clip, output)
    return Quality(*(_finite(v) for v in (m.residual_jitter_px, m.stability_translation, m.stability_rotation,
                                          m.cropping_ratio, m.distortion, m.black_fraction)))


# -- the command ---------------------------------------------------------------------------------------------

def add_parser(commands: Any) -> None:
    p = commands.add_parser("bench", help="benchmark ffviz's modes against peer stabilizers (speed, memory, quality)")
    p.add_argument("videos", type=Path, nargs="*", metavar="VIDEO",
                   help=f"clips or folders of clips (default: the clips in {SHARED_VIDEOS} if present, "
                        "else the synthetic demo clip)")
    p.add_argument("--modes", default=",".join(DEFAULT_MODES),
                   help="ffviz modes, comma-separated, or '' for peers only; MODE-mpeg4 writes MPEG-4 Part 2 "
                        "as the OpenCV sample does (default: %(default)s)")
    p.add_argument("--peers", default=",".join(PEERS),
                   help="peer methods, comma-separated, or none (default: %(default)s)")
    p.add_argument("--repeat", type=int, default=1, metavar="N", help="runs per clip and method; the table "
                   "reports the median seconds (default: %(default)s)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT,
                   help="folder for outputs and bench.md/csv/json/png (default: %(default)s)")


def _choices(text: str, allowed: Sequence[str], option: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in allowed]
    if unknown:
        raise ConfigError(f"{option}: unknown {', '.join(unknown)} (choose from {', '.join(allowed)})")
    return list(dict.fromkeys(names))


def _clips(paths: Sequence[Path], out: Path) -> list[Path]:
    if not paths:
        found = sorted(p for p in SHARED_VIDEOS.glob("*") if p.suffix.lower() in VIDEO_SUFFIXES)
        return found or [_synthetic_clip(out / "inputs")]
    clips: list[Path] = []
    for path in paths:
        if path.is_dir():
            clips += sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
        elif path.is_file():
            clips.append(path)
        else:
            raise InputError(f"input file not found: {path}")
    if not clips:
        raise InputError("no video files in " + ", ".join(map(str, paths)))
    names = [c.name for c in clips]
    if len(set(names)) < len(names):  # rows and output files are keyed by file name
        raise InputError("two clips share a file name: " + ", ".join(sorted({n for n in names if names.count(n) > 1})))
    return clips


def _synthetic_clip(folder: Path) -> Path:
    """The demo's synthetic clip (640x360, 120 frames, seed 0), generated once."""
    from pipeline import synthetic

    path = folder / f"synthetic_demo_{DEMO_FRAMES}.mp4"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        print(f"no real clips under {SHARED_VIDEOS}: generating the synthetic demo clip {path}", flush=True)
        temp = path.with_name(f".{path.name}.tmp.mp4")
        synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(n_frames=DEMO_FRAMES)), temp)
        temp.replace(path)
    return path


def cmd_bench(args: argparse.Namespace) -> int:
    from ffviz import bench_report as report

    modes = _choices(args.modes, MODES + MPEG4_MODES, "--modes")
    peers = [] if args.peers.strip() == "none" else _choices(args.peers, PEERS, "--peers")  # "none" is also a mode
    if args.repeat < 1:
        raise ConfigError(f"--repeat must be at least 1, not {args.repeat}")
    if not modes and not peers:
        raise ConfigError("nothing to run: --modes and --peers are both empty")
    out: Path = args.out
    clips = _clips(args.videos, out)  # before creating anything: a bad path fails with no trace
    work = out / "outputs"
    try:
        work.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"cannot create the output folder {work}: {error.strerror}") from None

    peer_list, notes = peer_methods(peers)
    methods = [ffviz_method(m) for m in modes] + peer_list
    for note in notes:
        print(f"ffviz bench: {note}", file=sys.stderr)
    load_before = os.getloadavg()
    print(report.HEADER, flush=True)

    inputs: dict[int, BenchRow | None] = {}
    rows: dict[tuple[int, str], BenchRow] = {}
    for repeat, c, order in schedule(args.repeat, len(clips), len(methods)):
        clip = clips[c]
        if c not in inputs:
            try:
                inputs[c] = input_row(clip)
            except FFVizError as error:
                print(f"ffviz bench: {clip.name}: cannot be read, skipped: {error}", file=sys.stderr)
                inputs[c] = None
            else:
                print(report.markdown_line(inputs[c]), flush=True)
        source = inputs[c]
        if source is None:
            continue
        for m in order:
            method = methods[m]
            row = rows.setdefault((c, method.name), BenchRow(clip.name, method.name, source.width, source.height,
                                                             source.frames))
            if row.error and not row.seconds_runs:
                continue  # it failed to run: do not retry every repeat
            output = method.output_path(clip, work)
            try:
                run = run_method(method, clip, output, work)
            except MethodFailed as error:
                row.error = str(error)
                print(f"ffviz bench: {clip.name}: {method.name} failed: {error}", file=sys.stderr, flush=True)
                if not row.seconds_runs or repeat == args.repeat - 1:
                    print(report.markdown_line(row), flush=True)
                continue
            row.seconds_runs.append(run.seconds)
            row.cpu_seconds_runs.append(run.cpu_seconds)
            if run.steal is not None:
                row.steal_runs.append(run.steal)
            row.peak_rss_bytes = max(row.peak_rss_bytes or 0, run.peak_rss_bytes)
            if row.quality is None and not row.error:
                try:
                    row.codec, row.kbit_s = describe_output(output)
                    row.quality = measure_quality(clip, output)
                except FFVizError as error:  # timing stands; the output cannot be compared
                    row.error = f"quality not measured: {error}"
                    print(f"ffviz bench: {clip.name}: {method.name}: {row.error}", file=sys.stderr, flush=True)
            if repeat == args.repeat - 1:
                print(report.markdown_line(row), flush=True)
            else:
                print(f"ffviz bench: repeat {repeat + 1}/{args.repeat}: {clip.name}: {method.name} "
                      f"{run.seconds:.2f} s", file=sys.stderr, flush=True)

    table = [r for c in range(len(clips)) if inputs.get(c) is not None
             for r in [inputs[c]] + [rows[(c, m.name)] for m in methods if (c, m.name) in rows]]
    run_info = report.RunInfo(repeat=args.repeat, cpus=os.cpu_count() or 0, load_before=load_before,
                              load_after=os.getloadavg(), notes=notes)
    paths = report.write_all(table, out, run_info)
    print()
    print("\n".join(report.targets(table)))
    print("\nresults: " + ", ".join(str(p) for p in paths))
    return 0
