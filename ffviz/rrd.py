"""Reading ffviz recordings back (tests, figures): rows per entity, scalar series, images, text."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader

from ffviz import entities as ent


@dataclass
class Recording:
    """Every chunk's record batch of a .rrd, grouped by entity path (without the leading slash)."""

    batches: dict[str, list]

    @classmethod
    def load(cls, path: Path | str) -> "Recording":
        batches: dict[str, list] = defaultdict(list)
        for chunk in RrdReader(str(path)).stream().to_chunks():
            batches[str(chunk.entity_path).strip("/")].append(chunk.to_record_batch())
        return cls(dict(batches))

    @property
    def entities(self) -> list[str]:
        return sorted(self.batches)

    def rows(self, entity: str, column: str | None = None) -> int:
        """Rows logged on the frame timeline (static rows excluded), optionally only those with ``column``."""
        count = 0
        for batch in self.batches.get(entity, []):
            if ent.FRAME_TIMELINE not in batch.schema.names:
                continue
            if column is None:
                count += batch.num_rows
            elif column in batch.schema.names:
                count += batch.num_rows - batch.column(column).null_count
        return count

    def scalars(self, entity: str) -> tuple[np.ndarray, np.ndarray]:
        """(frames, values) of a Scalars series, sorted by frame."""
        frames, values = [], []
        for batch in self.batches.get(entity, []):
            names = batch.schema.names
            if ent.FRAME_TIMELINE not in names or "Scalars:scalars" not in names:
                continue
            for frame, value in zip(batch.column(ent.FRAME_TIMELINE).to_pylist(),
                                    batch.column("Scalars:scalars").to_pylist()):
                if value is not None:
                    frames.append(frame)
                    values.append(value[0])
        order = np.argsort(frames, kind="stable")
        return np.asarray(frames)[order], np.asarray(values, dtype=np.float64)[order]

    def texts(self, entity: str, column: str) -> list[str]:
        out: list[str] = []
        for batch in self.batches.get(entity, []):
            if column in batch.schema.names:
                out.extend(str(v if not isinstance(v, list) else v[0]) for v in batch.column(column).to_pylist()
                           if v is not None)
        return out

    def timelines(self, entity: str) -> set[str]:
        names: set[str] = set()
        for batch in self.batches.get(entity, []):
            names.update(n for n in batch.schema.names if n in (ent.FRAME_TIMELINE, ent.VIDEO_TIME_TIMELINE))
        return names
