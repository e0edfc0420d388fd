"""The results of `ffviz bench`: the rows (BenchRow, which ffviz/bench/command.py fills in while it measures), the
Markdown table, bench.md/csv/json, the plot and the targets block, and the dated report (docs/benchmarks.md in a
source checkout) that says on what machine and versions they were measured. Imports nothing else of the bench: the
command imports the rows from here."""

from __future__ import annotations

import csv
import datetime
import json
import os
import platform
import re
import shutil
import statistics
import subprocess
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Callable, Sequence

X264_ONLY = "x264 only"  # the reference row's method name


# -- rows: what bench measures, what the report shows --------------------------------------------------------

@dataclass
class Quality:
    jitter_px: float | None
    stab_T: float | None
    stab_R: float | None
    crop: float | None = None
    distort: float | None = None
    black: float | None = None
    flicker: float | None = None  # synth_flicker_ratio: change of synthesized pixels over that of real ones


@dataclass
class BenchRow:
    """One line of the table: a method's runs on a clip (medians over the repeats), or the clip's own measures."""

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


# (column, value of a row, format); None prints as "-".
COLUMNS: tuple[tuple[str, Callable[[BenchRow], object], str], ...] = (
    ("clip", lambda r: r.clip, "{}"),
    ("method", lambda r: r.method, "{}"),
    ("size", lambda r: f"{r.width}x{r.height}", "{}"),
    ("frames", lambda r: r.frames, "{}"),
    ("seconds", lambda r: r.seconds, "{:.2f}"),
    ("fps", lambda r: r.fps, "{:.2f}"),
    ("cpu_s", lambda r: r.cpu_seconds, "{:.2f}"),
    ("steal_pct", lambda r: None if r.steal is None else 100 * r.steal, "{:.0f}"),
    ("peak_MiB", lambda r: r.peak_mib, "{:.0f}"),
    ("codec", lambda r: r.codec, "{}"),
    ("kbit_s", lambda r: r.kbit_s, "{:.0f}"),
    ("jitter_px", lambda r: r.quality and r.quality.jitter_px, "{:.3f}"),
    ("stab_T", lambda r: r.quality and r.quality.stab_T, "{:.3f}"),
    ("stab_R", lambda r: r.quality and r.quality.stab_R, "{:.3f}"),
    ("crop", lambda r: r.quality and r.quality.crop, "{:.3f}"),
    ("distort", lambda r: r.quality and r.quality.distort, "{:.3f}"),
    ("black", lambda r: r.quality and r.quality.black, "{:.4f}"),
    ("flicker", lambda r: r.quality and r.quality.flicker, "{:.2f}"),
    ("note", lambda r: r.error or None, "{}"),
)
HEADER = ("| " + " | ".join(name for name, _, _ in COLUMNS) + " |\n"
          + "|" + "---|" * len(COLUMNS))


@dataclass(frozen=True)
class RunInfo:
    repeat: int
    cpus: int
    load_before: tuple[float, float, float]
    load_after: tuple[float, float, float]
    notes: list[str] = field(default_factory=list)


def _cell(value: object, fmt: str) -> str:
    if value is None or value == "":
        return "-"
    return fmt.format(value).replace("|", "/")  # a note must not split the Markdown row


def markdown_line(row: BenchRow) -> str:
    return "| " + " | ".join(_cell(get(row), fmt) for _, get, fmt in COLUMNS) + " |"


def _flat(row: BenchRow) -> dict:
    return {name: get(row) for name, get, _ in COLUMNS}


def write_all(rows: Sequence[BenchRow], out: Path, run: RunInfo) -> list[Path]:
    """bench.md, bench.csv, bench.json and bench.png in out; returns their paths."""
    md, table_csv, table_json, png = (out / f"bench.{ext}" for ext in ("md", "csv", "json", "png"))
    seconds_note = f"median seconds of {run.repeat} runs" if run.repeat > 1 else "seconds of one run"
    md.write_text("\n".join([
        HEADER, *map(markdown_line, rows), "",
        f"{seconds_note}; fps = input frames / seconds; cpu_s = user + system seconds; "
        "steal_pct = share of the machine's CPU time the hypervisor took during the run (median); "
        "peak_MiB = the method's peak RSS (wait4); codec, kbit_s = what it wrote (file size over duration); "
        "quality from pipeline.evaluation.metrics.compare against the input; flicker = frame-to-frame change of the "
        "synthesized pixels over that of the real ones (synth_flicker_ratio; - without synthesized pixels).",
        f"{run.cpus} CPUs; load average {run.load_before[0]:.1f} at the start, {run.load_after[0]:.1f} at the end.",
        *run.notes, "", *targets(rows), ""]))
    with table_csv.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=[name for name, _, _ in COLUMNS])
        writer.writeheader()
        writer.writerows(_flat(r) for r in rows)
    table_json.write_text(json.dumps({
        "run": asdict(run),
        "machine": machine_info(),
        "rows": [{**_flat(r), "seconds_runs": r.seconds_runs, "cpu_seconds_runs": r.cpu_seconds_runs,
                  "steal_runs": r.steal_runs,
                  "peak_rss_bytes": r.peak_rss_bytes} for r in rows],
    }, indent=2))
    plot(rows, png)
    return [md, table_csv, table_json, png]


