"""What the recording's colours mean: class legends of the masks, colours of overlays and chart lines, and the
colour-key pictures shown beside every colour-mapped view."""

from __future__ import annotations

import functools

import numpy as np

from ffviz import entities as ent, visual
from pipeline.stages.completion import (SOURCE_AS_IS, SOURCE_CARRIED_ON, SOURCE_FALLBACK, SOURCE_LOCAL_WARP,
                                        SOURCE_MAJORITY, SOURCE_MOSAIC)

MISSING_CLASS = 1
FILLED_BY_BASE = 100  # filled_by class of a pixel a neighbour filled: FILLED_BY_BASE + the neighbour's offset
MAX_OFFSET = 30  # offsets with a colour and a name of their own (the PNG's classes are read back by colour)
MISSING_LEGEND = [(0, "valid", (0, 0, 0, 0)), (MISSING_CLASS, "missing", (255, 0, 64, 160))]
ACCEPTED_LEGEND = [(0, "known", (0, 0, 0, 0)), (1, "missing, rejected by the mosaic", (255, 0, 64, 160)),
                   (2, "missing, accepted by the mosaic", (40, 200, 90, 160))]
FALLBACK_LEGEND = [(0, "other", (0, 0, 0, 0)), (1, "fallback", (255, 200, 0, 200))]
# completion/source: how each pixel was filled (the classes are CompletionResult.source's codes)
SOURCE_LEGEND = [(0, "original", (0, 0, 0, 0)), (SOURCE_MOSAIC, "mosaic", (40, 200, 90, 170)),
                 (SOURCE_LOCAL_WARP, "local warp (flow)", (80, 150, 255, 190)),
                 (SOURCE_FALLBACK, "fallback", (255, 200, 0, 200)),
                 (SOURCE_CARRIED_ON, "carried on (moving content)", (230, 60, 200, 200)),
                 (SOURCE_AS_IS, "neighbour as is (no local motion)", (150, 110, 60, 190)),
                 (SOURCE_MAJORITY, "neighbours' majority (median, no local motion)", (0, 200, 200, 190))]
DEBLUR_REFUSED_NAME = "own: every sharper one refused (other content)"  # deblur/source's class 1, legend and key
CROP_COLOUR = (255, 220, 0)
FOREGROUND_COLOUR = (255, 150, 0)  # tracks of the motion not taken for the camera's
IGNORED_COLOUR = (200, 120, 255)  # outline of --ignore / --ignore-mask
ROLLING_SHUTTER_COLOUR = (0, 220, 255)
LABEL_COLOUR = (255, 255, 255, 255)  # stage labels: opaque white reads as dark text on a light tag (checked headless)


def offset_colour(offset: int, alpha: int = 190) -> tuple[int, int, int, int]:
    """Neighbour ``offset``'s colour: blues for earlier frames, oranges for later, darker further away."""
    base = np.array((40, 120, 255) if offset < 0 else (255, 110, 30), float)
    fade = min(abs(offset) - 1, MAX_OFFSET - 1) / (MAX_OFFSET - 1)
    light = base + (255 - base) * 0.45 * (1 - fade)
    return tuple(int(c) for c in light * (1 - 0.45 * fade)) + (alpha,)


@functools.cache
def filled_by_legend() -> tuple:
    legend = [(0, "original", (0, 0, 0, 0)), (1, "mosaic", (40, 200, 90, 170)), (2, "fallback", (255, 200, 0, 200))]
    legend += [(FILLED_BY_BASE + o, f"neighbour {o:+d}", offset_colour(o, 190))
               for o in range(-MAX_OFFSET, MAX_OFFSET + 1) if o]
    return tuple(legend)


@functools.cache
def deblur_source_legend() -> tuple:
    legend = [(0, "own frame", (0, 0, 0, 0)), (1, DEBLUR_REFUSED_NAME, (230, 40, 60, 200))]
    legend += [(FILLED_BY_BASE + o, f"from neighbour {o:+d}", offset_colour(o, 170))
               for o in range(-MAX_OFFSET, MAX_OFFSET + 1) if o]
    return tuple(legend)


def class_legends() -> dict[str, tuple[list | tuple, str]]:
    """entity -> (legend, title) of every class map: logged as the entity's AnnotationContext (hover names with
    --lossless; the paletted PNGs' colours otherwise)."""
    return {ent.STABILIZED_MISSING: (MISSING_LEGEND, "missing area"),
            ent.COMPLETION_ACCEPTED: (ACCEPTED_LEGEND, "mosaic (eqs. 20-21)"),
            ent.COMPLETION_FALLBACK: (FALLBACK_LEGEND, "fallback"),
            ent.COMPLETION_SOURCE: (SOURCE_LEGEND, "filled how"),
            ent.COMPLETION_FILLED_BY: (filled_by_legend(), "filled by"),
            ent.DEBLUR_SOURCE: (deblur_source_legend(), "deblurred pixel from")}


def _stats_style(name: str) -> str:
    return f"{ent.COMPLETION_STATS}/{name}"


