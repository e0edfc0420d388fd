"""Quality presets (pipeline/presets.py, `ffviz stabilize --quality`): what each one sets and what it leaves."""

from __future__ import annotations

import pytest

from ffviz.cli import build_parser, main
from ffviz.runner import stabilize_config
from pipeline.config import StabilizeConfig
from pipeline.errors import ConfigError
from pipeline.presets import QUALITIES, with_quality
from pipeline.stages.smoothing import SmoothingConfig


def test_default_is_the_config_as_given_and_fast_changes_only_completion_and_deblurring():
    config = StabilizeConfig(mode="full", smoothing=SmoothingConfig(radius_frames=12))
    assert with_quality(config, "default") is config
    fast = with_quality(config, "fast")
    assert (fast.mode, fast.motion, fast.smoothing) == (config.mode, config.motion, config.smoothing)
    assert fast.completion.max_warp_neighbours < config.completion.max_warp_neighbours
    assert fast.completion.flow_max_side < config.completion.flow_max_side
    assert config.completion.register_model is not None and fast.completion.register_model is None
    # a shorter chain of candidate sources, in the default's order
    assert fast.completion.candidates == ("local warp", "neighbour as is", "majority")
    assert config.completion.candidates == ("mosaic", "local warp", "neighbour as is", "majority", "carried on")
    assert fast.deblur.neighbour_frames < config.deblur.neighbour_frames and fast.deblur.alpha == config.deblur.alpha
    # the completion window still holds every neighbour the deblurring compares
    assert fast.deblur.neighbour_frames <= fast.completion.neighbour_frames
    with pytest.raises(ConfigError, match="quality must be one of default, fast"):
        with_quality(config, "best")


def test_quality_option_reaches_the_config_and_refuses_unknown_names(capsys, tmp_path):
    parse = build_parser().parse_args
    assert stabilize_config(parse(["stabilize", "in.mp4", "-o", "out.mp4"])) == StabilizeConfig()
    fast = stabilize_config(parse(["stabilize", "in.mp4", "-o", "out.mp4", "--quality", "fast"]))
    assert fast == with_quality(StabilizeConfig(), "fast")
    assert set(QUALITIES) == {"default", "fast"}
    with pytest.raises(SystemExit) as exit_info:
        main(["stabilize", str(tmp_path / "in.mp4"), "-o", str(tmp_path / "out.mp4"), "--quality", "best"])
    assert exit_info.value.code == 2 and "--quality" in capsys.readouterr().err
