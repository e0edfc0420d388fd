"""The video's colour description, and the conversions between its YUV samples and the pipeline's RGB.

Read once from the first decoded picture (range, matrix, primaries, transfer, bit depth, HDR mastering metadata)
and kept in VideoInfo.colour. Frames are converted to RGB with the input's own matrix and range, and written back
with the same matrix, range and tags, so a player that honours tags shows the output's colours as the input's.
Primaries and transfer are not converted: the pipeline works on the input's RGB code values as they are.

Depth: 8-bit video travels as uint8 RGB; deeper video (10/12 bits) as float32 RGB on the same 0..255 scale
(fractions of a level carry the extra bits), so every threshold in intensity units means the same at any depth.
``display_rgb`` turns either into 8-bit BT.709 display RGB (HDR tone-mapped: BT.2390 EETF) for people to look at.
Chroma location (where 4:2:0's chroma samples sit) is not exposed by PyAV 18: read by ffprobe when it is on PATH
(``probe_chroma_location``; unknown without it, and then nothing is written, as before), honoured by the 4:2:0
conversions and written back (x264/x265 ``chromaloc``, and the codec context's field, which MKV also carries).
"""

from __future__ import annotations

import functools
import json
import math
import os
import shutil
import struct
import subprocess
from dataclasses import dataclass

import av
import cv2
import numpy as np
from av.video.reformatter import Interpolation
from numba import njit

# FFmpeg's names (as ffprobe prints them) for the AVColorSpace / AVColorPrimaries / AVColorTransferCharacteristic /
# AVColorRange numbers.
MATRIX_NAMES = {0: "gbr", 1: "bt709", 2: "unknown", 4: "fcc", 5: "bt470bg", 6: "smpte170m", 7: "smpte240m",
                8: "ycgco", 9: "bt2020nc", 10: "bt2020c", 14: "ictcp"}
PRIMARIES_NAMES = {1: "bt709", 2: "unknown", 4: "bt470m", 5: "bt470bg", 6: "smpte170m", 7: "smpte240m", 8: "film",
                   9: "bt2020", 10: "smpte428", 11: "smpte431", 12: "smpte432", 22: "ebu3213"}
TRANSFER_NAMES = {1: "bt709", 2: "unknown", 4: "bt470m", 5: "bt470bg", 6: "smpte170m", 7: "smpte240m", 8: "linear",
                  9: "log100", 10: "log316", 11: "iec61966-2-4", 12: "bt1361e", 13: "iec61966-2-1", 14: "bt2020-10",
                  15: "bt2020-12", 16: "smpte2084", 17: "smpte428", 18: "arib-std-b67"}
RANGE_NAMES = {0: "unknown", 1: "tv", 2: "pc"}
LIMITED, FULL = 1, 2
BT601, BT709, BT2020_NCL = 6, 1, 9
PQ, HLG = 16, 18
# AVColorSpace -> the swscale matrix PyAV's reformat takes (SWS_CS_*); anything else is converted as BT.601,
# FFmpeg's default for untagged video, and tagged so.
_SWS_MATRIX = {1: 1, 4: 4, 5: 5, 6: 5, 7: 7, 9: 9, 10: 9}
# Planar 4:2:0 (nearly all video) is converted here, exactly and at its chroma location (from_rgb, _yuv420_to_rgb):
# swscale with these flags takes chroma as sited at the centre, half a pixel right of H.264/HEVC's default, and PyAV
# cannot tell it otherwise. Other layouts go through swscale with these flags, which read 8-bit levels right where its
# defaults do not; its 10-bit paths are off in gain, and full chroma interpolation misreads 10-bit input, so it is
# for 8 bits only (measurements: docs/colour.md; docs/decisions.md D15, D20).
_FLAGS_8 = Interpolation.BILINEAR | Interpolation.ACCURATE_RND | Interpolation.FULL_CHR_H_INT | \
    Interpolation.FULL_CHR_H_INP
_FLAGS_DEEP = Interpolation.BICUBIC | Interpolation.ACCURATE_RND
_KR_KB = {1: (0.2126, 0.0722), 4: (0.30, 0.11), 5: (0.299, 0.114), 6: (0.299, 0.114), 7: (0.212, 0.087),
          9: (0.2627, 0.0593), 10: (0.2627, 0.0593)}  # luma weights of R and B per matrix (ITU-T H.273)
