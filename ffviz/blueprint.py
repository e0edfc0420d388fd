"""The layout a recording opens with: on frame 0, paused; a first tab "overview" (input beside output, the
camera path original against smoothed, how to read the recording), then one tab per thesis stage in pipeline
order, each with a short note naming its equations and a colour key beside every colour-mapped image; the
traced frames' stage stepping; and an "about" tab (the run's summary and its warnings)."""

from __future__ import annotations

from typing import Callable, Sequence

import rerun.blueprint as rrb

from ffviz import entities as ent, visual
from ffviz.recording.variants import VARIANTS, variant_entity

TAB_ORDER = ("overview", "motion", "smoothing", "mosaic", "local flow + motion inpainting", "deblurring",
             "stage stepping", "about")

TAB_NOTES = {
    "overview": (
        "**How to read this recording.** The time line below is the frame number (`frame`): drag it or use the "
        "arrow keys, space plays. The input and the stabilized, completed, deblurred output side by side; with them, "
        "the camera path, original (warm colours) against smoothed (cool colours); the vertical line is the current "
        "frame. Each tab after this one is a stage of the pipeline, in order; masks are drawn over the frames they "
        "describe, and every colour-mapped image has a colour key beside it. *stage stepping* follows a few frames "
        "through every stage (time line `stage`); *about* summarises the run and lists its warnings."),
    "motion": ("**Motion estimation** (thesis ch. 3): corners tracked from frame t-1 to t (green inliers, red "
               "outliers), a robust fit of `curr_from_prev`; its shift, rotation and zoom per frame, inliers and "
               "the fit's residual. Orange: tracks of another motion (a moving object) the camera did not follow; "
               "which motion the camera took, and the evidence for it (occlusion: what a figure uncovers or covers "
               "belongs to a layer behind it; the frames around it: their evidence, carried by where tracks "
               "continue and how the camera's motion changes), is charted and named per frame; "
               "violet: where `--ignore` / `--ignore-mask` kept features out; cyan (`--rolling-shutter`): how far each "
               "band of rows was seen from the middle row's view (5x), and the bottom band's shift against the top's."),
    "smoothing": ("**Motion smoothing** (eq. 18, `S_t = sum G(i-t) T_t^i`) and **warping** (eq. 19, "
                  "`I'_t(p) = I_t(S_t p)`): the camera path original against smoothed; the stabilized frame and, "
                  "in red, the area no input pixel covers (the crop window in yellow with `--mode crop`). Each "
                  "path view also draws eq. 18's and the L1 path on the same motion, whichever the run follows; "
                  "with `--mode crop` the input shows the output's corners and their room inside it in px, charted "
                  "under the paths (below 0 the window leaves the frame there, and that part is completed as in "
                  "the mosaic and local flow tabs; with `--crop-fill 0` it never does)."),
    "mosaic": ("**Consistent mosaic** (eqs. 20-22): where the aligned neighbours agree (variance of eq. 20 "
               "below the threshold) the missing pixel takes their mean (eq. 21-22, green); where they disagree "
               "(red) it is left to motion inpainting."),
    "local flow + motion inpainting": (
        "**Local flow** (eq. 23) between a neighbour and the frame over their common area, **motion "
        "inpainting** of that flow into the missing area by Fast Marching (eq. 24, visiting order and arrival "
        "time T) and **local-warp mosaicing** (eq. 25): which neighbour filled each pixel (filled by) and how "
        "(filled how): its local warp, its moving content carried on by a frame, its sample as it is, or the "
        "median of the neighbours' majority where a passing object made a few of them disagree. Last, each "
        "synthesized pixel is averaged with the same scene point in the completed frames next to it where they "
        "agree (temporal consistency: how much, charted under the completed frame)."),
    "deblurring": ("**Deblurring** (thesis ch. 5): relative blurriness b_t (eq. 28: one over the gradient "
                   "energy, higher is blurrier); a blurrier frame takes pixels from sharper aligned neighbours, "
                   "weighted by eqs. 30-31. Before / after show only frames that were sharpened."),
}


def _note(tab: str) -> rrb.TextDocumentView:
    return rrb.TextDocumentView(name="how to read this tab", origin=f"/{ent.note_entity(tab)}")


def _key(name: str, title: str) -> rrb.Spatial2DView:
    return rrb.Spatial2DView(name=f"key: {title}", origin=f"/{ent.key_entity(name)}")


