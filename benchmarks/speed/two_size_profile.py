"""Benchmark: full mode's CPU a frame at two frame sizes, by stage and by call, fitted as a part fixed per frame plus
a part per pixel (issue 43: the per-frame cost that does not shrink with the frame).

The same content at both sizes, so that the fit is not a difference of content: the first --frames frames of --clip
(640x360) re-encoded as they are and upscaled to 1920x1080 (ffmpeg, Lanczos, x264 CRF 16 preset fast, as
speed_1080p.py makes its clip); --large-clip adds a real clip's first --frames frames at its own size as a check (its
content differs: it is reported, not fitted). Each clip runs full mode in this process on one worker with OpenCV's
threads off, under cProfile timed by this thread's CPU clock (as `ffviz bench --profile`, ffviz/bench/profile.py),
after an unmeasured run on the clip's first 8 frames (imports, numba's kernels for the clip's array layouts). A
stage's CPU: the chain's own per-frame timers (FrameResult.cpu_seconds: warp, completion, deblur, temporal) and
completion's parts as the cumulative CPU of the functions that make them; encode adds the process's CPU beyond this
thread's (x264's threads). The profiler costs about a microsecond a Python call, counted in the figures.

Fit: with P the frame's megapixels, ms a frame = fixed + per_mp * P from the two sizes; fixed is what a frame costs
whatever its size (work at a fixed working size, per neighbour and per call).

Then, at 640x360: each flow and local registration completion computes, by the pair of original frames it relates
(``PairTally``: how often the same pair is computed again in another target frame's coordinates), in a run of its own
without the profiler; and the start-up (``startup_table``): whole commands in fresh interpreters, measured from outside
as `ffviz bench` measures (ffviz/bench/measure.py), --repeat times, medians.

Usage: python -m benchmarks.speed.two_size_profile [--clip ../shared/videos/vplab_C.avi] [--frames 60]
       [--large-clip PATH] [--top 25] [--repeat 3] [--report docs/benchmarks-speed.md | --no-report]
"""

from __future__ import annotations

import cProfile
import pstats
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2

from benchmarks import common
from pipeline.runtime import memory

VIDEOS = common.VIDEOS
WARM_UP_FRAMES = 8


def _reencoded(clip: Path, frames: int, out: Path, size: tuple[int, int] | None = None) -> Path:
    """The first ``frames`` frames of ``clip`` (at ``size``, Lanczos; None: its own) as H.264 CRF 16."""
    scale = ["-vf", f"scale={size[0]}:{size[1]}:flags=lanczos"] if size else []
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(clip), "-frames:v", str(frames), "-an", *scale,
                    "-c:v", "libx264", "-crf", "16", "-preset", "fast", "-pix_fmt", "yuv420p", str(out)], check=True)
    return out


def _parts() -> list[tuple[str, tuple]]:
    """(label, functions whose cumulative CPU is that part) for the parts not timed by the chain itself. Within
    completion, in nesting order: a later part is not inside an earlier one."""
    from pipeline import chain
    from pipeline.runtime import video_reader, video_writer
    from pipeline.stages import background, candidates, completion, fallback, fmm, local_flow, local_warp, motion

    return [("decode", (video_reader.VideoReader.__iter__,)),
            ("motion", (motion.prepare, motion.estimate, background.LayerEvidence.push,
                        background.CameraChooser.push, background.CameraChooser.finish)),
            ("path", (chain.plan_path,)),
            ("registration (ECC per neighbour)", (completion.register_neighbours,)),
            ("samples at the missing pixels", (candidates.Evidence.__init__,)),
            ("mosaic (eqs. 20-22)", (completion._mosaic,)),
            ("neighbour priority (eq. 23)", (local_warp.priority,)),
            ("local flow (DIS + rescue)", (local_flow.local_flow,)),
            ("motion inpainting (FMM)", (fmm.inpaint_motion,)),
            ("fallback", (fallback.smooth_fill,)),
            ("encode (this thread)", (video_writer.VideoWriter.write, video_writer.VideoWriter.close))]


@dataclass
class SizeProfile:
    name: str
    width: int
    height: int
    frames: int
    stages_ms: dict[str, float]  # stage -> CPU ms a frame
    calls: dict[tuple, tuple[int, float, str]]  # function key -> (calls, tottime s, label)

    @property
    def megapixels(self) -> float:
        return self.width * self.height / 1e6


def _cumulative(stats: pstats.Stats, functions: tuple) -> float:
    keys = {(f.__code__.co_filename, f.__code__.co_firstlineno, f.__code__.co_name) for f in functions}
    return sum(entry[3] for key, entry in stats.stats.items() if key in keys)


