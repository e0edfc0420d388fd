"""pipeline.runtime's video I/O (video_reader, video_writer, audio, encoding): probing, counting, reading and writing,
on small videos made here with PyAV."""

from __future__ import annotations

import os
import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from pipeline.evaluation import synthetic
from pipeline.errors import ConfigError, InputError, OutputError
from pipeline.runtime.encoding import Encoding, x264_cpu_params, x264_options
from pipeline.runtime.video_reader import VideoReader, count_frames, probe_video
from pipeline.runtime.video_writer import VideoWriter, check_output_path
from tests.conftest import real_clip

W, H, N, FPS = 64, 48, 10, 25


def pattern(index: int, width: int = W, height: int = H) -> np.ndarray:
    """Smooth gradients (kind to a lossy codec) plus a bright block that moves with the index."""
    y, x = np.mgrid[0:height, 0:width]
    red, green = x * 255 // max(width - 1, 1), y * 255 // max(height - 1, 1)
    rgb = np.stack([red, green, np.full_like(x, (index * 25) % 256)], axis=-1).astype(np.uint8)
    left = (index * 4) % (width - 8)
    rgb[4:12, left : left + 8] = 255
    return rgb


def make_video(
    path: Path,
    *,
    width: int = W,
    height: int = H,
    frames: int = N,
    codec: str = "libx264",
    pix_fmt: str = "yuv420p",
    pts: list[int] | None = None,
    time_base: Fraction = Fraction(1, FPS),
    audio: str | None = None,
    rotation_ccw: int | None = None,
    options: dict[str, str] | None = None,
    muxer_options: dict[str, str] | None = None,
) -> Path:
    """A small test video; `pts` (in `time_base`) makes it VFR, `audio` adds a 440 Hz sine."""
    pts = pts if pts is not None else list(range(frames))
    with av.open(str(path), "w", options=muxer_options or {}) as container:
        stream = container.add_stream(codec, rate=FPS, options=options or {})
        stream.width, stream.height, stream.pix_fmt = width, height, pix_fmt
        stream.codec_context.time_base = time_base
        if rotation_ccw is not None:
            stream.set_display_rotation(rotation_ccw)
        audio_stream = container.add_stream(audio, rate=44100, layout="mono") if audio else None
        for index in range(frames):
            frame = av.VideoFrame.from_ndarray(pattern(index, width, height), format="rgb24")
            frame.pts, frame.time_base = pts[index], time_base
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
        if audio_stream is not None:
            mux_sine(container, audio_stream, float((pts[-1] + 1) * time_base))
    return path


def mux_sine(container: av.container.OutputContainer, audio_stream: av.audio.stream.AudioStream,
             seconds: float) -> None:
    """Encode and mux `seconds` of a 440 Hz mono sine at 44.1 kHz into `audio_stream`, then flush it."""
    chunk = 1024
    for start in range(0, int(seconds * 44100), chunk):
        t = (start + np.arange(chunk)) / 44100
        samples = (0.3 * np.sin(2 * np.pi * 440 * t)).astype(np.float32)[None]
        # PyAV converts float samples to whatever the encoder takes.
        frame = av.AudioFrame.from_ndarray(samples, format="fltp", layout="mono")
        frame.sample_rate, frame.pts, frame.time_base = 44100, start, Fraction(1, 44100)
        for packet in audio_stream.encode(frame):
            container.mux(packet)
    for packet in audio_stream.encode(None):
        container.mux(packet)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def copy_through(source: Path, target: Path, **writer_options) -> tuple[list, list[str]]:
    """Read source and write every frame unchanged with its pts; returns the frames and warnings."""
    frames = []
    with VideoReader(source) as reader, VideoWriter(target, like=reader.info, **writer_options) as writer:
        for frame in reader:
            writer.write(frame.rgb, pts=frame.pts)
            frames.append(frame)
    return frames, reader.warnings + writer.warnings


def read_all(path: Path) -> list:
    with VideoReader(path) as reader:
        return list(reader)


