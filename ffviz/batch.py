"""`ffviz batch`: many videos (or one long video in segments) on Ray, locally or on a cluster.

One Ray task per video; Ray schedules them. A video's failure is that video's result, not the batch's.
Outputs are written atomically by the workers (temp file renamed at the end) and a marker beside them
records what made them, so a re-run skips the videos already done with the same settings.
Ray is an optional extra (`pip install ffviz[ray]`): it is imported only here, only when a batch runs.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from ffviz.recording.view import RECORD_SIZE
from pipeline.runtime.encoding import Encoding
from pipeline.runtime import memory
from pipeline import segments
from pipeline import stabilize as stab
from pipeline.errors import ConfigError, FFVizError, InputError
from pipeline.results import FrameResult
from pipeline.runtime.observer import NullObserver, Observers

VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".m4v", ".webm", ".mts", ".mpg", ".mpeg")
MARKERS = ".ffviz-batch"  # folder in OUTDIR: one JSON marker per finished output


@dataclass(frozen=True)
class VideoJob:
    input: Path
    output: Path
    config: stab.StabilizeConfig
    encoding: Encoding = Encoding()
    rrd: Path | None = None
    record_level: str = "summary"
    jpeg_quality: int | None = 80
    record_size: int | None = RECORD_SIZE  # the recorded pictures' long side; None: the input's size

    def settings(self) -> str:
        """What the output depends on besides the input file (compared on re-runs)."""
        return repr((self.config, self.encoding))


@dataclass
class VideoResult:
    input: Path
    output: Path
    status: str  # done | skipped | failed
    n_frames: int = 0
    seconds: float = 0.0
    message: str = ""
    exit_code: int = 0
    frame_digests: tuple[str, ...] = ()  # blake2b of each output frame before encoding (compare runs cheaply)


class FrameDigests(NullObserver):
    def __init__(self) -> None:
        self.digests: list[str] = []

    def on_frame(self, result: FrameResult) -> None:
        self.digests.append(frame_digest(result.output))


def frame_digest(rgb: Any) -> str:
    return hashlib.blake2b(rgb.tobytes(), digest_size=8).hexdigest() + f"/{'x'.join(map(str, rgb.shape))}"


# -- inputs, outputs, markers -------------------------------------------------------------------------------

def expand_inputs(paths: Sequence[Path]) -> list[Path]:
    """Files as given; folders give their video files (by suffix, recursively, sorted)."""
    found: list[Path] = []
    for path in paths:
        if path.is_dir():
            found += sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
        else:
            found.append(path)  # a missing or bad file is that video's failure, reported with the others
    if not found:
        raise InputError("no input videos (folders are searched for " + ", ".join(VIDEO_SUFFIXES) + ")")
    return found


def output_paths(inputs: Sequence[Path], outdir: Path) -> list[Path]:
    outputs = [outdir / f"{p.stem}.mp4" for p in inputs]
    seen: dict[Path, Path] = {}
    for source, output in zip(inputs, outputs):
        if output in seen:
            raise ConfigError(f"{seen[output]} and {source} would both be written to {output}: rename one")
        seen[output] = source
    return outputs


def _marker_path(job: VideoJob) -> Path:
    return job.output.parent / MARKERS / f"{job.output.name}.json"


def _marker(job: VideoJob) -> dict[str, Any]:
    stat = job.input.stat()
    return {"input": str(job.input.resolve()), "size": stat.st_size, "mtime_ns": stat.st_mtime_ns,
            "settings": job.settings()}


def is_complete(job: VideoJob) -> bool:
    """The output exists and was made from this very input with these settings."""
    try:
        return job.output.is_file() and json.loads(_marker_path(job).read_text()) == _marker(job)
    except (OSError, ValueError):
        return False


def _write_marker(job: VideoJob) -> None:
    marker = _marker_path(job)
    marker.parent.mkdir(exist_ok=True)
    marker.write_text(json.dumps(_marker(job)))


# -- one video (runs in a Ray worker) -----------------------------------------------------------------------

def _recorder(job: VideoJob):
    if job.rrd is None:
        return None
    from ffviz.recorder import RerunRecorder

    return RerunRecorder(job.rrd, level=job.record_level, jpeg_quality=job.jpeg_quality, record_size=job.record_size)


def stabilize_one(job: VideoJob, segment_frames: int = 0, mapper: segments.Mapper | None = None) -> VideoResult:
    """Stabilize one video; every failure becomes a failed result (a batch never stops for one video)."""
    digests = FrameDigests()
    recorder = None
    started = time.perf_counter()
    try:
        recorder = _recorder(job)
        observer = Observers(recorder, digests)
        if segment_frames:
            report = segments.run(job.input, job.output, job.config, segment_frames=segment_frames,
                                  mapper=mapper or segments.serial_map, observer=observer, overwrite=True,
                                  encoding=job.encoding)
        else:
            # One core per Ray task (num_cpus=1): the task's frames are rendered on one thread.
            report = stab.stabilize(job.input, job.output, job.config, observer=observer, overwrite=True,
                                    encoding=job.encoding, workers=1)
        _write_marker(job)
    except Exception as error:  # noqa: BLE001 - reported in the summary, the other videos go on
        if recorder is not None:
            recorder.abort()
        if isinstance(error, FFVizError):
            message, code = str(error), error.exit_code
        else:
            message, code = f"internal error: {type(error).__name__}: {error}", 1
        return VideoResult(job.input, job.output, "failed", seconds=time.perf_counter() - started,
                           message=message, exit_code=code)
    n_warnings = len(report.warnings)
    return VideoResult(job.input, job.output, "done", n_frames=report.n_frames, seconds=report.seconds,
                       message=f"{n_warnings} warning(s)" if n_warnings else "",
                       frame_digests=tuple(digests.digests))


# -- Ray ----------------------------------------------------------------------------------------------------

def _ray():
    try:
        import ray
    except ImportError:
        raise ConfigError("ffviz batch needs Ray: pip install 'ffviz[ray]'") from None
    return ray


def connect(address: str | None, jobs: int | None) -> None:
    """A local Ray instance with ``jobs`` CPUs (default: all), or the cluster at ``address``."""
    ray = _ray()
    if ray.is_initialized():
        return
    try:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=jobs, include_dashboard=False, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as error:
        raise ConfigError(f"cannot start or reach Ray{f' at {address}' if address else ''}: {error}") from None


def _in_worker(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a Ray worker, after the allocator settings ffviz's entry point makes for its own process
    (pipeline/runtime/memory.py): Ray starts its workers itself, so without them every frame-sized array a task
    makes is faulted in afresh. Setting them again in a worker that has them changes nothing."""
    memory.reuse_freed_memory()
    return fn(*args)