def _label(key: tuple) -> str:
    filename, line, name = key
    if filename == "~":
        return name.replace("<", "").replace(">", "")
    parts = Path(filename).parts
    where = "/".join(parts[parts.index("pipeline"):]) if "pipeline" in parts else Path(filename).name
    return f"{where}:{line} {name}"


def _process_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _run(clip: Path, workdir: Path, profiled: bool):
    from ffviz.bench.profile import _StageTimes
    from pipeline.config import StabilizeConfig
    from pipeline.runtime.observer import Observers
    from pipeline.stabilize import stabilize

    times = _StageTimes()
    profile = cProfile.Profile(time.thread_time)
    threads_before = cv2.getNumThreads()
    cv2.setNumThreads(0)  # OpenCV's work on the calling thread, where it is attributed
    process_before, thread_before = _process_cpu(), time.thread_time()
    try:
        call = (lambda *a, **k: profile.runcall(stabilize, *a, **k)) if profiled else stabilize
        call(clip, workdir / "out.mp4", StabilizeConfig(mode="full"), observer=Observers(times), overwrite=True,
             workers=1)
    finally:
        cv2.setNumThreads(threads_before)
    return pstats.Stats(profile) if profiled else None, times, _process_cpu() - process_before, \
        time.thread_time() - thread_before


class PairTally:
    """Each flow and local registration a run computes, by the two original frames it relates: (kind, target t,
    frames a and b, this thread's CPU s). Installed by patching the functions that make them (module attributes,
    looked up at each call), for one run on one worker; ``restore`` undoes it."""

    def __init__(self) -> None:
        from pipeline import chain
        from pipeline.stages import candidates, completion, local_warp

        self.records: list[tuple[str, int, int, int, float]] = []
        self.t = -1
        self.offset = 0
        tally = self
        self._patched = [(chain.FrameChain, "__call__"), (local_warp, "neighbour_fill"),
                         (local_warp, "_flow_in_box"), (candidates.CarriedOn, "_candidate"),
                         (completion, "_registered")]
        self._originals = [getattr(owner, name) for owner, name in self._patched]
        frame_call, fill, flow_in_box, carried, registered = self._originals

        def timed(kind, a, b, call, *args, **kwargs):
            start = time.thread_time()
            result = call(*args, **kwargs)
            tally.records.append((kind, tally.t, a, b, time.thread_time() - start))
            return result

        def frame_call_(chain_self, window):
            tally.t = window.centre.index
            return frame_call(chain_self, window)

        def fill_(neighbour, *args, **kwargs):
            tally.offset = neighbour.offset
            return fill(neighbour, *args, **kwargs)

        chain.FrameChain.__call__ = frame_call_
        local_warp.neighbour_fill = fill_
        local_warp._flow_in_box = lambda *a, **k: timed("local warp (flow + FMM)", tally.t, tally.t + tally.offset,
                                                        flow_in_box, *a, **k)
        candidates.CarriedOn._candidate = lambda self_, contest, near, far, *a, **k: timed(
            "carried on (flow)", tally.t + near.offset, tally.t + far.offset, carried, self_, contest, near, far,
            *a, **k)
        completion._registered = lambda neighbour, *a, **k: timed(
            "registration (ECC)", tally.t, tally.t + neighbour.offset, registered, neighbour, *a, **k)

    def restore(self) -> None:
        for (owner, name), original in zip(self._patched, self._originals):
            setattr(owner, name, original)

    def table(self, frames: int) -> list[str]:
        """Per kind: calls and CPU ms a frame, and the CPU ms a frame spent on pairs of original frames that some
        other target frame relates too (by any kind of flow or registration, either way round): what computing each
        pair once could save at most, before the cost of carrying it into each target's coordinates."""
        targets_of: dict[frozenset, set[int]] = {}
        for _, t, a, b, _ in self.records:
            targets_of.setdefault(frozenset((a, b)), set()).add(t)
        lines = ["| kind | calls a frame | CPU ms a frame | distinct pairs a frame | CPU ms a frame on pairs another "
                 "target relates too |", "|---|---|---|---|---|"]
        for kind in dict.fromkeys(record[0] for record in self.records):
            mine = [r for r in self.records if r[0] == kind]
            shared = sum(cpu for _, t, a, b, cpu in mine if len(targets_of[frozenset((a, b))]) > 1)
            pairs = {frozenset((a, b)) for _, _, a, b, _ in mine}
            lines.append(f"| {kind} | {len(mine) / frames:.1f} | {1000 * sum(r[4] for r in mine) / frames:.1f} | "
                         f"{len(pairs) / frames:.1f} | {1000 * shared / frames:.1f} |")
        every_pair = {frozenset((a, b)) for _, _, a, b, _ in self.records}
        lines += ["", f"All kinds: {len(self.records) / frames:.1f} calls a frame on {len(every_pair) / frames:.1f} "
                  "distinct pairs of original frames a frame."]
        return lines