def audio_seconds(path: Path) -> tuple[str, float]:
    """Codec and decoded length of the first audio stream."""
    with av.open(str(path)) as container:
        stream = container.streams.audio[0]
        samples = sum(frame.samples for frame in container.decode(stream))
        return stream.codec_context.name, samples / stream.codec_context.sample_rate


def temp_leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if "ffviz-tmp" in p.name]


# --- probe and read -------------------------------------------------------------------------


def test_probe_reports_the_header(tmp_path):
    info = probe_video(make_video(tmp_path / "in.mp4"))
    assert (info.width, info.height) == (W, H)
    assert info.fps == FPS
    assert info.frame_count == N == count_frames(info.path)
    assert info.codec == "h264"
    assert info.rotation == 0
    assert not info.has_audio
    assert info.time_base > 0
    assert info.duration_s == pytest.approx(N / FPS, abs=1 / FPS)


def test_reader_streams_frames_in_order_with_timestamps(tmp_path):
    path = make_video(tmp_path / "in.mkv", codec="ffv1", pix_fmt="yuv444p")
    frames = read_all(path)
    assert [f.index for f in frames] == list(range(N))
    assert [round(f.time_s * FPS) for f in frames] == list(range(N))
    for index, frame in enumerate(frames):
        assert frame.rgb.shape == (H, W, 3) and frame.rgb.dtype == np.uint8
        assert psnr(frame.rgb, pattern(index)) > 35  # only the RGB<->YUV rounding is lost


def test_reader_is_single_pass(tmp_path):
    with VideoReader(make_video(tmp_path / "in.mp4")) as reader:
        assert len(list(reader)) == N
        with pytest.raises(RuntimeError):
            list(reader)


@pytest.mark.parametrize(
    ("codec", "pix_fmt", "suffix"),
    [("ffv1", "gray", ".mkv"), ("ffv1", "yuv420p10le", ".mkv"), ("libx264", "yuv420p10le", ".mp4")],
)
def test_grayscale_and_10bit_come_out_as_rgb_uint8(tmp_path, codec, pix_fmt, suffix):
    path = make_video(tmp_path / f"in{suffix}", codec=codec, pix_fmt=pix_fmt)
    frames = read_all(path)
    assert len(frames) == N
    rgb = frames[3].rgb
    assert rgb.shape == (H, W, 3) and rgb.dtype == np.uint8
    if pix_fmt == "gray":
        assert np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 1], rgb[..., 2])
        luma = pattern(3).astype(np.float64) @ [0.299, 0.587, 0.114]
        assert np.abs(rgb[..., 0] - luma).mean() < 3
    else:
        assert psnr(rgb, pattern(3)) > 30


def test_rotation_metadata_is_applied_to_frames(tmp_path):
    # FFmpeg's display matrix counts counterclockwise: -90 means "turn 90 clockwise to display".
    path = make_video(tmp_path / "in.mp4", rotation_ccw=-90)
    info = probe_video(path)
    assert info.rotation == 90
    assert (info.width, info.height) == (H, W)
    first = read_all(path)[0]
    assert first.rgb.shape == (W, H, 3)
    # The bright block at the stored top-left lands top-right after a clockwise quarter turn.
    assert psnr(first.rgb, np.rot90(pattern(0), k=-1)) > 35
    # The writer stores upright frames with no rotation tag.
    out = tmp_path / "out.mp4"
    copy_through(path, out)
    out_info = probe_video(out)
    assert (out_info.rotation, out_info.width, out_info.height) == (0, H, W)
    assert psnr(read_all(out)[0].rgb, first.rgb) > 35


# --- write ----------------------------------------------------------------------------------