def _task(fn: Callable[..., Any]) -> Callable[..., Any]:
    """A call that submits ``fn(*args)`` as a one-CPU Ray task run through _in_worker; returns its object ref."""
    return functools.partial(_ray().remote(num_cpus=1)(_in_worker).remote, fn)


def _slots(jobs: int | None) -> int:
    return jobs or max(1, int(_ray().cluster_resources().get("CPU", 1)))


def ray_mapper(jobs: int | None) -> segments.Mapper:
    """Ray tasks in order, at most ``2 * slots`` submitted ahead of the one being consumed (bounds memory)."""
    ray = _ray()

    def mapper(fn: Callable[..., Any], arg_list: Sequence[tuple]) -> Iterator[Any]:
        submit = _task(fn)
        # Arguments shared by every job (the whole path, the config) go to the object store once.
        shared: dict[int, Any] = {}

        def put(arg: Any) -> Any:
            if hasattr(arg, "nbytes") or hasattr(arg, "orig_from_stab"):
                if id(arg) not in shared:
                    shared[id(arg)] = ray.put(arg)
                return shared[id(arg)]
            return arg

        ahead = 2 * _slots(jobs)
        pending: list[Any] = []
        queue = iter(arg_list)
        while True:
            while len(pending) < ahead:
                args = next(queue, None)
                if args is None:
                    break
                pending.append(submit(*map(put, args)))
            if not pending:
                return
            yield ray.get(pending.pop(0))

    return mapper


def run_batch(jobs_list: Sequence[VideoJob], *, jobs: int | None = None, segment_frames: int = 0,
              on_result: Callable[[VideoResult], None] | None = None) -> list[VideoResult]:
    """Every job on Ray (connect() first); results in input order. Complete outputs are skipped."""
    ray = _ray()
    results: dict[int, VideoResult] = {}
    todo = []
    for i, job in enumerate(jobs_list):
        if is_complete(job):
            results[i] = VideoResult(job.input, job.output, "skipped", message="output complete")
            if on_result:
                on_result(results[i])
        else:
            todo.append(i)
    if segment_frames:
        # One video at a time, its segments spread over the workers.
        mapper = ray_mapper(jobs)
        for i in todo:
            results[i] = stabilize_one(jobs_list[i], segment_frames, mapper)
            if on_result:
                on_result(results[i])
        return [results[i] for i in range(len(jobs_list))]
    submit = _task(stabilize_one)
    slots = _slots(jobs)
    queue = iter(todo)
    running: dict[Any, int] = {}
    while True:
        while len(running) < slots:  # --jobs caps concurrency on a cluster too
            i = next(queue, None)
            if i is None:
                break
            running[submit(jobs_list[i])] = i
        if not running:
            break
        [ref], _ = ray.wait(list(running), num_returns=1)
        i = running.pop(ref)
        try:
            results[i] = ray.get(ref)
        except Exception as error:  # noqa: BLE001 - the worker died (crash, out of memory): that video failed
            job = jobs_list[i]
            results[i] = VideoResult(job.input, job.output, "failed", exit_code=1,
                                     message=f"worker failed: {type(error).__name__}: {str(error).splitlines()[0]}")
        if on_result:
            on_result(results[i])
    return [results[i] for i in range(len(jobs_list))]


