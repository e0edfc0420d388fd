"""The hook through which a run shows its typed results to the outside (the Rerun recorder, judges, tests).

pipeline/ computes; observers look and must not modify what they are given. An observer receives, in order:
``on_start``, ``on_motion`` per frame of pass 1 (single-process runs), ``on_path`` once, ``on_frame`` per
frame in frame order, ``on_warning`` whenever one is raised, ``on_finish``. The types are pipeline/results.py's.
``keep`` runs on the rendering threads, as soon as each frame is made and before ``on_frame``: what it returns
is what the run holds of the frame while the frame waits for its turn, so an observer that needs only a digest
of the intermediates keeps memory bounded by returning just that.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

from pipeline.results import FrameResult, PathPlan, Stamp
from pipeline.stages.motion import MotionEstimate

__all__ = ["Stamp", "Observer", "NullObserver", "Observers", "StageCollector", "is_null", "null_progress"]


class Observer(Protocol):
    def on_start(self, info: Any, config: Any) -> None:
        """``info``: the input's VideoInfo; ``config``: the run's StabilizeConfig."""

    def on_motion(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        """Pass 1's estimate for the pair (frame - 1, frame)."""

    def on_path(self, plan: PathPlan) -> None:
        """The whole video's path plan, before any frame is rendered."""

    def keep(self, result: FrameResult) -> FrameResult:
        """What of a frame's result this observer's ``on_frame`` needs: ``result`` itself, or
        ``result.without_intermediates()`` with a digest of its own in ``digests``. Called on a rendering thread
        (several frames at once), after ``on_path``; temporal consistency then sets the output and ``temporal``."""

    def on_frame(self, result: FrameResult) -> None:
        """One frame through the chain, in frame order."""

    def on_warning(self, stamp: Stamp | None, message: str) -> None: ...

    def on_finish(self, report: Any) -> None:
        """``report``: the run's stabilize.StabilizeReport."""


class NullObserver:
    """Looks at nothing: the default, and the base of observers that look at a part."""

    def on_start(self, info: Any, config: Any) -> None:
        pass

    def on_motion(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        pass

    def on_path(self, plan: PathPlan) -> None:
        pass

    def keep(self, result: FrameResult) -> FrameResult:
        return result  # an observer derived from this one sees every intermediate

    def on_frame(self, result: FrameResult) -> None:
        pass

    def on_warning(self, stamp: Stamp | None, message: str) -> None:
        pass

    def on_finish(self, report: Any) -> None:
        pass


class Progress(Protocol):
    def update(self, n: int = 1) -> None: ...

    def close(self) -> None: ...


class ProgressFactory(Protocol):
    def __call__(self, description: str, total: int | None) -> Progress: ...


class NullProgress:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def null_progress(description: str, total: int | None) -> Progress:
    return NullProgress()


def is_null(observer: Observer) -> bool:
    """Whether ``observer`` looks at nothing (so per-frame intermediates need not be kept for it)."""
    if isinstance(observer, Observers):
        return all(is_null(o) for o in observer.observers)
    return type(observer) is NullObserver


class Observers:
    """Fans every call out to several observers, in order."""

    def __init__(self, *observers: Observer) -> None:
        self.observers = [o for o in observers if o is not None]

    def on_start(self, info: Any, config: Any) -> None:
        for o in self.observers:
            o.on_start(info, config)

    def on_motion(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        for o in self.observers:
            o.on_motion(stamp, estimate)

    def on_path(self, plan: PathPlan) -> None:
        for o in self.observers:
            o.on_path(plan)

    def keep(self, result: FrameResult) -> FrameResult:
        """The intermediates if any observer keeps them, and every observer's digest."""
        kept = [o.keep(result) for o in self.observers]
        merged = result if any(k.has_intermediates for k in kept) else result.without_intermediates()
        digests = {key: digest for k in kept for key, digest in k.digests.items()}
        return dataclasses.replace(merged, digests=digests)

    def on_frame(self, result: FrameResult) -> None:
        for o in self.observers:
            o.on_frame(result)

    def on_warning(self, stamp: Stamp | None, message: str) -> None:
        for o in self.observers:
            o.on_warning(stamp, message)

    def on_finish(self, report: Any) -> None:
        for o in self.observers:
            o.on_finish(report)


FRAME_PARTS = ("input", "warp", "completion", "deblur", "output")  # FrameResult fields StageCollector keeps
PLAN_PARTS = ("smoothing", "crop")  # PathPlan fields StageCollector keeps ("path" keeps the plan itself)


class StageCollector(NullObserver):
    """Keeps chosen results in memory, as (stamp, result) lists by name (for tests and the demo's check).

    Names: "motion" (each MotionEstimate), "path" (the PathPlan), a PathPlan field ("smoothing", "crop";
    stamp None, kept only when not None), or a FrameResult field ("input", "warp", "completion", "deblur",
    "output"; kept only when not None)."""

    def __init__(self, *names: str) -> None:
        unknown = set(names) - {"motion", "path", *PLAN_PARTS, *FRAME_PARTS}
        if unknown:
            raise ValueError(f"StageCollector: no result called {', '.join(sorted(unknown))}")
        self.names = set(names)
        self.results: dict[str, list[tuple[Stamp | None, Any]]] = {n: [] for n in names}
        self.warnings: list[tuple[Stamp | None, str]] = []

    def on_motion(self, stamp: Stamp, estimate: MotionEstimate) -> None:
        if "motion" in self.names:
            self.results["motion"].append((stamp, estimate))

    def on_path(self, plan: PathPlan) -> None:
        if "path" in self.names:
            self.results["path"].append((None, plan))
        for name in PLAN_PARTS:
            part = getattr(plan, name)
            if name in self.names and part is not None:
                self.results[name].append((None, part))

    def on_frame(self, result: FrameResult) -> None:
        for name in FRAME_PARTS:
            part = getattr(result, name)
            if name in self.names and part is not None:
                self.results[name].append((result.stamp, part))

    def on_warning(self, stamp: Stamp | None, message: str) -> None:
        self.warnings.append((stamp, message))
