"""Shared fixtures: where the real clips live, and a skip when they are absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("RERUN_ANALYTICS", "0")

SHARED_VIDEOS = Path(__file__).resolve().parents[1].parent / "shared" / "videos"


def real_clip(name: str) -> Path:
    """Path of a clip from ../shared/videos, or skip the test cleanly when it is not on this machine."""
    path = SHARED_VIDEOS / name
    if not path.is_file():
        pytest.skip(f"real clip {name} not found under {SHARED_VIDEOS}")
    return path


@pytest.fixture
def shared_videos() -> Path:
    if not SHARED_VIDEOS.is_dir():
        pytest.skip(f"{SHARED_VIDEOS} not present")
    return SHARED_VIDEOS


@pytest.fixture(scope="session")
def uhd_recording(tmp_path_factory):
    """A short 3840x2160 synthetic clip stabilized in full mode and recorded at the default size (frame 4 traced):
    (the .rrd, the recorder). Shared by the recording-size and the browser tests."""
    from ffviz.recorder import RerunRecorder
    from pipeline.evaluation import synthetic
    from pipeline.stabilize import StabilizeConfig, stabilize

    folder = tmp_path_factory.mktemp("uhd")
    clip = folder / "uhd.mp4"
    synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(width=3840, height=2160, n_frames=8, seed=3)),
                          clip)
    rrd = folder / "uhd.rrd"
    recorder = RerunRecorder(rrd, trace_frames=[4])
    stabilize(clip, None, StabilizeConfig(), observer=recorder)
    return rrd, recorder
