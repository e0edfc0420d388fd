"""Reading ffviz recordings back (tests, figures): rows per entity, scalar series, images, text.

Any timeline can index a query (``frame`` by default; ``stage`` and ``fmm_step`` for traced frames).
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import pyarrow as pa
from rerun.chunk import RrdReader
from rerun.encodings import ChannelDatatype, ColorModel

from ffviz import entities as ent

IMAGE_COLUMNS = ("EncodedImage:blob", "Image:buffer", "DepthImage:buffer", "SegmentationImage:buffer",
                 "EncodedDepthImage:blob", "VideoStream:sample")
_DTYPES = {ChannelDatatype.U8: np.uint8, ChannelDatatype.I8: np.int8, ChannelDatatype.U16: np.uint16,
           ChannelDatatype.I16: np.int16, ChannelDatatype.U32: np.uint32, ChannelDatatype.I32: np.int32,
           ChannelDatatype.U64: np.uint64, ChannelDatatype.I64: np.int64, ChannelDatatype.F16: np.float16,
           ChannelDatatype.F32: np.float32, ChannelDatatype.F64: np.float64}
_CHANNELS = {ColorModel.L: 1, ColorModel.RGB: 3, ColorModel.BGR: 3, ColorModel.RGBA: 4, ColorModel.BGRA: 4}


@dataclass
class Recording:
    """Every chunk's record batch of a .rrd, grouped by entity path (without the leading slash)."""

    batches: dict[str, list]
    _videos: dict[str, dict[int, np.ndarray]] = field(default_factory=dict, repr=False)

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

    # -- any timeline, images --------------------------------------------------------------------

    def _rows(self, entity: str, timeline: str, column: str | None) -> Iterator[tuple[int, pa.RecordBatch, int, str]]:
        """(time, batch, row, data column) of the rows on ``timeline`` that have ``column`` (default: an image)."""
        for batch in self.batches.get(entity, []):
            names = batch.schema.names
            if timeline not in names:
                continue
            columns = [column] if column is not None else [c for c in IMAGE_COLUMNS if c in names]
            for name in (c for c in columns if c in names):
                valid = batch.column(name).is_valid().to_numpy(zero_copy_only=False)
                times = batch.column(timeline).to_numpy(zero_copy_only=False)
                for row in np.flatnonzero(valid):
                    yield int(times[row]), batch, int(row), name

    def indices(self, entity: str, timeline: str = ent.FRAME_TIMELINE, column: str | None = None) -> list[int]:
        """Sorted distinct times on ``timeline`` at which ``entity`` has ``column`` (default: an image)."""
        return sorted({time for time, *_ in self._rows(entity, timeline, column)})

    def image(self, entity: str, index: int, timeline: str = ent.FRAME_TIMELINE) -> np.ndarray:
        """The image logged at ``index`` on ``timeline`` (the last one if several), decoded: RGB uint8 for
        colour images (JPEG or raw), the raw values for depth and segmentation images. KeyError if none."""
        found = None
        for time, batch, row, column in self._rows(entity, timeline, None):
            if time == index:
                found = (batch, row, column)
        if found is None:
            raise KeyError(f"no image at {entity} {timeline}={index}")
        batch, row, column = found
        if column == "VideoStream:sample":
            return self.video_frames(entity)[index].copy()
        data = _blob(batch.column(column), row)
        if column == "EncodedDepthImage:blob":
            return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if column == "EncodedImage:blob" and data[:4].tobytes() == b"\x89PNG" and data[25] == 3:
            # Paletted (ffviz.recording.encoders.indexed_png): a class map's classes (the entity has a legend), else the
            # picture the viewer shows, RGBA (a colour-mapped float map; its values are at entities.map_values).
            indices, palette = _paletted_png(data.tobytes())
            return indices if self.annotation_colours(entity) else palette[indices]
        if column == "EncodedImage:blob" and data[:4].tobytes() == b"\x89PNG" and data[25] == 6:
            legend = self.annotation_colours(entity)
            if legend:  # an RGBA class map (ffviz.recording.encoders.palette_png): colours back to classes
                bgra = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
                rgba = bgra[..., [2, 1, 0, 3]].astype(np.uint32)
                packed = (rgba[..., 0] << 24) | (rgba[..., 1] << 16) | (rgba[..., 2] << 8) | rgba[..., 3]
                colours = np.array(sorted(legend), np.uint32)
                position = np.searchsorted(colours, packed)
                position = np.minimum(position, len(colours) - 1)
                if not (colours[position] == packed).all():
                    raise ValueError(f"{entity} {timeline}={index}: a colour outside the entity's legend")
                ids = np.array([legend[c] for c in colours], np.uint8)
                return ids[position]
        if column == "EncodedImage:blob":
            image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
            if image is None:
                raise ValueError(f"{entity} {timeline}={index}: undecodable image")
            if image.ndim == 3:  # RGB, or RGBA (a colour-mapped float map, transparent where it has no value)
                return cv2.cvtColor(image, cv2.COLOR_BGR2RGB if image.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
            return image
        archetype = column.split(":", 1)[0]
        fmt = batch.column(f"{archetype}:format")[row].values[0].as_py()
        dtype = _DTYPES[ChannelDatatype(fmt["channel_datatype"] or ChannelDatatype.U8)]
        model = ColorModel(fmt["color_model"]) if fmt.get("color_model") else None
        channels = _CHANNELS.get(model, 1)
        image = data.view(dtype).reshape((fmt["height"], fmt["width"]) + ((channels,) if channels > 1 else ()))
        if model in (ColorModel.BGR, ColorModel.BGRA):
            image = image[..., [2, 1, 0, 3][:channels]]
        return image.copy()

    def annotation_colours(self, entity: str) -> dict[int, int]:
        """{packed RGBA colour: class id} of the AnnotationContext logged at ``entity`` (0xRRGGBBAA)."""
        out: dict[int, int] = {}
        for batch in self.batches.get(entity, []):
            if "AnnotationContext:context" in batch.schema.names:
                for value in batch.column("AnnotationContext:context").to_pylist():
                    for entry in (value[0] if value and isinstance(value[0], list) else value or []):
                        info = entry["class_description"]["info"]
                        out[int(info["color"] or 0)] = int(entry["class_id"])
        return out

    def map(self, entity: str, index: int, timeline: str = ent.FRAME_TIMELINE) -> np.ndarray:
        """A float map in its units (NaN = no value), whether stored as 16-bit PNG (entities.MAP_STEPS) or float;
        read from entities.map_values(entity) (``entity`` itself is the colour-mapped picture the views show)."""
        image = self.image(ent.map_values(entity), index, timeline)
        if image.dtype == np.uint16 and entity in ent.MAP_STEPS:
            return np.where(image > 0, (image.astype(np.float32) - 1) * np.float32(ent.MAP_STEPS[entity]), np.nan)
        return image.astype(np.float32)

    def video_samples(self, entity: str) -> list[tuple[int, bytes, bool]]:
        """(frame, H.264 sample, is keyframe) of a VideoStream entity, in frame order."""
        samples = []
        for batch in self.batches.get(entity, []):
            names = batch.schema.names
            if ent.FRAME_TIMELINE not in names or "VideoStream:sample" not in names:
                continue
            frames = batch.column(ent.FRAME_TIMELINE).to_numpy(zero_copy_only=False)
            keys = (batch.column("VideoStream:is_keyframe").to_pylist() if "VideoStream:is_keyframe" in names
                    else [None] * batch.num_rows)
            column = batch.column("VideoStream:sample")
            for row in np.flatnonzero(column.is_valid().to_numpy(zero_copy_only=False)):
                key = keys[row]
                samples.append((int(frames[row]), _blob(column, int(row)).tobytes(),
                                bool(key[0] if isinstance(key, list) else key)))
        samples.sort(key=lambda s: s[0])
        return samples

    def video_codec(self, entity: str) -> int | None:
        for batch in self.batches.get(entity, []):
            if "VideoStream:codec" in batch.schema.names:
                values = [v for v in batch.column("VideoStream:codec").to_pylist() if v]
                if values:
                    return values[0][0] if isinstance(values[0], list) else values[0]
        return None

    def video_frames(self, entity: str) -> dict[int, np.ndarray]:
        """Every frame of a VideoStream entity decoded with PyAV (RGB uint8), by frame index; cached."""
        if entity not in self._videos:
            import av

            decoder = av.CodecContext.create("h264", "r")
            samples = self.video_samples(entity)
            decoded = []
            for _, data, _ in samples:
                decoded += [f.to_ndarray(format="rgb24") for f in decoder.decode(av.Packet(data))]
            decoded += [f.to_ndarray(format="rgb24") for f in decoder.decode(None)]
            if len(decoded) != len(samples):
                raise ValueError(f"{entity}: {len(samples)} samples decoded to {len(decoded)} frames")
            size = self._frame_size(entity)
            if size is not None:  # odd sizes were padded by a row / column for 4:2:0
                decoded = [image[:size[1], :size[0]] for image in decoded]
            self._videos[entity] = {frame: image for (frame, _, _), image in zip(samples, decoded)}
        return self._videos[entity]

    def _frame_size(self, entity: str) -> tuple[int, int] | None:
        """(width, height) the recorder noted for a frame stream of odd size; None when it noted none."""
        return self.size(entity, "frame_size")

    def size(self, entity: str, field: str) -> tuple[int, int] | None:
        """A (width, height) the recorder logged as ``field`` (AnyValues) at ``entity``, e.g. entities.SIZES'
        input_size and recorded_size; None if it logged none."""
        for batch in self.batches.get(entity, []):
            if field in batch.schema.names:
                values = [v for v in batch.column(field).to_pylist() if v]
                if values:
                    width, height = values[-1]
                    return int(width), int(height)
        return None

    def labels(self, entity: str, timeline: str = ent.FRAME_TIMELINE) -> dict[int, str]:
        """{time: first label} of a Boxes2D/Points2D entity on ``timeline``."""
        out: dict[int, str] = {}
        for batch in self.batches.get(entity, []):
            names = batch.schema.names
            column = next((c for c in names if c.endswith(":labels")), None)
            if timeline not in names or column is None:
                continue
            for time, value in zip(batch.column(timeline).to_pylist(), batch.column(column).to_pylist()):
                if value:
                    out[int(time)] = value[0]
        return out


def _paletted_png(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(uint8 indices, (256, 4) RGBA palette) of an 8-bit paletted PNG: decoded as the grey PNG it is but for its
    colour type and palette chunks (the inverse of ffviz.recording.encoders.indexed_png; OpenCV would expand the colours)."""
    palette = np.zeros((256, 4), np.uint8)
    palette[:, 3] = 255
    grey, offset = [data[:8]], 8
    while offset < len(data):
        length = struct.unpack(">I", data[offset:offset + 4])[0]
        kind, body = data[offset + 4:offset + 8], data[offset + 8:offset + 8 + length]
        end = offset + 12 + length
        if kind == b"IHDR":
            if body[8] != 8:
                raise ValueError(f"paletted PNG of bit depth {body[8]}: only 8 is read")
            header = bytearray(body)
            header[9] = 0  # grey
            grey.append(struct.pack(">I", length) + kind + bytes(header)
                        + struct.pack(">I", zlib.crc32(kind + bytes(header))))
        elif kind == b"PLTE":
            colours = np.frombuffer(body, np.uint8).reshape(-1, 3)
            palette[:len(colours), :3] = colours
        elif kind == b"tRNS":
            palette[:length, 3] = np.frombuffer(body, np.uint8)
        else:
            grey.append(data[offset:end])
        offset = end
    indices = cv2.imdecode(np.frombuffer(b"".join(grey), np.uint8), cv2.IMREAD_UNCHANGED)
    if indices is None:
        raise ValueError("undecodable paletted PNG")
    return indices, palette


def _blob(column: pa.Array, row: int) -> np.ndarray:
    """The bytes of one row of a list<list<uint8>> image column, without a Python list in between."""
    return column[row].values[0].values.to_numpy(zero_copy_only=False).view(np.uint8)
