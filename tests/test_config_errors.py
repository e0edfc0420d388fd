"""Bad configuration raises ConfigError, from every config dataclass, where the config is built.

ConfigError is an FFVizError (the CLI prints it on one line, exit status 2) and a ValueError (what the configs
raised before, so existing `except ValueError` callers keep working).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from pipeline.stages import adaptive_crop, completion, deblur, fmm, l1_path, local_flow, mosaic, motion, path_control
from pipeline.stages import smoothing
from pipeline.evaluation import metrics
from pipeline import stabilize
from pipeline.evaluation import synthetic
from pipeline.runtime.encoding import Encoding
from pipeline.errors import ConfigError, FFVizError

REPO = Path(__file__).resolve().parents[1]

# config class -> keyword arguments that each make it invalid
BAD = {
    completion.CompletionConfig: [dict(neighbour_frames=-1), dict(max_warp_neighbours=-1), dict(flow_max_side=8),
                                  dict(residual_radius=-1), dict(static_candidate_error=-1.0),
                                  dict(candidates=("local warp", "nope")), dict(candidates=("majority", "majority"))],
    deblur.DeblurConfig: [dict(alpha=0.0), dict(neighbour_frames=-1), dict(min_ratio=0.5), dict(error_sigma_px=-1.0),
                          dict(reject_error=0.0), dict(structure_min=2.0), dict(structure_window_px=0)],
    fmm.MotionInpaintConfig: [dict(radius_px=0), dict(colour_epsilon=0.0)],
    local_flow.LocalFlowConfig: [dict(method="nope"), dict(dis_preset="nope")],
    metrics.MetricsConfig: [dict(max_side=8)],
    mosaic.MosaicConfig: [dict(min_neighbours=1), dict(variance_threshold=0.0)],
    motion.MotionConfig: [dict(model="nope"), dict(refine="nope"), dict(ignore=((0, 0, 5, 5),)), dict(hist_step=0)],
    motion.IgnoreRegion: [dict(x=0, y=0, width=0, height=5), dict(x=-1, y=0, width=5, height=5),
                          dict(x=0, y=0, width=5, height=5, start_s=3.0, end_s=1.0)],
    smoothing.SmoothingConfig: [dict(radius_frames=-1), dict(sigma=0.0), dict(path="nope"), dict(max_shift=-1.0),
                                dict(max_angle=float("nan")), dict(path="tripod", smoothness=path_control.Smoothness()),
                                dict(segments=(path_control.PathSegment(0.0, None, "nope"),))],
    path_control.Smoothness: [dict(translation=101.0), dict(zoom=-1.0), dict(rotation=float("nan"))],
    path_control.PathSegment: [dict(start_s=-1.0), dict(end_s=0.0), dict(smoothness=path_control.Smoothness())],
    adaptive_crop.CropConfig: [dict(kind="nope"), dict(zoom_speed=0.0)],
    l1_path.L1PathConfig: [dict(margin_fraction=-0.1), dict(margin_deg=-1.0), dict(window=4), dict(overlap=2),
                           dict(window=100, overlap=60)],
    stabilize.StabilizeConfig: [dict(mode="nope")],
    synthetic.SyntheticConfig: [dict(width=4), dict(n_frames=0), dict(fps=0.0), dict(fps=float("nan")),
                                dict(object_kind="cat"), dict(n_frames=6, blurred_frames=(6,))],
    Encoding: [dict(codec="nope"), dict(crf=52), dict(preset="nope"), dict(qscale=1)],
}
CASES = [(cls, kwargs) for cls, bad in BAD.items() for kwargs in bad]
# Classes with required fields: a valid set, which each bad case overrides.
VALID = {motion.IgnoreRegion: dict(x=0, y=0, width=5, height=5),
         path_control.PathSegment: dict(start_s=0.0, end_s=5.0, path="tripod")}


def test_config_error_is_an_ffviz_error_and_a_value_error():
    assert issubclass(ConfigError, FFVizError) and issubclass(ConfigError, ValueError)
    assert ConfigError.exit_code == 2


@pytest.mark.parametrize("cls, kwargs", CASES, ids=[f"{c.__name__}-{next(iter(k))}" for c, k in CASES])
def test_bad_value_raises_config_error(cls, kwargs):
    cls(**VALID.get(cls, {}))  # the defaults are valid
    with pytest.raises(ConfigError) as info:
        cls(**{**VALID.get(cls, {}), **kwargs})
    assert "\n" not in str(info.value)


def _validated_classes() -> dict[str, list[str]]:
    """'module.Class' -> what each raise statement in its __post_init__ raises, for pipeline/ and ffviz/."""
    found = {}
    for package in ("pipeline", "ffviz"):
        for path in sorted((REPO / package).glob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if not isinstance(node, ast.ClassDef):
                    continue
                for method in node.body:
                    if isinstance(method, ast.FunctionDef) and method.name == "__post_init__":
                        raised = [ast.unparse(r.exc.func if isinstance(r.exc, ast.Call) else r.exc)
                                  for r in ast.walk(method) if isinstance(r, ast.Raise) and r.exc is not None]
                        found[f"{package}.{path.stem}.{node.name}"] = raised
    return found


def test_every_validating_dataclass_raises_config_error_and_is_tested_here():
    found = _validated_classes()
    wrong = {name: raised for name, raised in found.items() if set(raised) - {"ConfigError"}}
    assert not wrong, f"__post_init__ must raise ConfigError: {wrong}"
    tested = {f"{cls.__module__}.{cls.__name__}" for cls in BAD}
    assert set(found) <= tested, f"add a bad value for {sorted(set(found) - tested)} to BAD"
