"""The what-if debugger: re-run one frame's stages with other settings and see both, side by side in Rerun.

    dbg = Debugger("shaky.mp4", rrd="recordings/shaky.debug.rrd")   # pass 1 and the path, once (or from its cache)
    dbg.frame(231)                                                   # the default
    dbg.frame(231, {"deblur.alpha": 4})                              # a variant, named "alpha=4"
    dbg.frame(231, {"completion.neighbour_frames": 2, "deblur.alpha": 4}, name="tight")
    dbg.close()                                                      # the .rrd, every variant in it

Each call renders frame t alone (pipeline/frame_session.py: only its window decoded; what a whole run with the same
settings writes) and records it as a variant (ffviz/recording/variants.py). Settings that shape the path re-plan it
and record both paths; those that change pass 1 (motion.*, rolling_shutter) are refused with the way out.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Mapping

from ffviz import blueprint
from ffviz import entities as ent
from ffviz.recording.variants import VariantRecording
from ffviz.recording.view import RECORD_SIZE
from pipeline import settings as named
from pipeline.config import StabilizeConfig
from pipeline.errors import ConfigError, OutputError
from pipeline.frame_session import FrameSession
from pipeline.results import FrameResult
from pipeline.runtime.observer import ProgressFactory, null_progress

import rerun as rr


class Debugger:
    """``input`` opened for what-if rendering with ``config`` as the default, recorded to ``rrd`` (and shown live in
    a viewer at ``live_url``, or with ``stream`` kept readable at ``recording.stream`` for a page). Pass 1's motion
    is cached beside the recording (``<rrd>.motion.npz``)."""

    def __init__(self, input: Path | str, config: StabilizeConfig = StabilizeConfig(), *, rrd: Path | str,
                 live_url: str | None = None, stream: bool = False, record_size: int | None = RECORD_SIZE,
                 workers: int | None = None, progress: ProgressFactory = null_progress) -> None:
        self.rrd = Path(rrd)
        self.session = FrameSession(input, config, cache=self.rrd.with_suffix(".motion.npz"), progress=progress,
                                    workers=workers)
        info = self.session.info
        self.recording = VariantRecording(self.rrd, width=info.width, height=info.height, fps=float(info.fps),
                                          colour=getattr(info, "colour", None), record_size=record_size,
                                          live_url=live_url, stream=stream)
        self.recording.rec.log(ent.note_entity("debug"), rr.TextDocument(blueprint.DEBUG_NOTE,
                                                                        media_type=rr.MediaType.MARKDOWN), static=True)
        self._paths = False
        self.rendered: list[tuple[int, str, float]] = []  # (frame, variant, seconds), in order
        self._closed = False

    @property
    def n_frames(self) -> int:
        return self.session.n_frames

    def frame(self, t: int, settings: Mapping[str, Any] | None = None, *, name: str | None = None) -> FrameResult:
        """Frame ``t`` with ``settings`` (``{"deblur.alpha": 4}``; values as text or typed; none: the default),
        recorded as variant ``name`` (default: named by its settings); the default is rendered at ``t`` first if it
        was not yet, so that the two sit side by side with their difference. ConfigError, with nothing recorded, on
        an unknown setting, a value out of range or a frame not in the video."""
        settings = dict(settings or {})
        config = self.config_of(settings)
        if not 0 <= int(t) < self.n_frames:
            raise ConfigError(f"frame {t} is not in the video: its frames are 0-{self.n_frames - 1}")
        if settings and (int(t), "default") not in {(f, n) for f, n, _ in self.rendered}:
            self._render(int(t), {}, "default", self.session.config)
        return self._render(int(t), settings, name or named.label(settings), config)

    def _render(self, t: int, settings: Mapping[str, Any], name: str, config: StabilizeConfig) -> FrameResult:
        started = time.perf_counter()
        result = self.session.render(t, config)
        seconds = time.perf_counter() - started
        if named.changes_path(settings):
            self._paths = True
            self.recording.log_path("default", self.session.plan)
            self.recording.log_path(name, self.session.plan_for(config), settings)
        self.recording.log_variant(t, name, settings, result, seconds)
        self.rendered.append((t, name, seconds))
        self.recording.send_blueprint(blueprint.debug_blueprint(self.recording.names, paths=self._paths))
        if self.recording.error is not None:
            raise OutputError(f"cannot write the recording {self.rrd}: {self.recording.error.strerror}")
        return result

    def config_of(self, settings: Mapping[str, Any]) -> StabilizeConfig:
        """The session's settings with ``settings`` changed (ConfigError where one is unknown or refused)."""
        pass_1 = named.changes_pass_1(settings)
        if pass_1:
            raise ConfigError(f"{', '.join(pass_1)}: pass 1's settings (motion.*, rolling_shutter) cannot change per "
                              "frame; open the video with them (ffviz debug --base ...)")
        return named.with_settings(self.session.config, settings)

    def close(self) -> None:
        """Finish the recording (the layout with every variant in it)."""
        if not self._closed:
            self._closed = True
            self.recording.send_blueprint(blueprint.debug_blueprint(self.recording.names, paths=self._paths))
            self.recording.finish()

    def abort(self) -> None:
        if not self._closed:
            self._closed = True
            self.recording.drop()

    def __enter__(self) -> "Debugger":
        return self

    def __exit__(self, kind, error, trace) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()
