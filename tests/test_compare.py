"""ffviz compare (side by side with camera paths), and stabilize's --compare, --preview and --start, on a small
synthetic clip with known camera motion and an audio track whose loudness tells the time."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from ffviz import cli
from ffviz import compare as cmp
from pipeline import geometry
from pipeline.evaluation import synthetic
from pipeline.frames import Frame
from pipeline.runtime import video_reader

FPS = 30
N = 45  # 1.5 s
W, H = 320, 180
RATE = 44100


def loudness_at(t: np.ndarray) -> np.ndarray:
    """The test audio's amplitude at time t (s): a ramp, so a stretch of audio says where it came from."""
    return 0.05 + 0.4 * t / (N / FPS)


def write_clip(path: Path, frames, *, fps: int = FPS, audio: bool = True) -> Path:
    """H.264 (near lossless) with, when ``audio``, an AAC 440 Hz sine as long as the video, ramping in loudness."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps, options={"crf": "4", "preset": "ultrafast"})
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv420p"
        sound = container.add_stream("aac", rate=RATE, layout="mono") if audio else None
        for rgb in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
        if sound is not None:
            chunk = 1024
            for start in range(0, int(len(frames) / fps * RATE), chunk):
                t = (start + np.arange(chunk)) / RATE
                samples = (loudness_at(t) * np.sin(2 * np.pi * 440 * t)).astype(np.float32)[None]
                frame = av.AudioFrame.from_ndarray(samples, format="fltp", layout="mono")
                frame.sample_rate, frame.pts, frame.time_base = RATE, start, Fraction(1, RATE)
                for packet in sound.encode(frame):
                    container.mux(packet)
            for packet in sound.encode(None):
                container.mux(packet)
    return path


def audio_track(path: Path) -> np.ndarray:
    """The first audio stream decoded to mono float samples, from its first sample."""
    with av.open(str(path)) as container:
        stream = container.streams.audio[0]
        return np.concatenate([frame.to_ndarray().reshape(-1) for frame in container.decode(stream)])


def amplitude(samples: np.ndarray) -> float:
    return float(np.sqrt(2.0 * np.mean(samples.astype(np.float64) ** 2)))


def read(path: Path) -> list[Frame]:
    with video_reader.VideoReader(path) as reader:
        return list(reader)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(cv2.PSNR(np.ascontiguousarray(a), np.ascontiguousarray(b)))


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """The shaky input (with audio; a disc moves across the scene), its known motion; a half-size copy, a 15 frames/s
    copy and one cut short."""
    video = synthetic.generate(synthetic.SyntheticConfig(width=W, height=H, n_frames=N, seed=3, jitter_px=4.0,
                                                         blurred_frames=()))
    folder = tmp_path_factory.mktemp("compare")
    small = [cv2.resize(f, (W // 2, H // 2), interpolation=cv2.INTER_AREA) for f in video.frames]
    return dict(
        video=video, folder=folder,
        input=write_clip(folder / "shaky.mp4", video.frames),
        small=write_clip(folder / "small.mkv", small, audio=False),
        half_rate=write_clip(folder / "half_rate.mp4", video.frames[::2], fps=FPS // 2, audio=False),
        short=write_clip(folder / "short.mp4", video.frames[:30], audio=False),
    )


def panel_region(frame: np.ndarray, lay, i: int) -> np.ndarray:
    x, w = lay.panel_x[i], lay.panel_w[i]
    return frame[lay.video_top:lay.video_top + lay.video_height, x:x + w]


def test_compare_writes_even_size_every_frame_and_the_input_audio(clip, tmp_path):
    out = tmp_path / "sbs.mp4"
    assert cli.main(["compare", str(clip["input"]), str(clip["small"]), "-o", str(out)]) == 0
    lay = cmp.layout([(W, H), (W // 2, H // 2)], H)
    info = video_reader.probe_video(out)
    assert (info.width, info.height) == (lay.width, lay.height) == (W + cmp.GAP_PX + W, lay.header + H + lay.strip)
    assert info.width % 2 == 0 and info.height % 2 == 0
    assert info.fps == FPS
    frames = read(out)
    assert len(frames) == N
    assert [round(f.time_s * FPS) for f in frames] == list(range(N))  # the input's timing, from 0
    source = clip["video"].frames
    for t in (0, 17, N - 1):  # both videos in their place at their frame, the half-size one scaled back up
        # Measured 28.5-29.7 dB and 25.1-25.6 dB (two H.264 codings of saturated colours, a resize); against the
        # frame 3 before or after: 12-15 dB.
        for i, bound in ((0, 26), (1, 23)):
            shown = panel_region(frames[t].rgb, lay, i)
            assert psnr(shown, source[t]) > max(bound, psnr(shown, source[abs(t - 3)]) + 6)
    assert info.has_audio
    seconds_in, seconds_out = len(audio_track(clip["input"])) / RATE, len(audio_track(out)) / RATE
    assert seconds_out == pytest.approx(seconds_in, abs=0.05)


def test_camera_path_follows_the_known_camera_motion(clip):
    """The plotted path of the input is where each frame's centre lies in the first frame: the truth accumulated."""
    video = clip["video"]
    path = cmp.camera_path(cmp.Panel(clip["input"], "input"))
    truth = np.zeros((N, 3))
    first_from_t = geometry.IDENTITY.copy()
    for t in range(1, N):
        first_from_t = first_from_t @ np.linalg.inv(video.curr_from_prev[t])
        truth[t] = geometry.decompose(first_from_t / first_from_t[2, 2], W, H)[:3]
    assert np.ptp(truth[:, 0]) > 40  # a pan and shake worth plotting
    error = np.abs(path.xy_angle - truth)
    assert error[:, :2].max() < 0.8 and error[:, 2].max() < 0.2, error.max(axis=0)  # measured 0.33 px, 0.10 deg
    np.testing.assert_allclose(path.times, np.arange(N) / FPS, atol=1e-3)


