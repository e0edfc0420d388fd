"""Fuzzing the CLI (issue 8): mutated bytes of small valid clips, and option values, through cli.main.

Every run must end one of two ways: exit 0 with an output that keeps the frame count and timing the
reader makes of the input, or a clean refusal, i.e. one `ffviz: error:` line with exit 2 or 3, or
argparse's usage error (SystemExit 2) for a malformed option. An internal error (exit 1) or any other
exception is a failure, and so is a temp file left behind or a changed input.

The budget is bounded (FFVIZ_FUZZ_EXAMPLES, default 40 per test) and the examples are derandomized so
CI is repeatable; FFVIZ_FUZZ_RANDOM=1 draws new ones. The long variant (marked slow) runs more.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from ffviz import cli
from pipeline.evaluation import synthetic
from pipeline.runtime import video_reader

EXAMPLES = int(os.environ.get("FFVIZ_FUZZ_EXAMPLES", "40"))
LONG_EXAMPLES = int(os.environ.get("FFVIZ_FUZZ_LONG_EXAMPLES", "300"))
FUZZ_SETTINGS = dict(
    deadline=None,
    database=None,  # nothing written into the work tree
    derandomize=not os.environ.get("FFVIZ_FUZZ_RANDOM"),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    print_blob=True,
)
W, H, N, FPS = 96, 64, 6, 25


def _clip(path: Path, codec: str, pix_fmt: str, options: dict[str, str] | None = None,
          muxer_options: dict[str, str] | None = None) -> bytes:
    """N frames of a photograph panning right, encoded as asked; returns the file's bytes."""
    canvas = cv2.resize(synthetic.load_image("coffee"), (W + 4 * N, H), interpolation=cv2.INTER_AREA)
    with av.open(str(path), "w", options=muxer_options or {}) as container:
        stream = container.add_stream(codec, rate=FPS, options=options or {})
        stream.width, stream.height, stream.pix_fmt = W, H, pix_fmt
        stream.codec_context.time_base = Fraction(1, FPS)
        for t in range(N):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(canvas[:, 4 * t: 4 * t + W]), format="rgb24")
            frame.pts = t
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
    return path.read_bytes()


class Seeds(dict):
    """suffix -> bytes of a valid clip; a short repr, so a failing example prints readably."""

    def __repr__(self) -> str:
        return f"<seed clips {', '.join(self)}>"


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> Seeds:
    """Valid clips to mutate, in the containers users bring."""
    folder = tmp_path_factory.mktemp("seeds")
    return Seeds({
        ".mp4": _clip(folder / "a.mp4", "libx264", "yuv420p", {"preset": "ultrafast"}, {"movflags": "+faststart"}),
        ".mkv": _clip(folder / "b.mkv", "libx264", "yuv420p", {"preset": "ultrafast", "bf": "2"}),
        ".avi": _clip(folder / "c.avi", "mjpeg", "yuvj420p"),
    })


# --- mutations of bytes ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Mutation:
    kind: str  # flip, set, truncate, splice, insert, delete
    at: float  # where, as a fraction of the length (so the same draw fits every seed)
    other: float  # a second position (splice source) or a length fraction
    value: int  # bit index, byte value or random seed

    def apply(self, data: bytearray) -> bytearray:
        if not data:
            return data
        at = min(int(self.at * len(data)), len(data) - 1)
        span = max(1, int(self.other * len(data) / 8))
        if self.kind == "flip":
            data[at] ^= 1 << (self.value % 8)
        elif self.kind == "set":
            data[at] = self.value % 256
        elif self.kind == "truncate":
            del data[at:]
        elif self.kind == "splice":  # a chunk copied over another place: plausible but wrong structure
            source = min(int(self.other * len(data)), len(data) - 1)
            chunk = data[source: source + span]
            data[at: at + len(chunk)] = chunk
        elif self.kind == "insert":
            data[at:at] = np.random.default_rng(self.value).integers(0, 256, span, np.uint8).tobytes()
        elif self.kind == "delete":
            del data[at: at + span]
        return data