def _image(name: str, *entities: str) -> rrb.Spatial2DView:
    return rrb.Spatial2DView(name=name, origin="/", contents=[f"/{e}" for e in entities])


def _map(name: str, entity: str) -> rrb.Spatial2DView:
    """A colour-mapped float map: its pixels without a value are transparent and show the view's grey background
    (visual.NO_VALUE_COLOUR, in none of the colour maps), not the colour of the lowest value."""
    return rrb.Spatial2DView(name=name, origin="/", contents=[f"/{entity}"], background=visual.NO_VALUE_COLOUR)


def _trajectory_view(axes: Sequence[str], unit: str) -> rrb.TimeSeriesView:
    roots = (ent.TRAJECTORY_ORIGINAL, ent.TRAJECTORY_SMOOTHED, ent.TRAJECTORY_GAUSSIAN, ent.TRAJECTORY_L1)
    contents = [f"/{root}/{axis}" for axis in axes for root in roots]
    # the lines' names are in the legend; a longer title is cut at 1280 px wide
    return rrb.TimeSeriesView(name=f"camera paths {', '.join(axes)} ({unit})", origin="/motion/trajectory",
                              contents=contents)


def _traced_views(traced: Sequence[int], title: Callable[[int], str],
                  contents: Callable[[int], Sequence[str]]) -> list[rrb.View]:
    return [rrb.Spatial2DView(name=title(t), origin=f"/{ent.TRACE}/{t}", contents=[f"/{e}" for e in contents(t)])
            for t in traced]


def _stage_stepping_tab(traced: Sequence[int]) -> rrb.Container:
    stages = _traced_views(traced, lambda t: f"frame {t}: stages (time line stage)",
                           lambda t: [ent.trace_image(t), ent.trace_label(t)])
    fmm = _traced_views(traced, lambda t: f"frame {t}: FMM band (time line fmm_step)",
                        lambda t: [ent.trace_fmm(t), ent.trace_fmm_label(t)])
    if not stages:
        return rrb.Vertical(rrb.TextDocumentView(name="no traced frames (ffviz stabilize --frames T1,T2)",
                                                 origin=f"/{ent.META}"), name="stage stepping")
    return rrb.Vertical(rrb.Horizontal(*stages), rrb.Horizontal(*fmm), name="stage stepping")


def overview_tab(portrait: bool = False) -> rrb.Container:
    """``portrait``: frames taller than wide, side by side with the charts beside them (below, they would be
    narrow columns in wide panels)."""
    frames = (_image("input", ent.INPUT_FRAME), _image("output (stabilized, completed, deblurred)", ent.OUTPUT_FRAME))
    paths = (_trajectory_view(("x", "y"), "px"), _trajectory_view(("angle",), "deg"), _note("overview"))
    if portrait:
        return rrb.Horizontal(*frames, rrb.Vertical(*paths, row_shares=[2, 2, 1.4]), column_shares=[2, 2, 2.4],
                              name="overview")
    return rrb.Vertical(rrb.Horizontal(*frames), rrb.Horizontal(*paths, column_shares=[2, 2, 1.4]),
                        row_shares=[3, 2], name="overview")


def motion_tab(rolling_shutter: bool = False, portrait: bool = False) -> rrb.Container:
    """``rolling_shutter``: a --rolling-shutter run, whose skew gets a chart (empty otherwise); ``portrait``: frames
    taller than wide, given a narrower panel."""
    skew_chart = [rrb.TimeSeriesView(name="rolling shutter: bottom band's shift against the top's (px)",
                                     origin=f"/{ent.ROLLING_SHUTTER_SKEW}")] if rolling_shutter else []
    return rrb.Vertical(
        rrb.Horizontal(
            _image("input + tracked features (green inliers, red outliers)", ent.INPUT_FRAME, f"{ent.MOTION_FEATURES}/**"),
            rrb.Vertical(
                rrb.TimeSeriesView(name="inter-frame motion: dx, dy (px), angle (deg), scale",
                                   origin=f"/{ent.MOTION_PARAMS}"),
                rrb.Horizontal(
                    rrb.TimeSeriesView(name="inliers", origin=f"/{ent.MOTION_INLIERS}"),
                    rrb.TimeSeriesView(name="inlier ratio", origin=f"/{ent.MOTION_INLIER_RATIO}"),
                    rrb.TimeSeriesView(name="residual (px)", origin=f"/{ent.MOTION_RESIDUAL}"),
                ),
                rrb.Horizontal(
                    rrb.TimeSeriesView(name="camera's motion: evidence for the one taken (log-odds)",
                                       origin=f"/{ent.MOTION_CAMERA}"),
                    rrb.TextLogView(name="camera's motion: which, and why", origin=f"/{ent.MOTION_CAMERA_RULE}"),
                ),
                *skew_chart,
                row_shares=[3, 2, 2, 2][:3 + len(skew_chart)],
            ),
            column_shares=[2, 3] if portrait else [1, 1],
        ),
        _note("motion"),
        row_shares=[5, 1],
        name="motion",
    )


