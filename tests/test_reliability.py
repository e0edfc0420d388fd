"""Reliability (issue 8): every bad input gets a clear answer, no data is lost, long runs survive.

Every input is made here with PyAV. The CLI runs in-process (cli.main, streams captured at the file
descriptors) for every case, and as a real subprocess for a representative subset, the signals and the
output-safety cases: an input it refuses gives exactly one line on stderr (no traceback) and a non-zero
exit; an input it accepts gives an output with the input's frame count and timestamps, and a warning
where the input was odd. Either way no partial output and no temp file is left, and the input is
untouched. docs/bad-input.md lists the same cases: keep the two in step.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Callable

import av
import cv2
import numpy as np
import pytest

from ffviz import cli
from ffviz.bench.measure import measured_argv, read_measurement
from pipeline.evaluation import synthetic
from pipeline.frames import Frame
from pipeline.runtime.video_info import VideoInfo
from pipeline.runtime import video_reader, video_writer
from tests.test_video_io import mux_sine

ROOT = Path(__file__).resolve().parents[1]
FPS = 25
W, H = 160, 96  # most clips: small, with enough texture for the motion stage


# --- making inputs -------------------------------------------------------------------------


def photo_frames(n: int, width: int = W, height: int = H, image: str = "coffee", step_px: int = 2) -> list[np.ndarray]:
    """A camera panning over a photograph, `step_px` per frame, with a vertical wobble of up to 2 px."""
    photo = synthetic.load_image(image)
    scale = (height + 8) / photo.shape[0]
    photo = cv2.resize(photo, (max(round(photo.shape[1] * scale), width + step_px * n + 8), height + 8),
                       interpolation=cv2.INTER_AREA)
    return [np.ascontiguousarray(photo[2 + t % 3: 2 + t % 3 + height, step_px * t: step_px * t + width])
            for t in range(n)]


def write_video(path: Path, frames: list[np.ndarray], *, codec: str = "libx264", pix_fmt: str = "yuv420p",
                pts: list[int] | None = None, time_base: Fraction = Fraction(1, FPS), rotation_ccw: int | None = None,
                options: dict[str, str] | None = None, muxer_options: dict[str, str] | None = None,
                size: tuple[int, int] = (W, H)) -> Path:
    """Encode RGB frames (none: a header-only file) with the given codec; `pts` in `time_base` makes it VFR."""
    with av.open(str(path), "w", options=muxer_options or {}) as container:
        stream = container.add_stream(codec, rate=FPS, options=options or {})
        stream.width, stream.height = (frames[0].shape[1], frames[0].shape[0]) if frames else size
        stream.pix_fmt = pix_fmt
        stream.codec_context.time_base = time_base
        if rotation_ccw is not None:
            stream.set_display_rotation(rotation_ccw)
        container.start_encoding()
        for index, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            frame.pts, frame.time_base = (pts[index] if pts else index), time_base
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
    return path


def top_level_boxes(data: bytes) -> dict[str, tuple[int, int]]:
    """{type: (offset, size)} of an MP4's top-level boxes."""
    boxes, offset = {}, 0
    while offset + 8 <= len(data):
        size, kind = struct.unpack(">I4s", data[offset: offset + 8])
        boxes[kind.decode("latin-1")] = (offset, size)
        if size < 8:
            break
        offset += size
    return boxes


def packet_spans(path: Path) -> list[tuple[int, int]]:
    """(byte offset, size) of each video packet, in file order."""
    with av.open(str(path)) as container:
        return sorted((p.pos, p.size) for p in container.demux(video=0) if p.size)


