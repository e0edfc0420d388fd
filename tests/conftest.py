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
