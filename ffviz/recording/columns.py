"""Per-frame rows sent as columns: each entity's rows of a few frames in one ``send_columns`` call.

A ``log`` call costs the SDK's Python a fixed ~0.05-0.1 ms (building the archetype, its arrow arrays, one row for
the batcher), which at 640x360 is a large share of what a recorded frame costs; a column of N rows costs about that
once. The rows are the same as ``log`` would have made (the archetype's fields given, on the frame and video-time
timelines), so what the viewer and ffviz.rrd read is unchanged; only the chunks are cut differently.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import rerun as rr

from ffviz import entities as ent


@dataclass(frozen=True)
class Row:
    """One log call's worth of an archetype: ``kind`` (an rr archetype class, which has ``columns``) and its fields.
    ``instances``: None for one instance a row; else every field is a batch of this many instances (Arrows2D)."""

    kind: type
    fields: dict[str, Any]
    instances: int | None = None

    def archetype(self) -> Any:
        """The row as one archetype, for a single ``log`` call."""
        return self.kind.from_fields(**self.fields)

    @property
    def shape(self) -> tuple:
        """Rows of the same shape go into one column list (same archetype, same fields given)."""
        return self.kind, tuple(sorted(self.fields)), self.instances is None


@dataclass
class _Pending:
    shape: tuple  # the rows' (Row.shape, other timelines' names)
    frames: list[int] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    others: list[tuple[int, ...]] = field(default_factory=list)  # each row's times on the other timelines
    rows: list[Row] = field(default_factory=list)


class ColumnBuffer:
    """Holds rows per entity until ``send`` (the recorder sends every few frames and before flushing the SDK); an
    entity's rows of another shape send its held ones first, so each entity's rows keep their order."""

    def __init__(self, rec: rr.RecordingStream, spent: Callable[[str, float], None] | None = None) -> None:
        self.rec = rec
        self._spent = spent  # told each entity's CPU seconds of sending
        self._pending: dict[str, _Pending] = {}

    def add(self, entity: str, row: Row, frame: int, seconds: float, times: tuple[tuple[str, int], ...] = ()) -> None:
        """``row`` at ``frame`` (``seconds`` of video) and at ``times`` on other (sequence) timelines."""
        shape = (row.shape, tuple(name for name, _ in times))
        pending = self._pending.get(entity)
        if pending is not None and pending.shape != shape:
            self._send(entity, pending)
            pending = None
        if pending is None:
            pending = self._pending[entity] = _Pending(shape)
        pending.frames.append(frame)
        pending.seconds.append(seconds)
        pending.others.append(tuple(sequence for _, sequence in times))
        pending.rows.append(row)

    def send(self) -> None:
        """Every held row into the stream."""
        for entity, pending in list(self._pending.items()):
            self._send(entity, pending)

    def _send(self, entity: str, pending: _Pending) -> None:
        started = time.thread_time()
        (kind, names, one_each), timelines = pending.shape
        if one_each:
            columns = kind.columns(**{name: _stacked([row.fields[name] for row in pending.rows])
                                              for name in names})
        else:
            columns = kind.columns(**{name: np.concatenate([row.fields[name] for row in pending.rows])
                                              for name in names}).partition([row.instances for row in pending.rows])
        self.rec.send_columns(entity, indexes=[
            rr.TimeColumn(ent.FRAME_TIMELINE, sequence=pending.frames),
            rr.TimeColumn(ent.VIDEO_TIME_TIMELINE, duration=pending.seconds),
            *(rr.TimeColumn(name, sequence=[other[k] for other in pending.others]) for k, name in enumerate(timelines))],
            columns=columns)
        del self._pending[entity]
        if self._spent is not None:
            self._spent(entity, time.thread_time() - started)


def _stacked(values: list) -> Any:
    """One field's values of every row: numpy scalars as one array of their type (a packed colour stays a colour)."""
    return np.array(values) if isinstance(values[0], np.generic) else values
