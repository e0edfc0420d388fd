"""A sliding window over a stream of frames: each frame with up to ``radius`` frames either side.

Only 2 * radius + 1 decoded frames are held at any time, whatever the video's length.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from typing import Callable, Generic, Iterable, Iterator, TypeVar

T = TypeVar("T")
D = TypeVar("D")


@dataclass(frozen=True)
class Windowed(Generic[T]):
    index: int  # position of ``centre`` in the stream
    centre: T
    neighbours: dict[int, T]  # by time offset (-radius..radius, 0 excluded), clipped at the stream's ends


def sliding_window(items: Iterable[T], radius: int) -> Iterator[Windowed[T]]:
    if radius < 0:
        raise ValueError(f"window radius must be >= 0, not {radius}")
    buffer: deque[T] = deque()
    first = 0  # stream index of buffer[0]
    source = iter(items)
    exhausted = False
    centre = 0
    while True:
        # Read ahead until the window's right side is full or the stream ends.
        while not exhausted and first + len(buffer) <= centre + radius:
            try:
                buffer.append(next(source))
            except StopIteration:
                exhausted = True
        if centre >= first + len(buffer):
            return
        neighbours = {i - centre: buffer[i - first] for i in range(max(first, centre - radius),
                                                                    min(first + len(buffer), centre + radius + 1))
                      if i != centre}
        yield Windowed(centre, buffer[centre - first], neighbours)
        centre += 1
        while first < centre - radius:  # drop what no later window needs
            buffer.popleft()
            first += 1


# PerFrame caches keep this many frames beyond a frame's window before forgetting them: frames are rendered a
# little out of order on several threads.
RENDER_SLACK_FRAMES = 8


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
