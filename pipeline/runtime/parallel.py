"""Using both cores of a small machine: per-frame work on a thread pool, decoding ahead on its own thread.

Threads, not processes: the heavy calls (OpenCV, numpy on large arrays, numba kernels compiled ``nogil``,
PyAV's codecs) release the GIL, and a frame window shared by threads costs no copies. Results come back in
input order, so output and observers see exactly what a serial run gives them.
"""

from __future__ import annotations

import importlib
import os
import queue
import threading
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Iterable, Iterator, TypeVar

T = TypeVar("T")
R = TypeVar("R")


def default_workers() -> int:
    """The CPU cores this process may run on."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not Linux
        return max(os.cpu_count() or 1, 1)


def ordered_map(func: Callable[[T], R], items: Iterable[T], workers: int) -> Iterator[R]:
    """``map(func, items)`` with up to ``workers`` calls running at once, results in input order.

    At most ``2 * workers`` items are taken ahead of the one being yielded, so memory stays bounded.
    ``workers <= 1`` runs inline, with no thread at all. An exception in ``func`` is raised here, at its
    item's turn; pending calls are cancelled or waited for when the consumer stops early.
    """
    if workers <= 1:
        yield from map(func, items)
        return
    pending: deque[Future[R]] = deque()
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="ffviz-frame") as pool:
        try:
            source = iter(items)
            while True:
                try:
                    item = next(source)
                except StopIteration:
                    break
                except BaseException:
                    # As a serial map would: every result before the input's failure first, then the failure.
                    while pending:
                        yield pending.popleft().result()
                    raise
                pending.append(pool.submit(func, item))
                if len(pending) >= 2 * workers:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for future in pending:
                future.cancel()


class Prefetch(Iterator[T]):
    """Iterates ``items`` on a background thread, up to ``depth`` items ahead (decoding overlaps compute).

    An exception from ``items`` is re-raised to the consumer at its turn. ``close()`` stops the thread, which
    then closes the underlying iterator itself (it is running there), so files it holds are released.
    """

    def __init__(self, items: Iterable[T], depth: int = 4) -> None:
        self._queue: queue.Queue = queue.Queue(maxsize=max(depth, 1))
        self._stop = threading.Event()
        self._done = False
        self._thread = threading.Thread(target=self._run, args=(items,), name="ffviz-decode", daemon=True)
        self._thread.start()

    def _run(self, items: Iterable[T]) -> None:
        iterator = iter(items)
        try:
            for item in iterator:
                if not self._put(("item", item)):
                    return
            self._put(("end", None))
        except BaseException as error:  # handed to the consumer
            self._put(("error", error))
        finally:
            close = getattr(iterator, "close", None)
            if close is not None:
                close()

    def _put(self, entry: tuple[str, object]) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(entry, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def __next__(self) -> T:
        if self._done:
            raise StopIteration
        kind, value = self._queue.get()
        if kind == "item":
            return value  # type: ignore[return-value]
        self._done = True
        self._thread.join()
        if kind == "error":
            raise value  # type: ignore[misc]
        raise StopIteration

    def close(self) -> None:
        self._done = True
        self._stop.set()
        self._thread.join()


def import_in_background(*modules: str) -> threading.Thread:
    """Import ``modules`` on a daemon thread, so that a later import of them on the critical path finds them loaded
    (or waits only for the rest: Python's import locks make the two imports one). An import that fails here is left
    for the later import to raise where it is handled."""

    def load() -> None:
        for name in modules:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - raised again, where it matters, by the import that needs it
                return

    thread = threading.Thread(target=load, name="ffviz-import", daemon=True)
    thread.start()
    return thread
