"""The hook through which the orchestrator shows every stage's result to the outside (e.g. a Rerun recorder).

pipeline/ computes; observers look. An observer must not modify what it is given.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol


@dataclass(frozen=True)
class Stamp:
    """Where a per-frame result belongs in time."""

    index: int
    time_s: float


class Observer(Protocol):
    def on_start(self, info: Any, config: Any) -> None: ...

    def on_stage(self, stage: str, stamp: Stamp | None, result: Any) -> None:
        """A stage's result; ``stamp`` is None for whole-video results (e.g. the smoothed path)."""

    def on_warning(self, stamp: Stamp | None, message: str) -> None: ...

    def on_finish(self, report: Any) -> None: ...


class NullObserver:
    """Looks at nothing: the default."""

    def on_start(self, info: Any, config: Any) -> None:
        pass

    def on_stage(self, stage: str, stamp: Stamp | None, result: Any) -> None:
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
    """Whether ``observer`` looks at nothing (so per-frame results need not be kept for it)."""
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

    def on_stage(self, stage: str, stamp: Stamp | None, result: Any) -> None:
        for o in self.observers:
            o.on_stage(stage, stamp, result)

    def on_warning(self, stamp: Stamp | None, message: str) -> None:
        for o in self.observers:
            o.on_warning(stamp, message)

    def on_finish(self, report: Any) -> None:
        for o in self.observers:
            o.on_finish(report)


class StageCollector(NullObserver):
    """Keeps the results of chosen stages in memory (for tests and the demo's ground-truth check)."""

    def __init__(self, *stages: str) -> None:
        self.stages = set(stages)
        self.results: dict[str, list[tuple[Stamp | None, Any]]] = {s: [] for s in stages}
        self.warnings: list[tuple[Stamp | None, str]] = []

    def on_stage(self, stage: str, stamp: Stamp | None, result: Any) -> None:
        if stage in self.stages:
            self.results[stage].append((stamp, result))

    def on_warning(self, stamp: Stamp | None, message: str) -> None:
        self.warnings.append((stamp, message))
