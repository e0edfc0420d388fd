"""Scale-out on Ray (local instance, 2 CPUs): batches and segment-parallel runs give the single run's frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ffviz import batch, cli
from pipeline.runtime.encoding import Encoding
from pipeline.runtime import video_reader
from pipeline import segments
from pipeline.evaluation import synthetic
from pipeline import stabilize as stab
from pipeline.runtime.observer import StageCollector

ray = pytest.importorskip("ray")

SMALL = dict(width=320, height=180)


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _single_run_digests(path: Path, config: stab.StabilizeConfig) -> list[str]:
    collector = StageCollector("output")
    stab.stabilize(path, None, config, observer=collector)
    return [batch.frame_digest(frame) for _, frame in collector.results["output"]]


@pytest.fixture(scope="module")
def batch_run(local_ray, tmp_path_factory):
    folder = tmp_path_factory.mktemp("batch")
    inputs = []
    for seed in range(3):
        clip = folder / "in" / f"clip{seed}.mp4"
        clip.parent.mkdir(exist_ok=True)
        synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(n_frames=30, seed=seed, **SMALL)), clip)
        inputs.append(clip)
    corrupt = folder / "in" / "corrupt.mp4"
    corrupt.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    inputs.insert(1, corrupt)
    config = stab.StabilizeConfig(mode="crop")
    outdir = folder / "out"
    outdir.mkdir()
    jobs = [batch.VideoJob(i, o, config) for i, o in zip(inputs, batch.output_paths(inputs, outdir))]
    return jobs, batch.run_batch(jobs, jobs=2)


def test_batch_gives_the_frames_of_single_runs(batch_run):
    jobs, results = batch_run
    done = [(job, result) for job, result in zip(jobs, results) if result.status == "done"]
    assert len(done) == 3
    for job, result in done:
        expected = _single_run_digests(job.input, job.config)
        assert len(expected) == 30
        assert list(result.frame_digests) == expected
        assert job.output.is_file() and result.n_frames == 30


def test_corrupt_video_is_reported_and_the_others_complete(batch_run):
    jobs, results = batch_run
    assert [r.status for r in results] == ["done", "failed", "done", "done"]
    failed = results[1]
    assert failed.exit_code == 2 and "not a video file" in failed.message and "corrupt.mp4" in failed.message
    assert not jobs[1].output.exists()


def test_rerun_skips_complete_outputs_and_redoes_changed_settings(batch_run, capsys):
    jobs, first = batch_run
    again = batch.run_batch(jobs, jobs=2)
    assert [r.status for r in again] == ["skipped", "failed", "skipped", "skipped"]
    changed = [batch.VideoJob(job.input, job.output, job.config, encoding=Encoding(crf=job.encoding.crf + 1))
               for job in jobs]
    assert not any(batch.is_complete(job) for job in changed)
    # The CLI over the same folder (Ray already up): summary table, failure's exit code.
    outdir = jobs[0].output.parent
    code = cli.main(["batch", str(jobs[0].input.parent), "--output-dir", str(outdir), "--mode", "crop", "--jobs", "2"])
    out = capsys.readouterr().out
    assert code == 2
    assert "0 done, 3 skipped (already complete), 1 failed" in out
    assert "corrupt.mp4  failed" in out


def test_segment_plan_covers_every_frame_once():
    ranges = segments.plan(20, 6)
    assert [(r.start, r.stop) for r in ranges[:-1]] == [(0, 6), (6, 12), (12, 18)]
    assert ranges[-1].start == 18 and ranges[-1].stop > 20  # open-ended: the header may undercount
    with pytest.raises(ValueError):
        segments.plan(20, 0)


@pytest.mark.parametrize("mode", ["full", "crop"])
def test_segment_parallel_run_gives_the_single_runs_frames(local_ray, tmp_path, mode):
    # Two shots with a cut at frame 12, which is also a segment boundary; full mode with deblurring reads
    # 6 frames either side, so every segment's window crosses into its neighbours (crop mode's window is completed
    # where it leaves a frame, alike).
    a = synthetic.generate(synthetic.SyntheticConfig(n_frames=12, seed=1, image="coffee", **SMALL))
    b = synthetic.generate(synthetic.SyntheticConfig(n_frames=12, seed=2, image="astronaut", **SMALL))
    clip = tmp_path / "two_shots.mp4"
    synthetic.write_video(list(a.frames) + list(b.frames), clip, fps=30.0)
    config = stab.StabilizeConfig(mode=mode)
    assert config.window_frames > 0 and config.completing

    single = StageCollector("output")
    single_report = stab.stabilize(clip, None, config, observer=single)
    parallel = StageCollector("output")
    report = segments.run(clip, tmp_path / "out.mp4", config, segment_frames=6, mapper=batch.ray_mapper(2),
                          observer=parallel)

    assert single_report.cuts == report.cuts == [12]
    assert [s.index for s, _ in parallel.results["output"]] == list(range(24))
    assert len(single.results["output"]) == 24
    for (_, expected), (_, got) in zip(single.results["output"], parallel.results["output"]):
        np.testing.assert_array_equal(got, expected)
    assert (tmp_path / "out.mp4").is_file()


def test_segmented_output_keeps_the_audio_and_the_timing(tmp_path):
    from tests.test_video_io import audio_seconds, make_video

    clip = make_video(tmp_path / "with_audio.mp4", frames=40, audio="aac")
    out = tmp_path / "out.mp4"
    # Segments run in this process here (serial_map): what is checked is the join, not Ray.
    segments.run(clip, out, stab.StabilizeConfig(mode="none"), segment_frames=12)
    source, result = video_reader.probe_video(clip), video_reader.probe_video(out)
    assert result.has_audio
    assert video_reader.count_frames(out) == video_reader.count_frames(clip) == 40
    assert result.fps == source.fps and (result.width, result.height) == (source.width, source.height)
    codec, seconds = audio_seconds(out)
    assert codec == "aac" and abs(seconds - audio_seconds(clip)[1]) < 0.05


def test_ray_workers_reuse_freed_memory_as_the_cli_does(local_ray):
    """A Ray worker is a process Ray starts, not ffviz's entry point: the allocator settings
    (pipeline/runtime/memory.py) must be made in it too, or each frame-sized array is faulted in afresh."""
    from pipeline.runtime import memory

    if memory._libc() is None:
        pytest.skip("glibc's mallopt only")

    def churn() -> int:  # tests/test_memory.py's measure, in the worker
        import resource

        for _ in range(2):
            frames = [np.ones((720, 1280, 3), np.float32) for _ in range(4)]
            del frames
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        for i in range(10):
            frames = [np.full((720, 1280, 3), i, np.float32) for _ in range(4)]
            del frames
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

    pages_a_frame = 720 * 1280 * 3 * 4 // 4096
    faults = list(batch.ray_mapper(2)(churn, [() for _ in range(4)]))
    assert len(faults) == 4
    assert max(faults) < 2 * pages_a_frame