# -- CLI ----------------------------------------------------------------------------------------------------

def add_parser(commands: Any, add_stabilize_options: Callable[..., None]) -> None:
    p = commands.add_parser("batch", help="stabilize many videos (or one long one in segments) on Ray")
    p.add_argument("inputs", type=Path, nargs="+", metavar="INPUT",
                   help="video files, or folders searched recursively for video files")
    p.add_argument("--output-dir", type=Path, default=None, metavar="OUTDIR",
                   help="folder for the outputs, OUTDIR/<input name>.mp4, created if missing (required)")
    p.add_argument("-o", dest="output_dir", type=Path, help=argparse.SUPPRESS)  # the old spelling
    p.add_argument("--address", default=None,
                   help="Ray cluster to use, e.g. ray://head:10001 or auto (default: a local Ray instance)")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="videos (or segments) at once (default: one per CPU of the local machine or cluster)")
    p.add_argument("--segment-frames", type=int, default=0, metavar="N",
                   help="split each video into segments of N frames run in parallel, one video at a time; "
                        "frames identical to a whole-video run (default: 0, one task per video)")
    add_stabilize_options(p, rrd_folder=True)


def _job_list(args: argparse.Namespace, config: stab.StabilizeConfig, encoding: Encoding) -> list[VideoJob]:
    outdir = args.output_dir
    if outdir is None:
        raise ConfigError("batch: --output-dir OUTDIR is required (the folder for the outputs)")
    inputs = expand_inputs(args.inputs)
    if not outdir.is_dir():
        try:
            outdir.mkdir(parents=True)
        except OSError as error:
            raise ConfigError(f"cannot create the output folder {outdir}: {error.strerror}") from None
    rrd_dir = None
    if args.rrd is not None:
        rrd_dir = outdir / "recordings" if args.rrd == Path("AUTO") else args.rrd
    return [VideoJob(i.absolute(), o.absolute(), config, encoding=encoding,
                     rrd=(rrd_dir / f"{i.stem}.rrd").absolute() if rrd_dir else None,
                     record_level=args.record, jpeg_quality=None if args.lossless else 80,
                     record_size=args.record_size)
            for i, o in zip(inputs, output_paths(inputs, outdir))]


def summary_table(results: Sequence[VideoResult]) -> str:
    rows = [("video", "status", "frames", "seconds", "frames/s", "note")]
    for r in results:
        fps = f"{r.n_frames / r.seconds:.1f}" if r.status == "done" and r.seconds > 0 else ""
        rows.append((r.input.name, r.status, str(r.n_frames) if r.n_frames else "",
                     f"{r.seconds:.1f}" if r.status != "skipped" else "", fps, r.message))
    widths = [max(len(row[c]) for row in rows) for c in range(5)]
    lines = ["  ".join(f"{cell:<{w}}" if c < 2 else f"{cell:>{w}}" for c, (cell, w) in enumerate(zip(row, widths)))
             + f"  {row[5]}" for row in rows]
    counts = {s: sum(r.status == s for r in results) for s in ("done", "skipped", "failed")}
    lines.append(f"{counts['done']} done, {counts['skipped']} skipped (already complete), {counts['failed']} failed")
    return "\n".join(line.rstrip() for line in lines)


def cmd_batch(args: argparse.Namespace, config: stab.StabilizeConfig, encoding: Encoding) -> int:
    from tqdm import tqdm

    if args.jobs is not None and args.jobs < 1:
        raise ConfigError(f"--jobs must be at least 1, not {args.jobs}")
    if args.segment_frames < 0:
        raise ConfigError(f"--segment-frames must be 0 (off) or more, not {args.segment_frames}")
    job_list = _job_list(args, config, encoding)
    connect(args.address, args.jobs)
    counts = {"done": 0, "skipped": 0, "failed": 0}
    bar = tqdm(total=len(job_list), desc="videos", unit="video", file=sys.stderr, dynamic_ncols=True)

    def on_result(result: VideoResult) -> None:
        counts[result.status] += 1
        if result.status == "failed":
            where = "" if str(result.input) in result.message else f"{result.input}: "
            bar.write(f"ffviz: error: {where}{result.message}", file=sys.stderr)
        bar.set_postfix(counts)
        bar.update()

    started = time.perf_counter()
    try:
        results = run_batch(job_list, jobs=args.jobs, segment_frames=args.segment_frames, on_result=on_result)
    finally:
        bar.close()
    elapsed = time.perf_counter() - started
    print(summary_table(results))
    done = counts["done"]
    print(f"{done} video(s) stabilized in {elapsed:.1f} s ({60 * done / max(elapsed, 1e-9):.1f} videos/min); "
          f"outputs in {args.output_dir}/" + (f", recordings in {job_list[0].rrd.parent}/ (ffviz view FILE.rrd)"
                                              if job_list and job_list[0].rrd is not None else ""))
    failed = [r.exit_code for r in results if r.status == "failed"]
    return max(failed) if failed else 0
