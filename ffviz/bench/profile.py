"""`ffviz bench --profile`: CPU milliseconds a frame for each stage of a run, so the next bottleneck is visible.

Each clip and mode runs in this process on one worker (every stage on the calling thread; defaults) with
OpenCV's own threads off, under cProfile timed by this thread's CPU clock. A stage's CPU is the cumulative time
of the functions that make it up (both passes); the chain's own per-stage CPU (FrameResult.cpu_seconds) gives warp,
completion and deblurring. The encoder's threads are the process's CPU beyond this thread's, added to encode.
Recording is a second run with a full recording (.rrd): its extra CPU over a third, plain and unprofiled (at least
what the recorder counted), and by entity family what the recorder counted (its digests on the rendering thread, its own thread's encoding and logging); the rest of the extra
is the SDK's threads (batching, compression, writing) and what the run does differently. A short synthetic run comes
first, so that imports and numba's compilation stay out of the figures.
"""

from __future__ import annotations

import cProfile
import functools
import pstats
import resource
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2

from pipeline.runtime.observer import NullObserver

STAGES = ("decode", "motion", "smoothing", "warp", "mosaic", "flow", "FMM", "local warp", "deblur", "encode",
          "recording", "other")



def _functions() -> dict[str, tuple]:
    """stage -> the functions whose cumulative CPU on the main thread is that stage's (none calls another)."""
    from pipeline import chain
    from pipeline.runtime.encoding import Encoding
    from pipeline.runtime import video_reader, video_writer
    from pipeline.stages import background, completion, fmm, local_flow, mosaic, motion

    return {"decode": (video_reader.VideoReader.__iter__,),
            "motion": (motion.prepare, motion.estimate, background.LayerEvidence.push,
                        background.CameraChooser.push, background.CameraChooser.finish),
            "smoothing": (chain.plan_path,),
            "mosaic": tuple(f for f in (mosaic.mosaic_from_samples, getattr(completion, "register_neighbours", None))
                            if f is not None),  # with the neighbours' local registration where there is one
            "flow": (local_flow.local_flow,),
            "FMM": (fmm.inpaint_motion,),
            "encode": (video_writer.VideoWriter.write, video_writer.VideoWriter.close)}


@dataclass
class StageProfile:
    clip: str
    mode: str
    frames: int
    cpu_ms: dict[str, float] = field(default_factory=dict)  # stage -> CPU ms a frame
    total_cpu_s: float = 0.0  # the run without recording, every thread
    recording_ms: dict[str, float] = field(default_factory=dict)  # entity family -> the recorder's CPU ms a frame

    def line(self) -> str:
        return (f"| {self.clip} | {self.mode} | " + " | ".join(f"{self.cpu_ms.get(s, 0.0):.1f}" for s in STAGES)
                + f" | {1000 * self.total_cpu_s / max(self.frames, 1):.1f} |")


def table_header() -> str:
    return ("| clip | mode | " + " | ".join(STAGES) + " | total |\n|---|---|" + "---|" * (len(STAGES) + 1))


def recording_table(profiles: list[StageProfile]) -> str:
    """The recording's CPU ms a frame by entity family (costliest first), and the rest of its extra CPU."""
    totals: dict[str, float] = {}
    for profile in profiles:
        for name, ms in profile.recording_ms.items():
            totals[name] = totals.get(name, 0.0) + ms
    families = sorted(totals, key=totals.get, reverse=True)
    lines = ["| clip | mode | recording | " + " | ".join(families) + " | SDK threads and the rest |",
             "|---|---|---|" + "---|" * (len(families) + 1)]
    for profile in profiles:
        counted = sum(profile.recording_ms.values())
        total = profile.cpu_ms.get("recording", 0.0)
        lines.append(f"| {profile.clip} | {profile.mode} | {total:.1f} | "
                     + " | ".join(f"{profile.recording_ms.get(name, 0.0):.1f}" for name in families)
                     + f" | {max(total - counted, 0.0):.1f} |")
    return "\n".join(lines)


class _StageTimes(NullObserver):
    def __init__(self) -> None:
        self.cpu: dict[str, float] = {}
        self.frames = 0

    def on_frame(self, result) -> None:
        self.frames += 1
        for stage, seconds in result.cpu_seconds.items():
            self.cpu[stage] = self.cpu.get(stage, 0.0) + seconds