# Every chart line: a name and a colour of its own (distinct hues, readable on the dark theme), and a width.
SERIES_STYLES: dict[str, tuple[str, tuple[int, int, int], float]] = {
    f"{ent.MOTION_PARAMS}/dx": ("dx (px)", (230, 90, 60), 2.0),
    f"{ent.MOTION_PARAMS}/dy": ("dy (px)", (40, 150, 240), 2.0),
    f"{ent.MOTION_PARAMS}/angle": ("angle (deg)", (240, 200, 40), 2.0),
    f"{ent.MOTION_PARAMS}/scale": ("scale", (180, 100, 240), 2.0),
    ent.MOTION_INLIERS: ("inliers", (60, 200, 120), 2.0),
    ent.MOTION_INLIER_RATIO: ("inlier ratio", (60, 200, 220), 2.0),
    ent.MOTION_RESIDUAL: ("residual (px)", (240, 120, 180), 2.0),
    _stats_style("missing"): ("missing", (240, 60, 80), 2.0),
    _stats_style("mosaic"): ("mosaic", (60, 200, 90), 2.0),
    _stats_style("local_warp"): ("local warp (motion inpainting)", (80, 150, 255), 2.0),
    _stats_style("fallback"): ("fallback", (255, 200, 0), 2.0),
    _stats_style("carried_on"): ("carried on (moving content)", (230, 60, 200), 2.0),
    _stats_style("neighbour_as_is"): ("neighbour as is", (150, 110, 60), 2.0),
    _stats_style("majority"): ("neighbours' majority", (0, 200, 200), 2.0),
    ent.COMPLETION_TEMPORAL: ("share averaged in", (235, 235, 235), 2.0),
    ent.DEBLUR_REFUSED: ("a neighbour refused (share)", (230, 40, 60), 1.0),
    ent.DEBLUR_BLURRINESS: ("blurriness b_t", (200, 80, 200), 1.0),
    ent.DEBLUR_NEIGHBOURS: ("sharper neighbours used", (90, 160, 90), 1.0),
    ent.CROP_ROOM: ("crop window's room inside the input (px)", CROP_COLOUR, 2.0),
}
# Original in warm colours, smoothed in cool ones; eq. 18's and the L1 path on the same motion thin, in colours of
# their own; x and y told apart within each (visual.TRAJECTORY_COLOURS).
for _root, _kind, _name, _width in ((ent.TRAJECTORY_ORIGINAL, "original", "original", 2.0),
                                    (ent.TRAJECTORY_SMOOTHED, "smoothed", "smoothed", 2.0),
                                    (ent.TRAJECTORY_GAUSSIAN, "gaussian", "eq. 18 (gaussian)", 1.0),
                                    (ent.TRAJECTORY_L1, "l1", "L1", 1.0)):
    for _axis in ent.TRAJECTORY_AXES:
        SERIES_STYLES[f"{_root}/{_axis}"] = (f"{_axis} {_name}", visual.TRAJECTORY_COLOURS[_kind, _axis], _width)


def colour_keys() -> dict[str, np.ndarray]:
    """Key pictures by name (entities.key_entity(name)); KEY_OF maps each colour-mapped entity to one."""
    neighbours = [(f"neighbour {o:+d}", offset_colour(o)) for o in (-10, -1, 1, 10)]
    return {
        "flow": visual.flow_wheel(),
        "variance": visual.colour_bar("turbo", 0, visual.VARIANCE_RANGE[1], "intensity^2 (0-255 scale); threshold: "
                                      "green in the mosaic map", "mosaic variance (eq. 20)",
                                      no_value="not missing, or under 2 neighbours there"),
        "fmm_order": visual.colour_bar("viridis", 0, 1, "share of the neighbour's filled pixels visited before",
                                       "Fast Marching visiting order", fmt="{:.2f}", no_value="known, or not reached"),
        "fmm_arrival": visual.colour_bar("magma", 0, visual.ARRIVAL_RANGE[1], "px from the nearest known pixel",
                                         "Fast Marching arrival time T", no_value="known (T = 0), or not reached"),
        "deblur_weights": visual.colour_bar("viridis", 0, 1, "share of the pixel from sharper neighbours",
                                            "deblurring weights (eqs. 30-31)", fmt="{:.2f}"),
        "missing": visual.palette_key([(n, c) for _, n, c in MISSING_LEGEND[1:]], "stabilized frame"),
        "accepted": visual.palette_key([(n, c) for _, n, c in ACCEPTED_LEGEND[1:]], "mosaic (eqs. 20-21)"),
        "source": visual.palette_key([(n, c) for _, n, c in SOURCE_LEGEND[1:]], "filled how"),
        "filled_by": visual.palette_key([("mosaic", (40, 200, 90, 170)), ("fallback", (255, 200, 0, 200))] + neighbours,
                                        "filled by (neighbours: blue = earlier, orange = later)"),
        "deblur_source": visual.palette_key(
            [(DEBLUR_REFUSED_NAME, (230, 40, 60, 200))]
            + [(f"from neighbour {o:+d}", offset_colour(o)) for o in (-5, 5)],
            "pixel from (blue: earlier, orange: later)"),
    }