_DEPTHS = {"yuv420p": 8, "yuvj420p": 8, "yuv420p10le": 10, "yuv420p12le": 12}
# FFmpeg's chroma location names -> H.264/HEVC chroma_sample_loc_type (x264/x265 ``chromaloc``), and where the
# chroma sample of each 2x2 block sits, in luma pixels right and down of its top-left pixel.
CHROMA_LOCATIONS = {"left": 0, "center": 1, "topleft": 2, "top": 3, "bottomleft": 4, "bottom": 5}
_CHROMA_SITES = {"left": (0.0, 0.5), "center": (0.5, 0.5), "topleft": (0.0, 0.0), "top": (0.5, 0.0),
                 "bottomleft": (0.0, 1.0), "bottom": (0.5, 1.0)}


@dataclass(frozen=True)
class ColourDescription:
    """How the video's samples map to colour. The defaults are what an untagged 8-bit source (and frames
    handed in as arrays) is taken to be: BT.601 limited range, primaries and transfer unknown."""

    matrix: int = BT601  # AVColorSpace the conversion uses (an untagged input's BT.601 is written as such)
    range: int = LIMITED  # AVColorRange: 1 limited (tv), 2 full (pc)
    primaries: int = 2  # AVColorPrimaries, 2 unknown: tagged as read, never converted
    transfer: int = 2  # AVColorTransferCharacteristic, 2 unknown: tagged as read, never converted
    bit_depth: int = 8  # bits per sample of the stored video
    pix_fmt: str = "yuv420p"  # the input's pixel format, for the record
    mastering: tuple[tuple[float, float], ...] | None = None  # R, G, B, white (x, y); (min, max) cd/m2 last
    content_light: tuple[int, int] | None = None  # MaxCLL, MaxFALL (cd/m2)
    dynamic_metadata: str | None = None  # "Dolby Vision" / "HDR10+" per-scene metadata, which is not carried over
    chroma_location: str | None = None  # CHROMA_LOCATIONS name (ffprobe's); None: unknown, converted as "left"

    @property
    def deep(self) -> bool:
        """More than 8 bits: frames travel as float32 RGB (module docstring)."""
        return self.bit_depth > 8

    @property
    def chroma(self) -> str:
        """The input's chroma subsampling: 4:2:0, 4:2:2, 4:4:4 (YUV), or rgb / gray."""
        if self.pix_fmt.startswith(("gbr", "rgb", "bgr")):
            return "rgb"
        if self.pix_fmt.startswith(("gray", "ya")):
            return "gray"
        return "4:4:4" if "444" in self.pix_fmt else "4:2:2" if "422" in self.pix_fmt else "4:2:0"

    @property
    def hdr(self) -> bool:
        return self.transfer in (PQ, HLG)

    def summary(self) -> str:
        """One line as ffprobe would put it: pixel format, range, matrix, primaries, transfer, depth, HDR metadata."""
        text = (f"{self.pix_fmt}, {RANGE_NAMES.get(self.range, self.range)}, {MATRIX_NAMES.get(self.matrix, self.matrix)}"
                f", {PRIMARIES_NAMES.get(self.primaries, self.primaries)}, "
                f"{TRANSFER_NAMES.get(self.transfer, self.transfer)}, {self.bit_depth}-bit")
        if self.mastering is not None:
            text += f", mastering display {self.mastering[-1][0]:g}-{self.mastering[-1][1]:g} cd/m2"
        if self.content_light is not None:
            text += f", MaxCLL {self.content_light[0]}, MaxFALL {self.content_light[1]}"
        if self.chroma == "4:2:0":
            text += f", chroma {self.chroma_location or 'location unknown'}"
        return text

    def chroma_params(self) -> list[str]:
        """x264's and x265's setting that writes the chroma location into the stream (empty when unknown)."""
        if self.chroma_location not in CHROMA_LOCATIONS:
            return []
        return [f"chromaloc={CHROMA_LOCATIONS[self.chroma_location]}"]

    def x265_hdr_params(self) -> list[str]:
        """x265's master-display and max-cll settings that carry the input's HDR metadata (empty without it)."""
        params = []
        if self.mastering is not None:
            (rx, ry), (gx, gy), (bx, by), (wx, wy), (low, high) = self.mastering
            c = [round(v * 50000) for v in (gx, gy, bx, by, rx, ry, wx, wy)]
            params.append(f"master-display=G({c[0]},{c[1]})B({c[2]},{c[3]})R({c[4]},{c[5]})WP({c[6]},{c[7]})"
                          f"L({round(high * 10000)},{round(low * 10000)})")
        if self.content_light is not None:
            params.append(f"max-cll={self.content_light[0]},{self.content_light[1]}")
        return params