mutations = st.builds(
    Mutation,
    kind=st.sampled_from(["flip", "set", "truncate", "splice", "insert", "delete"]),
    at=st.floats(0, 1),
    other=st.floats(0, 1),
    value=st.integers(0, 2**16),
)


# --- one run and what it must satisfy ------------------------------------------------------------


@dataclass
class Outcome:
    code: int
    stdout: str
    stderr: str


def run(argv: list[str]) -> Outcome:
    """cli.main in-process; a SystemExit (argparse) becomes its code, every other exception propagates."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli.main(argv)
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 2
            if code != 2 or "error:" not in err.getvalue():
                raise
    return Outcome(code, out.getvalue(), err.getvalue())


def check(outcome: Outcome, source: Path, output: Path, *, before: bytes, existed: bytes | None) -> None:
    folder = output.parent
    assert source.read_bytes() == before, "the input was changed"
    assert not [p.name for p in folder.iterdir() if "ffviz-tmp" in p.name], "a temp file was left"
    assert "Traceback" not in outcome.stderr
    if outcome.code == 0:
        lines = outcome.stderr.strip().splitlines()
        assert all(line.startswith("ffviz: warning: ") for line in lines), outcome.stderr
        with video_reader.VideoReader(source) as reader:
            times_in = [f.time_s for f in reader]
        with video_reader.VideoReader(output) as reader:
            times_out = [f.time_s for f in reader]
        assert times_out == pytest.approx(times_in, abs=1e-6)
        return
    assert outcome.code in (2, 3), f"exit {outcome.code}: {outcome.stderr}"
    lines = outcome.stderr.strip().splitlines()
    if lines and lines[0].startswith("usage:"):  # argparse: usage, then one error line
        assert lines[-1].startswith("ffviz stabilize: error:") or lines[-1].startswith("ffviz: error:")
    else:
        assert len(lines) == 1 and lines[0].startswith("ffviz: error: "), outcome.stderr
    # A refused run leaves the output as it was (absent, or the earlier file).
    if existed is None:
        assert not output.exists()
    else:
        assert output.read_bytes() == existed


def fuzz_bytes(seeds: dict[str, bytes], suffix: str, changes: list[Mutation]) -> None:
    data = bytearray(seeds[suffix])
    for change in changes:
        data = change.apply(data)
    with tempfile.TemporaryDirectory() as folder:
        source, output = Path(folder) / f"in{suffix}", Path(folder) / "out" / "out.mp4"
        source.write_bytes(bytes(data))
        output.parent.mkdir()
        outcome = run(["stabilize", str(source), "-o", str(output), "--mode", "none", "-k", "2"])
        check(outcome, source, output, before=bytes(data), existed=None)


suffixes = st.sampled_from([".mp4", ".mkv", ".avi"])


@settings(max_examples=EXAMPLES, **FUZZ_SETTINGS)
@given(suffix=suffixes, changes=st.lists(mutations, min_size=1, max_size=4))
# Found by the long run: a splice that leaves a stream tag not valid UTF-8 (PyAV raised UnicodeDecodeError).
@example(suffix=".mkv", changes=[Mutation("splice", 1.0, 0.5, 0), Mutation("splice", 1.0, 0.5, 0),
                                 Mutation("splice", 0.09375, 1.0, 0)])
@pytest.mark.timeout(300)
def test_mutated_input_bytes(seeds, suffix, changes):
    fuzz_bytes(seeds, suffix, changes)


@pytest.mark.slow
@settings(max_examples=LONG_EXAMPLES, **FUZZ_SETTINGS)
@given(suffix=suffixes, changes=st.lists(mutations, min_size=1, max_size=8))
@pytest.mark.timeout(1200)
def test_mutated_input_bytes_long(seeds, suffix, changes):
    fuzz_bytes(seeds, suffix, changes)


# --- options --------------------------------------------------------------------------------------


def _number(value) -> str:
    return repr(value) if isinstance(value, float) else str(value)


def mostly(valid: st.SearchStrategy, invalid: st.SearchStrategy) -> st.SearchStrategy:
    """Valid about nine times in ten, so most runs get past argparse and reach the pipeline."""
    return st.integers(0, 9).flatmap(lambda roll: invalid if roll == 9 else valid)


options = st.fixed_dictionaries(
    {},
    optional={
        "--mode": mostly(st.sampled_from(["none", "crop", "full"]), st.sampled_from(["bogus", ""])),
        "-k": mostly(st.integers(0, 60), st.one_of(st.integers(-(2**40), 2**40), st.sampled_from(["x", "1.5", ""]))),
        "--smoothing-sigma": mostly(st.floats(1e-3, 100), st.one_of(
            st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(["nan", "-inf", "1e-200", "y"]))),
        "--motion-model": mostly(st.sampled_from(["affine", "similarity", "homography"]), st.just("projective")),
        "--refine": mostly(st.sampled_from(["none", "ecc"]), st.just("yes")),
        "--crf": mostly(st.integers(0, 51), st.one_of(st.integers(-(2**31), 2**31), st.sampled_from(["18.5", "best"]))),
        "--codec": mostly(st.sampled_from(["h264", "mpeg4"]), st.sampled_from(["vp9", ""])),
        "--qscale": mostly(st.integers(2, 31), st.one_of(st.integers(-(2**31), 2**31), st.sampled_from(["3.5", "q"]))),
        "--deblur-alpha": mostly(st.floats(0.1, 1000), st.floats(allow_nan=True, allow_infinity=True)),
        "--no-deblur": st.just(None),
        "--smoothness": mostly(st.one_of(st.floats(0, 100).map(_number), st.sampled_from(["t=80,z=20", "r=0"])),
                               st.sampled_from(["101", "nan", "t=", "q=5", "-1", ""])),
        "--max-shift": mostly(st.floats(0, 100), st.floats(allow_nan=True, allow_infinity=True)),
        "--max-angle": mostly(st.floats(0, 10), st.floats(allow_nan=True, allow_infinity=True)),
        "--path-segment": mostly(st.sampled_from(["0-0.5:tripod", "0.3-:l1:70", "-0.2:gaussian:t=90"]),
                                 st.sampled_from(["5:l1", "1-0:tripod", "0-1:dolly", "0-1:tripod:50", "x-y:l1"])),
        "--crop": mostly(st.sampled_from(["fixed", "adaptive"]), st.just("wide")),
        "--zoom-speed": mostly(st.floats(0.01, 10), st.floats(allow_nan=True, allow_infinity=True)),
    },
)


def fuzz_options(seeds: dict[str, bytes], chosen: dict[str, object], overwrite: bool, existing: bool) -> None:
    with tempfile.TemporaryDirectory() as folder:
        source, output = Path(folder) / "in.mp4", Path(folder) / "out" / "out.mp4"
        source.write_bytes(seeds[".mp4"])
        output.parent.mkdir()
        if existing:
            output.write_bytes(b"an earlier result")
        argv = ["stabilize", str(source), "-o", str(output)]
        for flag, value in chosen.items():
            # '=': a value like -3 must not read as an option; None: a flag without a value
            argv.append(flag if value is None else f"{flag}={_number(value)}")
        if overwrite:
            argv.append("--overwrite")
        outcome = run(argv)
        check(outcome, source, output, before=seeds[".mp4"], existed=b"an earlier result" if existing else None)
        if existing and not overwrite:
            assert outcome.code != 0, "an existing output was replaced without --overwrite"


@settings(max_examples=EXAMPLES, **FUZZ_SETTINGS)
@given(chosen=options, overwrite=st.booleans(), existing=st.booleans())
# Found by a random long run: sigma**2 overflowed (OverflowError) in the option check itself.
@example(chosen={"--smoothing-sigma": 1.3407807929942597e154}, overwrite=False, existing=False)
@pytest.mark.timeout(300)
def test_option_values(seeds, chosen, overwrite, existing):
    fuzz_options(seeds, chosen, overwrite, existing)


@pytest.mark.slow
@settings(max_examples=LONG_EXAMPLES // 2, **FUZZ_SETTINGS)
@given(chosen=options, overwrite=st.booleans(), existing=st.booleans())
@pytest.mark.timeout(1200)
def test_option_values_long(seeds, chosen, overwrite, existing):
    fuzz_options(seeds, chosen, overwrite, existing)