@pytest.mark.parametrize("time_base", [Fraction(1, FPS), Fraction(1, 90000)])
def test_mpeg4_output_keeps_timestamps_and_its_quantiser_trades_bits_for_fidelity(tmp_path, time_base):
    # 1/90000 is beyond MPEG-4 Part 2's time base limit (65535): frames must keep their times all the same.
    ticks = round(1 / (FPS * time_base))
    pts = [i * ticks for i in range(N - 2)] + [(N - 1) * ticks, (N + 2) * ticks]  # VFR at the end
    source = make_video(tmp_path / "in.mp4", options={"crf": "0"}, pts=pts, time_base=time_base)
    outputs = {}
    for q in (2, 12):
        outputs[q] = tmp_path / f"q{q}.mp4"
        written, warnings = copy_through(source, outputs[q], encoding=Encoding(codec="mpeg4", qscale=q))
        assert warnings == []
        with av.open(str(outputs[q])) as container:
            assert container.streams.video[0].codec_context.name == "mpeg4"
        again = read_all(outputs[q])
        assert [float(f.time_s) for f in again] == pytest.approx([float(f.time_s) for f in written], abs=1e-4)
        outputs[q] = (outputs[q].stat().st_size, min(psnr(a.rgb, b.rgb) for a, b in zip(written, again)))
    (fine_bytes, fine_psnr), (coarse_bytes, coarse_psnr) = outputs[2], outputs[12]
    assert fine_psnr > 30 and fine_psnr > coarse_psnr + 3 and fine_bytes > 1.5 * coarse_bytes


@pytest.mark.parametrize("options, word", [({"codec": "vp9"}, "codec"), ({"crf": 52}, "crf"),
                                           ({"preset": "warp9"}, "preset"), ({"qscale": 1}, "qscale")])
def test_encoding_refuses_values_its_encoders_cannot_take(options, word):
    with pytest.raises(ConfigError, match=word):
        Encoding(**options)


def test_round_trip_keeps_count_rate_size_timestamps_and_pixels(tmp_path):
    source = make_video(tmp_path / "in.mp4", options={"crf": "0"})
    target = tmp_path / "out.mp4"
    written, warnings = copy_through(source, target, encoding=Encoding(crf=18))
    assert warnings == []
    info_in, info_out = probe_video(source), probe_video(target)
    assert (info_out.width, info_out.height, info_out.fps) == (info_in.width, info_in.height, info_in.fps)
    assert count_frames(target) == N
    back = read_all(target)
    assert len(back) == N
    assert [f.time_s for f in back] == pytest.approx([f.time_s for f in written], abs=1e-9)
    for before, after in zip(written, back):
        assert psnr(before.rgb, after.rgb) > 35
    assert temp_leftovers(tmp_path) == []


def _slices_per_frame(path: Path) -> list[int]:
    """Coded slices (NAL types 1 and 5) in each H.264 packet of an MP4 (4-byte length-prefixed NAL units)."""
    counts = []
    with av.open(str(path)) as container:
        for packet in container.demux(video=0):
            data, at, slices = bytes(packet), 0, 0
            while at + 4 <= len(data):
                size = int.from_bytes(data[at:at + 4], "big")
                slices += (data[at + 4] & 0x1F) in (1, 5) if size else 0
                at += 4 + size
            if data:
                counts.append(slices)
    return counts


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="x264 runs one thread on one core: one slice either way")
def test_h264_is_encoded_on_frame_threads_one_slice_a_frame(tmp_path):
    """PyAV's default (slice threads) makes x264 cut every frame into one slice per thread; frame threads, as
    the ffmpeg command line uses, keep one slice a frame: the same CPU, less wall time, no slice-edge cost."""
    source = make_video(tmp_path / "in.mp4", width=640, height=360, frames=8)  # tiny frames get one slice anyway
    copy_through(source, tmp_path / "out.mp4", encoding=Encoding(codec="h264", crf=18))
    assert set(_slices_per_frame(tmp_path / "out.mp4")) == {1}