def _process_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _cumulative(stats: pstats.Stats, functions: tuple) -> float:
    keys = {(f.__code__.co_filename, f.__code__.co_firstlineno, f.__code__.co_name) for f in functions}
    return sum(entry[3] for key, entry in stats.stats.items() if key in keys)  # entry[3]: cumulative time


def _run(clip: Path, mode: str, workdir: Path, record: bool | None, codec: str):
    """(profile of this thread, stage times, process CPU s, this thread's CPU s, the recorder or None). ``record``:
    True records, False profiles, None does neither (the plain run the recorded one is compared with). A recorded
    run is not profiled: its digests run on this thread, and the profiler's cost would count as the recording's."""
    from pipeline.config import StabilizeConfig
    from pipeline.runtime.encoding import Encoding
    from pipeline.runtime import video_reader, video_writer
    from pipeline.runtime.observer import Observers
    from pipeline.stabilize import stabilize

    recorder = None
    if record:
        from ffviz.recorder import RerunRecorder

        recorder = RerunRecorder(workdir / f"{mode}.rrd", level="full", jpeg_quality=80)
    times = _StageTimes()
    profile = cProfile.Profile(time.thread_time)
    run = functools.partial(profile.runcall, stabilize) if record is False else stabilize
    threads_before = cv2.getNumThreads()
    cv2.setNumThreads(0)  # OpenCV's work on the calling thread, where it is attributed
    cpu_before, thread_before = _process_cpu(), time.thread_time()
    try:
        run(clip, workdir / f"{mode}.mp4", StabilizeConfig(mode=mode), observer=Observers(recorder, times),
            overwrite=True, encoding=Encoding(codec=codec), workers=1)
    finally:
        cv2.setNumThreads(threads_before)
    process_cpu, thread_cpu = _process_cpu() - cpu_before, time.thread_time() - thread_before
    return pstats.Stats(profile) if record is False else None, times, process_cpu, thread_cpu, recorder


def _warm_up(mode: str, workdir: Path, codec: str) -> None:
    """A run on a short synthetic clip first, so that imports and numba's compilation fall outside the figures."""
    from pipeline.evaluation import synthetic

    clip = workdir / "warm_up.mp4"
    if not clip.is_file():
        synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=16)), clip)
    _run(clip, mode, workdir, True, codec)


def profile_stages(clip: Path, mode: str, *, recording: bool = True, codec: str = "auto") -> StageProfile:
    """CPU ms a frame for each of STAGES on ``clip`` in ``mode``, the output written with ``codec``."""
    with tempfile.TemporaryDirectory() as tmp:
        _warm_up(mode, Path(tmp), codec)
        stats, times, process_cpu, thread_cpu, _ = _run(clip, mode, Path(tmp), False, codec)
        recorded = _run(clip, mode, Path(tmp), True, codec) if recording else None
        # The recording's cost is the recorded run's CPU beyond a plain run's measured the same way, unprofiled:
        # the profiler's own cost in the run above can exceed what a short clip's recording costs.
        plain_cpu = _run(clip, mode, Path(tmp), None, codec)[2] if recording else process_cpu
    recorded_cpu = recorded[2] if recorded is not None else process_cpu
    frames = max(times.frames, 1)
    seconds = {stage: _cumulative(stats, functions) for stage, functions in _functions().items()}
    seconds["encode"] += max(process_cpu - thread_cpu, 0.0)  # the encoder's own threads
    seconds["warp"] = times.cpu.get("warp", 0.0)
    seconds["deblur"] = times.cpu.get("deblur", 0.0)
    completion = times.cpu.get("completion", 0.0)
    seconds["local warp"] = max(completion - seconds["mosaic"] - seconds["flow"] - seconds["FMM"], 0.0)
    counted = sum(recorded[4].cpu_by_family.values()) if recorded is not None else 0.0
    seconds["recording"] = max(recorded_cpu - plain_cpu, counted) if recording else 0.0
    seconds["other"] = max(process_cpu - sum(v for k, v in seconds.items() if k != "recording"), 0.0)
    families = recorded[4].cpu_by_family if recorded is not None else {}
    return StageProfile(clip.name, mode, times.frames,
                        {stage: 1000 * seconds.get(stage, 0.0) / frames for stage in STAGES}, process_cpu,
                        {name: 1000 * cpu / frames for name, cpu in families.items()})
