"""Named quality presets of a full-frame run (``ffviz stabilize --quality``).

``default``: the thesis's chain as configured everywhere else (chapter 4's local warp from four neighbours at the
flow's 640 px working size, deblurring over +-6 frames). ``fast``: less of the expensive parts, above all motion
inpainting (eqs. 24-25): local flow to the two nearest neighbours at a 320 px working size, no local registration of
the neighbours before the mosaic (an ECC fit per neighbour), a shorter chain of completion's candidates
(``FAST_LEAVES_OUT``), deblurring over +-3 frames (docs/decisions.md D18, D34). What it costs and gives against the
default and against mosaic + Telea (OpenCV's chain): docs/benchmarks-speed.md.
"""

from __future__ import annotations

import dataclasses

from pipeline.config import StabilizeConfig
from pipeline.errors import ConfigError

QUALITIES: tuple[str, ...] = ("default", "fast")
# Completion's candidate sources fast leaves out of the chain: the mosaic's doubtful pixels (contesting them needs the
# local flows over them too) and the moving content carried on (two more flows a frame).
FAST_LEAVES_OUT: tuple[str, ...] = ("mosaic", "carried on")


def with_quality(config: StabilizeConfig, quality: str) -> StabilizeConfig:
    """``config`` with the completion and deblurring settings of preset ``quality`` (other settings kept)."""
    if quality not in QUALITIES:
        raise ConfigError(f"quality must be one of {', '.join(QUALITIES)}, not {quality!r}")
    if quality == "default":
        return config
    chain = tuple(name for name in config.completion.candidates if name not in FAST_LEAVES_OUT)
    completion = dataclasses.replace(config.completion, max_warp_neighbours=2, flow_max_side=320, register_model=None,
                                     candidates=chain)
    deblur = dataclasses.replace(config.deblur, neighbour_frames=min(config.deblur.neighbour_frames, 3))
    return dataclasses.replace(config, completion=completion, deblur=deblur)
