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


def _recorded_synthetic(folder, width: int, height: int):
    """An 8-frame synthetic clip of width x height stabilized in full mode and recorded at the default size (frame 4
    traced): (the .rrd, the recorder)."""
    from ffviz.recorder import RerunRecorder
    from pipeline.evaluation import synthetic
    from pipeline.stabilize import StabilizeConfig, stabilize

    clip = folder / "clip.mp4"
    synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(width=width, height=height, n_frames=8, seed=3)),
                          clip)
    rrd = folder / "clip.rrd"
    recorder = RerunRecorder(rrd, trace_frames=[4])
    stabilize(clip, None, StabilizeConfig(), observer=recorder)
    return rrd, recorder


@pytest.fixture(scope="session")
def uhd_recording(tmp_path_factory):
    """A 3840x2160 clip's recording (``_recorded_synthetic``), shared by the recording-size and the browser tests."""
    return _recorded_synthetic(tmp_path_factory.mktemp("uhd"), 3840, 2160)


@pytest.fixture(scope="session")
def portrait_recording(tmp_path_factory):
    """A 1080x1920 (portrait phone) clip's recording (``_recorded_synthetic``)."""
    return _recorded_synthetic(tmp_path_factory.mktemp("portrait"), 1080, 1920)