def profile_size(name: str, clip: Path, warm_up: Path, workdir: Path) -> SizeProfile:
    """Full mode's CPU a frame on ``clip`` by stage and by call, after an unmeasured run on ``warm_up``."""
    _run(warm_up, workdir, profiled=False)
    stats, times, process_cpu, thread_cpu = _run(clip, workdir, profiled=True)
    frames = max(times.frames, 1)
    seconds = {label: _cumulative(stats, functions) for label, functions in _parts()}
    completion_parts = [label for label, _ in _parts()][3:-1]
    completion = times.cpu.get("completion", 0.0)
    stages = {"decode": seconds["decode"], "motion": seconds["motion"], "path": seconds["path"],
              "warp (frame, neighbours)": times.cpu.get("warp", 0.0),
              **{label: seconds[label] for label in completion_parts},
              "candidates' sampling, errors, choice": max(completion - sum(seconds[p] for p in completion_parts), 0),
              "temporal consistency": times.cpu.get("temporal", 0.0),
              "deblur": times.cpu.get("deblur", 0.0),
              "encode (x264 threads + writer)": seconds["encode (this thread)"] + max(process_cpu - thread_cpu, 0.0)}
    stages["rest (orchestration, observers)"] = max(process_cpu - sum(stages.values()), 0.0)
    stages["total (process)"] = process_cpu
    height, width = cv2.VideoCapture(str(clip)).read()[1].shape[:2]
    calls = {key: (entry[1], entry[2], _label(key)) for key, entry in stats.stats.items()}
    return SizeProfile(name, width, height, frames, {k: 1000 * v / frames for k, v in stages.items()}, calls)


def _fit(small: float, large: float, p_small: float, p_large: float) -> tuple[float, float]:
    """(fixed ms, ms a megapixel) of the line through (p_small, small) and (p_large, large)."""
    per_mp = (large - small) / (p_large - p_small)
    return small - per_mp * p_small, per_mp


def stage_table(profiles: list[SizeProfile]) -> list[str]:
    small, large = profiles[0], profiles[1]
    header = ["stage", *(f"{p.name} ms" for p in profiles), "fixed ms", "ms a MP", "fixed share at 640x360"]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---|" * (len(header) - 1)]
    for stage in small.stages_ms:
        fixed, per_mp = _fit(small.stages_ms[stage], large.stages_ms[stage], small.megapixels, large.megapixels)
        share = fixed / small.stages_ms[stage] if small.stages_ms[stage] > 0 else 0.0
        lines.append(f"| {stage} | " + " | ".join(f"{p.stages_ms[stage]:.1f}" for p in profiles)
                     + f" | {fixed:.1f} | {per_mp:.1f} | {100 * min(max(share, 0.0), 1.0):.0f} % |")
    return lines


def call_table(profiles: list[SizeProfile], top: int) -> list[str]:
    """The ``top`` calls by own CPU a frame at the smaller size: calls a frame, own CPU ms a frame at each size,
    and the fit of the two sizes with the same content."""
    small, large = profiles[0], profiles[1]
    ranked = sorted(small.calls, key=lambda key: small.calls[key][1], reverse=True)[:top]
    lines = ["| call | calls a frame | " + " | ".join(f"{p.name} ms" for p in profiles)
             + " | us a call (640x360) | fixed ms | ms a MP |", "|---|---|" + "---|" * (len(profiles) + 3)]
    for key in ranked:
        calls, own, label = small.calls[key]
        at = [1000 * p.calls.get(key, (0, 0.0, ""))[1] / p.frames for p in profiles]
        fixed, per_mp = _fit(at[0], at[1], small.megapixels, large.megapixels)
        lines.append(f"| `{label}` | {calls / small.frames:.1f} | " + " | ".join(f"{ms:.1f}" for ms in at)
                     + f" | {1e6 * own / max(calls, 1):.0f} | {fixed:.1f} | {per_mp:.1f} |")
    return lines


# Start-up, each in a fresh interpreter: what a run pays before and besides its frames. _clip_round is one of the
# pipeline's numba kernels (already in numba's on-disk cache): its first call is numba's own start.
NUMBA_FIRST_CALL = ("import numpy as np; import ffviz.cli; from pipeline.runtime import colour; "
                    "colour._clip_round(np.zeros((2, 2, 3), np.float32))")