def truncated(folder: Path, where: str) -> Path:
    """A 30-frame MP4 cut short. 'moov last' files (the muxer's default) keep their index at the end."""
    faststart = where.startswith("faststart")
    whole = write_video(folder / "whole.mp4", photo_frames(30),
                        muxer_options={"movflags": "+faststart"} if faststart else None)
    data = whole.read_bytes()
    moov_offset, moov_size = top_level_boxes(data)["moov"]
    assert (moov_offset < top_level_boxes(data)["mdat"][0]) == faststart
    packets = packet_spans(whole)
    cut = {
        "in the file type box": 16,
        "moov last, before the index": moov_offset,
        "moov last, inside the index": moov_offset + moov_size // 2,
        "faststart, inside the index": moov_offset + moov_size // 2,
        "faststart, inside the first frame": packets[0][0] + packets[0][1] // 2,
        "faststart, two thirds in": packets[20][0] + packets[20][1] // 2,
    }[where]
    whole.unlink()
    path = folder / "cut.mp4"
    path.write_bytes(data[:cut])
    return path


def with_damaged_packet(source: Path, target: Path, index: int, how: str) -> Path:
    """Remux `source` with packet `index` (decode order) zeroed or with its tail replaced by noise."""
    with av.open(str(source)) as src, av.open(str(target), "w") as dst:
        stream_in = src.streams.video[0]
        stream_out = dst.add_stream_from_template(stream_in)
        packets = [p for p in src.demux(stream_in) if p.size]
        for k, packet in enumerate(packets):
            if k == index:
                data = bytearray(bytes(packet))
                if how == "zeroed":
                    data[:] = bytes(len(data))
                else:
                    tail = len(data) // 3
                    data[tail:] = np.random.default_rng(k).integers(0, 256, len(data) - tail, np.uint8).tobytes()
                damaged = av.Packet(bytes(data))
                damaged.pts, damaged.dts, damaged.time_base = packet.pts, packet.dts, packet.time_base
                damaged.is_keyframe = packet.is_keyframe
                packet = damaged
            packet.stream = stream_out
            dst.mux(packet)
    source.unlink()
    return target


def audio_only(path: Path) -> Path:
    with av.open(str(path), "w", format="mp4") as container:
        mux_sine(container, container.add_stream("aac", rate=44100, layout="mono"), 1.0)
    return path


