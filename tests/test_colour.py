"""Faithful colour: the output keeps the input's matrix, range, primaries, transfer, bit depth and HDR metadata.

Tiny clips (160x96, 16 frames) with a shaking camera over a still scene, tagged BT.601, BT.709, full range, and
BT.2020 10-bit HLG and PQ (the last with mastering display metadata), go through the reader/writer alone and
through ``--mode none``, ``crop`` and ``full``. The scene's centre is a flat saturated patch wider than the shake,
so its mean colour is known in every output frame whatever the warp; each file is decoded by its own tags (the
mean Y'CbCr of the region, turned into R'G'B' by the tagged matrix and range: the map is affine, so the mean
converts exactly), independently of the pipeline's own conversions.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess

import av
import numpy as np
import pytest

from ffviz import cli
from pipeline.runtime import colour as colours
from pipeline.runtime import video_reader, video_writer
from pipeline.runtime.colour import ColourDescription

W, H, N = 160, 96, 16
PATCH = (slice(24, 72), slice(44, 116))  # the flat patch (rows, columns); the shake is at most 5 px
REGION = (slice(40, 56), slice(64, 96))  # the region measured, well inside the patch in every frame
PATCH_RGB = (201.3, 58.6, 41.2)  # R'G'B' code values, 0..255 scale (fractions: 10-bit clips keep them)
MASTERING = ((0.68, 0.32), (0.265, 0.69), (0.15, 0.06), (0.3127, 0.329), (0.0001, 1000.0))  # P3 in BT.2020, 1000 nits

CLIPS = {
    "bt601": ("libx264", "yuv420p", ColourDescription(matrix=6, range=1, primaries=6, transfer=6)),
    "bt709": ("libx264", "yuv420p", ColourDescription(matrix=1, range=1, primaries=1, transfer=1)),
    "full_range": ("libx264", "yuv420p", ColourDescription(matrix=1, range=2, primaries=1, transfer=13)),
    "bt2020_hlg_10bit": ("libx265", "yuv420p10le",
                         ColourDescription(matrix=9, range=1, primaries=9, transfer=18, bit_depth=10)),
    "bt2020_pq_10bit": ("libx265", "yuv420p10le",
                        ColourDescription(matrix=9, range=1, primaries=9, transfer=16, bit_depth=10,
                                          mastering=MASTERING, content_light=(1000, 400))),
}


def scene(t: int) -> np.ndarray:
    """Frame t: a textured still scene seen by a camera shaking by a known few pixels, float32 0..255."""
    dx, dy = 4 * np.sin(1.7 * t), 3 * np.cos(2.3 * t)
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    x, y = x + dx, y + dy
    rgb = np.stack([128 + 90 * np.sin(x / 5) * np.cos(y / 7), 128 + 90 * np.cos(y / 4 + x / 9),
                    128 + 70 * np.sin((x - y) / 6)], -1)
    inside = (np.abs(x - 80) < 36 - 5) & (np.abs(y - 48) < 24 - 5)  # moves with the scene
    rgb[inside] = PATCH_RGB
    return rgb.astype(np.float32)


def make_clip(path, kind: str, *, sei: bytes = b"") -> None:
    """The shaky scene as clip ``kind``; ``sei``: Annex B NAL units put before every picture (HEVC)."""
    codec, pix_fmt, description = CLIPS[kind]
    options = {"crf": "8", "preset": "fast"}
    if codec == "libx265":
        options["x265-params"] = ":".join(["log-level=error", *description.x265_hdr_params()])
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=25, options=options)
        stream.width, stream.height, stream.pix_fmt = W, H, pix_fmt
        colours.tag_stream(stream.codec_context, description)

        def mux(packets):
            for packet in packets:
                if sei:
                    prefixed = av.Packet(sei + bytes(packet))
                    prefixed.pts, prefixed.dts, prefixed.time_base = packet.pts, packet.dts, packet.time_base
                    prefixed.is_keyframe, prefixed.stream = packet.is_keyframe, stream
                    packet = prefixed
                container.mux(packet)

        for t in range(N):
            frame = colours.from_rgb(scene(t), description, pix_fmt)
            frame.pts = t
            mux(stream.encode(frame))
        mux(stream.encode(None))


@pytest.fixture(scope="module", params=list(CLIPS))
def clip(request, tmp_path_factory):
    path = tmp_path_factory.mktemp("colour") / f"{request.param}.mp4"
    make_clip(path, request.param)
    return request.param, path


_KR_KB = {1: (0.2126, 0.0722), 9: (0.2627, 0.0593)}  # anything else: BT.601's (0.299, 0.114)


def stream_tags(path) -> dict:
    """The colour tags and depth of the file's video stream, and its first frame's HDR metadata."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frame = next(container.decode(stream))
        described = colours.describe(frame)
        context = stream.codec_context
        return {"matrix": int(context.colorspace), "range": int(context.color_range),
                "primaries": int(context.color_primaries), "transfer": int(context.color_trc),
                "depth": described.bit_depth, "mastering": described.mastering,
                "content_light": described.content_light}