def test_x264_is_kept_off_avx512_naming_only_the_cpus_own_instruction_sets(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nflags\t\t: fpu sse sse2 pni ssse3 sse4_1 sse4_2 avx avx2 fma bmi1 bmi2 "
                       "avx512f avx512bw\nclflush size\t: 64\n")
    assert x264_cpu_params(cpuinfo) == ("asm=SSE,SSE2Fast,SSE3,SSSE3,SSE4.1,SSE4.2,AVX,FMA3,BMI1,BMI2,AVX2,Cache64",)
    older = tmp_path / "older"  # no AVX-512: x264's own detection stands
    older.write_text("flags\t\t: fpu sse sse2 avx avx2\n")
    assert x264_cpu_params(older) == () and x264_cpu_params(tmp_path / "absent") == ()
    assert x264_options("chromaloc=0") == {"x264-params": ":".join(("chromaloc=0", *x264_cpu_params()))}


def test_the_same_frames_encode_to_the_same_bytes(tmp_path):
    """Test clips, benchmarks and users' re-runs need it. PyAV's libx264 reads uninitialised memory in an
    AVX-512 routine at this size: without x264_cpu_params, eight encodes in one process gave two or more
    different files in each of five runs on an AVX-512 machine."""
    video = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=30, seed=1))
    sources = [tmp_path / f"in{i}.mp4" for i in range(8)]
    for source in sources:
        synthetic.write_video(video, source)
    assert len({source.read_bytes() for source in sources}) == 1
    outputs = [tmp_path / f"out{i}.mp4" for i in range(8)]
    for output in outputs:
        copy_through(sources[0], output, encoding=Encoding(codec="h264", crf=18))
    assert len({output.read_bytes() for output in outputs}) == 1


def test_variable_frame_rate_timing_is_kept(tmp_path):
    pts_ms = [0, 40, 80, 200, 240, 250, 400, 433, 500, 700]
    source = make_video(tmp_path / "in.mp4", pts=pts_ms, time_base=Fraction(1, 1000))
    target = tmp_path / "out.mp4"
    copy_through(source, target)
    times_in = [f.time_s for f in read_all(source)]
    times_out = [f.time_s for f in read_all(target)]
    assert times_in == pytest.approx([p / 1000 for p in pts_ms], abs=1e-6)
    assert times_out == pytest.approx(times_in, abs=1e-6)


def test_late_start_in_an_ntsc_time_base_is_kept(tmp_path):
    # Like vplab_C.avi: 29.97 fps counted in 100/2997 s, first frame at pts 1, not 0. The MP4's
    # edit list (which delays the start) must count in 1/2997 s too, or the start gets rounded.
    source = make_video(
        tmp_path / "in.mp4",
        time_base=Fraction(100, 2997),
        pts=list(range(1, N + 1)),
        muxer_options={"movie_timescale": "2997"},
    )
    target = tmp_path / "out.mp4"
    copy_through(source, target)

    def clock(path: Path) -> list[Fraction]:  # absolute times: Frame.time_s counts from the first frame
        time_base = probe_video(path).time_base
        return [f.pts * time_base for f in read_all(path)]

    assert clock(source)[0] == Fraction(100, 2997)
    assert clock(target) == clock(source)


def test_write_without_pts_spaces_frames_at_the_input_rate(tmp_path):
    like = probe_video(make_video(tmp_path / "in.mp4"))
    target = tmp_path / "out.mp4"
    with VideoWriter(target, like=like) as writer:
        for index in range(N):
            writer.write(pattern(index), time_s=index / FPS if index % 2 else None)
    assert [round(f.time_s * FPS, 6) for f in read_all(target)] == list(range(N))


def test_repeated_pts_is_nudged_with_a_warning_not_an_error(tmp_path):
    like = probe_video(make_video(tmp_path / "in.mp4"))
    target = tmp_path / "out.mp4"
    with VideoWriter(target, like=like) as writer:
        for index, pts in enumerate([0, 1, 1, 3]):
            writer.write(pattern(index), pts=pts)
    assert len(writer.warnings) == 1
    assert [f.pts for f in read_all(target)] == [
        round(t * like.time_base / probe_video(target).time_base) for t in (0, 1, 2, 3)
    ]


