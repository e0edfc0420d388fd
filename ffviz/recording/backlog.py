"""The recorder's own thread and the work waiting for it, bounded in bytes.

The pipeline's thread hands each piece of work over with the bytes it holds (``put``) and goes on; it waits only
when the work already waiting holds ``budget_bytes`` or more, so memory stays bounded however slow the writing
is and whatever the frames' size. Work runs in order; the first error stops the rest and is raised to the pipeline's
thread at its next ``put`` or at ``close``.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Any, Callable

BUDGET_BYTES = 128 << 20  # a dozen or more frames at the recorded size: the writer's jitter absorbed, no more


class Backlog:
    """Runs ``put`` work in order on a thread of its own, holding at most ``budget_bytes`` of it (one item always
    fits, however large)."""

    def __init__(self, budget_bytes: int = BUDGET_BYTES, name: str = "ffviz-recorder") -> None:
        self.budget_bytes = budget_bytes
        self.held_bytes = 0
        self.peak_bytes = 0  # the most bytes ever waiting (for tests and benchmarks)
        self.error: BaseException | None = None
        self._items: deque[tuple[Callable[..., Any], tuple, int]] = deque()
        self._changed = threading.Condition()
        self._closing = False
        self._dropping = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, nbytes: int, work: Callable[..., Any], *args: Any) -> None:
        """Queue ``work(*args)``, which holds ``nbytes`` until it has run; wait while the budget is spent."""
        with self._changed:
            self._raise_error()
            while self._items and self.held_bytes + nbytes > self.budget_bytes and self.error is None:
                self._changed.wait()
            self._raise_error()
            self._items.append((work, args, nbytes))
            self.held_bytes += nbytes
            self.peak_bytes = max(self.peak_bytes, self.held_bytes)
            self._changed.notify_all()

    def _raise_error(self) -> None:
        if self.error is not None:
            raise self.error

    def _run(self) -> None:
        while True:
            with self._changed:
                while not self._items and not self._closing:
                    self._changed.wait()
                if not self._items:
                    return
                work, args, nbytes = self._items[0]
            if self.error is None and not self._dropping:
                try:
                    work(*args)
                except BaseException as error:  # noqa: BLE001 - handed to the pipeline's thread
                    self.error = error
            with self._changed:
                self._items.popleft()
                self.held_bytes -= nbytes
                self._changed.notify_all()

    def close(self, *, drop: bool = False) -> None:
        """Run what is waiting (or, with ``drop``, skip it) and stop the thread. Raises the first error, if any."""
        with self._changed:
            self._closing = True
            self._dropping = self._dropping or drop
            self._changed.notify_all()
        self._thread.join()
        if not drop:
            self._raise_error()
