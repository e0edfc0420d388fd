"""The layout a recording opens with: frames side by side, trajectories original vs smoothed, motion, log."""

from __future__ import annotations

import rerun.blueprint as rrb

from ffviz import entities as ent


def _trajectory_view(axis: str, unit: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        name=f"trajectory {axis} ({unit}): original vs smoothed",
        origin="/motion/trajectory",
        contents=[f"/{ent.TRAJECTORY_ORIGINAL}/{axis}", f"/{ent.TRAJECTORY_SMOOTHED}/{axis}"],
    )


def default_blueprint() -> rrb.Blueprint:
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
                rrb.Vertical(trajectories, name="trajectories"),
                rrb.Vertical(motion, name="motion"),
                rrb.TextDocumentView(name="about", origin=f"/{ent.META}"),
            ),
            rrb.TextLogView(name="warnings", origin=f"/{ent.LOG}"),
            row_shares=[5, 1],
        ),
        rrb.TimePanel(state="expanded"),
        collapse_panels=True,
    )