# -- the report ----------------------------------------------------------------------------------------------

PACKAGES = ("ffviz", "numpy", "scipy", "opencv-python-headless", "av", "numba", "rerun-sdk", "scikit-image")


def cpu_model(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The CPU's model name (Linux /proc/cpuinfo), else what platform knows."""
    try:
        for line in cpuinfo.read_text().splitlines():
            if line.lower().startswith("model name") and ":" in line:
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def machine_info() -> dict[str, str]:
    """What the figures depend on besides the code: CPU, cores, memory, OS, Python and the key packages."""
    info = {"cpu": cpu_model(), "cores": str(os.cpu_count() or "?"), "os": platform.platform(),
            "python": platform.python_version()}
    try:
        pages, page_size = os.sysconf("SC_PHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
        info["memory"] = f"{pages * page_size / 2**30:.1f} GiB"
    except (ValueError, OSError, AttributeError):
        pass
    for name in PACKAGES:
        try:
            info[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            info[name] = "not installed"
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg:
        try:
            first = subprocess.run([ffmpeg, "-version"], capture_output=True, text=True, timeout=10).stdout
            info["ffmpeg (peers)"] = first.split("\n", 1)[0].removeprefix("ffmpeg version ").split(" Copyright")[0]
        except (OSError, subprocess.SubprocessError):
            pass
    return info


def write_report(rows: Sequence[BenchRow], path: Path, run: RunInfo, *, clips: Sequence[Path] = (),
                 now: datetime.datetime | None = None) -> list[Path]:
    """The dated Markdown report at ``path`` and its plot beside it (same name, .png); returns both paths."""
    now = now or datetime.datetime.now().astimezone()
    path.parent.mkdir(parents=True, exist_ok=True)
    png = path.with_suffix(".png")
    plot(rows, png)
    machine = machine_info()
    seconds_note = f"median seconds of {run.repeat} runs" if run.repeat > 1 else "seconds of one run"
    lines = [
        "# Benchmarks",
        "",
        f"Written by `ffviz bench` on {now:%Y-%m-%d %H:%M %Z}; every run of `./run bench` (or `ffviz bench`) "
        "replaces this file but for the sections at its end that start with a `<!-- section: NAME -->` marker. How "
        "the benchmark measures: [benchmarking.md](benchmarking.md); earlier measured figures: "
        "[benchmarks-history.md](benchmarks-history.md).",
        "",
        "## Machine",
        "",
        "| | |",
        "|---|---|",
        *(f"| {key} | {value} |" for key, value in machine.items()),
        f"| load average | {run.load_before[0]:.1f} at the start, {run.load_after[0]:.1f} at the end |",
        "",
        "## Results",
        "",
        f"Clips: {', '.join(c.name for c in clips) or '-'}. {seconds_note.capitalize()} per clip and method.",
        "",
        HEADER, *map(markdown_line, rows), "",
        "fps = input frames / seconds; cpu_s = user + system seconds; steal_pct = share of the machine's CPU time "
        "the hypervisor took during the run (median); peak_MiB = the method's peak RSS (wait4); codec, kbit_s = what "
        "it wrote (file size over duration); quality from pipeline.evaluation.metrics.compare against the input.",
        *(f"- {note}" for note in run.notes),
        "",
        f"![speed against steadiness, frames/s and peak memory]({png.name})",
        "",
        "## Targets",
        "",
        "```",
        *targets(rows),
        "```",
        "",
    ]
    path.write_text("\n".join(lines) + kept_sections(path))
    return [path, png]


SECTION_MARKER = re.compile(r"^<!-- section: ", re.M)  # a line that starts a section written by hand


def kept_sections(path: Path) -> str:
    """What a rewrite of the report at ``path`` keeps at its end: the old file from the first line that starts
    with a ``<!-- section: NAME -->`` marker on (the decision log's figures, written by hand); "" when none does."""
    found = SECTION_MARKER.search(path.read_text()) if path.is_file() else None
    return "" if found is None else "\n" + found.string[found.start():].rstrip() + "\n"


# -- targets -------------------------------------------------------------------------------------------------

def _by_clip(rows: Sequence[BenchRow]) -> dict[str, dict[str, BenchRow]]:
    grouped: dict[str, dict[str, BenchRow]] = {}
    for row in rows:
        grouped.setdefault(row.clip, {})[row.method] = row
    return grouped


def _seconds(row: BenchRow) -> str:
    cpu = f" / {row.cpu_seconds:.2f}" if row.cpu_seconds is not None else " / -"
    return f"{row.seconds:.2f}{cpu} s"


def _compared(ours: BenchRow | None, peer: BenchRow | None, ours_name: str, peer_name: str,
              wall_bound: float | None, cpu_bound: float | None) -> str:
    """One clip's line of a target: both methods' wall / CPU seconds, ours over the peer's, and the verdict
    (each ratio at most its bound; None: not judged)."""
    missing = [name for name, row in ((ours_name, ours), (peer_name, peer)) if row is None or not row.seconds]
    if missing:
        return f"{ours_name} vs {peer_name}: n/a ({', '.join(missing)} not measured)"
    parts, met, unmeasured = [], True, []
    for label, a, b, bound in (("wall", ours.seconds, peer.seconds, wall_bound),
                               ("CPU", ours.cpu_seconds, peer.cpu_seconds, cpu_bound)):
        if a is None or not b:
            if bound is not None:
                unmeasured.append(label)  # a bound with nothing to hold it against: no verdict
            continue
        parts.append(f"{label} {a / b:.2f}x")
        if bound is not None:
            met = met and a / b <= bound
    if unmeasured:
        verdict = f" (not judged: {' and '.join(unmeasured)} not measured)"
    elif wall_bound is not None or cpu_bound is not None:
        verdict = f" ({'met' if met else 'not met'})"
    else:
        verdict = ""
    return f"{ours_name} {_seconds(ours)} vs {peer_name} {_seconds(peer)}: {', '.join(parts)}{verdict}"


HD_ROWS = 1080
HD_CPU_BOUND = 2.0  # target 4: full mode's CPU seconds a frame over the plain x264 transcode's at 1080p


def targets(rows: Sequence[BenchRow]) -> list[str]:
    """The speed targets (issue 24) read off the table, in wall and CPU seconds (medians of the runs): 1. none and
    crop wall <= vid.stab's; 2. full at 640x360 wall <= the OpenCV sample's and CPU <= 1.3x its; 4. full at 1080p
    CPU a frame <= 2x the x264-only transcode's. Target 3 (--quality fast) needs ground truth:
    benchmarks/speed/fast_preset.py. Peers and ffviz write x264 at CRF 18 (the sample: XVID; the full-mpeg4 row
    compares it at its own codec, unjudged)."""
    lines = ["speed targets read off this table (wall / CPU seconds; ratio = ffviz / peer; printed, never asserted):"]
    grouped = _by_clip(rows)
    # (title, which clips it applies to by their input row (None: not read off this table), what to say without
    # one, (ffviz method, peer, wall bound, CPU bound) each, a bound None: not judged)
    sections = (
        ("1. none and crop: wall <= vid.stab's", lambda r: True, "no clip in this run",
         (("ffviz none", "vidstab", 1.0, None), ("ffviz crop", "vidstab", 1.0, None))),
        ("2. full at 640x360: wall <= the OpenCV sample's, CPU <= 1.3x its",
         lambda r: (r.width, r.height) == (640, 360), "no 640x360 clip in this run",
         (("ffviz full", "opencv", 1.0, 1.3), ("ffviz full mpeg4", "opencv", None, None))),
        ("3. --quality fast: judged on ground truth by benchmarks/speed/fast_preset.py (docs/benchmarks-speed.md)",
         None, "", ()),
        (f"4. full at 1080p: CPU a frame <= {HD_CPU_BOUND:g}x the x264-only transcode's",
         lambda r: r.height >= HD_ROWS, f"no clip of {HD_ROWS}+ rows in this run",
         (("ffviz full", X264_ONLY, None, HD_CPU_BOUND),)),
    )
    for title, applies, none_text, comparisons in sections:
        if applies is None:
            lines.append(f"  {title}")
            continue
        lines.append(f"  {title}:")
        clips = [(clip, methods) for clip, methods in grouped.items()
                 if "input" in methods and applies(methods["input"])]
        if not clips:
            lines.append(f"    {none_text}")
        for clip, methods in clips:
            for ours, peer, wall_bound, cpu_bound in comparisons:
                if ours not in methods and ours.endswith("mpeg4"):
                    continue  # the unjudged same-codec row is optional
                text = _compared(methods.get(ours), methods.get(peer), ours, peer, wall_bound, cpu_bound)
                lines.append(f"    {clip}: {text}")
    return lines + _stolen(rows) + _encoder_floor(grouped)


STEAL_NOTE = 0.05  # above this share of stolen CPU time a row's speed is flagged


def _stolen(rows: Sequence[BenchRow]) -> list[str]:
    """A warning naming the rows that ran while the hypervisor took a noticeable share of the machine."""
    flagged = [f"{row.clip} {row.method} {100 * row.steal:.0f} %" for row in rows
               if row.steal is not None and row.steal > STEAL_NOTE]
    if not flagged:
        return []
    return [f"  steal above {100 * STEAL_NOTE:.0f} % of the machine's CPU time during: {', '.join(flagged)}; "
            "it slows a program running on every core more than one on fewer, so read those ratios with care"]


def _encoder_floor(grouped: dict[str, dict[str, BenchRow]]) -> list[str]:
    """What the encoder alone costs, as a share of the methods' times (those that write H.264 like it)."""
    lines = []
    for clip, methods in grouped.items():
        floor = methods.get(X264_ONLY)
        if floor is None or not floor.seconds:
            continue
        shares = [f"{100 * floor.seconds / methods[name].seconds:.0f} % of {name}'s"
                  for name in ("vidstab", "ffviz none", "ffviz crop", "ffviz full")
                  if name in methods and methods[name].seconds]
        lines.append(f"  {clip}: {X264_ONLY} {floor.seconds:.2f} s" + (" = " + ", ".join(shares) if shares else ""))
    if lines:
        lines.insert(0, f"encoder floor ({X264_ONLY}: ffmpeg decoding and encoding with the same x264 settings, "
                        "nothing stabilized):")
    return lines


# -- plot ----------------------------------------------------------------------------------------------------

def plot(rows: Sequence[BenchRow], path: Path) -> None:
    """Left: speed against steadiness per clip; right: median frames/s and peak memory per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    input_jitter = {r.clip: r.quality.jitter_px for r in rows
                    if r.method == "input" and r.quality and r.quality.jitter_px}
    methods = list(dict.fromkeys(r.method for r in rows if r.method != "input"))
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    fig, (scatter, fps_bars, mem_bars) = plt.subplots(1, 3, figsize=(17, 5.2),
                                                      gridspec_kw={"width_ratios": [1.4, 1, 1]})
    for method in methods:
        points = [(r.fps, r.quality.jitter_px / input_jitter[r.clip]) for r in rows
                  if r.method == method and r.fps and r.quality and r.quality.jitter_px is not None
                  and r.clip in input_jitter]
        if points:
            xs, ys = zip(*points)
            scatter.scatter(xs, ys, s=40, color=colours[method], label=method, alpha=0.85)
    scatter.axhline(1.0, color="grey", linestyle="--", linewidth=1, label="input (1.0)")
    scatter.set_xscale("log")
    plain = matplotlib.ticker.FuncFormatter(lambda value, _: f"{value:g}")  # 20, not 2x10^1
    scatter.xaxis.set_major_formatter(plain)
    scatter.xaxis.set_minor_formatter(plain)
    scatter.set_xlabel("frames/s (log scale; right is faster)")
    scatter.set_ylabel("residual jitter, output / input (lower is steadier)")
    scatter.set_title("speed vs steadiness, one point per clip")
    scatter.grid(True, which="both", alpha=0.3)
    scatter.legend(fontsize=8)

    for axis, value, title, fmt in ((fps_bars, lambda r: r.fps, "frames/s (median over clips)", "{:.1f}"),
                                    (mem_bars, lambda r: r.peak_mib, "peak memory, MiB (median over clips)", "{:.0f}")):
        medians = []
        for method in methods:
            values = [value(r) for r in rows if r.method == method and value(r) is not None]
            medians.append(statistics.median(values) if values else 0.0)
        bars = axis.bar(range(len(methods)), medians, color=[colours[m] for m in methods])
        axis.bar_label(bars, labels=[fmt.format(v) for v in medians], fontsize=8)
        axis.set_xticks(range(len(methods)), methods, rotation=30, ha="right")
        axis.set_title(title)
        axis.grid(True, axis="y", alpha=0.3)
    clips = len(input_jitter)
    fig.suptitle(f"ffviz bench: {clips} clip{'s' if clips != 1 else ''}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