def test_three_videos_of_different_rates_line_up_by_time(clip, tmp_path):
    out = tmp_path / "three.mkv"
    assert cli.main(["compare", str(clip["input"]), str(clip["small"]), str(clip["half_rate"]), "-o", str(out),
                     "--labels", "original,,half rate", "--height", "120"]) == 0
    lay = cmp.layout([(W, H), (W // 2, H // 2), (W, H)], 120)
    frames = read(out)
    assert len(frames) == N and (frames[0].rgb.shape[1], frames[0].rgb.shape[0]) == (lay.width, lay.height)
    assert lay.video_height == 120 and lay.panel_w == (214, 214, 214)
    source = [cv2.resize(f, (214, 120), interpolation=cv2.INTER_AREA) for f in clip["video"].frames]
    for t in (10, 11, 31):  # the 15 frames/s video shows its latest frame: input frame t rounded down to even
        third = panel_region(frames[t].rgb, lay, 2)
        shown = t - t % 2
        assert psnr(third, source[shown]) > 28
        if t % 2:
            assert psnr(third, source[shown]) > psnr(third, source[t]) + 3


def test_a_shorter_video_is_refused_unless_shortest(clip, tmp_path, capsys):
    out = tmp_path / "sbs.mp4"
    assert cli.main(["compare", str(clip["input"]), str(clip["short"]), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "short.mp4 ends at 1.00 s (30 frames)" in err and "--shortest" in err and "\n" not in err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if "ffviz-tmp" in p.name]
    assert cli.main(["compare", str(clip["input"]), str(clip["short"]), "-o", str(out), "--shortest"]) == 0
    assert len(read(out)) == 30
    assert len(audio_track(out)) / RATE == pytest.approx(1.0, abs=0.05)  # the audio ends with the video


@pytest.mark.parametrize("case, code, words", [
    ("missing", 2, "input file not found"),
    ("not a video", 2, "not a video file"),
    ("output is an input", 3, "output is the same file as the input"),
    ("output exists", 3, "output already exists"),
    ("too many labels", 2, "--labels gives 3 labels for 2 videos"),
    ("bad height", 2, "--height must be between 16 and 4320 px"),
])
def test_bad_input_gets_one_line_and_no_output(clip, tmp_path, capsys, case, code, words):
    out = tmp_path / "sbs.mp4"
    other = str(clip["small"])
    extra: list[str] = []
    if case == "missing":
        other = str(tmp_path / "nowhere.mp4")
    elif case == "not a video":
        (tmp_path / "noise.mp4").write_bytes(np.random.default_rng(0).bytes(5000))
        other = str(tmp_path / "noise.mp4")
    elif case == "output is an input":
        out = Path(other)
    elif case == "output exists":
        out.write_bytes(b"keep me")
    elif case == "too many labels":
        extra = ["--labels", "a,b,c"]
    elif case == "bad height":
        extra = ["--height", "8"]
    before = out.read_bytes() if out.exists() else None
    assert cli.main(["compare", str(clip["input"]), other, "-o", str(out), *extra]) == code
    err = capsys.readouterr().err.strip()
    assert err.startswith("ffviz: error: ") and words in err and "\n" not in err, err
    assert (out.read_bytes() if out.exists() else None) == before
    assert not [p for p in tmp_path.iterdir() if "ffviz-tmp" in p.name]


def test_reading_a_time_range_gives_the_same_frames_as_reading_all(clip):
    with video_reader.VideoReader(clip["input"]) as reader:
        everything = list(reader)
    with video_reader.VideoReader(clip["input"], start_s=0.5, end_s=1.0) as reader:
        part = list(reader)
        assert reader.info.clip == (0.5, 1.0) and reader.info.frame_count == 15
    assert [f.index for f in part] == list(range(15))
    assert [f.pts for f in part] == [f.pts for f in everything[15:30]]
    assert all(np.array_equal(a.rgb, b.rgb) for a, b in zip(part, everything[15:30]))


def test_preview_stabilizes_a_stretch_from_start_with_its_audio_and_compares_it(clip, tmp_path):
    out, sbs = tmp_path / "preview.mp4", tmp_path / "preview_sbs.mp4"
    assert cli.main(["stabilize", str(clip["input"]), "-o", str(out), "--mode", "crop", "--no-deblur",
                     "--preview", "0.5", "--start", "0.6", "--compare", str(sbs)]) == 0
    frames = read(out)
    assert len(frames) == 15 and frames[0].time_s == 0.0  # input frames 18..32, written from 0 s
    samples = audio_track(out)
    assert len(samples) / RATE == pytest.approx(0.5, abs=0.05)
    # The audio is the input's from 0.6 s: its loudness there, not at 0 s.
    assert amplitude(samples[2048:6144]) == pytest.approx(float(loudness_at(np.array(0.6 + 4096 / RATE))), rel=0.1)
    compared = read(sbs)
    assert len(compared) == 15
    lay = cmp.layout([(W, H), (W, H)], H)
    source = clip["video"].frames
    left, right = panel_region(compared[0].rgb, lay, 0), panel_region(compared[0].rgb, lay, 1)
    assert psnr(left, source[18]) > max(26, psnr(left, source[0]) + 6)  # the input panel shows the same stretch
    assert psnr(right, frames[0].rgb) > 30
    assert len(audio_track(sbs)) / RATE == pytest.approx(0.5, abs=0.05)


def test_preview_and_compare_options_are_checked_before_the_run(clip, tmp_path, capsys):
    out = tmp_path / "o.mp4"
    for argv, code, words in ((["--preview", "0"], 2, "--preview must be more than 0 seconds"),
                              (["--start", "9"], 2, "start time 9 s is past the end of"),
                              (["--compare", str(out)], 2, "is the stabilized output itself"),
                              (["--compare", str(clip["input"])], 3, "output is the same file as the input")):
        assert cli.main(["stabilize", str(clip["input"]), "-o", str(out), *argv]) == code
        err = capsys.readouterr().err.strip()
        assert words in err and "\n" not in err, err
        assert not out.exists()


def test_cursor_dots_land_on_the_path_lines_matplotlib_drew():
    """The per-frame dots are placed by the plots' data-to-pixel map: on the drawn line, not 8 px off it (the
    vertical plot is flipped so that up is up, which the map must follow)."""
    t = np.arange(60) / 30
    paths = [np.stack([40 * np.sin(t * 2), 10 * np.cos(t * 3), 0.5 * np.sin(t)], 1),
             np.stack([30 * t, -25 * t, 0.4 * t - 0.3], 1)]
    lay = cmp.layout([(W, H), (W, H)], H)
    background, axes = cmp._background(lay, ["a", "b"], paths, [t, t], 2.0)
    for ax, (_, column) in zip(axes, cmp.PLOTS):
        for i, path in enumerate(paths):
            for k in (5, 30, 55):
                x, y = ax.px(t[k]), ax.py(path[k, column])

                def distance(row: int) -> int:  # to the video's colour, nearest pixel of a 3x3 patch
                    patch = background[row - 1:row + 2, x - 1:x + 2].astype(int)
                    return int(np.abs(patch - cmp.PANEL_COLOURS[i]).sum(axis=2).min())

                # Measured: 0-15 on the line, 190 or more 8 px above or below it.
                assert distance(y) < 40 and distance(y - 8) > 120 and distance(y + 8) > 120, (column, i, k)
    frame = Frame(index=30, pts=30, time_s=1.0, rgb=np.zeros((H, W, 3), np.uint8))
    drawn = cmp.compose(background, lay, axes, 1.0, [frame, frame], paths)
    for ax, (_, column) in zip(axes, cmp.PLOTS):
        x = ax.px(1.0)
        assert (drawn[int(ax.y1) + 2:int(ax.y0) - 2, x] > 200).all(axis=1).mean() > 0.5  # the white cursor
        for i, path in enumerate(paths):
            assert np.abs(drawn[ax.py(path[30, column]), x].astype(int) - cmp.PANEL_COLOURS[i]).sum() < 40


def test_a_long_label_is_shortened_to_its_own_video():
    long = "a_very_long_name_for_the_original_video_taken_on_a_bicycle_through_the_old_town_at_dusk.mp4"
    lay = cmp.layout([(W, H), (W, H)], H)
    background, _ = cmp._background(lay, [long, "b"], [np.zeros((2, 3))] * 2, [np.array([0.0, 0.1])] * 2, 0.2)
    header = background[:lay.header].astype(int)
    red = np.abs(header - cmp.PANEL_COLOURS[0]).sum(axis=2) < 60
    columns = np.flatnonzero(red.any(axis=0))
    assert len(columns) and columns.max() < lay.panel_x[1] and columns.min() > 0  # drawn, within its video
    assert cmp._fitted(long, 30).endswith("dusk.mp4") and len(cmp._fitted(long, 30)) == 30