def smoothing_tab(crop: bool = False, portrait: bool = False) -> rrb.Container:
    """``crop``: a --mode crop run, whose crop scale and crop-window room get charts (empty in the other modes);
    ``portrait``: frames taller than wide, side by side (stacked, they would be small)."""
    crop_charts = [rrb.TimeSeriesView(name="crop scale", origin=f"/{ent.CROP_SCALE}"),
                   rrb.TimeSeriesView(name="crop window's room in the input, px (< 0: completed there)",
                                      origin=f"/{ent.CROP_ROOM}")] if crop else []
    paths = rrb.Vertical(_trajectory_view(("x",), "px"), _trajectory_view(("y",), "px"),
                         _trajectory_view(("angle",), "deg"), _trajectory_view(("zoom",), "%"), *crop_charts)
    frames = (_image("stabilized (eq. 19); crop window in yellow (--mode crop)", ent.STABILIZED_FRAME, ent.CROP_WINDOW),
              _image("missing area (red)", ent.STABILIZED_FRAME, ent.STABILIZED_MISSING, ent.CROP_WINDOW),
              _image("input; the output's corners in yellow (--mode crop: the crop-window constraint)",
                     ent.INPUT_FRAME, ent.CROP_CONSTRAINT))
    key = _key("missing", "missing area")
    if portrait:
        return rrb.Vertical(rrb.Horizontal(*frames, paths, column_shares=[2, 2, 2, 3]),
                            rrb.Horizontal(key, _note("smoothing"), column_shares=[1, 3]),
                            row_shares=[5, 1], name="smoothing")
    return rrb.Vertical(
        rrb.Horizontal(paths, rrb.Vertical(frames[0], frames[1], key, frames[2], row_shares=[4, 4, 1.6, 4])),
        _note("smoothing"),
        row_shares=[5, 1],
        name="smoothing",
    )


def mosaic_tab() -> rrb.Container:
    return rrb.Vertical(
        rrb.Horizontal(
            rrb.Vertical(_map("mosaic variance (eq. 20)", ent.COMPLETION_VARIANCE), _key("variance", "variance"),
                         row_shares=[4, 1]),
            rrb.Vertical(_image("missing pixels accepted (green) / rejected (red) by the mosaic",
                                ent.COMPLETION_FRAME, ent.COMPLETION_ACCEPTED),
                         _key("accepted", "mosaic"), row_shares=[4, 1]),
        ),
        rrb.Horizontal(
            rrb.TimeSeriesView(name="share of the frame: missing / mosaic / local warp / fallback",
                               origin=f"/{ent.COMPLETION_STATS}"),
            _note("mosaic"),
            column_shares=[2, 1],
        ),
        row_shares=[3, 1],
        name="mosaic",
    )


