"""Full mode on the real clips: does it keep the full frame, the timing, and the shots apart? (prints a table)

Per clip, from the pipeline's own stage results while it writes the output:
- ``missing``: mean fraction of the frame the 2D-stabilized frames lacked (what completion had to fill);
- ``black``: fraction of those missing pixels that came out exactly black minus the input's own
  fraction of exactly black pixels (so black content does not count) — 0 means no black border is left;
- ``worst``: the same for the worst frame;
- ``src mosaic/warp/fallback``: shares of the missing pixels each completion step filled;
- ``x-cut``: neighbours handed to completion (mosaic and local warp) from another shot (must be 0);
then the written file is probed: frame count, size and frame rate against the input's.

Usage: python -m benchmarks.quality.full_mode_clips [--out DIR] [CLIPS...]   (default: every clip in ../shared/videos)
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import common
from pipeline.stages import completion
from pipeline.runtime import video_reader
from pipeline.runtime.observer import NullObserver
from pipeline.stabilize import StabilizeConfig, stabilize

VIDEOS = common.VIDEOS
DARK = 0  # exactly black in every channel: what an unfilled missing pixel looks like


class _FullModeAudit(NullObserver):
    def __init__(self) -> None:
        self.segment_of: np.ndarray | None = None
        self.input_dark: list[float] = []
        self.missing: list[float] = []
        self.black: list[float] = []
        self.sources = np.zeros(len(completion.SOURCE_NAMES))
        self.cross_cut = 0

    def on_path(self, plan) -> None:
        n = len(plan.smoothing.orig_from_stab)
        self.segment_of = np.searchsorted(plan.smoothing.segment_starts, np.arange(n), side="right") - 1

    def on_frame(self, frame) -> None:
        self.input_dark.append(float(np.mean(frame.input.rgb.max(axis=2) <= DARK)))
        result = frame.completion
        if result is None:
            return
        missing = result.missing
        self.missing.append(float(missing.mean()))
        if missing.any():
            dark = result.frame[missing].max(axis=1) <= DARK
            self.black.append(max(float(dark.mean()) - self.input_dark[frame.stamp.index], 0.0))
            codes = result.source[missing]
            self.sources += np.bincount(codes, minlength=len(completion.SOURCE_NAMES))
        # Every neighbour completion was handed (mosaic and local warp alike).
        used = set(result.neighbour_order) | {fill.offset for fill in result.fills}
        t = frame.stamp.index
        segment = self.segment_of[t]
        self.cross_cut += sum(1 for offset in used
                              if not 0 <= t + offset < len(self.segment_of) or self.segment_of[t + offset] != segment)


def main(argv: list[str] | None = None) -> int:
    parser = common.parser(__doc__)
    parser.add_argument("clips", nargs="*", type=Path)
    parser.add_argument("--out", type=Path, help="keep the outputs here (default: a temporary folder)")
    args = parser.parse_args(argv)
    clips = args.clips or sorted(p for p in VIDEOS.glob("*") if p.suffix in (".mp4", ".avi"))
    if not clips:
        print(f"no clips in {VIDEOS}", file=sys.stderr)
        return 1
    header = (f"{'clip':34} {'frames':>11} {'size':>10} {'fps':>13} {'cuts':>4} {'missing':>7} {'black':>7} "
              f"{'worst':>7} {'mosaic':>6} {'warp':>6} {'fallbk':>6} {'x-cut':>5} {'s':>6} {'fps_run':>7}")
    print(header)
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = args.out or Path(tmp)
        out_dir.mkdir(parents=True, exist_ok=True)
        for clip in clips:
            audit = _FullModeAudit()
            out = out_dir / f"{clip.stem}_full.mp4"
            started = time.perf_counter()
            report = stabilize(clip, out, StabilizeConfig(mode="full"), observer=audit, overwrite=True)
            seconds = time.perf_counter() - started
            src, dst = video_reader.probe_video(clip), video_reader.probe_video(out)
            n_in, n_out = video_reader.count_frames(clip), video_reader.count_frames(out)
            filled = audit.sources / max(audit.sources.sum(), 1)
            print(f"{clip.name[:34]:34} {n_in:>5}->{n_out:<5} {dst.width:>4}x{dst.height:<5} "
                  f"{float(src.fps):>6.2f}->{float(dst.fps):<6.2f} {len(report.cuts):>4} "
                  f"{np.mean(audit.missing):>7.3f} {np.mean(audit.black or [0]):>7.4f} {max(audit.black or [0]):>7.4f} "
                  f"{filled[completion.SOURCE_MOSAIC]:>6.3f} {filled[list(completion.NEIGHBOUR_SOURCES)].sum():>6.3f} "
                  f"{filled[completion.SOURCE_FALLBACK]:>6.3f} {audit.cross_cut:>5} {seconds:>6.0f} "
                  f"{n_in / seconds:>7.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
