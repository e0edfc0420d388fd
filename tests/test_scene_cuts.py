"""Scene cuts: detected, the path restarts, and full-frame completion takes nothing across a cut."""

from __future__ import annotations

import numpy as np

from pipeline.evaluation import synthetic
from pipeline.runtime.observer import StageCollector
from pipeline.runtime.source import ArraySource
from pipeline.stabilize import StabilizeConfig, stabilize_source


def two_shots(n: int = 16) -> tuple[list[np.ndarray], int]:
    first = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=n, image="coffee", seed=4,
                                                         blurred_frames=(), jitter_px=5))
    second = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=n, image="astronaut", seed=5,
                                                          blurred_frames=(), jitter_px=5))
    return first.frames + second.frames, n


def test_cut_is_found_and_no_window_crosses_it():
    frames, cut = two_shots()
    collector = StageCollector("motion", "smoothing", "completion")
    report = stabilize_source(ArraySource(frames), None, StabilizeConfig(mode="full"), observer=collector)
    assert report.cuts == [cut]
    (_, smoothed), = collector.results["smoothing"]
    assert smoothed.segment_starts == (0, cut)
    for stamp, completed in collector.results["completion"]:
        shot = stamp.index >= cut
        # Every neighbour the completion looked at belongs to the same shot.
        assert all((stamp.index + offset >= cut) == shot for offset in completed.neighbour_order), stamp.index
        assert all((stamp.index + fill.offset >= cut) == shot for fill in completed.fills)


def test_frames_next_to_the_cut_keep_their_own_shot_colours():
    frames, cut = two_shots()
    collector = StageCollector("completion")
    stabilize_source(ArraySource(frames), None, StabilizeConfig(mode="full"), observer=collector)
    results = {stamp.index: r for stamp, r in collector.results["completion"]}
    for t in (cut - 1, cut):
        completed = results[t]
        # Filled pixels look like the frame's own shot: compare mean colours of filled vs known pixels.
        if completed.missing.sum() < 50:
            continue
        filled_mean = completed.frame[completed.missing].reshape(-1, 3).mean(0)
        known_mean = completed.frame[~completed.missing].reshape(-1, 3).mean(0)
        other = frames[t + 1] if t == cut - 1 else frames[t - 1]
        assert np.abs(filled_mean - known_mean).sum() < np.abs(filled_mean - other.reshape(-1, 3).mean(0)).sum()
