"""`ffviz bench` end to end on a tiny synthetic clip, and the child-process measurement it relies on."""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import sys
from collections import Counter

import av
import cv2
import numpy as np
import pytest

from ffviz.bench import command, measure, methods
from ffviz.cli import main
from pipeline.evaluation import synthetic

MiB = 2**20


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    """30 frames of 320x180 with the demo's hand-held shake (6 px, 1 degree)."""
    path = tmp_path_factory.mktemp("bench-in") / "tiny.mp4"
    synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=30, seed=1)),
                          path)
    return path


@pytest.fixture(scope="module")
def bench_run(tiny_clip, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench-out")
    code = main(["bench", str(tiny_clip), "--modes", "crop,none,none-mpeg4", "--peers", "vidstab,deshake,opencv,x264",
                 "--output-dir", str(out), "-o", str(out / "report" / "benchmarks.md")])
    assert code == 0
    rows = {row["method"]: row for row in json.loads((out / "bench.json").read_text())["rows"]}
    return out, rows


def test_writes_table_files_and_plot(bench_run):
    out, rows = bench_run
    markdown = (out / "bench.md").read_text()
    assert markdown.startswith("| clip | method |")
    for method in rows:
        assert f"| tiny.mp4 | {method} |" in markdown
    with (out / "bench.csv").open() as f:
        assert [r["method"] for r in csv.DictReader(f)] == list(rows)
    png = (out / "bench.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 10_000


def test_writes_a_dated_report_with_the_machine(bench_run):
    out, rows = bench_run
    report = (out / "report" / "benchmarks.md").read_text()
    assert report.startswith("# Benchmarks\n")
    assert re.search(r"Written by `ffviz bench` on 20\d\d-\d\d-\d\d \d\d:\d\d", report)
    for key in ("| cpu |", "| cores |", "| python |", "| numpy |", "| rerun-sdk |", "| opencv-python-headless |"):
        assert key in report
    assert "Clips: tiny.mp4." in report and "| tiny.mp4 | ffviz crop |" in report
    assert "speed targets read off this table" in report and "![speed against steadiness" in report
    assert (out / "report" / "benchmarks.png").read_bytes().startswith(b"\x89PNG")
    assert json.loads((out / "bench.json").read_text())["machine"]["cores"] == str(os.cpu_count())


def test_report_defaults_to_docs_in_a_checkout_only(tmp_path):
    from ffviz.cli import build_parser

    args = build_parser().parse_args(["bench"])
    assert args.output is None and args.output_dir == command.DEFAULT_OUT  # cmd_bench picks docs/ or DIR/
    assert command.DEFAULT_REPORT == methods.REPO / "docs" / "benchmarks.md"
    assert build_parser().parse_args(["bench", "--out", str(tmp_path)]).output_dir == tmp_path  # the old spelling


def test_a_rewritten_report_keeps_the_sections_written_by_hand(tmp_path):
    """The reports `ffviz bench -o` rewrites keep their decision-log figures: the part from the first
    ``<!-- section: NAME -->`` marker on is carried over, once."""
    from ffviz.bench.report import BenchRow, RunInfo, write_report

    path = tmp_path / "report.md"
    rows = [BenchRow("a.mp4", "input", 640, 360, 30)]
    run = RunInfo(repeat=1, cpus=2, load_before=(0.0, 0.0, 0.0), load_after=(0.0, 0.0, 0.0))
    hand = "<!-- section: decision-log -->\n## From the decision log\n\nD1: 1.02x\n"
    path.write_text("# Benchmarks\n\nthe old table\n\n" + hand)
    for _ in range(2):
        write_report(rows, path, run)
        text = path.read_text()
        assert text.startswith("# Benchmarks\n") and "the old table" not in text and "| a.mp4 | input |" in text
        assert text.endswith("```\n\n" + hand) and text.count("\n<!-- section: ") == 1


def test_cpu_model_from_proc_cpuinfo(tmp_path):
    from ffviz.bench.report import cpu_model

    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: X\nmodel name\t: Test CPU 3000 @ 2.0GHz\n")
    assert cpu_model(info) == "Test CPU 3000 @ 2.0GHz"
    assert cpu_model(tmp_path / "absent")  # falls back to something, never empty


def test_ffviz_rows_measure_speed_memory_and_quality(bench_run):
    out, rows = bench_run
    source = rows["input"]
    assert source["frames"] == 30 and source["fps"] is None and source["jitter_px"] > 3.0
    for mode in ("crop", "none"):
        row = rows[f"ffviz {mode}"]
        assert row["note"] is None
        assert row["frames"] == 30 and row["fps"] > 0 and row["cpu_s"] > 0
        assert row["fps"] == pytest.approx(30 / row["seconds"])
        assert 10 < row["peak_MiB"] < 4096
        assert len(row["steal_runs"]) == 1 and 0 <= row["steal_pct"] == 100 * row["steal_runs"][0] <= 100
        assert row["jitter_px"] < source["jitter_px"]
        written = out / "outputs" / f"tiny.mp4.ffviz-{mode}.mp4"
        with av.open(str(written)) as container:
            assert container.streams.video[0].codec_context.name == row["codec"] == "h264"
            seconds = container.duration / av.time_base
        assert row["kbit_s"] == pytest.approx(written.stat().st_size * 8 / 1000 / seconds, rel=1e-3)
    assert rows["ffviz crop"]["black"] < 0.01
    same_as_opencv = rows["ffviz none mpeg4"]  # --codec mpeg4: the OpenCV sample's codec, the same frames
    assert same_as_opencv["codec"] == "mpeg4" and same_as_opencv["fps"] > 0
    # the same stabilization (measured 3.2 px against none's 3.1; the input's 10.8): codec noise apart
    assert same_as_opencv["jitter_px"] < 0.4 * source["jitter_px"]
    assert rows["ffviz none"]["black"] > rows["ffviz crop"]["black"] + 0.005  # uncovered borders stay black
    # the figure sees synthesized pixels where there are some: none's uncovered borders (crop mode's window is
    # completed where it leaves the frames, so it may have some too)
    assert rows["ffviz none"]["flicker"] is not None
    assert "flicker" in (out / "bench.md").read_text().splitlines()[0]


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg not installed: no vidstab/deshake peers")
def test_installed_peers_get_rows(bench_run):
    _, rows = bench_run
    peers = ["vidstab", "deshake"] + (["opencv"] if methods.OPENCV_VIDEOSTAB.is_file() else [])
    for peer in peers:
        row = rows[peer]
        assert row["note"] is None, row["note"]
        assert row["fps"] > 0 and 10 < row["peak_MiB"] < 4096
        assert row["jitter_px"] is not None and row["black"] is not None
        assert row["codec"] == ("mpeg4" if peer == "opencv" else "h264") and row["kbit_s"] > 0
    assert rows["vidstab"]["jitter_px"] < rows["input"]["jitter_px"]
    floor = rows["x264 only"]  # the encoder alone: the input's own shake and frame, ffviz's codec
    assert floor["note"] is None and floor["codec"] == "h264" and floor["fps"] > 0
    assert floor["jitter_px"] > 0.7 * rows["input"]["jitter_px"]  # measured 1.11 (encoder noise, 30 frames)
    assert floor["crop"] > 0.99 and floor["black"] < 0.001


def test_missing_video_is_one_line_error(tmp_path, capsys):
    code = main(["bench", str(tmp_path / "absent.mp4"), "--modes", "none", "--peers", "none",
                 "--output-dir", str(tmp_path / "out"), "-o", str(tmp_path / "report.md")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.strip().splitlines() == [f"ffviz: error: input file not found: {tmp_path / 'absent.mp4'}"]
    assert not (tmp_path / "out" / "bench.md").exists() and not (tmp_path / "report.md").exists()


def test_unknown_peer_is_one_line_error(tiny_clip, tmp_path, capsys):
    assert main(["bench", str(tiny_clip), "--peers", "vidstab,handbrake", "--output-dir", str(tmp_path),
                 "-o", str(tmp_path / "report.md")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "ffviz: error: --peers: unknown handbrake (choose from vidstab, deshake, opencv, x264)"]


def test_peak_memory_is_the_childs_own():
    # Ballast in this process: a child forked straight from it would report at least this much.
    ballast = b"x" * (300 * MiB)
    big = measure.run_measured([sys.executable, "-c", "data = b'x' * (200 * 2**20)"])
    small = measure.run_measured([sys.executable, "-c", "pass"])
    assert len(ballast) == 300 * MiB
    assert big.returncode == 0 and small.returncode == 0
    assert big.peak_rss_bytes >= 200 * MiB
    assert small.peak_rss_bytes < 50 * MiB
    assert big.seconds > 0 and big.cpu_seconds > 0


def test_run_measured_reports_failures():
    failed = measure.run_measured([sys.executable, "-c", "import sys; print('working'); sys.exit('boom: bad input')"])
    assert failed.returncode == 1 and failed.output_tail == "boom: bad input"
    killed = measure.run_measured([sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGKILL)"])
    assert killed.returncode == 128 + 9
    missing = measure.run_measured(["/nonexistent/program"])
    assert missing.returncode == 127 and "cannot run /nonexistent/program" in missing.output_tail


def test_schedule_interleaves_and_rotates_methods():
    visits = list(command.schedule(repeats=2, n_clips=3, n_methods=3))
    assert [(repeat, clip) for repeat, clip, _ in visits] == [(r, c) for r in range(2) for c in range(3)]
    for _, _, order in visits:
        assert sorted(order) == [0, 1, 2]
        assert order == order[:1] + [(order[0] + i) % 3 for i in range(1, 3)]  # a rotation of the method list
    assert Counter(order[0] for _, _, order in visits) == {0: 2, 1: 2, 2: 2}  # each method goes first as often


def test_stream_frames_renders_a_shaky_clip_lazily():
    config = synthetic.SyntheticConfig(width=320, height=180, n_frames=40, pan_px_per_frame=0.0, moving_object=False,
                                       blurred_frames=(), jitter_px=6.0, seed=3)
    frames = synthetic.stream_frames(config)
    first = next(frames)  # lazily: one frame rendered, the rest not yet
    rest = list(frames)
    assert first.shape == (180, 320, 3) and first.dtype.name == "uint8" and len(rest) == 39
    again = list(synthetic.stream_frames(config))
    assert all((a == b).all() for a, b in zip([first] + rest, again))  # deterministic given the seed
    grey = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY).astype(np.float64) for f in [first] + rest]
    shifts = [np.hypot(*cv2.phaseCorrelate(a, b)[0]) for a, b in zip(grey, grey[1:])]
    assert np.median(shifts) > 2.0  # the camera shakes between frames (without jitter: 0.2 px, the slow drift)
    with pytest.raises(ValueError, match="pan_px_per_frame=0"):
        next(synthetic.stream_frames(synthetic.SyntheticConfig(n_frames=5)))


def test_targets_compare_wall_and_cpu_with_the_peers_against_each_bound():
    from ffviz.bench.report import X264_ONLY, BenchRow, targets

    def row(clip, method, size, seconds=None, cpu=None):
        return BenchRow(clip, method, *size, 60, seconds_runs=[] if seconds is None else [seconds],
                        cpu_seconds_runs=[] if cpu is None else [cpu])

    rows = [row("a.mp4", "input", (640, 360)), row("a.mp4", "ffviz full", (640, 360), 9.0, 24.0),
            row("a.mp4", "opencv", (640, 360), 10.0, 20.0), row("a.mp4", "ffviz none", (640, 360), 6.0, 9.0),
            row("a.mp4", "vidstab", (640, 360), 3.0, 4.0),
            row("hd.mp4", "input", (1920, 1080)), row("hd.mp4", "ffviz full", (1920, 1080), 15.0, 19.0),
            row("hd.mp4", X264_ONLY, (1920, 1080), 5.0, 10.0)]
    text = "\n".join(targets(rows))
    assert "a.mp4: ffviz none 6.00 / 9.00 s vs vidstab 3.00 / 4.00 s: wall 2.00x, CPU 2.25x (not met)" in text
    assert "a.mp4: ffviz crop vs vidstab: n/a (ffviz crop not measured)" in text
    # Target 2 needs both: the wall is under the sample's, the CPU 1.2x its (<= 1.3x).
    assert "a.mp4: ffviz full 9.00 / 24.00 s vs opencv 10.00 / 20.00 s: wall 0.90x, CPU 1.20x (met)" in text
    costly = "\n".join(targets([r if r.method != "ffviz full" or r.clip != "a.mp4" else
                                row("a.mp4", "ffviz full", (640, 360), 9.0, 27.0) for r in rows]))
    assert "wall 0.90x, CPU 1.35x (not met)" in costly
    assert "ffviz full mpeg4" not in text  # the optional same-codec row, absent
    same_codec = "\n".join(targets(rows + [row("a.mp4", "ffviz full mpeg4", (640, 360), 5.0, 12.0)]))
    assert "a.mp4: ffviz full mpeg4 5.00 / 12.00 s vs opencv 10.00 / 20.00 s: wall 0.50x, CPU 0.60x\n" in same_codec + "\n"
    # Target 4 on CPU only (a ratio of CPU a frame: the same frames on both sides).
    assert "hd.mp4: ffviz full 15.00 / 19.00 s vs x264 only 5.00 / 10.00 s: wall 3.00x, CPU 1.90x (met)" in text
    slow = "\n".join(targets(rows[:-2] + [row("hd.mp4", "ffviz full", (1920, 1080), 15.0, 21.0), rows[-1]]))
    assert "CPU 2.10x (not met)" in slow
    assert any("no clip of 1080+ rows" in line for line in targets(rows[:5]))
    assert "hd.mp4: ffviz full vs x264 only: n/a (x264 only not measured)" in "\n".join(targets(rows[:-1]))
    # A bound with no measure to hold against it gives no verdict (not "met").
    no_cpu = "\n".join(targets(rows[:-2] + [row("hd.mp4", "ffviz full", (1920, 1080), 15.0), rows[-1]]))
    assert "hd.mp4: ffviz full 15.00 / - s vs x264 only 5.00 / 10.00 s: wall 3.00x (not judged: CPU not measured)" \
        in no_cpu
    assert any("3. --quality fast" in line for line in targets(rows))
    floor = "\n".join(targets(rows))
    assert "hd.mp4: x264 only 5.00 s = 33 % of ffviz full's" in floor
    assert not any("encoder floor" in line for line in targets(rows[:5]))  # no x264-only row: no floor block


def test_machine_ticks_read_steal_from_proc_stat(tmp_path):
    stat = tmp_path / "stat"
    # user nice system idle iowait irq softirq steal guest guest_nice (guest time is inside user and nice)
    stat.write_text("cpu  300 10 40 500 20 0 5 125 50 0\ncpu0 150 5 20 250 10 0 2 63 25 0\n")
    assert measure.machine_ticks(stat) == (125, 1000)
    assert measure.steal_share(measure.ticks_between((100, 1000), (125, 1100))) == 0.25
    assert measure.steal_share(measure.add_ticks((10, 100), (15, 100))) == 0.125
    assert measure.steal_share((0, 0)) is None and measure.steal_share(None) is None
    assert measure.ticks_between(None, (1, 2)) is None and measure.add_ticks((1, 2), None) is None
    for text in ("", "intr 1 2 3\n", "cpu  1 2 x 4 5 6 7 8\n", "cpu  1 2 3\n"):
        stat.write_text(text)
        assert measure.machine_ticks(stat) is None, text
    assert measure.machine_ticks(tmp_path / "absent") is None


@pytest.mark.skipif(measure.machine_ticks() is None, reason="no /proc/stat here")
def test_run_measured_reports_the_machines_steal():
    run = measure.run_measured([sys.executable, "-c", "import time; time.sleep(0.3)"])
    stolen, total = run.machine_ticks
    # 0.3 s on every CPU is at least 30 ticks of the machine (USER_HZ is 100 on Linux), some perhaps stolen.
    assert total >= 25 * (os.cpu_count() or 1) and 0 <= stolen <= total
    assert 0.0 <= run.steal <= 1.0


def test_targets_flag_rows_measured_while_the_machine_was_stolen():
    from ffviz.bench.report import BenchRow, markdown_line, targets

    quiet = BenchRow("a.mp4", "opencv", 640, 360, 60, seconds_runs=[10.0], steal_runs=[0.01, 0.02, 0.40])
    busy = BenchRow("a.mp4", "ffviz full", 640, 360, 60, seconds_runs=[20.0], steal_runs=[0.30, 0.33, 0.20])
    rows = [BenchRow("a.mp4", "input", 640, 360, 60), quiet, busy]
    warnings = [line for line in targets(rows) if "steal above" in line]
    assert len(warnings) == 1 and "a.mp4 ffviz full 30 %" in warnings[0] and "opencv" not in warnings[0]
    assert "| 2 |" in markdown_line(quiet) and "| 30 |" in markdown_line(busy)  # the median run's share
    assert not any("steal above" in line for line in targets(rows[:2]))


def test_profile_attributes_the_cpu_to_every_stage_of_full_mode(tiny_clip, capsys):
    from ffviz.bench.profile import STAGES

    assert main(["bench", str(tiny_clip), "--profile", "--modes", "full"]) == 0
    stage_table, _, recording_table = capsys.readouterr().out.partition("by entity family")
    rows = [line for line in stage_table.splitlines() if line.startswith("| tiny.mp4 | full |")]
    assert len(rows) == 1
    cells = [float(c) for c in rows[0].strip("|").split("|")[2:]]
    by_stage, total = dict(zip(STAGES, cells)), cells[-1]
    # each stage's functions were found and ran (a renamed stage function would read 0 here)
    for stage in ("decode", "motion", "smoothing", "warp", "mosaic", "flow", "FMM", "local warp", "deblur", "encode",
                  "recording"):
        assert by_stage[stage] > 0, stage
    # the stages of the run without recording add up to its measured CPU, with what no stage claims as 'other'
    assert sum(by_stage[s] for s in STAGES if s != "recording") == pytest.approx(total, rel=0.02, abs=0.3)
    # the recording's cost by entity family: every frame-sized family counted
    lines = recording_table.splitlines()
    header = next(line for line in lines if line.startswith("| clip |")).strip("|").split("|")
    row = next(line for line in lines if line.startswith("| tiny.mp4 | full |")).strip("|").split("|")
    by_family = {name.strip(): float(cell) for name, cell in zip(header[2:], row[2:])}
    for family in ("stabilized/missing", "completion/mosaic", "completion/source", "motion"):  # counted (a class map
        assert family in by_family, family  # of this tiny clip can take under the 0.05 ms a frame the table shows)
    for family in ("input/frame", "stabilized/frame", "completion/frame", "completion/fmm", "output/frame"):
        assert by_family[family] > 0, family


def test_l1_modes_run_the_l1_path_and_the_profile_refuses_them(tmp_path):
    l1 = methods.ffviz_command(tmp_path / "a.mp4", tmp_path / "o.mp4", "crop-l1")
    assert l1[l1.index("--mode") + 1] == "crop" and l1[l1.index("--path") + 1] == "l1"
    assert "--codec" not in l1
    mpeg4 = methods.ffviz_command(tmp_path / "a.mp4", tmp_path / "o.mp4", "full-mpeg4")
    assert mpeg4[mpeg4.index("--codec") + 1] == "mpeg4" and "--path" not in mpeg4
    from pipeline.errors import ConfigError

    with pytest.raises(ConfigError, match="crop-l1"):
        command._profile([], ["crop", "crop-l1"])
