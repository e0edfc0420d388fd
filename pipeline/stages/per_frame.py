"""A per-frame cache for what a stage derives from each frame once and reuses for every frame the frame is a
neighbour of (a shrunk copy, a gradient-energy map). The stage defines what is made; the chain, which knows the
window, decides when entries are forgotten (``forget_before``)."""

from __future__ import annotations

import threading
from typing import Callable, Generic, TypeVar

T = TypeVar("T")
D = TypeVar("D")


class PerFrame(Generic[T, D]):
    """What ``make`` derives from a frame, by frame index, made once while the frame is in the window (every
    frame it is a neighbour of reuses it). Thread-safe: frames are rendered on several threads."""

    def __init__(self, make: Callable[[T], D]) -> None:
        self._make = make
        self._by_frame: dict[int, D] = {}
        self._lock = threading.Lock()

    def get(self, index: int, frame: T) -> D:
        with self._lock:
            derived = self._by_frame.get(index)
        if derived is None:  # two threads may both make it: the same result, no harm
            derived = self._make(frame)
            with self._lock:
                self._by_frame[index] = derived
        return derived

    def forget_before(self, index: int) -> None:
        with self._lock:
            for old in [i for i in self._by_frame if i < index]:
                del self._by_frame[old]
