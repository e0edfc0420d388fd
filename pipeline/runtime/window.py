"""A sliding window over a stream of frames: each frame with up to ``radius`` frames either side.

Only 2 * radius + 1 decoded frames are held at any time, whatever the video's length.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, Iterable, Iterator, TypeVar

T = TypeVar("T")


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


# Per-frame caches (pipeline/stages/per_frame.py) keep this many frames beyond a frame's window before forgetting
# them: frames are rendered a little out of order on several threads.
RENDER_SLACK_FRAMES = 8