def tags_not_utf8(path: Path) -> Path:
    """An MKV whose title tags are bytes that are not UTF-8 (FFmpeg hands tags on as they are)."""
    with av.open(str(path), "w") as container:
        container.metadata["title"] = "TITLETITLE"
        stream = container.add_stream("libx264", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
        stream.metadata["title"] = "STREAMNAME"
        for index, rgb in enumerate(photo_frames(6)):
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
            frame.pts = index
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
    data = path.read_bytes()  # same lengths: the container stays valid
    path.write_bytes(data.replace(b"TITLETITLE", b"\xff\xfeTITLE\xc0\xc1\xc2")
                     .replace(b"STREAMNAME", b"\xc0\xc1\xfe\xffNAME\xc0\xc0"))
    return path


def fade_to_black(n: int) -> list[np.ndarray]:
    return [(f * (1 - t / (n - 1))).astype(np.uint8) for t, f in enumerate(photo_frames(n))]


def scene_cut() -> list[np.ndarray]:
    return photo_frames(8, image="coffee") + photo_frames(8, image="astronaut")


def noise_in_the_middle() -> list[np.ndarray]:
    frames = photo_frames(11)
    frames[5] = np.random.default_rng(5).integers(0, 256, (H, W, 3), np.uint8)
    return frames


# --- the matrix ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One input and what the CLI must do with it; `error` xor output (with `warning` if not None)."""

    make: Callable[[Path], Path]  # writes the input into a folder, returns its path
    error: str | None = None  # regex the single stderr line must match
    warning: str | None = None  # regex one warning line must match; None: no warning at all
    mode: str = "none"
    size: tuple[int, int] | None = None  # expected output (width, height); None: the input's display size
    max_memory_mib: float | None = None  # bound on the run's peak memory (checked in the subprocess run)


def _missing(folder: Path) -> Path:
    return folder / "missing.mp4"


def _directory(folder: Path) -> Path:
    (folder / "clip.mp4").mkdir()
    return folder / "clip.mp4"


def _file(name: str, data: bytes) -> Callable[[Path], Path]:
    def make(folder: Path) -> Path:
        (folder / name).write_bytes(data)
        return folder / name
    return make


RANDOM_BYTES = np.random.default_rng(8).integers(0, 256, 50_000, np.uint8).tobytes()
TEXT = b"This is not a video, only its name says so.\n" * 200

CASES: dict[str, Case] = {
    "missing file": Case(_missing, error=r"input file not found: .*missing\.mp4$"),
    "directory": Case(_directory, error=r"input is a directory, not a video file: .*clip\.mp4$"),
    "empty file": Case(_file("empty.mp4", b""), error=r"input file is empty: .*empty\.mp4$"),
    "random bytes": Case(_file("random.mp4", RANDOM_BYTES), error=r"not a video file .*random\.mp4$"),
    "text file named .mp4": Case(_file("notes.mp4", TEXT), error=r"not a video file .*notes\.mp4$"),
    "truncated: in the file type box": Case(
        lambda d: truncated(d, "in the file type box"), error=r"damaged or truncated MP4/MOV: .*moov.*cut\.mp4$"),
    "truncated: moov last, before the index": Case(
        lambda d: truncated(d, "moov last, before the index"), error=r"damaged or truncated MP4/MOV: .*cut\.mp4$"),
    "truncated: moov last, inside the index": Case(
        lambda d: truncated(d, "moov last, inside the index"),
        # Depending on where in the index the cut falls, FFmpeg finds no track or runs out of bytes.
        error=r"(no video stream in .*cut\.mp4 \(no streams at all: empty, damaged or truncated\)|"
              r"file ends too early \(truncated\?\): .*cut\.mp4)$"),
    "truncated: faststart, inside the index": Case(
        lambda d: truncated(d, "faststart, inside the index"), error=r"file ends too early \(truncated\?\): .*cut\.mp4$"),
    "truncated: faststart, inside the first frame": Case(
        lambda d: truncated(d, "faststart, inside the first frame"), error=r"no decodable video frame in .*cut\.mp4$"),
    "truncated: faststart, two thirds in": Case(
        lambda d: truncated(d, "faststart, two thirds in"), warning=r"ends early \(truncated\?\): read 21 of the 30 frames"),
    "audio only": Case(lambda d: audio_only(d / "sound.m4a"), error=r"no video stream in .*sound\.m4a \(audio only\)$"),
    "0 frames (MP4)": Case(lambda d: write_video(d / "zero.mp4", []), error=r"no video stream in .*zero\.mp4 \(no streams"),
    "0 frames (MKV)": Case(lambda d: write_video(d / "zero.mkv", [], codec="ffv1", pix_fmt="yuv444p"),
                           error=r"file ends too early \(truncated\?\): .*zero\.mkv$"),
    "1 frame": Case(lambda d: write_video(d / "one.mp4", photo_frames(1)), warning=r"only one frame"),
    "2 frames": Case(lambda d: write_video(d / "two.mp4", photo_frames(2))),
    "3 frames": Case(lambda d: write_video(d / "three.mp4", photo_frames(3))),
    "2 frames, full mode": Case(lambda d: write_video(d / "two.mp4", photo_frames(2)), mode="full"),
    "3 frames, full mode": Case(lambda d: write_video(d / "three.mp4", photo_frames(3)), mode="full"),
    "odd width and height": Case(
        lambda d: write_video(d / "odd.mkv", photo_frames(8, 65, 49), codec="ffv1", pix_fmt="yuv444p"),
        warning=r"odd frame size 65x49: padded to 66x50", size=(66, 50)),
    "16x16 frames": Case(lambda d: write_video(d / "tiny.mp4", photo_frames(8, 16, 16, step_px=1)),
                         warning=r"featureless frame"),
    "16x16 frames, full mode": Case(lambda d: write_video(d / "tiny.mp4", photo_frames(8, 16, 16, step_px=1)),
                                    warning=r"featureless frame", mode="full"),
    # One 4K RGB frame is 24 MiB: a streaming run holds a handful (decoder, warp, encoder lookahead).
    "4K frames (3)": Case(lambda d: write_video(d / "uhd.mp4", photo_frames(3, 3840, 2160, step_px=8),
                                                options={"preset": "ultrafast"}), mode="crop", max_memory_mib=1500),
    "grayscale (ffv1 gray)": Case(lambda d: write_video(d / "gray.mkv", photo_frames(8), codec="ffv1", pix_fmt="gray")),
    "10-bit (x265 yuv420p10le)": Case(lambda d: write_video(
        d / "hevc10.mp4", photo_frames(8), codec="libx265", pix_fmt="yuv420p10le",
        options={"x265-params": "log-level=none"})),
    "10-bit (ffv1 yuv420p10le)": Case(lambda d: write_video(
        d / "ffv1_10.mkv", photo_frames(8), codec="ffv1", pix_fmt="yuv420p10le")),
    "variable frame rate": Case(lambda d: write_video(
        d / "vfr.mp4", photo_frames(10), pts=[0, 40, 80, 200, 240, 250, 400, 433, 500, 700],
        time_base=Fraction(1, 1000))),
    "rotation metadata (90 deg)": Case(lambda d: write_video(d / "rotated.mp4", photo_frames(8), rotation_ccw=-90),
                                       size=(H, W)),
    "all-black frames": Case(lambda d: write_video(d / "black.mp4", [np.zeros((H, W, 3), np.uint8)] * 8),
                             warning=r"motion fallback to identity: featureless frame"),
    "constant colour frames": Case(lambda d: write_video(d / "grey.mp4", [np.full((H, W, 3), 128, np.uint8)] * 8),
                                   warning=r"motion fallback to identity: featureless frame"),
    "identical frames": Case(lambda d: write_video(d / "still.mp4", photo_frames(1) * 8)),
    "fade to black": Case(lambda d: write_video(d / "fade.mp4", fade_to_black(12)),
                          warning=r"scene cut .*smoothing restarts"),
    "scene cut": Case(lambda d: write_video(d / "cut.mp4", scene_cut()), warning=r"scene cut .*smoothing restarts"),
    "pure noise frame in the middle": Case(lambda d: write_video(d / "noisy.mp4", noise_in_the_middle()),
                                           warning=r"scene cut .*smoothing restarts here \(frame 5\)"),
    "tags that are not UTF-8": Case(lambda d: tags_not_utf8(d / "tags.mkv")),
    "corrupt frame mid-file (MJPEG, zeroed)": Case(lambda d: with_damaged_packet(
        write_video(d / "src.avi", photo_frames(12), codec="mjpeg", pix_fmt="yuvj420p"), d / "mjpeg.avi", 5, "zeroed"),
        warning=r"frame at 0\.200 s undecodable .*previous frame is repeated"),
    "corrupt frame mid-file (H.264, garbled)": Case(lambda d: with_damaged_packet(
        write_video(d / "src.mp4", photo_frames(12), options={"bf": "0"}), d / "h264.mp4", 5, "garbled"),
        warning=r"frame at 0\.200 s undecodable .*previous frame is repeated"),
}


# --- running the CLI -----------------------------------------------------------------------


@dataclass
class Run:
    returncode: int
    stdout: str
    stderr: str
    peak_memory_mib: float | None = None  # subprocess runs only


def run_cli(*args: str, timeout_s: float = 300) -> Run:
    """The CLI as a user runs it: its own process, its exit code, both streams as they come out, and
    its peak memory (wait4's rusage of that one process, taken by ffviz bench's small launcher: a child
    forked straight from pytest would count pytest's own pages in its peak)."""
    env = {**os.environ, "RERUN_ANALYTICS": "0"}
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryFile("w+") as out, \
            tempfile.TemporaryFile("w+") as err:
        report = Path(tmp) / "rusage"
        process = subprocess.Popen(measured_argv([sys.executable, "-m", "ffviz.cli", *args], report), cwd=ROOT,
                                   env=env, stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                   start_new_session=True)
        try:
            returncode = process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
            pytest.fail(f"ffviz {' '.join(args)} ran over {timeout_s} s")
        out.seek(0)
        err.seek(0)
        _, _, peak = read_measurement(report)
        return Run(returncode, out.read(), err.read(), peak / 2**20)


def run_in_process(capfd: pytest.CaptureFixture[str], *args: str) -> Run:
    """cli.main in this process (no interpreter start-up: 2-3 s a run here), streams captured at the
    file-descriptor level, so anything FFmpeg writes to fd 2 is seen as a subprocess would see it."""
    capfd.readouterr()
    code = cli.main(list(args))
    out, err = capfd.readouterr()
    return Run(code, out, err)


def digest(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def temp_leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if "ffviz-tmp" in p.name]


def decode(path: Path) -> tuple[VideoInfo, list[Frame]]:
    with video_reader.VideoReader(path) as reader:
        return reader.info, list(reader)


def assert_one_line_error(result: Run, exit_code: int, pattern: str) -> str:
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert result.returncode == exit_code, result.stderr
    assert lines[0].startswith("ffviz: error: ")
    message = lines[0].removeprefix("ffviz: error: ")
    assert re.search(pattern, message), message
    return message


# These run as real subprocesses too; the rest of the matrix runs cli.main in-process (same code path).
SUBPROCESS_CASES = ("missing file", "text file named .mp4", "truncated: moov last, before the index", "audio only",
                    "odd width and height", "corrupt frame mid-file (MJPEG, zeroed)", "3 frames, full mode",
                    "4K frames (3)")


@pytest.mark.parametrize(("name", "process"), [*((name, "in-process") for name in CASES if name != "4K frames (3)"),
                                              *((name, "subprocess") for name in SUBPROCESS_CASES)])
def test_bad_input_matrix(name, process, tmp_path, capfd):
    case = CASES[name]
    inputs, outputs = tmp_path / "in", tmp_path / "out"
    inputs.mkdir()
    outputs.mkdir()
    source = case.make(inputs)
    before = digest(source)
    output = outputs / "steady.mp4"
    argv = ("stabilize", str(source), "-o", str(output), "--mode", case.mode, "-k", "6")
    result = run_cli(*argv) if process == "subprocess" else run_in_process(capfd, *argv)

    assert digest(source) == before  # the input is never touched
    assert temp_leftovers(outputs) == []
    if case.error is not None:
        assert_one_line_error(result, 2, case.error)
        assert result.stdout == ""
        assert list(outputs.iterdir()) == []
        return

    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    if case.max_memory_mib is not None and result.peak_memory_mib is not None:
        print(f"{name}: peak memory {result.peak_memory_mib:.0f} MiB")
        assert result.peak_memory_mib < case.max_memory_mib
    warnings = result.stderr.strip().splitlines()
    assert all(line.startswith("ffviz: warning: ") for line in warnings), result.stderr
    if case.warning is None:
        assert warnings == []
    else:
        assert any(re.search(case.warning, line) for line in warnings), result.stderr
    # The output keeps what the reader makes of the input: frame count, timestamps, rate; upright size.
    info_in, frames_in = decode(source)
    info_out, frames_out = decode(output)
    assert len(frames_out) == len(frames_in) == video_reader.count_frames(output)
    assert [f.time_s for f in frames_out] == pytest.approx([f.time_s for f in frames_in], abs=1e-6)
    steps = np.diff([f.time_s for f in frames_in])
    if len(steps) < 2 or np.ptp(steps) < 1e-6:  # a constant rate: the same rate
        assert info_out.fps == info_in.fps
    assert (info_out.width, info_out.height) == (case.size or (info_in.width, info_in.height))
    assert info_out.rotation == 0
    # A sensible picture: as bright as the input (borders left black by --mode none cost a little).
    for f_in, f_out in zip(frames_in, frames_out):
        assert f_out.rgb.mean() >= 0.7 * f_in.rgb.mean() - 2


# --- what the input-making helpers promise (so the matrix tests what it says) ----------------


def test_the_corrupt_inputs_really_lose_a_frame_and_keep_its_slot(tmp_path):
    for name in ("corrupt frame mid-file (MJPEG, zeroed)", "corrupt frame mid-file (H.264, garbled)"):
        path = CASES[name].make(tmp_path)
        with video_reader.VideoReader(path) as reader:
            frames = list(reader)
        assert [round(f.time_s * FPS) for f in frames] == list(range(12)), name
        assert np.array_equal(frames[5].rgb, frames[4].rgb), name  # the previous frame, repeated
        assert not np.array_equal(frames[6].rgb, frames[5].rgb), name
        assert len(reader.warnings) == 1, reader.warnings


def test_a_lost_first_frame_takes_the_first_good_one(tmp_path):
    source = write_video(tmp_path / "src.avi", photo_frames(6), codec="mjpeg", pix_fmt="yuvj420p")
    path = with_damaged_packet(source, tmp_path / "first.avi", 0, "zeroed")
    with video_reader.VideoReader(path) as reader:
        frames = list(reader)
    assert [round(f.time_s * FPS) for f in frames] == list(range(6))
    assert np.array_equal(frames[0].rgb, frames[1].rgb)
    assert synthetic.psnr(frames[1].rgb, photo_frames(6)[1]) > 30
    assert len(reader.warnings) == 1 and "first good frame stands in" in reader.warnings[0]


def test_a_cut_in_the_middle_keeps_every_frame_before_the_cut(tmp_path):
    path = truncated(tmp_path, "faststart, two thirds in")
    with video_reader.VideoReader(path) as reader:
        frames = list(reader)
    # 21 packets demuxed (the 21st cut off), frames in presentation order up to that point, original times.
    assert len(frames) == 21 == video_reader.count_frames(path)
    assert [f.time_s for f in frames] == sorted(f.time_s for f in frames)
    truth = photo_frames(30)
    good = [f for f in frames if not any(f"{f.time_s:.3f} s" in w for w in reader.warnings)]
    assert len(good) >= 18
    for frame in good:
        assert synthetic.psnr(frame.rgb, truth[round(frame.time_s * FPS)]) > 25


# --- output safety ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    return write_video(tmp_path_factory.mktemp("clip") / "clip.mp4", photo_frames(12))


def test_output_equal_to_the_input_is_refused(clip, tmp_path, capfd):
    before = digest(clip)
    link = tmp_path / "link.mp4"
    link.symlink_to(clip)
    hard_link = tmp_path / "hard.mp4"
    hard_link.hardlink_to(clip)
    result = run_cli("stabilize", str(clip), "-o", str(clip), "--overwrite")
    assert_one_line_error(result, 3, r"output is the same file as the input")
    for output in (clip.parent / "." / clip.name, link, hard_link):  # other names of the same file
        result = run_in_process(capfd, "stabilize", str(clip), "-o", str(output), "--overwrite")
        assert_one_line_error(result, 3, r"output is the same file as the input")
    assert digest(clip) == before and temp_leftovers(clip.parent) == [] and temp_leftovers(tmp_path) == []


def test_existing_output_is_replaced_only_with_overwrite(clip, tmp_path):
    output = tmp_path / "out.mp4"
    output.write_bytes(b"an earlier result")
    result = run_cli("stabilize", str(clip), "-o", str(output), "--mode", "none")
    assert_one_line_error(result, 3, r"output already exists: .*out\.mp4 \(pass --overwrite to replace it\)")
    assert output.read_bytes() == b"an earlier result"
    result = run_cli("stabilize", str(clip), "-o", str(output), "--mode", "none", "--overwrite")
    assert result.returncode == 0, result.stderr
    assert video_reader.count_frames(output) == 12
    assert temp_leftovers(tmp_path) == []


@pytest.fixture(scope="module")
def long_clip(tmp_path_factory) -> Path:
    """200 frames at 320x180: long enough to be caught mid-run."""
    return write_video(tmp_path_factory.mktemp("long") / "long.mp4", photo_frames(200, 320, 180, step_px=1),
                       options={"preset": "ultrafast"})


def _default_sigint() -> None:
    # Tests started in the background (nohup, `cmd &` in a script) inherit SIGINT ignored, and Python keeps it
    # ignored in the child, as a background job should: the Ctrl-C this test sends would be lost.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize(("signum", "exit_code", "message"),
                         [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")])
def test_signal_mid_run_leaves_no_partial_output(long_clip, tmp_path, signum, exit_code, message):
    output = tmp_path / "out.mp4"
    output.write_bytes(b"an earlier result")  # --overwrite: an interrupted run must not destroy it either
    process = subprocess.Popen(
        [sys.executable, "-m", "ffviz.cli", "stabilize", str(long_clip), "-o", str(output), "--mode", "crop",
         "--overwrite"], cwd=ROOT, env={**os.environ, "RERUN_ANALYTICS": "0"},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    # Wait for pass 2: its temp file beside the output is the partial output that must not survive.
    deadline = time.monotonic() + 120
    while not temp_leftovers(tmp_path) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert temp_leftovers(tmp_path), "pass 2 never started"
    time.sleep(0.3)  # well inside the encoding loop
    process.send_signal(signum)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == exit_code, stderr
    assert stderr.strip().splitlines() == [f"ffviz: {message}; no output written"]
    assert stdout == ""
    assert output.read_bytes() == b"an earlier result"
    assert temp_leftovers(tmp_path) == []


@pytest.fixture
def tiny_tmpfs(tmp_path):
    """A 200 KiB filesystem, mounted for the test (needs root; skipped cleanly otherwise)."""
    mount_point = tmp_path / "small_disk"
    mount_point.mkdir()
    can_mount = os.geteuid() == 0 and shutil.which("mount") and shutil.which("umount")
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(mount_point)],
                             capture_output=True, text=True) if can_mount else None
    if mounted is None or mounted.returncode != 0:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", str(mount_point)], check=True)


def test_full_disk_reports_one_line_and_leaves_no_partial_file(tiny_tmpfs, tmp_path):
    # Noise does not compress: 8 frames of 320x180 at crf 10 need far more than 200 KiB.
    rng = np.random.default_rng(0)
    source = write_video(tmp_path / "noise.mp4", [rng.integers(0, 256, (180, 320, 3), np.uint8) for _ in range(8)],
                         options={"crf": "10", "preset": "ultrafast"})
    before = digest(source)
    result = run_cli("stabilize", str(source), "-o", str(tiny_tmpfs / "out.mp4"), "--mode", "none", "--crf", "10")
    assert_one_line_error(result, 3, r"(cannot (finish )?writ|cannot create).*No space left on device")
    assert list(tiny_tmpfs.iterdir()) == []
    assert digest(source) == before


class _FillsUp:
    """An output container whose disk fills up after `room` packets (every other call goes through)."""

    def __init__(self, container, room: int) -> None:
        self._container, self._room = container, room

    def mux(self, packet) -> None:
        if self._room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._room -= 1
        self._container.mux(packet)

    def __getattr__(self, name):
        return getattr(self._container, name)


@pytest.mark.parametrize("room", [0, 5])
def test_disk_full_while_writing_in_process(clip, tmp_path, monkeypatch, capsys, room):
    """The same without root: the muxer raises ENOSPC, as FFmpeg does when a write fails."""
    real_open = av.open

    def open_filling_up(file, mode="r", **kwargs):
        container = real_open(file, mode, **kwargs)
        return _FillsUp(container, room) if mode == "w" else container

    monkeypatch.setattr(video_writer.av, "open", open_filling_up)
    output = tmp_path / "out.mp4"
    assert cli.main(["stabilize", str(clip), "-o", str(output), "--mode", "none"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0] and err[0].startswith("ffviz: error: cannot")
    assert list(tmp_path.iterdir()) == []