_DYNAMIC = {av.sidedata.sidedata.Type.DOVI_METADATA: "Dolby Vision", av.sidedata.sidedata.Type.DOVI_RPU_BUFFER:
            "Dolby Vision", av.sidedata.sidedata.Type.DYNAMIC_HDR_PLUS: "HDR10+"}


def describe(frame: av.VideoFrame) -> ColourDescription:
    """The colour description of a decoded picture (the first one: read once per video)."""
    name = frame.format.name
    depth = max(component.bits for component in frame.format.components)
    matrix = int(frame.colorspace)
    if matrix not in _SWS_MATRIX:  # untagged, or a matrix swscale lacks: converted as BT.601, and said so
        matrix = BT601
    colour_range = int(frame.color_range)
    if colour_range not in (LIMITED, FULL):  # swscale's own rule: the JPEG formats are full range, the rest limited
        colour_range = FULL if name.startswith("yuvj") or name.startswith(("gbr", "rgb", "bgr")) else LIMITED
    mastering = content_light = dynamic = None
    for side in frame.side_data:
        if side.type in _DYNAMIC:
            dynamic = _DYNAMIC[side.type]
        data = bytes(side)
        if side.type == av.sidedata.sidedata.Type.MASTERING_DISPLAY_METADATA and len(data) >= 88:
            numbers = struct.unpack("22i", data[:88])
            ratios = [numbers[i] / numbers[i + 1] if numbers[i + 1] else 0.0 for i in range(0, 20, 2)]
            if numbers[20] and numbers[21]:  # has primaries, has luminance
                mastering = (tuple(ratios[0:2]), tuple(ratios[2:4]), tuple(ratios[4:6]), tuple(ratios[6:8]),
                             tuple(ratios[8:10]))
        elif side.type == av.sidedata.sidedata.Type.CONTENT_LIGHT_LEVEL and len(data) >= 8:
            content_light = struct.unpack("2I", data[:8])
    return ColourDescription(matrix=matrix, range=colour_range, primaries=int(frame.color_primaries),
                             transfer=int(frame.color_trc), bit_depth=int(depth), pix_fmt=name,
                             mastering=mastering, content_light=content_light, dynamic_metadata=dynamic)