def mean_rgb(path) -> tuple[np.ndarray, int]:
    """Per frame, the mean R'G'B' (0..1) of REGION decoded by the file's own tags; and its bit depth."""
    means = []
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        context = stream.codec_context
        kr, kb = _KR_KB.get(int(context.colorspace), (0.299, 0.114))
        full = int(context.color_range) == 2
        for frame in container.decode(stream):
            depth = frame.format.components[0].bits
            dtype = np.uint16 if depth > 8 else np.uint8
            planes = [np.frombuffer(p, dtype).reshape(p.height, p.line_size // dtype().itemsize)[:, :p.width]
                      for p in frame.planes]
            rows, cols = REGION
            luma = planes[0][rows, cols].mean()
            chroma_box = (slice(rows.start // 2, rows.stop // 2), slice(cols.start // 2, cols.stop // 2))
            cb, cr = planes[1][chroma_box].mean(), planes[2][chroma_box].mean()
            s = 2 ** (depth - 8)
            if full:
                y, u, v = luma / (255 * s), (cb - 128 * s) / (255 * s), (cr - 128 * s) / (255 * s)
            else:
                y, u, v = (luma - 16 * s) / (219 * s), (cb - 128 * s) / (224 * s), (cr - 128 * s) / (224 * s)
            r, b = y + 2 * (1 - kr) * v, y + 2 * (1 - kb) * u
            g = (y - kr * r - kb * b) / (1 - kr - kb)
            means.append((r, g, b))
    return np.array(means), depth


def assert_faithful(input_path, output_path, kind: str) -> None:
    tags_in, tags_out = stream_tags(input_path), stream_tags(output_path)
    assert tags_out == tags_in, f"{kind}: {tags_out} != {tags_in}"
    rgb_in, depth = mean_rgb(input_path)
    rgb_out, _ = mean_rgb(output_path)
    assert len(rgb_out) == len(rgb_in)
    levels = 2 ** depth - 1
    bound = 1 if depth == 8 else 4  # 1 level in 255, 4 in 1023
    drift = np.abs(rgb_out - rgb_in).max() * levels
    assert drift <= bound, f"{kind}: the patch's mean colour moved by {drift:.2f} of {levels} levels"
    # and it is the colour that was put in (up to the 8-bit Y'CbCr steps: a step of Cr is 1.8 levels of R)
    assert np.abs(rgb_in.mean(axis=0) * 255 - PATCH_RGB).max() < (1.0 if depth > 8 else 1.5)


def test_reader_and_writer_alone_keep_tags_depth_and_colour(clip, tmp_path):
    kind, path = clip
    output = tmp_path / "copy.mp4"
    with video_reader.VideoReader(path, keep_depth=True) as reader:
        description = reader.info.colour
        assert description == ColourDescription(**{**CLIPS[kind][2].__dict__, "pix_fmt": description.pix_fmt,
                                                   "chroma_location": description.chroma_location})  # as written
        assert description.chroma_location in ("left", None)  # x264's and x265's default (None: no ffprobe)
        with video_writer.VideoWriter(output, like=reader.info) as writer:
            for frame in reader:
                assert frame.rgb.dtype == (np.float32 if description.deep else np.uint8)
                writer.write(frame.rgb, pts=frame.pts)
    assert writer.warnings == []
    assert_faithful(path, output, kind)


@pytest.mark.parametrize("frames", [1, 2, 3])
def test_a_one_or_two_picture_hevc_output_is_written_every_time(frames, tmp_path):
    """libx265 leaves the dts of a one- or two-picture video uninitialised (a different value from run to run);
    the writer must still produce a whole file that decodes to every picture, however often it is tried."""
    path = tmp_path / "hlg.mp4"
    make_clip(path, "bt2020_hlg_10bit")
    like = video_reader.probe_video(path)
    for attempt, garbage in enumerate([None, -94218684620720, -4611756388245323776, 7, None, None]):
        output = tmp_path / f"out{attempt}.mp4"
        with video_writer.VideoWriter(output, like=like) as writer:
            if garbage is not None:  # what libx265 hands back on a bad run, made certain
                encode = writer._video.encode

                def encode_with_garbage_dts(frame, encode=encode, garbage=garbage):
                    packets = list(encode(frame))
                    for packet in packets:
                        packet.dts = garbage
                    return packets

                writer._video = dataclasses.make_dataclass("S", [("encode", object)])(encode_with_garbage_dts)
            for t in range(frames):
                writer.write(scene(t).astype(np.float32))
        with av.open(str(output)) as container:
            assert sum(1 for _ in container.decode(video=0)) == frames


@pytest.mark.parametrize("mode", ["none", "crop", "full"])
def test_every_mode_keeps_tags_depth_and_colour(clip, mode, tmp_path, capsys):
    kind, path = clip
    output = tmp_path / f"{mode}.mp4"
    assert cli.main(["stabilize", str(path), "-o", str(output), "--mode", mode]) == 0
    assert_faithful(path, output, kind)
    assert "warning" not in capsys.readouterr().err.lower()


def test_8bit_reader_still_gives_uint8_by_the_input_matrix(tmp_path):
    """Without keep_depth a 10-bit clip reads as uint8, by its own (BT.2020) matrix: within a level of the truth."""
    path = tmp_path / "hlg.mp4"
    make_clip(path, "bt2020_hlg_10bit")
    with video_reader.VideoReader(path) as reader:
        frame = next(iter(reader))
    assert frame.rgb.dtype == np.uint8
    assert np.abs(frame.rgb[REGION].reshape(-1, 3).mean(axis=0) - PATCH_RGB).max() < 1.0


def test_a_codec_without_10_bits_says_so_in_one_line_and_keeps_the_tags(tmp_path, capsys):
    path = tmp_path / "hlg.mp4"
    make_clip(path, "bt2020_hlg_10bit")
    output = tmp_path / "out.mp4"
    assert cli.main(["stabilize", str(path), "-o", str(output), "--mode", "none", "--codec", "mpeg4"]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "cannot store 10-bit" in line]
    assert len(lines) == 1
    tags = stream_tags(output)
    assert tags["depth"] == 8
    assert (tags["matrix"], tags["range"], tags["primaries"], tags["transfer"]) == (9, 1, 9, 18)
    rgb_in, _ = mean_rgb(path)
    rgb_out, _ = mean_rgb(output)
    assert np.abs(rgb_out - rgb_in).max() * 255 <= 1.0  # 8 bits of the same colour


def test_422_input_is_written_420_with_one_warning_line_and_its_tags_and_depth(tmp_path, capsys):
    path = tmp_path / "in422.mkv"
    description = ColourDescription(matrix=1, range=1, primaries=1, transfer=1, bit_depth=10)
    with av.open(str(path), "w") as container:  # 4:2:2 by swscale from exact 4:2:0 pictures: the same colours
        stream = container.add_stream("libx265", rate=25, options={"crf": "8", "x265-params": "log-level=error"})
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv422p10le"
        colours.tag_stream(stream.codec_context, description)
        for t in range(N):
            frame = colours.from_rgb(scene(t), description, "yuv420p10le").reformat(format="yuv422p10le")
            frame.pts = t
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
    output = tmp_path / "out.mp4"
    assert cli.main(["stabilize", str(path), "-o", str(output), "--mode", "none"]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "4:2:2 input written as 4:2:0" in line]
    assert len(lines) == 1
    with av.open(str(output)) as container:
        assert next(container.decode(video=0)).format.name == "yuv420p10le"
    tags = stream_tags(output)
    assert (tags["matrix"], tags["range"], tags["primaries"], tags["transfer"], tags["depth"]) == (1, 1, 1, 1, 10)


def test_pq_and_hlg_curves_give_bt2100_and_bt2408_reference_levels():
    """BT.2408's reference levels: HDR reference white (203 cd/m2) at PQ 58% and, on the 1000 cd/m2 reference
    display, HLG 75% (inverse OETF, then the OOTF's 1000 Ys^1.2); PQ 75% is 1000 cd/m2, PQ 1.0 10000."""
    assert abs(colours.nits_to_pq(203) - 0.5807) < 1e-3 and abs(colours.nits_to_pq(1000) - 0.7518) < 1e-3
    nits = np.array([0.01, 1, 100, 203, 1000, 10000])
    assert np.allclose(colours.pq_to_nits(colours.nits_to_pq(nits)), nits, rtol=1e-6)
    assert colours.pq_to_nits(np.array(1.0)) == pytest.approx(10000)
    assert colours.hlg_to_scene(np.array(0.5)) == pytest.approx(1 / 12)
    assert colours.hlg_to_scene(np.array(1.0)) == pytest.approx(1)
    assert 1000 * colours.hlg_to_scene(np.array(0.75)) ** 1.2 == pytest.approx(203, abs=1.5)


@pytest.mark.parametrize("source_peak", [400.0, 1000.0, 4000.0])
def test_bt2390_eetf_keeps_what_fits_and_compresses_the_rest_without_clipping(source_peak):
    """Report ITU-R BT.2390's EETF, source peak -> 203 cd/m2: light below the knee unchanged, the source peak at
    the target peak exactly, monotonic with no clipping below it, continuous with slope 1 at the knee."""
    target = colours.SDR_WHITE_NITS
    source_pq = colours.nits_to_pq(source_peak)
    codes = np.linspace(0, source_pq, 2001)
    mapped = colours.bt2390_eetf(codes, source_peak, target)
    assert np.all(np.diff(mapped) > 0)  # strictly increasing: nothing below the source peak is clipped
    assert colours.pq_to_nits(mapped[-1]) == pytest.approx(target, rel=1e-9)
    assert np.all(colours.pq_to_nits(mapped[:-1]) < target)
    knee = (1.5 * colours.nits_to_pq(target) / source_pq - 0.5) * source_pq
    below = codes < knee
    assert below.sum() > 100 and np.allclose(mapped[below], codes[below], rtol=1e-12, atol=0)  # untouched
    eps = 1e-6
    slope = (colours.bt2390_eetf(np.array(knee + eps), source_peak, target) - (knee - eps)) / (2 * eps)
    assert slope == pytest.approx(1, abs=1e-4)
    assert colours.bt2390_eetf(np.array(1.0), source_peak, target) == pytest.approx(colours.nits_to_pq(target))
    # a video that fits the target is left as it is
    assert np.allclose(colours.bt2390_eetf(codes[:50], 150, target), codes[:50], rtol=1e-12, atol=0)


def grey(code: float, colour: ColourDescription) -> int:
    shown = colours.display_rgb(np.full((2, 2, 3), code * 255, np.float32), colour)[0, 0]
    assert len(set(shown.tolist())) == 1  # a grey stays grey
    return int(shown[0])


def test_display_rgb_shows_hdr_white_near_sdr_white_and_leaves_sdr_alone():
    sdr = ColourDescription(matrix=1, primaries=1, transfer=1)
    frame = scene(0)
    assert np.array_equal(colours.display_rgb(np.round(frame).astype(np.uint8), sdr), np.round(frame).astype(np.uint8))
    pq = ColourDescription(matrix=9, primaries=9, transfer=16, bit_depth=10)
    hlg = ColourDescription(matrix=9, primaries=9, transfer=18, bit_depth=10)
    # 100 cd/m2 is below the knee: shown exactly as its light relative to SDR white (203), BT.1886-encoded
    hundred = grey(colours.nits_to_pq(100), pq)
    assert abs(hundred - 255 * (colours.pq_to_nits(colours.bt2390_eetf(colours.nits_to_pq(100), 1000, 203)) / 203)
               ** (1 / 2.4)) <= 0.5 and abs(hundred - 255 * (100 / 203) ** (1 / 2.4)) <= 1.5
    # HDR reference white (PQ 58%, HLG 75%) near SDR white, and the same from either transfer
    white = grey(colours.nits_to_pq(203), pq)
    assert 0.9 * 255 <= white < 255 and abs(grey(0.75, hlg) - white) <= 1
    # the whole range of codes, dark to peak: never darker for a brighter code, white at the peak
    for colour in (pq, hlg):
        ramp = colours.display_rgb(np.linspace(0, 255, 1024, dtype=np.float32)[:, None, None].repeat(3, 2), colour)
        assert np.all(np.diff(ramp[:, 0, 0].astype(int)) >= 0) and ramp[-1, 0, 0] == 255 and ramp[0, 0, 0] == 0
    # highlights below the video's peak are not clipped: 1000 cd/m2 is white for a 1000 cd/m2 video (the default
    # peak) and still below white, and above 500 cd/m2, for one whose MaxCLL says 4000
    bright = dataclasses.replace(pq, content_light=(4000, 400))
    assert grey(colours.nits_to_pq(1000), pq) == 255
    assert grey(colours.nits_to_pq(500), bright) < grey(colours.nits_to_pq(1000), bright) < 255
    # BT.2020's saturated red lies outside BT.709: shown as BT.709's most saturated red, not a dull one
    red = colours.display_rgb(np.array([[[0.75 * 255, 0, 0]]], np.float32), hlg)[0, 0]
    assert red[0] > 200 and red[1] == 0 and red[2] == 0


def test_the_recording_shows_display_rgb_and_names_the_colour(tmp_path):
    """An HLG BT.2020 clip's recording shows its frames tone-mapped into BT.709 display RGB (the patch's colour as
    display_rgb gives it, far from its raw code values), and the about panel names the colour description."""
    from ffviz import entities as ent
    from ffviz.rrd import Recording

    path = tmp_path / "hlg.mp4"
    make_clip(path, "bt2020_hlg_10bit")
    rrd = tmp_path / "run.rrd"
    assert cli.main(["stabilize", str(path), "-o", str(tmp_path / "out.mp4"), "--mode", "none", "--rrd", str(rrd),
                     "--lossless"]) == 0
    recording = Recording.load(rrd)
    description = ColourDescription(matrix=9, range=1, primaries=9, transfer=18, bit_depth=10)
    expected = colours.display_rgb(np.array([[PATCH_RGB]], np.float32), description)[0, 0].astype(float)
    assert np.abs(expected - PATCH_RGB).max() > 20  # tone mapping and gamut mapping move it well away
    for entity in (ent.INPUT_FRAME, ent.OUTPUT_FRAME):
        shown = recording.image(entity, N // 2)
        assert shown.dtype == np.uint8
        assert np.abs(shown[REGION].reshape(-1, 3).mean(axis=0) - expected).max() < 2.0, entity
    meta = recording.texts(ent.META, "TextDocument:text")[-1]
    assert "tv, bt2020nc, bt2020, arib-std-b67, 10-bit" in meta and "tone-mapped" in meta


def test_float32_frames_take_every_full_mode_stage_as_uint8_frames_do():
    """Deeper video's float32 path against the uint8 path on the same frames: a synthetic shaky clip with
    motion-blurred frames in full mode (warp, mosaic, local warps, fallback, deblurring). The outputs agree to
    within the uint8 path's rounding, and the float32 path keeps its fractions."""
    from pipeline.evaluation import synthetic
    from pipeline.runtime.observer import StageCollector
    from pipeline.runtime.source import ArraySource
    from pipeline.stabilize import StabilizeConfig, stabilize_source

    video = synthetic.generate(synthetic.SyntheticConfig(width=160, height=96, n_frames=12, seed=5, jitter_px=5.0,
                                                         blur_length_px=5.0))
    runs = {}
    for dtype in (np.uint8, np.float32):
        collector = StageCollector("completion", "deblur", "output")
        stabilize_source(ArraySource([f.astype(dtype) for f in video.frames]), None, StabilizeConfig(mode="full"),
                         observer=collector, workers=1)
        runs[dtype] = collector.results
    plain = np.stack([out for _, out in runs[np.uint8]["output"]]).astype(np.float32)
    deep = np.stack([out for _, out in runs[np.float32]["output"]])
    assert deep.dtype == np.float32 and plain.shape == deep.shape
    assert np.any(deep != np.round(deep))  # fractions of a level survive
    assert sum(r.missing.sum() for _, r in runs[np.float32]["completion"]) > 0  # completion filled pixels
    assert any(r.neighbours for _, r in runs[np.float32]["deblur"])  # deblurring blended neighbours
    difference = np.abs(deep - plain)
    # uint8 rounding alone leaves a median of 0.25 (measured 0.25); a few pixels take another source where a choice
    # sits on its threshold (measured: 1.1% of the samples more than a level apart)
    assert np.median(difference) < 0.3 and (difference > 1).mean() < 0.02, (np.median(difference), difference.max())


# ------------------------------------------------------------------------------------------------ chroma location

needs_ffmpeg = pytest.mark.skipif(shutil.which("ffmpeg") is None or shutil.which("ffprobe") is None,
                                  reason="the system ffmpeg and ffprobe make and read chroma-located clips")


def ffprobe_chroma_location(path) -> str:
    result = subprocess.run(["ffprobe", "-v", "error", "-select_streams", "v:0", "-show_entries",
                             "stream=chroma_location", "-of", "json", str(path)], capture_output=True, text=True,
                            check=True)
    return json.loads(result.stdout)["streams"][0]["chroma_location"]


def make_ffmpeg_clip(path, codec: str, location: str) -> None:
    """The shaky scene encoded by the system ffmpeg (its own RGB -> Y'CbCr, BT.709 limited range), its chroma
    location tagged with ``-chroma_sample_location``: 8-bit H.264 or 10-bit HEVC."""
    deep = codec == "libx265"
    frames = np.stack([scene(t) for t in range(N)])
    raw = (np.round(frames * 257).astype("<u2") if deep else np.round(frames).astype(np.uint8)).tobytes()
    command = ["ffmpeg", "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb48le" if deep else "rgb24",
               "-s", f"{W}x{H}", "-r", "25", "-i", "-", "-vf", "scale=out_color_matrix=bt709:out_range=tv",
               "-c:v", codec, "-crf", "8", "-pix_fmt", "yuv420p10le" if deep else "yuv420p",
               "-colorspace", "bt709", "-color_primaries", "bt709", "-color_trc", "bt709", "-color_range", "tv",
               "-chroma_sample_location", location, str(path)]
    if deep:
        command[-1:-1] = ["-x265-params", "log-level=error"]
    subprocess.run(command, input=raw, check=True, capture_output=True)


@pytest.fixture(scope="module", params=[(codec, location) for codec in ("libx264", "libx265")
                                        for location in ("left", "center", "topleft")],
                ids=lambda p: f"{'h264_8bit' if p[0] == 'libx264' else 'hevc_10bit'}_{p[1]}")
def located_clip(request, tmp_path_factory):
    if shutil.which("ffmpeg") is None or shutil.which("ffprobe") is None:
        pytest.skip("the system ffmpeg and ffprobe make and read chroma-located clips")
    codec, location = request.param
    path = tmp_path_factory.mktemp("chroma") / f"{codec}_{location}.mp4"
    make_ffmpeg_clip(path, codec, location)
    assert ffprobe_chroma_location(path) == location
    return location, path


@pytest.mark.parametrize("mode", ["none", "crop", "full"])
def test_every_mode_keeps_the_chroma_location(located_clip, mode, tmp_path, capsys):
    location, path = located_clip
    assert video_reader.probe_video(path).colour.chroma_location == location
    output = tmp_path / f"{mode}.mp4"
    assert cli.main(["stabilize", str(path), "-o", str(output), "--mode", mode]) == 0
    assert ffprobe_chroma_location(output) == location
    assert_faithful(path, output, location)
    assert "warning" not in capsys.readouterr().err.lower()


@needs_ffmpeg
def test_mkv_output_carries_the_chroma_location_in_the_container(tmp_path):
    """MKV has a field of its own (ChromaSitingHorz/Vert), written from the codec context: with mpeg4, whose
    bitstream has none, it is the only place the location is kept. Matroska's ChromaSitingHorz / Vert (IDs
    0x55B7 / 0x55B8): topleft is 1 / 1, sited on the top-left pixel (left would be 1 / 2, center 2 / 2)."""
    path = tmp_path / "topleft.mp4"
    make_ffmpeg_clip(path, "libx264", "topleft")
    output = tmp_path / "out.mkv"
    assert cli.main(["stabilize", str(path), "-o", str(output), "--mode", "none", "--codec", "mpeg4"]) == 0
    header = output.read_bytes()[:4096]
    assert b"\x55\xb7\x81\x01" in header and b"\x55\xb8\x81\x01" in header


@pytest.mark.parametrize("depth", [8, 10])
@pytest.mark.parametrize("location", ["left", "center", "topleft", "bottom"])
def test_chroma_is_interpolated_and_subsampled_at_its_location(location, depth):
    """Chroma planes that are linear ramps (Cb across, Cr down; in gamut), read as sited: each pixel's Cb and Cr
    are the ramps' values at that pixel, from where the samples sit. Written back from those pixels, the samples
    come out as they were. Read as sited elsewhere (left, what an unknown location means), they are off."""
    width, height, s = 64, 48, 2 ** (depth - 8)
    pix_fmt = "yuv420p" if depth == 8 else "yuv420p10le"
    dtype = np.uint8 if depth == 8 else np.uint16
    site_x, site_y = colours._CHROMA_SITES[location]
    cb_of, cr_of = (lambda i, j: (80 + 3 * j) * s), (lambda i, j: (90 + 4 * i) * s)
    frame = av.VideoFrame(width, height, pix_fmt)
    for plane, values in zip(frame.planes, (lambda i, j: 126 * s + 0 * i, cb_of, cr_of)):
        i, j = np.mgrid[0:plane.height, 0:plane.width]
        np.frombuffer(plane, dtype).reshape(plane.height, -1)[:, :plane.width] = np.round(values(i, j))
    colour = ColourDescription(matrix=1, range=1, bit_depth=depth, pix_fmt=pix_fmt, chroma_location=location)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    expected_cb, expected_cr = cb_of((y - site_y) / 2, (x - site_x) / 2), cr_of((y - site_y) / 2, (x - site_x) / 2)
    inside = (slice(4, height - 4), slice(4, width - 4))  # away from the edges, where the ramps are held

    def chroma_error(as_colour) -> float:
        """Mean |error| of Cb and Cr, in levels of the video's depth, over the inside."""
        rgb = colours.to_rgb(frame, as_colour, width, height, deep=True).astype(np.float64)
        encode, _ = colours._yuv_affine(as_colour, depth)
        ycc = rgb @ encode[:, :3].T.astype(np.float64) + encode[:, 3]
        return max(np.abs(ycc[..., 1] - expected_cb)[inside].mean(), np.abs(ycc[..., 2] - expected_cr)[inside].mean())

    # 8 bits: uint8 RGB's rounding alone leaves ~0.1 level; 10 bits travel as float32
    assert chroma_error(colour) < (0.2 if depth == 8 else 0.02)
    if location != "left":  # half a luma pixel of a 1.5 (Cb) or 2 (Cr) levels a pixel ramp
        assert chroma_error(dataclasses.replace(colour, chroma_location=None)) > 0.6 * s
    # and written back at the same sites, from full-resolution RGB that carries the ramps exactly
    _, decode = colours._yuv_affine(colour, depth)
    rgb = np.stack([np.full((height, width), 126.0 * s), expected_cb, expected_cr], -1) @ decode[:, :3].T + decode[:, 3]
    written = colours.from_rgb(rgb.astype(np.float32), colour, pix_fmt)
    planes = [np.frombuffer(p, dtype).reshape(p.height, -1)[:, :p.width].astype(np.float64) for p in written.planes]
    i, j = np.mgrid[0:height // 2, 0:width // 2]
    assert np.abs(planes[1] - np.round(cb_of(i, j)))[2:-2, 2:-2].max() <= 1
    assert np.abs(planes[2] - np.round(cr_of(i, j)))[2:-2, 2:-2].max() <= 1


@pytest.mark.parametrize("depth", [8, 10])
@pytest.mark.parametrize("location", ["left", "center", "topleft", "top", "bottomleft", "bottom"])
def test_4_2_0_conversion_equals_the_plain_warp_and_matrix_to_the_bit(location, depth):
    """to_rgb's one-pass chroma interpolation and rounding give exactly what the plain OpenCV chain gives (chroma
    merged to float and warped bilinearly with the edges repeated, the matrix by cv2.transform, clipped, + 0.5,
    truncated): on random planes, at every chroma location, both ranges; 8 bits as uint8, 10 bits as float32."""
    import cv2

    width, height = 70, 46
    pix_fmt = "yuv420p" if depth == 8 else "yuv420p10le"
    dtype = np.uint8 if depth == 8 else np.uint16
    rng = np.random.default_rng(depth)
    frame = av.VideoFrame(width, height, pix_fmt)
    planes = []
    for plane in frame.planes:
        values = rng.integers(0, 2 ** depth, (plane.height, plane.width))
        np.frombuffer(plane, dtype).reshape(plane.height, -1)[:, :plane.width] = values
        planes.append(values.astype(np.float32))
    site_x, site_y = colours._CHROMA_SITES[location]
    chroma = cv2.warpAffine(cv2.merge(planes[1:]), np.array([[0.5, 0, -site_x / 2], [0, 0.5, -site_y / 2]]),
                            (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                            borderMode=cv2.BORDER_REPLICATE)
    for colour_range in (1, 2):
        colour = ColourDescription(matrix=1, range=colour_range, bit_depth=depth, pix_fmt=pix_fmt,
                                   chroma_location=location)
        _, decode = colours._yuv_affine(colour, depth)
        expected = np.clip(cv2.transform(cv2.merge([planes[0], chroma]), decode), 0, 255)
        if depth == 8:
            expected = (expected + np.float32(0.5)).astype(np.uint8)
        got = colours.to_rgb(frame, colour, width, height, deep=True)
        assert got.dtype == expected.dtype and np.array_equal(got, expected)


def test_without_ffprobe_the_chroma_location_is_unknown_and_the_job_runs(tmp_path, monkeypatch, capsys):
    """A clean setup has no system ffmpeg: the location is unknown (said so in the description), the frames are
    read as sited left, and the output is written as before. An ffprobe that fails is the same."""
    path = tmp_path / "bt709.mp4"
    make_clip(path, "bt709")
    for fake_ffprobe in (None, "#!/bin/sh\nexit 1\n"):
        bin_dir = tmp_path / f"bin{fake_ffprobe is None}"
        bin_dir.mkdir()
        if fake_ffprobe is not None:
            (bin_dir / "ffprobe").write_text(fake_ffprobe)
            (bin_dir / "ffprobe").chmod(0o755)
        monkeypatch.setenv("PATH", str(bin_dir))
        info = video_reader.probe_video(path)
        assert info.colour.chroma_location is None
        assert info.colour.summary().endswith("8-bit, chroma location unknown")
        output = tmp_path / f"out{fake_ffprobe is None}.mp4"
        assert cli.main(["stabilize", str(path), "-o", str(output), "--mode", "none"]) == 0
        assert "warning" not in capsys.readouterr().err.lower()
        monkeypatch.undo()
        assert_faithful(path, output, "bt709")


# ------------------------------------------------------------------------------------------------ dynamic metadata

def hdr10plus_sei() -> bytes:
    """An HEVC prefix SEI NAL unit (Annex B) carrying one SMPTE ST 2094-40 (HDR10+) message as ITU-T T.35
    registered user data (payload type 4): country 0xB5, provider 0x003C, oriented code 1, application 4, then the
    metadata's bit fields as FFmpeg's parser reads them (one window, no percentiles, no tone mapping curve). No
    encoder here writes HDR10+ (this x265 is built without it, as Debian's is), so it is made by hand; FFmpeg's
    decoder turns it into the frames' DYNAMIC_HDR_PLUS side data, as it does for a phone's HDR10+ video."""
    fields = [(8, 1), (2, 1), (27, 400), (1, 0),  # application_version, num_windows, target display peak, flag
              (17, 90000), (17, 90000), (17, 90000), (17, 10000),  # maxscl R, G, B and average maxrgb (1e-5 units)
              (4, 0), (10, 0), (1, 0), (1, 0), (1, 0)]  # percentiles, bright pixels, three flags off
    bits = "".join(format(value, f"0{size}b") for size, value in fields)
    bits += "0" * (-len(bits) % 8)
    t35 = bytes([0xB5, 0x00, 0x3C, 0x00, 0x01, 0x04]) + int(bits, 2).to_bytes(len(bits) // 8, "big")
    payload = bytes([4, len(t35)]) + t35 + b"\x80"  # payload type, size, message, rbsp trailing bits
    escaped, zeros = bytearray(), 0  # emulation prevention: no 00 00 0x inside a NAL unit
    for byte in payload:
        if zeros >= 2 and byte <= 3:
            escaped.append(3)
            zeros = 0
        escaped.append(byte)
        zeros = zeros + 1 if byte == 0 else 0
    return b"\x00\x00\x00\x01" + bytes([39 << 1, 1]) + bytes(escaped)  # NAL type 39: prefix SEI


def test_hdr10plus_input_says_in_one_line_that_its_dynamic_metadata_is_not_kept(tmp_path, capsys):
    """A real HDR10+ clip (PQ, mastering metadata, an HDR10+ SEI on every picture): detected from the decoded
    frames, one warning line, and the output is plain HDR10: tags, depth, static metadata and colour kept."""
    path = tmp_path / "hdr10plus.mp4"
    make_clip(path, "bt2020_pq_10bit", sei=hdr10plus_sei())
    with av.open(str(path)) as container:
        first = next(container.decode(video=0))
        assert av.sidedata.sidedata.Type.DYNAMIC_HDR_PLUS in [side.type for side in first.side_data]
    assert video_reader.probe_video(path).colour.dynamic_metadata == "HDR10+"
    output = tmp_path / "out.mp4"
    assert cli.main(["stabilize", str(path), "-o", str(output), "--mode", "none"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line.lower()]
    assert len(warnings) == 1 and "HDR10+ dynamic metadata is not carried over" in warnings[0], warnings
    assert "plain HDR10" in warnings[0]
    assert_faithful(path, output, "bt2020_pq_10bit")  # mastering display and MaxCLL among the tags compared
    assert video_reader.probe_video(output).colour.dynamic_metadata is None
    # the clip without the SEI says nothing (the warning is the SEI's)
    make_clip(tmp_path / "hdr10.mp4", "bt2020_pq_10bit")
    assert video_reader.probe_video(tmp_path / "hdr10.mp4").colour.dynamic_metadata is None


class _FrameWithSideData:
    """A decoded frame with more side data: PyAV can read a frame's side data but not add to it, and no encoder
    or tool here writes a Dolby Vision RPU that FFmpeg's decoder would accept (it drops RPUs that do not parse)."""

    def __init__(self, frame: av.VideoFrame, *extra) -> None:
        self._frame, self.side_data = frame, [*frame.side_data, *extra]

    def __getattr__(self, name):
        return getattr(self._frame, name)


class _SideData:
    def __init__(self, kind, data: bytes = b"") -> None:
        self.type, self._data = kind, data

    def __bytes__(self) -> bytes:
        return self._data


@pytest.mark.parametrize("kind", ["DOVI_METADATA", "DOVI_RPU_BUFFER"])
def test_dolby_vision_side_data_is_detected_and_warned_of_once(kind, tmp_path):
    """Dolby Vision through the seam describe() reads, the frame's side data (a stand-in entry on a real decoded
    HLG frame: profile 8.4 is HLG-based); the writer then names it in one warning line and says the output is
    plain HLG, with the tags kept."""
    path = tmp_path / "hlg.mp4"
    make_clip(path, "bt2020_hlg_10bit")
    with av.open(str(path)) as container:
        frame = next(container.decode(video=0))
        plain = colours.describe(frame)
        described = colours.describe(_FrameWithSideData(frame, _SideData(getattr(av.sidedata.sidedata.Type, kind))))
    assert plain.dynamic_metadata is None and described.dynamic_metadata == "Dolby Vision"
    assert dataclasses.replace(described, dynamic_metadata=None) == plain  # nothing else read differently
    like = dataclasses.replace(video_reader.probe_video(path), colour=described)
    with video_writer.VideoWriter(tmp_path / "out.mp4", like=like) as writer:
        writer.write(np.zeros((H, W, 3), np.float32))
    assert writer.warnings == ["the input's Dolby Vision dynamic metadata is not carried over: the output is plain "
                               "HLG, tags kept"]
    assert stream_tags(tmp_path / "out.mp4")["transfer"] == 18
