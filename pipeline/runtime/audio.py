"""The input's audio carried into the output: copied when the output's container takes its codec, else
transcoded to AAC, interleaved with the video as it is written."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av

from pipeline.runtime.video_info import AV_ERRORS, reason
from pipeline.runtime.video_reader import checked_input_path, open_input

# Audio codecs copied into each output format as they are; anything else is transcoded to AAC.
# Narrower than what the muxers claim: they accept PCM or Vorbis in MP4, which players often do not
# play, and claim FLAC in MOV, which then fails to mux.
COPYABLE_AUDIO_CODECS = {
    "mp4": frozenset({"aac", "mp3", "opus", "alac", "ac3", "eac3", "flac"}),
    "mov": frozenset(
        {"aac", "mp3", "alac", "ac3", "eac3", "pcm_s16le", "pcm_s16be", "pcm_s24le", "pcm_s24be"}
    ),
    "matroska": frozenset(
        {"aac", "mp3", "opus", "vorbis", "alac", "ac3", "eac3", "flac", "pcm_s16le", "pcm_s24le", "pcm_f32le"}
    ),
}
# What the AAC encoder accepts when transcoding: other layouts become mono/stereo, other rates 48 kHz.
_AAC_LAYOUTS = frozenset({"mono", "stereo", "2.1", "3.0", "4.0", "5.0", "5.1", "6.1", "7.1"})
_AAC_SAMPLE_RATES = frozenset(
    {96000, 88200, 64000, 48000, 44100, 32000, 24000, 22050, 16000, 12000, 11025, 8000, 7350}
)


class AudioPassthrough:
    """Feeds the audio of `source` into `output`, copied when the codec allows, else as AAC.

    Packets are read lazily and muxed up to the time of the latest video frame, so memory stays
    bounded; FFmpeg's interleaver absorbs the encoder's lookahead delay. After ``start_at(t)`` only the audio from
    t on (whole packets or decoded frames) is muxed, moved t earlier: the video was cut at t.
    """

    def __init__(self, source: Path, output: av.container.OutputContainer, warnings: list[str]) -> None:
        self._source_path = source
        self._warnings = warnings
        self._container = open_input(checked_input_path(source))
        self._output = output
        self._in = self._container.streams.audio[0] if self._container.streams.audio else None
        self._pending: av.Packet | None = None
        self._next_sample: int | None = None  # transcoding: pts of the next sample
        self._done = self._in is None
        self._start_s: float | None = None  # start_at: audio before it is dropped, the rest moved back by it
        self.copied = False
        if self._in is None:
            return
        codec = self._in.codec_context.codec.canonical_name
        self.copied = codec in COPYABLE_AUDIO_CODECS[output.format.name]
        if self.copied:
            self._out = output.add_stream_from_template(self._in)
        else:
            in_ctx = self._in.codec_context
            rate = in_ctx.sample_rate if in_ctx.sample_rate in _AAC_SAMPLE_RATES else 48000
            layout = in_ctx.layout.name
            if layout not in _AAC_LAYOUTS:  # e.g. "1 channels" (PCM in MKV), which the encoder refuses
                layout = "mono" if in_ctx.channels == 1 else "stereo"
            self._out = output.add_stream("aac", rate=rate, layout=layout)
        self._packets = self._container.demux(self._in)

    def _next_packet(self) -> av.Packet | None:
        try:
            return next(self._packets)
        except StopIteration:
            return None
        except AV_ERRORS as error:
            self._warnings.append(f"{self._source_path.name}: audio stopped early: {reason(error)}")
            return None

    def start_at(self, time_s: float) -> None:
        """Drop the audio before ``time_s`` (seconds, absolute: pts x time base) and start the rest at 0."""
        self._start_s = time_s

    def finish(self, end_s: float | None) -> None:
        """Mux the audio up to ``end_s`` (None: all that is left) and flush the encoder."""
        if end_s is None:
            self.mux_until(None)
            return
        self.mux_until(end_s)
        if not self._done and not self.copied:
            self._transcode(None)  # flush the decoder, then the encoder
            self._mux_encoded(None)
        self._done = True

    def mux_until(self, time_s: float | None) -> None:
        """Mux audio up to time_s seconds (everything left when None)."""
        while not self._done:
            packet = self._pending or self._next_packet()
            self._pending = None
            if packet is None:
                self._done = True
                if not self.copied:
                    self._mux_encoded(None)
                return
            if packet.dts is None and packet.pts is None:
                if not self.copied:  # the final empty packet flushes the decoder
                    self._transcode(packet)
                continue
            stamp = packet.pts if packet.pts is not None else packet.dts
            if time_s is not None and stamp * packet.time_base > time_s:
                self._pending = packet
                return
            if self.copied:
                if self._start_s is not None:
                    if stamp * packet.time_base < self._start_s:
                        continue
                    shift = round(self._start_s / packet.time_base)
                    packet.pts = None if packet.pts is None else packet.pts - shift
                    packet.dts = None if packet.dts is None else packet.dts - shift
                packet.stream = self._out
                self._output.mux(packet)
            else:
                self._transcode(packet)

    def _transcode(self, packet: av.Packet) -> None:
        try:
            frames = self._in.decode(packet)
        except AV_ERRORS as error:
            self._warnings.append(f"{self._source_path.name}: skipped undecodable audio: {reason(error)}")
            return
        for frame in frames:
            # Stamp by sample count: a millisecond time base (MKV) would jitter AAC's timestamps.
            if self._next_sample is None:
                start = frame.pts * frame.time_base if frame.pts is not None else 0
                if self._start_s is not None:
                    if start + Fraction(frame.samples, frame.sample_rate) <= self._start_s:
                        continue  # wholly before the cut
                    start = max(start - Fraction(self._start_s), 0)
                self._next_sample = round(start * frame.sample_rate)
            frame.pts, frame.time_base = self._next_sample, Fraction(1, frame.sample_rate)
            self._next_sample += frame.samples
            self._mux_encoded(frame)

    def _mux_encoded(self, frame: av.AudioFrame | None) -> None:
        for packet in self._out.encode(frame):
            self._output.mux(packet)

    def close(self) -> None:
        self._container.close()
