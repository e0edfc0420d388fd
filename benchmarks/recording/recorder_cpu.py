"""What `--record full` costs in CPU per frame, and where it goes: the recorder alone, replaying a real run's results.

One full-mode run of the clip with the recorder attached gives the full recording's size per frame; its
results for frames FIRST..FIRST+N-1 (and every pass-1 and path event) are kept and handed again, R + 1 times (the
first a warm-up), to a recorder without its own thread, so that all the CPU time of the process in that span
(user + system, every thread: the SDK's writer too) is the recorder's. Each replay starts from the results as
the pipeline left them (the full-frame flow views the recorder asks for are made again). A profile of one more
replay splits the recorder's own thread's CPU time among H.264 encoding, PNG/JPEG encoding and the rest.
Writes its section of docs/benchmarks-recording.md (--no-report: print only).
Usage: python -m benchmarks.recording.recorder_cpu [--clip ../shared/videos/vplab_C.avi] [--first 200] [--frames 40]
       [--repeat 3] [--report docs/benchmarks-recording.md | --no-report]
"""

from __future__ import annotations

import cProfile
import os
import pstats
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")

import rerun as rr  # noqa: E402

from benchmarks import common  # noqa: E402
from ffviz.recorder import RerunRecorder  # noqa: E402
from ffviz.recording.encoders import H264_OPTIONS  # noqa: E402
from pipeline.runtime.observer import Observers  # noqa: E402
from pipeline.stabilize import StabilizeConfig, stabilize  # noqa: E402


class Keep:
    """Keeps the events a recorder receives: every one but on_frame's outside [first, first + frames)."""

    def __init__(self, first: int, frames: int) -> None:
        self.first, self.frames, self.events = first, frames, []

    def keep(self, result):
        return result  # every intermediate, so that a replaying recorder makes its own digest of each frame

    def __getattr__(self, name: str):
        if not name.startswith("on_"):
            raise AttributeError(name)

        def keep(*args) -> None:
            if name == "on_frame" and not self.first <= args[0].stamp.index < self.first + self.frames:
                return
            if name != "on_finish":
                self.events.append((name, args))
        return keep


def fresh(events: list) -> None:
    """Drop the full-frame flow views a replay made (NeighbourFill caches them on first use)."""
    for name, args in events:
        if name == "on_frame" and args[0].completion is not None:
            for fill in args[0].completion.fills:
                fill.__dict__.pop("_full_frame_views", None)


def replay(events: list, folder: Path, profile: cProfile.Profile | None = None) -> float:
    """CPU seconds of the process while a recorder records ``events`` (frames and the close)."""
    fresh(events)
    recorder = RerunRecorder(folder / "replay.rrd", level="full", threaded=False)
    cpu = 0.0
    for name, args in events:
        if name != "on_frame":
            getattr(recorder, name)(*args)
            continue
        if profile is not None:
            profile.enable()
        started = time.process_time()
        recorder.on_frame(*args)
        cpu += time.process_time() - started
        if profile is not None:
            profile.disable()
    started = time.process_time()
    recorder.close()
    return cpu + time.process_time() - started


def split(profile: cProfile.Profile, frames: int) -> dict[str, float]:
    """Thread CPU ms a frame: H.264 encoding, image encoding (PNG, JPEG), everything else."""
    stats = pstats.Stats(profile).stats
    total = sum(tottime for (_, _, _), (_, _, tottime, _, _) in stats.items())
    parts = {"H.264 encoding": 0.0, "PNG/JPEG encoding": 0.0}
    for (_, _, name), (_, _, tottime, _, _) in stats.items():
        if "'encode' of 'av.codec.context.CodecContext'" in name:
            parts["H.264 encoding"] += tottime
        elif name == "<built-in method cv2.imencode>" or name.endswith("imencode>") or name == "{imencode}":
            parts["PNG/JPEG encoding"] += tottime
    parts["the rest (flow views, colour maps, the SDK's logging, ...)"] = total - sum(parts.values())
    return {k: v * 1000 / frames for k, v in parts.items()}


def main() -> None:
    parser = common.parser(__doc__)
    common.add_clip(parser, common.VIDEOS / "vplab_C.avi")
    parser.add_argument("--first", type=int, default=200, help="the first frame replayed (default: %(default)s)")
    common.add_frames(parser, 40, "frames replayed")
    common.add_repeat(parser, 3, "--repeats")
    common.add_report(parser, common.RECORDING_REPORT)
    args = parser.parse_args()
    if not args.clip.is_file():
        raise SystemExit(f"{args.clip}: no such clip")
    lines = [f"## recorder_cpu.py: `--record full` CPU per frame, {args.clip.name} frames {args.first}-"
             f"{args.first + args.frames - 1}", "",
             common.machine_line() + f"; rerun-sdk {rr.__version__}, x264 preset "
             f"{H264_OPTIONS['preset']}", ""]
    with tempfile.TemporaryDirectory(prefix="ffviz-recorder-cpu-") as tmp:
        folder = Path(tmp)
        keep = Keep(args.first, args.frames)
        recorder = RerunRecorder(folder / "full.rrd", level="full")
        report = stabilize(args.clip, None, StabilizeConfig(mode="full"), observer=Observers(recorder, keep))
        size = (folder / "full.rrd").stat().st_size
        frames = sum(1 for name, _ in keep.events if name == "on_frame")
        replay(keep.events, folder)  # warm-up
        runs = [replay(keep.events, folder) * 1000 / frames for _ in range(args.repeat)]
        profile = cProfile.Profile(time.thread_time)
        replay(keep.events, folder, profile)
    lines += [f"- full recording of all {report.n_frames} frames: {size / 1e6:.1f} MB, "
              f"{size / 1e6 / report.n_frames:.3f} MB a frame",
              f"- recorder CPU, {frames} frames replayed: median {statistics.median(runs):.1f} ms a frame "
              f"(runs: {', '.join(f'{r:.1f}' for r in runs)})",
              "- of which, on the recorder's thread (one profiled replay; the profiler adds its own cost):"]
    lines += [f"  - {part}: {ms:.1f} ms a frame" for part, ms in split(profile, frames).items()]
    common.publish("recorder_cpu", lines, common.report_path(args), common.RECORDING_HEADER)


if __name__ == "__main__":
    main()