def probe_chroma_location(path: str | os.PathLike[str], stream_index: int) -> str | None:
    """The stream's chroma location as ffprobe names it (a CHROMA_LOCATIONS key), or None where it is unspecified,
    ffprobe is not on PATH, or it fails: PyAV 18 exposes the field nowhere (frame, stream, codec context). Cached
    per file version, so the readers a run opens start ffprobe once."""
    ffprobe = shutil.which("ffprobe")
    try:
        stat = os.stat(path)
    except OSError:
        return None
    if ffprobe is None:
        return None
    return _probe_chroma_location(ffprobe, os.fspath(path), stream_index, stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _probe_chroma_location(ffprobe: str, path: str, stream_index: int, size: int, mtime_ns: int) -> str | None:
    try:
        result = subprocess.run([ffprobe, "-v", "error", "-select_streams", str(stream_index), "-show_entries",
                                 "stream=chroma_location", "-of", "json", path],
                                capture_output=True, text=True, timeout=30, check=True)
        streams = json.loads(result.stdout).get("streams") or [{}]
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    location = streams[0].get("chroma_location")
    return location if location in CHROMA_LOCATIONS else None


def to_rgb(frame: av.VideoFrame, colour: ColourDescription, width: int, height: int, *, deep: bool) -> np.ndarray:
    """(height, width, 3) RGB of a decoded picture by the video's matrix and range: uint8, or with ``deep`` (and
    more than 8 bits in the video) float32 on the 0..255 scale."""
    if frame.format.name in _DEPTHS and (frame.width, frame.height) == (width, height):
        return _yuv420_to_rgb(frame, colour, rounded=not (deep and colour.deep))
    if deep and colour.deep:
        rgb = frame.to_ndarray(format="rgb48le", width=width, height=height, src_colorspace=_SWS_MATRIX[colour.matrix],
                               src_color_range=colour.range, interpolation=_FLAGS_DEEP)
        return rgb.astype(np.float32) * np.float32(1 / 257)
    return frame.to_ndarray(format="rgb24", width=width, height=height, src_colorspace=_SWS_MATRIX[colour.matrix],
                            src_color_range=colour.range, interpolation=_FLAGS_8)


def from_rgb(rgb: np.ndarray, colour: ColourDescription, pix_fmt: str) -> av.VideoFrame:
    """A 4:2:0 picture in ``pix_fmt`` (yuv420p, yuv420p10le, yuv420p12le; even sizes) from RGB (uint8, or float32 on
    the 0..255 scale), by the video's matrix and range (exactly, rounded), tagged with its description. Chroma of
    each 2x2 block is taken at its chroma location (unknown: left, MPEG-2/H.264's default): [1 2 1] / 4 centred on
    a pixel, [1 1] / 2 between two."""
    frame = _rgb_to_yuv420(np.asarray(rgb, np.float32), colour, pix_fmt, _DEPTHS[pix_fmt])
    frame.colorspace, frame.color_range = colour.matrix, colour.range
    frame.color_primaries, frame.color_trc = colour.primaries, colour.transfer
    return frame


def _rgb_to_yuv420(rgb: np.ndarray, colour: ColourDescription, pix_fmt: str, depth: int) -> av.VideoFrame:
    encode, _ = _yuv_affine(colour, depth)
    luma = cv2.transform(rgb, encode[:1])
    # the block's filter, centred on its chroma sample, kept at its top-left pixel and picked out by a
    # nearest-neighbour halving
    site_x, site_y = _CHROMA_SITES.get(colour.chroma_location, _CHROMA_SITES["left"])
    across, anchor_x = _SITE_KERNELS[site_x]
    down, anchor_y = _SITE_KERNELS[site_y]
    blocks = cv2.sepFilter2D(rgb, cv2.CV_32F, across, down, anchor=(anchor_x, anchor_y),
                             borderType=cv2.BORDER_REPLICATE)
    blocks = cv2.resize(blocks, (rgb.shape[1] // 2, rgb.shape[0] // 2), interpolation=cv2.INTER_NEAREST)
    chroma = cv2.transform(blocks, encode[1:])
    frame = av.VideoFrame(rgb.shape[1], rgb.shape[0], pix_fmt)
    dtype = np.uint8 if depth == 8 else np.uint16
    for plane, values in zip(frame.planes, (luma, chroma[..., 0], chroma[..., 1])):
        stored = np.frombuffer(plane, dtype).reshape(plane.height, -1)[:, :plane.width]
        np.clip(values + np.float32(0.5), 0, 2 ** depth - 1, out=stored, casting="unsafe")
    return frame


# chroma sample's offset in the block (luma pixels) -> (kernel, anchor) that centres the filter on it
_SITE_KERNELS = {0.0: (np.array([0.25, 0.5, 0.25], np.float32), 1),  # on the first pixel (and its neighbours)
                 0.5: (np.array([0.5, 0.5], np.float32), 0),  # between the block's two pixels
                 1.0: (np.array([0.25, 0.5, 0.25], np.float32), 0)}  # on the second pixel


def _yuv_affine(colour: ColourDescription, depth: int) -> tuple[np.ndarray, np.ndarray]:
    """3x4 float32 affine maps R'G'B' (0..255) -> Y'CbCr code values and back, by the matrix and range (ITU-T
    H.273: limited Y' = (219 E'y + 16) 2^(n-8), Cb = (224 E'pb + 128) 2^(n-8); full Y' = (2^n - 1) E'y, Cb =
    (2^n - 1) E'pb + 2^(n-1)). Read-only: made once per matrix, range and depth, shared by every frame."""
    return _affine_maps(colour.matrix, colour.range, depth)


@functools.lru_cache(maxsize=16)
def _affine_maps(matrix: int, colour_range: int, depth: int) -> tuple[np.ndarray, np.ndarray]:
    kr, kb = _KR_KB.get(matrix, _KR_KB[BT601])
    kg = 1 - kr - kb
    to_ypbpr = np.array([[kr, kg, kb], [-kr / (2 * (1 - kb)), -kg / (2 * (1 - kb)), 0.5],
                         [0.5, -kg / (2 * (1 - kr)), -kb / (2 * (1 - kr))]]) / 255
    scale = 2.0 ** (depth - 8)
    if colour_range == FULL:
        gains, offsets = np.full(3, 2.0 ** depth - 1), np.array([0, 128, 128]) * scale
    else:
        gains, offsets = np.array([219, 224, 224]) * scale, np.array([16, 128, 128]) * scale
    encode = np.hstack([gains[:, None] * to_ypbpr, offsets[:, None]])
    to_rgb = np.linalg.inv(to_ypbpr) / gains[None, :]  # code values minus offsets -> R'G'B'
    decode = np.hstack([to_rgb, -(to_rgb @ offsets)[:, None]])
    maps = encode.astype(np.float32), decode.astype(np.float32)
    for array in maps:
        array.flags.writeable = False
    return maps


def _yuv420_to_rgb(frame: av.VideoFrame, colour: ColourDescription, *, rounded: bool = False) -> np.ndarray:
    """RGB of a planar 4:2:0 picture, exactly by the matrix and range (swscale's 10-bit paths are ~0.4% off in gain
    both ways, its 8-bit full range half a level off in chroma): float32 (0..255), or with ``rounded`` uint8 rounded
    to the nearest level. Chroma is interpolated bilinearly from where it is sited (its chroma location; unknown:
    left, between two rows), as from_rgb writes it.

    The chroma's bilinear weights are multiples of 1/16 and the samples integers, so the interpolation is exact in
    float32 whatever the order of its sums (``_ycbcr420``: the values cv2.warpAffine gives); the matrix is applied
    by cv2.transform as before, and clipping and rounding take one pass (``_clip_round``)."""
    depth = _DEPTHS[frame.format.name]
    dtype = np.uint8 if depth == 8 else np.uint16
    luma, cb, cr = (np.frombuffer(p, dtype).reshape(p.height, -1)[:, :p.width] for p in frame.planes)
    site_x, site_y = _CHROMA_SITES.get(colour.chroma_location, _CHROMA_SITES["left"])
    ycbcr = _ycbcr420(luma, cb, cr, site_x, site_y)
    _, decode = _yuv_affine(colour, depth)
    rgb = cv2.transform(ycbcr, decode, dst=ycbcr)
    if rounded:
        return _clip_round(rgb)
    return np.clip(rgb, 0, 255, out=rgb)


@njit(cache=True, nogil=True)
def _ycbcr420(luma: np.ndarray, cb: np.ndarray, cr: np.ndarray, site_x: float, site_y: float) -> np.ndarray:
    """(H, W, 3) float32 Y', Cb, Cr at every luma pixel: chroma sample (i, j) sits at luma (2j + site_x, 2i +
    site_y), read bilinearly at ((x - site_x) / 2, (y - site_y) / 2) with the edges repeated."""
    height, width = luma.shape
    chroma_height, chroma_width = cb.shape
    out = np.empty((height, width, 3), np.float32)
    left = np.empty(width, np.int64)
    right = np.empty(width, np.int64)
    across = np.empty(width, np.float32)
    for x in range(width):
        u = (x - site_x) * 0.5
        j = math.floor(u)
        across[x] = u - j
        left[x] = min(max(j, 0), chroma_width - 1)
        right[x] = min(max(j + 1, 0), chroma_width - 1)
    one = np.float32(1.0)
    cb_row = np.empty(chroma_width, np.float32)  # chroma interpolated down to row y, at chroma columns
    cr_row = np.empty(chroma_width, np.float32)
    for y in range(height):
        v = (y - site_y) * 0.5
        i = math.floor(v)
        down = np.float32(v - i)
        up = one - down
        top, bottom = min(max(i, 0), chroma_height - 1), min(max(i + 1, 0), chroma_height - 1)
        for j in range(chroma_width):
            cb_row[j] = np.float32(cb[top, j]) * up + np.float32(cb[bottom, j]) * down
            cr_row[j] = np.float32(cr[top, j]) * up + np.float32(cr[bottom, j]) * down
        for x in range(width):
            a, b, w = left[x], right[x], across[x]
            out[y, x, 0] = luma[y, x]
            out[y, x, 1] = cb_row[a] + (cb_row[b] - cb_row[a]) * w
            out[y, x, 2] = cr_row[a] + (cr_row[b] - cr_row[a]) * w
    return out


@njit(cache=True, nogil=True)
def _clip_round(rgb: np.ndarray) -> np.ndarray:
    """uint8 of float32 ``rgb`` clipped to 0..255 and rounded half up (np.clip, + 0.5, truncation)."""
    flat = rgb.reshape(-1)
    out = np.empty(flat.size, np.uint8)
    low, high, half = np.float32(0.0), np.float32(255.0), np.float32(0.5)
    for i in range(flat.size):
        out[i] = np.uint8(min(max(flat[i], low), high) + half)
    return out.reshape(rgb.shape)


def tag_stream(context: av.codec.context.CodecContext, colour: ColourDescription) -> None:
    """The encoder writes the description into the stream (VUI: matrix, range, primaries, transfer). The chroma
    location has no field in PyAV: ``encoder_options`` sets it."""
    context.colorspace = colour.matrix
    context.color_range = colour.range
    context.color_primaries = colour.primaries
    context.color_trc = colour.transfer


def encoder_options(colour: ColourDescription) -> dict[str, str]:
    """Codec context options for the description's chroma location (the AVOption ``chroma_sample_location``,
    which the muxer copies into MKV's chroma siting), or none when it is unknown."""
    if colour.chroma_location not in CHROMA_LOCATIONS:
        return {}
    return {"chroma_sample_location": colour.chroma_location}


# ------------------------------------------------------------------------------------------------ display
#
# HDR shown on an SDR screen (ITU-R BT.2408): HDR reference white (203 cd/m2) is SDR's white, so display light is
# taken relative to it, and brighter light is compressed towards it by the BT.2390 EETF (Report ITU-R BT.2390,
# 5.4.1; BT.2408 3.1.1). PQ: the EETF on each of R'G'B' (code values), PQ's EOTF, then / 203. HLG: the inverse OETF
# and the OOTF of BT.2100 (system gamma 1.2 on the scene luminance, for the 1000 cd/m2 reference display, BT.2408's
# conversion point), then the EETF on that luminance, colour ratios kept.

# Linear BT.2020 RGB -> linear BT.709 RGB (ITU-R BT.2087).
_BT2020_TO_BT709 = np.array([[1.6605, -0.5876, -0.0728], [-0.1246, 1.1329, -0.0083], [-0.0182, -0.1006, 1.1187]],
                            np.float32)
SDR_WHITE_NITS = 203.0  # ITU-R BT.2408: HDR reference white, shown as SDR's white (and the EETF's target peak)
HDR_PEAK_NITS = 1000.0  # an HDR video's peak when it does not say (BT.2408's reference display); HLG's always
_LUMA_2020 = np.array([0.2627, 0.6780, 0.0593], np.float32)  # BT.2100 luminance of linear BT.2020 RGB
_PQ = (2610 / 16384, 2523 / 4096 * 128, 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32)  # m1, m2, c1, c2, c3


def pq_to_nits(code: np.ndarray) -> np.ndarray:
    """PQ's EOTF (BT.2100): non-linear signal 0..1 -> display light, cd/m2."""
    m1, m2, c1, c2, c3 = _PQ
    p = np.power(np.clip(code, 0, 1), 1 / m2)
    return 10000 * np.power(np.maximum(p - c1, 0) / (c2 - c3 * p), 1 / m1)


def nits_to_pq(nits: np.ndarray) -> np.ndarray:
    """PQ's inverse EOTF (BT.2100): display light, cd/m2 -> non-linear signal 0..1."""
    m1, m2, c1, c2, c3 = _PQ
    y = np.power(np.clip(np.asarray(nits, np.float64) / 10000, 0, 1), m1)
    return np.power((c1 + c2 * y) / (1 + c3 * y), m2)


def bt2390_eetf(code: np.ndarray, source_peak: float, target_peak: float) -> np.ndarray:
    """Report ITU-R BT.2390's EETF on PQ code values: light from black to ``source_peak`` (cd/m2) fitted under
    ``target_peak``. Unchanged up to the knee KS = 1.5 maxLum - 0.5 (in PQ, relative to the source peak), a Hermite
    spline above it with slope 1 at the knee and reaching exactly the target peak at the source peak: monotonic,
    nothing below the source peak clipped. Black levels 0 (the black lift term vanishes). Above the source peak:
    the target peak."""
    source_pq = float(nits_to_pq(source_peak))
    if target_peak >= source_peak:
        return np.minimum(code, nits_to_pq(target_peak))
    max_lum = float(nits_to_pq(target_peak)) / source_pq
    knee = 1.5 * max_lum - 0.5
    e1 = np.clip(np.asarray(code, np.float64) / source_pq, 0, 1)
    t = (e1 - knee) / (1 - knee)
    spline = (2 * t**3 - 3 * t**2 + 1) * knee + (t**3 - 2 * t**2 + t) * (1 - knee) + (-2 * t**3 + 3 * t**2) * max_lum
    return np.where(e1 < knee, e1, spline) * source_pq


def hlg_to_scene(code: np.ndarray) -> np.ndarray:
    """HLG's inverse OETF (BT.2100): non-linear signal 0..1 -> scene light 0..1."""
    a, b, c = 0.17883277, 0.28466892, 0.55991073
    code = np.clip(code, 0, 1)
    return np.where(code <= 0.5, code * code / 3, (np.exp((code - c) / a) + b) / 12)


def source_peak_nits(colour: ColourDescription) -> float:
    """The brightest light the video holds: its MaxCLL, else its mastering display's peak, else HDR_PEAK_NITS."""
    if colour.content_light is not None and colour.content_light[0] > 0:
        return float(colour.content_light[0])
    if colour.mastering is not None and colour.mastering[-1][1] > 0:
        return float(colour.mastering[-1][1])
    return HDR_PEAK_NITS


_STEPS = 4096  # look-up table size over the 0..255 code values


@functools.lru_cache(maxsize=16)
def _channel_lut(colour: ColourDescription) -> np.ndarray | None:
    """Code value (_STEPS steps over 0..255) -> linear light relative to SDR white, channel by channel: PQ (EETF)
    and BT.2020 SDR (BT.1886's gamma 2.4); None where there is nothing to convert (BT.601/709 SDR)."""
    code = np.linspace(0, 1, _STEPS)
    if colour.transfer == PQ:
        mapped = bt2390_eetf(code, source_peak_nits(colour), SDR_WHITE_NITS)
        return (pq_to_nits(mapped) / SDR_WHITE_NITS).astype(np.float32)
    if colour.primaries == 9 and colour.transfer != HLG:
        return np.power(code, 2.4).astype(np.float32)
    return None


def _hlg_gain_lut() -> np.ndarray:
    """sqrt(scene luminance Ys) (_STEPS steps over 0..1) -> the factor taking HLG's scene light to display light
    relative to SDR white: the OOTF's 1000 Ys^1.2 cd/m2, through the EETF, over 203 cd/m2, per unit of Ys."""
    root = np.linspace(0, 1, _STEPS)
    scene = np.maximum(root * root, 1e-12)
    display = HDR_PEAK_NITS * np.power(scene, 1.2)
    mapped = pq_to_nits(bt2390_eetf(nits_to_pq(display), HDR_PEAK_NITS, SDR_WHITE_NITS))
    return (mapped / SDR_WHITE_NITS / scene).astype(np.float32)


def display_rgb(rgb: np.ndarray, colour: ColourDescription) -> np.ndarray:
    """uint8 RGB of a frame as a person sees it on an ordinary (BT.709 / sRGB) screen: the frame as it is for
    BT.601/709 video; BT.2020 primaries mapped into BT.709, PQ and HLG tone-mapped for SDR (module notes above:
    HDR reference white near SDR white, brighter highlights compressed, not clipped, below the video's peak). A
    display's view, not a colorimetric conversion."""
    lut = None if colour.transfer == HLG else _channel_lut(colour)
    if lut is None and colour.transfer != HLG:
        if rgb.dtype == np.uint8:
            return rgb
        return np.clip(np.asarray(rgb, np.float32) + np.float32(0.5), 0, 255).astype(np.uint8)
    index = np.clip(np.asarray(rgb, np.float32) * np.float32((_STEPS - 1) / 255) + np.float32(0.5), 0,
                    _STEPS - 1).astype(np.int16)
    if colour.transfer == HLG:
        scene = _HLG_SCENE_LUT[index]
        root = np.sqrt(scene @ _LUMA_2020)
        linear = scene * _HLG_GAIN_LUT[(root * np.float32(_STEPS - 1) + np.float32(0.5)).astype(np.int16)][..., None]
    else:
        linear = lut[index]
    if colour.primaries == 9:
        linear = linear @ _BT2020_TO_BT709.T
    encoded = np.power(np.clip(linear, 0, 1), np.float32(1 / 2.4))
    return (encoded * np.float32(255) + np.float32(0.5)).astype(np.uint8)


_HLG_SCENE_LUT = hlg_to_scene(np.linspace(0, 1, _STEPS)).astype(np.float32)
_HLG_GAIN_LUT = _hlg_gain_lut()