def test_writer_can_write_another_size(tmp_path):
    like = probe_video(make_video(tmp_path / "in.mp4"))
    target = tmp_path / "out.mp4"
    with VideoWriter(target, like=like, width=32, height=24) as writer:
        for index in range(3):
            writer.write(pattern(index, 32, 24))
    info = probe_video(target)
    assert (info.width, info.height, info.frame_count, info.fps) == (32, 24, 3, like.fps)


def test_odd_size_is_padded_to_even_with_content_kept(tmp_path):
    source = make_video(tmp_path / "in.mkv", width=65, height=49, codec="ffv1", pix_fmt="yuv444p")
    target = tmp_path / "out.mp4"
    written, _ = copy_through(source, target)
    info = probe_video(target)
    # yuv420p H.264 cannot store odd sizes: one replicated pixel is added on each odd side.
    assert (info.width, info.height) == (66, 50)
    back = read_all(target)
    assert len(back) == N
    for before, after in zip(written, back):
        assert psnr(before.rgb, after.rgb[:49, :65]) > 35


def test_audio_is_copied_when_mp4_can_hold_it(tmp_path):
    source = make_video(tmp_path / "in.mp4", audio="aac")
    target = tmp_path / "out.mp4"
    copy_through(source, target, audio_from=source)
    assert probe_video(target).has_audio
    codec_in, seconds_in = audio_seconds(source)
    codec_out, seconds_out = audio_seconds(target)
    assert codec_out == codec_in == "aac"
    assert seconds_out == pytest.approx(seconds_in, abs=0.1)
    with av.open(str(source)) as a, av.open(str(target)) as b:  # copied, not re-encoded
        payload_in = [bytes(p) for p in a.demux(audio=0) if p.size]
        assert payload_in == [bytes(p) for p in b.demux(audio=0) if p.size]


def test_audio_mp4_cannot_hold_is_transcoded_to_aac(tmp_path):
    source = make_video(tmp_path / "in.mkv", audio="pcm_s16le")
    target = tmp_path / "out.mp4"
    copy_through(source, target, audio_from=source)
    codec_out, seconds_out = audio_seconds(target)
    assert codec_out == "aac"
    assert seconds_out == pytest.approx(audio_seconds(source)[1], abs=0.1)


def test_no_audio_source_track_gives_silent_output(tmp_path):
    source = make_video(tmp_path / "in.mp4")
    target = tmp_path / "out.mp4"
    copy_through(source, target, audio_from=source)
    assert not probe_video(target).has_audio


def test_failed_run_leaves_nothing_behind(tmp_path):
    source = make_video(tmp_path / "in.mp4", audio="aac")
    target = tmp_path / "out.mp4"
    with pytest.raises(ZeroDivisionError):
        with (
            VideoReader(source) as reader,
            VideoWriter(target, like=reader.info, audio_from=source) as writer,
        ):
            for frame in reader:
                writer.write(frame.rgb, pts=frame.pts)
                assert temp_leftovers(tmp_path)  # work in progress is in a temp file beside the target
                if frame.index == 5:
                    1 / 0
    assert not target.exists()
    assert temp_leftovers(tmp_path) == []


def test_failed_run_keeps_the_previous_output(tmp_path):
    source = make_video(tmp_path / "in.mp4")
    target = tmp_path / "out.mp4"
    target.write_bytes(b"previous result")
    writer = VideoWriter(target, like=probe_video(source))
    writer.write(pattern(0))
    writer.abort()
    assert target.read_bytes() == b"previous result"
    assert temp_leftovers(tmp_path) == []


def test_writer_rejects_a_wrongly_shaped_frame(tmp_path):
    like = probe_video(make_video(tmp_path / "in.mp4"))
    with pytest.raises(ValueError), VideoWriter(tmp_path / "out.mp4", like=like) as writer:
        writer.write(np.zeros((H, W + 2, 3), np.uint8))
    assert not (tmp_path / "out.mp4").exists() and temp_leftovers(tmp_path) == []


