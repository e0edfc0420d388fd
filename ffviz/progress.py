"""Progress bars for the CLI (tqdm on stderr), matching pipeline.observer.ProgressFactory."""

from __future__ import annotations

import sys

from tqdm import tqdm


def tqdm_progress(description: str, total: int | None) -> tqdm:
    return tqdm(total=total, desc=description, unit="frame", file=sys.stderr, dynamic_ncols=True, leave=True,
                disable=None)  # None: off when stderr is not a terminal (CI logs stay clean)
