"""Render docs/img/viewer/*.jpg and docs/img/viewer.jpg: `ffviz snapshot` pictures of the built-in demo's recording.

Usage: .venv/bin/python docs/img/make_viewer_pictures.py [WORK_DIR]   (default: a temporary folder)
The recording is exactly `./run demo`'s (seed 0, 120 frames, full mode, its default traced frames), so a reader
who runs the demo sees what these pictures show. The demo's input is generated, so its frames may be published;
the shared real clips' may not (their licence is unknown), which is why no picture here shows one.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from ffviz import cli
from ffviz.snapshot import layout_facts, snapshot

HERE = Path(__file__).resolve().parent
FRAME = 42  # a blurred frame with a moving disc, missing area at two borders (docs/viewer.md's worked example)
TABS = ("overview", "motion", "smoothing", "mosaic", "local", "deblurring")


def main(work: Path) -> None:
    rrd = work / "demo.rrd"
    assert cli.main(["demo", "--output-dir", str(work / "demo"), "--rrd", str(rrd)]) == 0
    (HERE / "viewer").mkdir(exist_ok=True)
    for tab in TABS:
        snapshot(rrd, HERE / "viewer" / f"{tab}-{FRAME}.jpg", frame=FRAME, tab=tab)
    traced = layout_facts(rrd)[0]
    stepped = min(traced, key=lambda t: abs(t - FRAME))
    snapshot(rrd, HERE / "viewer" / f"stage-{stepped}.jpg", frame=stepped, tab="stage")
    snapshot(rrd, HERE / "viewer" / "about-0.jpg", frame=0, tab="about")
    snapshot(rrd, HERE / "viewer.jpg", frame=FRAME, tab="overview")
    print(f"wrote {HERE / 'viewer'}/*.jpg (traced frames {traced}; stage stepping at {stepped}) and viewer.jpg")


if __name__ == "__main__":
    if len(sys.argv) > 1:
        main(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as folder:
            main(Path(folder))
