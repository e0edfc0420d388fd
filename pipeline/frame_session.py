"""One video opened to render its frames one at a time, with any settings: the debugger's pipeline.

Opening runs pass 1 (the motion, thesis 3.2) once, or reads it from a cache file keyed by the input's identity and
the motion settings, and plans the path. ``render(t, config)`` then makes frame t alone: it decodes only the frames
its window needs (seeking to the key frame before them), renders frame t and the frames temporal consistency averages
into it (chain.render_frames over that stretch), and returns frame t's FrameResult with every intermediate. Frame t
is what a whole run with the same settings writes (the chain is a pure function of the plan and the window; the
segment-parallel runs rely on the same). Settings that shape the path re-plan it (seconds); those that change pass 1
(motion.*, rolling_shutter) need the video opened again with them.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from pipeline.chain import frames_read, plan_path, render_frames
from pipeline.config import StabilizeConfig
from pipeline.errors import ConfigError
from pipeline.results import FrameResult, MotionPass, PathPlan
from pipeline.runtime import parallel, video_reader
from pipeline.runtime.observer import NullObserver, ProgressFactory, null_progress
from pipeline.runtime.source import FileSource, WindowSource
from pipeline.stabilize import estimate_motion

CACHE_VERSION = 2  # bump when MotionPass's meaning changes


class FrameSession:
    """``path`` opened for single-frame rendering with ``config`` as the default settings.

    ``cache``: a file for pass 1's motion (read when it matches the input and the motion settings, else written);
    None: no cache. ``workers``: frames rendered at once (threads)."""

    def __init__(self, path: Path | str, config: StabilizeConfig = StabilizeConfig(), *, cache: Path | None = None,
                 progress: ProgressFactory = null_progress, workers: int | None = None) -> None:
        self.path = Path(path)
        self.config = config
        self.info = video_reader.probe_video(self.path)
        self.workers = parallel.default_workers() if workers is None else max(int(workers), 1)
        self.motion = cached_motion(self.path, config, cache, progress)
        self._plans: dict[tuple, PathPlan] = {}
        self.plan = self.plan_for(config)

    @property
    def n_frames(self) -> int:
        return self.motion.n_frames

    def plan_for(self, config: StabilizeConfig) -> PathPlan:
        """The path plan of ``config`` (planned once per distinct path-shaping settings)."""
        self._check_pass_1(config)
        key = (config.mode, config.smoothing, config.crop)
        if key not in self._plans:
            self._plans[key] = plan_path(self.motion, config, self.info.width, self.info.height)
        return self._plans[key]

    def render(self, t: int, config: StabilizeConfig | None = None) -> FrameResult:
        """Frame ``t`` with ``config`` (default: the session's), every intermediate kept."""
        config = self.config if config is None else config
        if not 0 <= t < self.n_frames:
            raise ConfigError(f"frame {t} is not in the video: its frames are 0-{self.n_frames - 1}")
        plan = self.plan_for(config)
        read = frames_read(config, range(t, t + 1), self.n_frames)
        source = WindowSource(self.path, self.motion.times_s, read.start, read.stop)
        results = list(render_frames(source, plan, config, keep=_everything, frames=range(t, t + 1),
                                     workers=self.workers))
        if len(results) != 1:
            raise ConfigError(f"frame {t} could not be rendered alone ({len(results)} results)")
        return results[0]

    def _check_pass_1(self, config: StabilizeConfig) -> None:
        changed = [name for name in ("motion", "rolling_shutter")
                   if getattr(config, name) != getattr(self.config, name)]
        if changed:
            raise ConfigError(f"{' and '.join(changed)} settings change pass 1 (the motion): open the video again "
                              "with them")


def _everything(result: FrameResult) -> FrameResult:
    return result


# -- pass 1's cache -------------------------------------------------------------------------------------------

def motion_key(path: Path, config: StabilizeConfig) -> str:
    """What pass 1's result depends on: the input file (path, size, modification time) and the motion settings."""
    stat = path.stat()
    identity = [str(path.resolve()), stat.st_size, stat.st_mtime_ns, repr(config.motion),
                config.rolling_shutter is not None, CACHE_VERSION]
    return hashlib.sha256(json.dumps(identity).encode()).hexdigest()


def cached_motion(path: Path, config: StabilizeConfig, cache: Path | None,
                  progress: ProgressFactory = null_progress) -> MotionPass:
    """Pass 1's result from ``cache`` when it was made for this input and these settings, else computed (and
    written to ``cache``, unless it holds rolling-shutter tracks)."""
    key = motion_key(path, config)
    if cache is not None and cache.is_file():
        loaded = _load(cache, key)
        if loaded is not None:
            return loaded
    source = FileSource(path)
    motion = estimate_motion(source, config.motion, observer=NullObserver(), progress=progress,
                             total=source.info.frame_count or None, workers=parallel.default_workers(),
                             keep_tracks=config.rolling_shutter is not None)
    if cache is not None and motion.tracks is None:
        _save(cache, key, motion)
    return motion


def _load(cache: Path, key: str) -> MotionPass | None:
    try:
        with np.load(cache, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            if meta.get("key") != key:
                return None
            return MotionPass(data["curr_from_prev"], list(meta["statuses"]), list(meta["times_s"]),
                              [(w[0], w[1]) for w in meta["warnings"]])
    except (OSError, KeyError, ValueError):  # unreadable or from another version: computed again
        return None


def _save(cache: Path, key: str, motion: MotionPass) -> None:
    """Written beside its place and renamed: a half-written cache is never read."""
    meta = json.dumps({"key": key, "statuses": motion.statuses, "times_s": motion.times_s,
                       "warnings": [list(w) for w in motion.warnings]})
    cache.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{cache.name}.", suffix=".npz", dir=cache.parent)
    try:
        with os.fdopen(fd, "wb") as file:
            np.savez(file, curr_from_prev=motion.curr_from_prev, meta=np.array(meta))
        os.replace(tmp, cache)
    except OSError:
        Path(tmp).unlink(missing_ok=True)  # a cache that cannot be written is not an error: pass 1 runs again