def startup_table(clip: Path, work: Path, repeat: int) -> list[str]:
    """CPU and wall s of the process tree (median of ``repeat``) for: Python alone, importing the CLI, that and
    numba's first call, and `ffviz stabilize` on ``clip`` (a few frames) in --mode none and full."""
    import statistics

    from ffviz.bench.measure import run_measured
    from ffviz.bench.methods import ffviz_command

    commands = {"Python alone": [sys.executable, "-c", "pass"],
                "import ffviz.cli": [sys.executable, "-c", "import ffviz.cli"],
                "import ffviz.cli + numba's first call (a cached kernel)": [sys.executable, "-c", NUMBA_FIRST_CALL],
                f"ffviz stabilize, {WARM_UP_FRAMES} frames, --mode none": ffviz_command(clip, work / "none.mp4", "none"),
                f"ffviz stabilize, {WARM_UP_FRAMES} frames, --mode full": ffviz_command(clip, work / "full.mp4", "full")}
    runs: dict[str, list] = {name: [] for name in commands}
    for name, command in commands.items():  # once unmeasured: numba's cache and the page cache warm
        run_measured(command, cwd=common.ROOT)
    for _ in range(repeat):
        for name, command in commands.items():
            runs[name].append(run_measured(command, cwd=common.ROOT))
    lines = ["| command | CPU s | wall s |", "|---|---|---|"]
    for name, measured in runs.items():
        lines.append(f"| {name} | {statistics.median(r.cpu_seconds for r in measured):.2f} | "
                     f"{statistics.median(r.seconds for r in measured):.2f} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    common.add_clip(parser, VIDEOS / "vplab_C.avi")
    common.add_frames(parser, 60)
    parser.add_argument("--large-clip", type=Path, default=None,
                        help="a real clip at its own size, reported beside the fitted pair (default: none)")
    parser.add_argument("--top", type=int, default=25, help="calls in the per-call table (default: %(default)s)")
    common.add_repeat(parser, 3)
    common.add_report(parser, common.SPEED_REPORT)
    args = parser.parse_args(argv)
    if not args.clip.is_file() or shutil.which("ffmpeg") is None:
        print(f"{args.clip} or ffmpeg not found: nothing measured")
        return 0
    memory.reuse_freed_memory()  # as `ffviz` does at its start (pipeline/runtime/memory.py)
    started = common.machine_line()
    with tempfile.TemporaryDirectory(prefix="ffviz-two-size-") as tmp:
        work = Path(tmp)
        inputs = [("640x360", args.clip, None), ("1920x1080", args.clip, (1920, 1080))]
        if args.large_clip is not None and args.large_clip.is_file():
            inputs.append((args.large_clip.stem, args.large_clip, None))
        profiles = []
        for name, clip, size in inputs:
            measured = _reencoded(clip, args.frames, work / f"{name}.mp4", size)
            warm_up = _reencoded(clip, WARM_UP_FRAMES, work / f"{name}.warm.mp4", size)
            profiles.append(profile_size(name, measured, warm_up, work))
            print(f"{name}: {profiles[-1].stages_ms['total (process)']:.0f} CPU ms a frame", flush=True)
        tally = PairTally()
        try:  # a run of its own, unprofiled: the profiler's cost would count in each call's CPU
            _run(work / "640x360.mp4", work, profiled=False)
        finally:
            tally.restore()
        startup = startup_table(work / "640x360.warm.mp4", work, args.repeat)
    names = ", ".join(f"{p.name} ({p.width}x{p.height})" for p in profiles)
    lines = ["## Full mode at two sizes: the part of a frame's CPU that does not shrink with the frame", "",
             f"Written by `benchmarks/speed/two_size_profile.py` ({started}): the first {args.frames} frames of "
             f"{args.clip.name} as they are and upscaled to 1920x1080 (the same content, the fit's two points)"
             + (f", and {profiles[2].name} at its own size (other content: not fitted)" if len(profiles) > 2 else "")
             + f"; full mode, one worker in process, OpenCV's threads off, under cProfile (its cost included). "
             "Fixed and ms a MP: ms a frame = fixed + ms a MP x the frame's megapixels, through the two sizes.",
             "", f"CPU ms a frame by stage ({names}):", "", *stage_table(profiles), "",
             f"The {args.top} calls with the most own CPU at 640x360 (own: without the calls they make):", "",
             *call_table(profiles, args.top), "",
             "The relations between two frames that completion computes at 640x360 (a run of its own, without the "
             "profiler; a pair is two original frames, either way round, whichever target frame's coordinates it "
             "was computed in):", "", *tally.table(profiles[0].frames), "",
             f"Start-up: whole commands in a fresh interpreter, CPU and wall s of the process tree (median of "
             f"{args.repeat}; ffviz/bench/measure.py), the {WARM_UP_FRAMES}-frame clip at 640x360:", "", *startup]
    common.publish("two-size-profile", lines, common.report_path(args), common.SPEED_HEADER)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
