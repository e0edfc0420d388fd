"""Progress bars for the CLI (tqdm on stderr), matching pipeline.runtime.observer.ProgressFactory.

In a terminal every long step shows a bar with its ETA; when stderr is not a terminal (logs, CI, pipes) the
bars are off, so logs hold only the one-line messages.
"""

from __future__ import annotations

import sys
from typing import Callable

from tqdm import tqdm

# With a known total: done/total, elapsed, ETA and rate, e.g. "pass 1/2: motion  40%|####  | 48/120 frames
# [00:06 elapsed, ETA 00:09, 7.9 frames/s]". Without one tqdm shows the count, elapsed time and rate.
BAR_FORMAT = ("{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {unit}s "
              "[{elapsed} elapsed, ETA {remaining}, {rate_fmt}]")


def tqdm_progress(description: str, total: int | None, unit: str = "frame") -> tqdm:
    return tqdm(total=total, desc=description, unit=unit, file=sys.stderr, dynamic_ncols=True, leave=True,
                bar_format=BAR_FORMAT if total else None,
                disable=None)  # None: off when stderr is not a terminal (CI logs stay clean)


def tqdm_callback(description: str, unit: str = "frame") -> tuple[Callable[[int, int], None], Callable[[], None]]:
    """A ``progress(done, total)`` callback (the form pipeline.evaluation.metrics takes) drawing a bar, and its close."""
    bar: tqdm | None = None

    def update(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm_progress(description, total or None, unit)
        bar.update(done - bar.n)

    def close() -> None:
        if bar is not None:
            bar.close()

    return update, close
