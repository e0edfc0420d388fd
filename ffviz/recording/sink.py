"""The recording's file: a RecordingStream saved beside its place and renamed when finished (``RecordingFile``),
written by a thread of ours: the SDK's file sink writes into a pipe that this thread drains into the file.

So a failed write (a full disk) is an ``OSError`` with its reason, ours to report in one line, instead of the SDK's
writer stopping with a log line and its flush waiting for ever; after a failure the pipe is still drained (and the
bytes dropped), so the SDK never blocks. What is held between the SDK and the file is the pipe's buffer and one read.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import uuid
from pathlib import Path

import rerun as rr

READ_BYTES = 1 << 20


class PipedFile:
    """Drains the pipe at ``pipe_path`` (hand it to ``rr.FileSink`` / ``RecordingStream.save``) into ``path``.

    Both ends are opened here first, without blocking: the SDK opens its end holding the GIL, and would wait for ever
    for a reader that needs the GIL to open its own. The write end kept here holds off the end of the stream until
    ``close``, after the SDK has closed its end."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._folder = Path(tempfile.mkdtemp(prefix="ffviz-recording-"))
        self.pipe_path = self._folder / "stream.rrd"
        os.mkfifo(self.pipe_path, 0o600)
        self._source = os.open(self.pipe_path, os.O_RDONLY | os.O_NONBLOCK)
        self._held_open = os.open(self.pipe_path, os.O_WRONLY | os.O_NONBLOCK)
        os.set_blocking(self._source, True)
        self.error: OSError | None = None
        self.bytes_written = 0
        self._thread = threading.Thread(target=self._drain, name="ffviz-recording-file", daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        try:
            target = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        except OSError as error:
            self.error, target = error, None
        while chunk := os.read(self._source, READ_BYTES):
            if self.error is None and target is not None:
                self._write(target, chunk)
        os.close(self._source)
        if target is not None:
            self._close(target)

    def _write(self, target: int, chunk: bytes) -> None:
        view = memoryview(chunk)
        try:
            while view:
                written = os.write(target, view)
                view = view[written:]
                self.bytes_written += written
        except OSError as error:
            self.error = error

    def _close(self, target: int) -> None:
        try:
            os.close(target)
        except OSError as error:  # a network file system may report a failed write only here
            self.error = self.error or error

    def close(self) -> None:
        """Once the SDK has closed its end: wait until everything is written; raises the first write error."""
        if self._held_open is not None:
            os.close(self._held_open)
            self._held_open = None
        self._thread.join()
        shutil.rmtree(self._folder, ignore_errors=True)
        if self.error is not None:
            raise self.error


class RecordingFile:
    """``rec``, a RecordingStream saved to ``path`` (and streamed to a viewer at ``live_url``; with ``stream``, also
    to ``self.stream``, a BinaryStream the caller reads and forwards, e.g. to a page): written to a hidden file beside
    ``path`` through a ``PipedFile`` and renamed at ``finish``; ``drop`` leaves nothing behind."""

    def __init__(self, path: Path, *, application_id: str, batcher: rr.ChunkBatcherConfig,
                 live_url: str | None = None, stream: bool = False) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=".rrd.tmp", dir=self.path.parent)
        os.close(fd)
        self._tmp_path = Path(tmp)
        self.rec = rr.RecordingStream(application_id, recording_id=str(uuid.uuid4()), batcher_config=batcher)
        self._file = PipedFile(self._tmp_path)
        self.stream = rr.binary_stream(recording=self.rec) if stream else None
        others = ([rr.GrpcSink(live_url)] if live_url else []) + ([self.stream] if stream else [])
        if not others:
            self.rec.save(self._file.pipe_path)
        else:  # every sink at once: a running viewer (live view) or a stream, and the file
            rr.set_sinks(*others, rr.FileSink(str(self._file.pipe_path)), recording=self.rec)

    @property
    def error(self) -> OSError | None:
        """The first failed write to the file, if any (the run may stop there, not at the end)."""
        return self._file.error

    def finish(self) -> None:
        """Everything written, the file moved into place; raises the writer's error (the caller drops the file)."""
        self.rec.flush()
        self.rec.disconnect()
        self._file.close()
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(self._tmp_path, 0o666 & ~umask)  # mkstemp made it private; give it the usual mode
        os.replace(self._tmp_path, self.path)

    def drop(self) -> None:
        """Nothing half-written left behind."""
        for step in (self.rec.disconnect, self._file.close):
            try:
                step()
            except Exception:  # noqa: BLE001 - dropping it anyway
                pass
        self._tmp_path.unlink(missing_ok=True)
