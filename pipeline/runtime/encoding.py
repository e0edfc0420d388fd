"""How the output video is compressed: the codecs and their settings (``Encoding``), and what the encoders
are told about this CPU (``x264_cpu_params``)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

from pipeline.errors import ConfigError

X264_PRESETS: tuple[str, ...] = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow",
                                 "slower", "veryslow")  # x265's presets have the same names
ENCODERS = {"h264": "libx264", "hevc": "libx265", "mpeg4": "mpeg4"}  # --codec name -> FFmpeg encoder
VIDEO_CODECS: tuple[str, ...] = ("auto", *ENCODERS)
# the Encoding fields each codec uses
CODEC_OPTIONS = {"auto": ("crf", "preset"), "h264": ("crf", "preset"), "hevc": ("crf", "preset"), "mpeg4": ("qscale",)}
MAX_DEPTH = {"h264": 10, "hevc": 12, "mpeg4": 8}  # bits per sample each encoder can write (4:2:0)
MPEG4_MAX_TIME_BASE_DENOMINATOR = 65535  # the MPEG-4 Part 2 standard's limit (FFmpeg refuses more)


# /proc/cpuinfo's flag -> x264's name for that instruction set (its `asm` option), in x264's order
_X264_INSTRUCTION_SETS = (("sse", "SSE"), ("sse2", "SSE2Fast"), ("pni", "SSE3"), ("ssse3", "SSSE3"),
                          ("sse4_1", "SSE4.1"), ("sse4_2", "SSE4.2"), ("abm", "LZCNT"), ("avx", "AVX"),
                          ("fma", "FMA3"), ("bmi1", "BMI1"), ("bmi2", "BMI2"), ("avx2", "AVX2"))


@functools.cache
def x264_cpu_params(cpuinfo: Path = Path("/proc/cpuinfo")) -> tuple[str, ...]:
    """x264-params entries that keep libx264 off its AVX-512 routines on a CPU that has them; none elsewhere.

    Why: the libx264 that PyAV bundles reads uninitialised memory in an AVX-512 routine of its macroblock-tree
    rate control at some frame sizes (320x180 is one), so the same frames encode to different bytes from one run,
    or one encode, to the next: ``MALLOC_PERTURB_`` changes the output, while ``mbtree=0`` or an instruction set
    without AVX-512 makes it repeatable. Where the bug does not strike, the list gives the same bytes as x264's
    own detection. The sets named are those /proc/cpuinfo lists, so none the CPU lacks is forced on (x264 would
    run it and die of an illegal instruction)."""
    try:
        text = cpuinfo.read_text(errors="replace")
    except OSError:
        return ()
    lines = text.splitlines()
    flags = next((line.split(":", 1)[1].split() for line in lines if line.startswith("flags")), [])
    if "avx512f" not in flags:
        return ()
    names = [name for flag, name in _X264_INSTRUCTION_SETS if flag in flags]
    if any(line.startswith("clflush size") and line.split(":", 1)[1].strip() == "64" for line in lines):
        names.append("Cache64")
    return (f"asm={','.join(names)}",)


def x264_options(*params: str) -> dict[str, str]:
    """PyAV stream options carrying ``params`` and ``x264_cpu_params()`` as libx264's x264-params (empty: none)."""
    joined = ":".join((*params, *x264_cpu_params()))
    return {"x264-params": joined} if joined else {}


@dataclass(frozen=True)
class Encoding:
    """How the output video is compressed.

    ``auto`` (default): ``h264`` for 8-bit input, ``hevc`` for deeper input (10/12-bit, HDR: docs/colour.md).
    ``h264``: x264 at constant quality ``crf`` (0-51, lower is better) with its speed/size ``preset``; High 10
    for deeper input. ``hevc``: x265 (Main, Main 10 or Main 12 by the input's depth), the same two settings.
    ``mpeg4``: FFmpeg's MPEG-4 Part 2 encoder, which OpenCV's XVID writer uses, at the fixed quantiser
    ``qscale`` (2-31, lower is better): far less CPU than x264 medium, paid for in bits at a like quality, which
    is why OpenCV's sample writes it (figures: docs/benchmarks-speed.md, "From the decision log").
    """

    codec: str = "auto"
    crf: int = 18
    preset: str = "medium"
    qscale: int = 3

    def __post_init__(self) -> None:
        if self.codec not in VIDEO_CODECS:
            raise ConfigError(f"codec must be one of {', '.join(VIDEO_CODECS)}, not {self.codec!r}")
        if not 0 <= self.crf <= 51:
            raise ConfigError(f"crf must be between 0 and 51 (x264's range), not {self.crf}")
        if self.preset not in X264_PRESETS:
            raise ConfigError(f"preset must be one of {', '.join(X264_PRESETS)}, not {self.preset!r}")
        if not 2 <= self.qscale <= 31:
            raise ConfigError(f"qscale must be between 2 and 31 (MPEG-4's quantisers), not {self.qscale}")

    def encoder(self, bit_depth: int) -> str:
        """The --codec name used for video of ``bit_depth`` bits ("auto" resolved)."""
        if self.codec == "auto":
            return "hevc" if bit_depth > 8 else "h264"
        return self.codec

    def stream_options(self, bit_depth: int = 8) -> dict[str, str]:
        if self.encoder(bit_depth) in ("h264", "hevc"):
            return {"crf": str(self.crf), "preset": self.preset}
        # A fixed quantiser: FFmpeg's -q:v sets it per frame, which PyAV cannot; clamping the rate control's
        # range to one value does the same.
        return {"qmin": str(self.qscale), "qmax": str(self.qscale)}

