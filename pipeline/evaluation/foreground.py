"""Ground truth for the camera's motion when figures walk in front of it: shaken, panned camera over a still
photograph, figures dressed in cuts of the photograph itself (its colours and texture: camouflage), and how steady
the stabilized view is in the world (the residual shake the camera's motion leaves).

Each case varies what a figure does (size, speed, direction changes, entering and leaving, several figures, motion
blur); a case is judged against the same scene with a small figure (``reference``), so what the scene itself costs
(the path's own residual, blur) is the same on both sides. Used by tests/test_robust_motion.py and
benchmarks/quality/robust_motion.py.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline import geometry
from pipeline.evaluation import metrics
from pipeline.evaluation.synthetic import SyntheticConfig, SyntheticVideo, generate

WIDTH, HEIGHT = 640, 360
SMALL = dict(person_size=(150 / WIDTH, 300 / HEIGHT), person_speed_px=(5.0, 12.0))  # about 16 % of the frame


@dataclass(frozen=True)
class Case:
    """A figure's part in a clip (SyntheticConfig fields) and the small-figure scene it is judged against."""

    name: str
    figure: dict  # person_size, person_speed_px, people, object_sweep, blurred_frames ...
    reference: str = "small"


CASES = {case.name: case for case in (
    Case("small", SMALL),
    Case("half", dict(person_size=(390 / WIDTH, 560 / HEIGHT), person_speed_px=(8.0, 19.0))),
    Case("60% fast", dict(person_size=(0.75, 1.6), person_speed_px=(12.0, 25.0))),
    Case("60% enters and leaves", dict(person_size=(0.75, 1.6), person_speed_px=(12.0, 25.0), object_sweep=1.8)),
    Case("three figures", dict(person_size=(0.45, 1.2), person_speed_px=(8.0, 19.0), people=3)),
    Case("small, blurred", dict(SMALL, blurred_frames=None)),
    Case("half, blurred", dict(person_size=(390 / WIDTH, 560 / HEIGHT), person_speed_px=(8.0, 19.0),
                               blurred_frames=None), reference="small, blurred"),
)}


def clip(case: str, image: str, seed: int, n_frames: int = 120) -> SyntheticVideo:
    """The case's clip: 640x360 at 30 fps, a steady pan and hand-held shake (no slow drift, so that a perfect
    stabilizer leaves no residual), the figures walking back and forth across 0.6 of the view (turning at random
    too) unless the case says otherwise, no blurred frames unless it says so."""
    config = SyntheticConfig(width=WIDTH, height=HEIGHT, n_frames=n_frames, image=image, seed=seed,
                             object_kind="person", object_sweep=0.6, drift_px=0.0, drift_deg=0.0, blurred_frames=())
    return generate(replace(config, **CASES[case].figure))


@dataclass(frozen=True)
class Shake:
    """How a run's camera motion did on a clip: the output view's residual shake in the world (px, RMS of the
    high-pass of its path, metrics.residual_jitter), the pairs whose motion is off the true camera's by more than
    2 px (corner error), and the largest share of the frame the figures cover."""

    px: float
    wrong_pairs: int
    figure_share: float


def residual_shake(video: SyntheticVideo, mode: str = "full") -> Shake:
    """Pass 1 and the path plan of ``mode`` (the default settings) on ``video``, against its truth."""
    return residual_shakes(video, (mode,))[mode]


def residual_shakes(video: SyntheticVideo, modes: tuple[str, ...]) -> dict[str, Shake]:
    """``residual_shake`` for each of ``modes``, from one pass 1 (the modes share the motion settings)."""
    from pipeline.chain import plan_path
    from pipeline.runtime.observer import NullObserver, null_progress
    from pipeline.runtime.source import ArraySource
    from pipeline.stabilize import StabilizeConfig, estimate_motion

    configs = {mode: StabilizeConfig(mode=mode) for mode in modes}
    assert len({config.motion for config in configs.values()}) == 1, "the modes' motion settings differ"
    found = estimate_motion(ArraySource(video.frames, fps=video.config.fps, name="truth"),
                            configs[modes[0]].motion, observer=NullObserver(), progress=null_progress, total=None)
    wrong = sum(geometry.corner_error(found.curr_from_prev[t], video.curr_from_prev[t], WIDTH, HEIGHT) > 2.0
                for t in range(1, video.n_frames))
    share = float(max(m.mean() for m in video.object_mask))
    shakes = {}
    for mode, config in configs.items():
        plan = plan_path(found, config, WIDTH, HEIGHT)
        px = metrics.residual_jitter(video.view_path(plan.orig_from_out), video.config.fps)[0]
        shakes[mode] = Shake(px, wrong, share)
    return shakes