def inpainting_tab(portrait: bool = False) -> rrb.Container:
    """``portrait``: frames taller than wide, all six pictures in one row (in two rows they would be small)."""
    flow = rrb.Vertical(_image("local flow, 1st neighbour (eqs. 23-24)", ent.COMPLETION_FLOW_IMAGE,
                               ent.COMPLETION_FLOW_ARROWS), row_shares=[1])
    order = _map("Fast Marching visiting order", ent.COMPLETION_FMM_ORDER)
    arrival = _map("Fast Marching arrival time T", ent.COMPLETION_FMM_ARRIVAL)
    filled_by = _image("filled by (eq. 25)", ent.COMPLETION_FRAME, ent.COMPLETION_FILLED_BY)
    filled_how = _image("filled how", ent.COMPLETION_FRAME, ent.COMPLETION_SOURCE)
    completed = _image("completed", ent.COMPLETION_FRAME)
    temporal = rrb.TimeSeriesView(name="temporal consistency", origin=f"/{ent.COMPLETION_TEMPORAL}")
    keys = (_key("flow", "flow"), _key("filled_by", "filled by"), _key("source", "filled how"))
    note = _note("local flow + motion inpainting")
    if portrait:
        side = rrb.Vertical(_key("fmm_order", "visiting order"), _key("fmm_arrival", "arrival time"), *keys, temporal,
                            note)
        return rrb.Horizontal(flow, order, arrival, filled_by, filled_how, completed, side,
                              name="local flow + motion inpainting")
    return rrb.Vertical(
        rrb.Horizontal(flow, rrb.Vertical(order, _key("fmm_order", "visiting order"), row_shares=[2, 1]),
                       rrb.Vertical(arrival, _key("fmm_arrival", "arrival time"), row_shares=[2, 1])),
        rrb.Horizontal(filled_by, filled_how, rrb.Vertical(completed, temporal, row_shares=[2, 1]),
                       rrb.Vertical(*keys), note),
        name="local flow + motion inpainting",
    )


def deblur_tab() -> rrb.Container:
    return rrb.Vertical(
        rrb.Horizontal(
            _image("before (sharpened frames only)", ent.DEBLUR_BEFORE),
            _image("after (eq. 30)", ent.DEBLUR_AFTER),
            rrb.Vertical(_image("weights (eqs. 30-31)", ent.DEBLUR_WEIGHTS),
                         _key("deblur_weights", "weights"), row_shares=[2, 1]),
            rrb.Vertical(_image("source per pixel (red: all refused)", ent.DEBLUR_AFTER, ent.DEBLUR_SOURCE),
                         _key("deblur_source", "source"), row_shares=[2, 1]),
        ),
        rrb.Horizontal(
            rrb.TimeSeriesView(name="relative blurriness b_t (eq. 28)", origin=f"/{ent.DEBLUR_BLURRINESS}"),
            rrb.TimeSeriesView(name="sharper neighbours used", origin=f"/{ent.DEBLUR_NEIGHBOURS}"),
            rrb.TimeSeriesView(name="neighbour refused (share)", origin=f"/{ent.DEBLUR_REFUSED}"),
            _note("deblurring"),
        ),
        name="deblurring",
    )


def about_tab(log: bool = True) -> rrb.Container:
    """``log``: the run logged warnings or notes (their table is shown; without any it would be an empty panel)."""
    log_view = [rrb.TextLogView(name="warnings and notes", origin=f"/{ent.LOG}")] if log else []
    return rrb.Vertical(
        rrb.TextDocumentView(name="about this run", origin=f"/{ent.META}"),
        *log_view,
        row_shares=[3, 1][:1 + len(log_view)],
        name="about",
    )


def default_blueprint(traced: Sequence[int] = (), *, crop: bool = False, rolling_shutter: bool = False,
                      log: bool = True, portrait: bool = False) -> rrb.Blueprint:
    """``traced``: the frames logged on the `stage`/`fmm_step` timelines (a view each); ``crop`` / ``rolling_shutter``:
    a --mode crop / --rolling-shutter run (their charts are shown; other runs have no data for them, and an empty
    panel reads as a fault); ``log``: the run logged warnings or notes (their table is shown); ``portrait``: the
    frames are taller than wide (the tabs with several frames lay them out side by side)."""
    return rrb.Blueprint(
        rrb.Tabs(
            overview_tab(portrait), motion_tab(rolling_shutter, portrait), smoothing_tab(crop, portrait), mosaic_tab(),
            inpainting_tab(portrait), deblur_tab(), _stage_stepping_tab(traced), about_tab(log),
            active_tab=0,
        ),
        # Opens on frame 0, paused (without play_state the viewer starts on the last frame, playing).
        rrb.TimePanel(state="collapsed", timeline=ent.FRAME_TIMELINE, play_state="paused"),
        collapse_panels=True,
    )


# -- the debugger's layout: one column per variant, the same stage side by side -----------------------------------

DEBUG_NOTE = (
    "**What-if debugger.** Each column is a variant of the frames rendered alone (`ffviz debug`): `default` with the "
    "session's settings, the others with the settings their name says. Each tab is a stage; the same stage of every "
    "variant sits side by side, with the same colour keys. Under a variant: its difference from the default at that "
    "frame (largest channel change, and the pixels it filled another way). Move the time line to another debugged "
    "frame.")