# --- refusals and errors --------------------------------------------------------------------


def test_output_same_as_input_is_refused(tmp_path):
    source = make_video(tmp_path / "in.mp4")
    other_spelling = tmp_path / "sub" / ".." / "in.mp4"
    (tmp_path / "sub").mkdir()
    link = tmp_path / "link.mp4"
    link.symlink_to(source)
    for output in (source, other_spelling, link):
        with pytest.raises(OutputError, match="same file"):
            check_output_path(output, source, overwrite=True)
        with pytest.raises(OutputError, match="same file"):
            VideoWriter(output, like=probe_video(source))
    other = make_video(tmp_path / "other.mp4")
    with pytest.raises(OutputError, match="same file"):  # the audio source counts as an input too
        VideoWriter(link, like=probe_video(other), audio_from=source)
    assert source.stat().st_size > 0 and temp_leftovers(tmp_path) == []


def test_existing_output_needs_overwrite(tmp_path):
    source = make_video(tmp_path / "in.mp4")
    target = tmp_path / "out.mp4"
    target.write_bytes(b"keep me")
    with pytest.raises(OutputError, match="--overwrite"):
        check_output_path(target, source, overwrite=False)
    check_output_path(target, source, overwrite=True)
    check_output_path(tmp_path / "new.mp4", source, overwrite=False)
    assert target.read_bytes() == b"keep me"


@pytest.mark.parametrize(
    ("name", "message"),
    [("out.avi", r"\.mp4, \.mov, \.mkv"), ("missing/out.mp4", "does not exist"), ("dir.mp4", "directory")],
)
def test_bad_output_paths_are_refused(tmp_path, name, message):
    source = make_video(tmp_path / "in.mp4")
    (tmp_path / "dir.mp4").mkdir()
    with pytest.raises(OutputError, match=message) as caught:
        check_output_path(tmp_path / name, source, overwrite=True)
    assert "\n" not in str(caught.value)


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write into read-only folders")
def test_unwritable_output_folder_is_refused(tmp_path):
    source = make_video(tmp_path / "in.mp4")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    with pytest.raises(OutputError, match="not writable"):
        check_output_path(locked / "out.mp4", source, overwrite=False)


def _make_bad_input(tmp_path: Path, kind: str) -> Path:
    path = tmp_path / "bad.mp4"
    if kind == "directory":
        path.mkdir()
    elif kind == "empty":
        path.touch()
    elif kind == "random bytes":
        path.write_bytes(np.random.default_rng(0).integers(0, 256, 20000, dtype=np.uint8).tobytes())
    elif kind == "text":
        path.write_text("this is not a video\n" * 100)
    elif kind == "text as .nfo":  # FFmpeg's tty demuxer would play this as an ANSI-art video
        path = tmp_path / "bad.nfo"
        path.write_text("this is not a video\n" * 100)
    elif kind == "audio only":
        path = tmp_path / "bad.m4a"
        with av.open(str(path), "w", format="mp4") as container:
            stream = container.add_stream("aac", rate=44100, layout="mono")
            frame = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
            frame.sample_rate, frame.pts = 44100, 0
            for packet in [*stream.encode(frame), *stream.encode(None)]:
                container.mux(packet)
    return path


@pytest.mark.parametrize(
    ("kind", "message"),
    [
        ("missing", "not found"),
        ("directory", "directory"),
        ("empty", "empty"),
        ("random bytes", "not a video"),
        ("text", "not a video"),
        ("text as .nfo", "not a video"),
        ("audio only", "no video stream"),
    ],
)
@pytest.mark.parametrize("open_it", [probe_video, count_frames, VideoReader])
def test_bad_inputs_give_one_line_input_errors(tmp_path, kind, message, open_it):
    path = _make_bad_input(tmp_path, kind)
    with pytest.raises(InputError, match=message) as caught:
        open_it(path)
    assert "\n" not in str(caught.value)
    assert path.name in str(caught.value)


