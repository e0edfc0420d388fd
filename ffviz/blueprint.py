"""The layout a recording opens with: frames side by side, completion, stage stepping of the traced frames,
deblurring, trajectories original vs smoothed, motion, log."""

from __future__ import annotations

from typing import Callable, Sequence

import rerun.blueprint as rrb

from ffviz import entities as ent


def _trajectory_view(axis: str, unit: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        name=f"trajectory {axis} ({unit}): original vs smoothed",
        origin="/motion/trajectory",
        contents=[f"/{ent.TRAJECTORY_ORIGINAL}/{axis}", f"/{ent.TRAJECTORY_SMOOTHED}/{axis}"],
    )


def _traced_tab(name: str, traced: Sequence[int], title: Callable[[int], str],
                contents: Callable[[int], Sequence[str]]) -> rrb.Container:
    """One view per traced frame (or a placeholder when none is traced)."""
    views = [rrb.Spatial2DView(name=title(t), origin=f"/{ent.TRACE}/{t}", contents=[f"/{e}" for e in contents(t)])
             for t in traced]
    if not views:
        views = [rrb.TextDocumentView(name="no traced frames", origin=f"/{ent.META}")]
    return rrb.Grid(*views, name=name)


def _stages_tab(traced: Sequence[int]) -> rrb.Container:
    """The traced frames step through the stages on the `stage` timeline."""
    return _traced_tab("stages", traced, lambda t: f"frame {t}: input -> ... -> output (select timeline 'stage')",
                       lambda t: [ent.trace_image(t), ent.trace_label(t)])


def _fmm_tab(traced: Sequence[int]) -> rrb.Container:
    return _traced_tab("motion inpainting", traced,
                       lambda t: f"frame {t}: motion inpainting, Fast Marching band (select timeline 'fmm_step')",
                       lambda t: [ent.trace_fmm(t), ent.trace_fmm_label(t)])


def _deblur_tab() -> rrb.Container:
    return rrb.Vertical(
        rrb.Horizontal(
            rrb.Spatial2DView(name="before deblurring", origin="/", contents=[f"/{ent.DEBLUR_BEFORE}"]),
            rrb.Spatial2DView(name="after deblurring (eq. 30)", origin="/", contents=[f"/{ent.DEBLUR_AFTER}"]),
            rrb.Spatial2DView(name="share from sharper neighbours (eqs. 30-31)", origin="/", contents=[f"/{ent.DEBLUR_WEIGHTS}"]),
            rrb.Spatial2DView(name="main source per pixel; red: refused, other content",
                              origin="/", contents=[f"/{ent.DEBLUR_BEFORE}", f"/{ent.DEBLUR_SOURCE}"]),
        ),
        rrb.Horizontal(
            rrb.TimeSeriesView(name="relative blurriness b_t (eq. 28)", origin=f"/{ent.DEBLUR_BLURRINESS}"),
            rrb.TimeSeriesView(name="sharper neighbours used", origin=f"/{ent.DEBLUR_NEIGHBOURS}"),
            rrb.TimeSeriesView(name="refused share of the frame", origin=f"/{ent.DEBLUR_REFUSED}"),
        ),
        name="deblur",
    )


def default_blueprint(traced: Sequence[int] = ()) -> rrb.Blueprint:
    """``traced``: the frames logged on the `stage`/`fmm_step` timelines (a view each)."""
    frames = rrb.Horizontal(
        rrb.Spatial2DView(name="input + tracked features", origin="/",
                          contents=[f"/{ent.INPUT_FRAME}", f"/{ent.MOTION_FEATURES}/**"]),
        rrb.Spatial2DView(name="stabilized (missing in red)", origin="/stabilized"),
        rrb.Spatial2DView(name="output", origin="/output"),
    )
    trajectories = rrb.Vertical(
        _trajectory_view("x", "px"), _trajectory_view("y", "px"), _trajectory_view("angle", "deg"),
    )
    motion = rrb.Vertical(
        rrb.TimeSeriesView(name="inter-frame motion (dx, dy px; angle deg; scale)", origin=f"/{ent.MOTION_PARAMS}"),
        rrb.Horizontal(
            rrb.TimeSeriesView(name="inliers", origin=f"/{ent.MOTION_INLIERS}"),
            rrb.TimeSeriesView(name="inlier ratio", origin=f"/{ent.MOTION_INLIER_RATIO}"),
            rrb.TimeSeriesView(name="residual (px)", origin=f"/{ent.MOTION_RESIDUAL}"),
        ),
    )
    completion = rrb.Grid(
        rrb.Spatial2DView(name="stabilized (missing in red)", origin="/stabilized"),
        rrb.Spatial2DView(name="mosaic variance (eq. 20)", origin="/", contents=[f"/{ent.COMPLETION_VARIANCE}"]),
        rrb.Spatial2DView(name="mosaic accepted (green) / rejected (red)", origin="/",
                          contents=[f"/{ent.STABILIZED_FRAME}", f"/{ent.COMPLETION_ACCEPTED}"]),
        rrb.Spatial2DView(name="local flow, motion-inpainted", origin="/completion/flow"),
        rrb.Spatial2DView(name="FMM visiting order", origin="/", contents=[f"/{ent.COMPLETION_FMM_ORDER}"]),
        rrb.Spatial2DView(name="FMM arrival time T", origin="/", contents=[f"/{ent.COMPLETION_FMM_ARRIVAL}"]),
        rrb.Spatial2DView(name="filled by (neighbour offset / mosaic / fallback)", origin="/",
                          contents=[f"/{ent.COMPLETION_FRAME}", f"/{ent.COMPLETION_FILLED_BY}", f"/{ent.COMPLETION_FALLBACK}"]),
        rrb.Spatial2DView(name="completed", origin="/", contents=[f"/{ent.COMPLETION_FRAME}"]),
        rrb.TimeSeriesView(name="fraction of frame: missing / mosaic / local warp / fallback",
                           origin=f"/{ent.COMPLETION_STATS}"),
        name="completion",
    )
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Tabs(
                rrb.Vertical(frames, name="frames"),
                completion,
                _stages_tab(traced),
                _fmm_tab(traced),
                _deblur_tab(),
                rrb.Vertical(trajectories, name="trajectories"),
                rrb.Vertical(motion, name="motion"),
                rrb.TextDocumentView(name="about", origin=f"/{ent.META}"),
            ),
            rrb.TextLogView(name="warnings", origin=f"/{ent.LOG}"),
            row_shares=[5, 1],
        ),
        rrb.TimePanel(state="expanded", timeline=ent.FRAME_TIMELINE),
        collapse_panels=True,
    )