def _variant(name: str, entity: str) -> str:
    return variant_entity(name, entity)


def _variant_columns(names: list[str], title: str, views) -> rrb.Container:
    """One column per variant of ``views(name)`` (a list of views), titled with the variant's name."""
    return rrb.Horizontal(*[rrb.Vertical(*views(name), name=f"{name}: {title}") for name in names], name=title)


def debug_tabs(paths: bool = False) -> tuple[str, ...]:
    """The debugger layout's tabs, in order (``paths``: some variant re-planned the path)."""
    return ("output", "completion", "mosaic", "flow + FMM", "deblurring") + (("path",) if paths else ()) + ("settings",)


def debug_blueprint(names: list[str], *, paths: bool = False) -> rrb.Blueprint:
    """``names``: the variants recorded so far, in order; ``paths``: some variant re-planned the path."""
    def output(name: str) -> list[rrb.View]:
        views = [_image(f"{name}: output", _variant(name, ent.OUTPUT_FRAME))]
        if name != "default":
            views.append(_map(f"{name}: change from the default", _variant(name, "diff/output")))
        return views

    def fill(name: str) -> list[rrb.View]:
        views = [_image(f"{name}: filled how", _variant(name, ent.COMPLETION_FRAME), _variant(name, ent.COMPLETION_SOURCE)),
                 _image(f"{name}: filled by", _variant(name, ent.COMPLETION_FRAME),
                        _variant(name, ent.COMPLETION_FILLED_BY))]
        if name != "default":
            views.append(_image(f"{name}: filled another way", _variant(name, ent.COMPLETION_FRAME),
                                _variant(name, "diff/source")))
        return views

    def mosaic(name: str) -> list[rrb.View]:
        return [_image(f"{name}: missing", _variant(name, ent.STABILIZED_FRAME), _variant(name, ent.STABILIZED_MISSING)),
                _map(f"{name}: mosaic variance", _variant(name, ent.COMPLETION_VARIANCE)),
                _image(f"{name}: mosaic accepted", _variant(name, ent.COMPLETION_FRAME),
                       _variant(name, ent.COMPLETION_ACCEPTED))]

    def flow(name: str) -> list[rrb.View]:
        return [_image(f"{name}: local flow", _variant(name, ent.COMPLETION_FLOW_IMAGE),
                       _variant(name, ent.COMPLETION_FLOW_ARROWS)),
                _map(f"{name}: FMM order", _variant(name, ent.COMPLETION_FMM_ORDER)),
                _map(f"{name}: FMM arrival", _variant(name, ent.COMPLETION_FMM_ARRIVAL))]

    def deblurring(name: str) -> list[rrb.View]:
        return [_image(f"{name}: deblurred", _variant(name, ent.DEBLUR_AFTER), _variant(name, ent.DEBLUR_SOURCE)),
                _image(f"{name}: weights", _variant(name, ent.DEBLUR_WEIGHTS))]

    def keys() -> rrb.Container:  # a container of its own in each tab (a blueprint's parts have one place each)
        return rrb.Vertical(*[_key(key, key.replace("_", " ")) for key in ("diff", "source", "filled_by", "accepted",
                                                                            "variance", "fmm_order", "deblur_weights")],
                            rrb.TextDocumentView(name="how to read", origin=f"/{ent.note_entity('debug')}"))

    stages = dict(zip(debug_tabs(), (output, fill, mosaic, flow, deblurring)))
    tabs = [rrb.Horizontal(_variant_columns(names, title, views), keys(), column_shares=[5, 1], name=title)
            for title, views in stages.items()]
    if paths:  # the original path and each variant's planned one, per axis
        tabs.append(rrb.Vertical(*[rrb.TimeSeriesView(name=f"camera path {axis} ({unit}): original and each variant's",
                                                      origin=f"/{VARIANTS}", contents=[f"/{VARIANTS}/**/{axis}"])
                                   for axis, unit in (("x", "px"), ("y", "px"), ("angle", "deg"))], name="path"))
    tabs.append(rrb.Vertical(*[rrb.TextDocumentView(name=name, origin=f"/{_variant(name, 'about')}") for name in names],
                             name="settings"))
    return rrb.Blueprint(rrb.Tabs(*tabs, active_tab=0),
                         rrb.TimePanel(state="collapsed", timeline=ent.FRAME_TIMELINE, play_state="paused"),
                         collapse_panels=True)