def test_undecodable_packet_is_replaced_by_the_previous_frame_with_a_warning(tmp_path):
    # MJPEG in MKV, with packet 4's bytes zeroed: the container is fine, one picture is not.
    path = tmp_path / "broken.mkv"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mjpeg", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = W, H, "yuvj420p"
        for index in range(N):
            frame = av.VideoFrame.from_ndarray(pattern(index), format="rgb24")
            frame.pts = index
            for packet in stream.encode(frame):
                if index == 4:
                    broken = av.Packet(bytes(packet.size))
                    broken.pts, broken.dts, broken.time_base = packet.pts, packet.dts, packet.time_base
                    broken.stream, packet = stream, broken
                container.mux(packet)
    with VideoReader(path) as reader:
        frames = list(reader)
    # Frame count and timing are the file's: frame 3's picture stands in at frame 4's time.
    assert [f.index for f in frames] == list(range(N))
    assert [round(f.time_s * FPS) for f in frames] == list(range(N))
    assert np.array_equal(frames[4].rgb, frames[3].rgb)
    assert psnr(frames[5].rgb, pattern(5)) > 30
    assert len(reader.warnings) == 1 and "undecodable" in reader.warnings[0] and "0.160 s" in reader.warnings[0]


def test_pipeline_io_does_not_import_viewers():
    code = ("import sys, pipeline.runtime.video_reader, pipeline.runtime.video_writer; "
            "sys.exit(bool({'rerun', 'matplotlib'} & set(sys.modules)))")
    root = Path(__file__).resolve().parents[1]
    assert subprocess.run([sys.executable, "-c", code], cwd=root).returncode == 0


# --- real clips -----------------------------------------------------------------------------

README_CLIPS = {  # name: (width, height, fps, frames), from ../shared/videos/README.md
    "sudheerachary_small-shaky-5.avi": (320, 180, 30, 210),
    "linyihaolyh_shaky.mp4": (480, 360, 25, 245),
    "selh_tasc.mp4": (360, 240, 30, 370),
    "selh_asb_1.mp4": (360, 240, 30, 315),
    "sudheerachary_shaky-5.avi": (640, 360, 30, 496),
    "selh_shaky_1.mp4": (480, 360, 30, 904),
    "dfkimera_shaky.mp4": (640, 360, 30, 916),
    "zhangyilang_03_input.avi": (640, 360, 30, 288),
    "vplab_C.avi": (640, 360, 30, 250),
    "lohoi_test_eric_vid_original.mp4": (1280, 720, 25, 221),
    "scikitvideo_bikes.mp4": (640, 272, 25, 250),
}


@pytest.mark.real_video
@pytest.mark.parametrize("name", README_CLIPS)
def test_real_clip_probe_and_count_match_readme(name):
    width, height, fps, frames = README_CLIPS[name]
    info = probe_video(real_clip(name))
    assert (info.width, info.height, round(info.fps)) == (width, height, fps)
    assert info.frame_count == frames
    assert count_frames(info.path) == frames
    with VideoReader(info.path) as reader:  # what the reader really yields (decoded, not converted)
        assert sum(1 for _ in reader.decoded_frames()) == frames
        assert reader.warnings == []


@pytest.mark.real_video
def test_real_clip_copy_through_keeps_count_rate_size_and_audio(tmp_path):
    source = real_clip("linyihaolyh_shaky.mp4")
    target = tmp_path / "out.mp4"
    written, warnings = copy_through(source, target, audio_from=source, encoding=Encoding(preset="veryfast"))
    assert len(written) == 245 and warnings == []
    info = probe_video(target)
    assert (info.width, info.height, info.fps, info.frame_count) == (480, 360, Fraction(25), 245)
    assert count_frames(target) == 245
    assert info.has_audio
    assert audio_seconds(target)[1] == pytest.approx(audio_seconds(source)[1], abs=0.1)
