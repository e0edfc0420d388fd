"""The one table from result field to recording: every field of every result type the recorder receives, with the
entity paths it is recorded under, ``Nested`` (another type's row), or ``NotRecorded`` and why.

Keyed by type name, the rows are checked against the dataclasses themselves (tests/test_recording.py): a new field
fails that test until it is mapped here, and every entity named here must be in a full recording.
"""

from __future__ import annotations

from ffviz import entities as ent
from pipeline.stages.completion import SOURCE_NAMES


class NotRecorded(str):
    """A result field the recording leaves out, and why."""


class Nested(str):
    """A field whose value is another result type: recorded as that type's own row of RECORDED_FIELDS says."""


_MOTION_SERIES = tuple(f"{ent.MOTION_PARAMS}/{name}" for name in ent.MOTION_PARAM_NAMES)
_TRAJECTORY = {root: tuple(f"{root}/{axis}" for axis in ent.TRAJECTORY_AXES)
               for root in (ent.TRAJECTORY_ORIGINAL, ent.TRAJECTORY_SMOOTHED, ent.TRAJECTORY_GAUSSIAN, ent.TRAJECTORY_L1)}
_COMPLETION_STATS = tuple(f"{ent.COMPLETION_STATS}/{name.replace(' ', '_')}" for name in ("missing", *SOURCE_NAMES[1:]))

RECORDED_FIELDS: dict[str, dict[str, tuple[str, ...] | Nested | NotRecorded]] = {
    "MotionEstimate": {  # on_motion, every frame of pass 1
        "curr_from_prev": _MOTION_SERIES,
        "status": (ent.MOTION_STATUS,),
        "n_tracked": (ent.MOTION_INLIER_RATIO,),  # inliers / tracked
        "n_inliers": (ent.MOTION_INLIERS, ent.MOTION_INLIER_RATIO),
        "residual_px": (ent.MOTION_RESIDUAL,),
        "hist_distance": NotRecorded("cut detection's input; its decision is the status"),
        "warning": (ent.LOG,),
        "prev_points": (f"{ent.MOTION_FEATURES}/arrows",),
        "curr_points": (f"{ent.MOTION_FEATURES}/points", f"{ent.MOTION_FEATURES}/arrows"),
        "inliers": (f"{ent.MOTION_FEATURES}/points",),  # as the points' colours
        "others": Nested("OtherMotion"),
        "chose_other": (ent.LOG, ent.MOTION_CAMERA_RULE),
        "ignored": (ent.MOTION_IGNORED,),
        "camera": Nested("CameraChoice"),
    },
    "OtherMotion": {  # a motion the camera did not take (a figure's)
        "curr_from_prev": NotRecorded("a figure's motion; its effect is which motion the camera took"),
        "prev_points": NotRecorded("where its tracks start; their ends are drawn"),
        "curr_points": (ent.MOTION_FOREGROUND,),
        "carried": (ent.MOTION_CAMERA_RULE,),
    },
    "CameraChoice": {  # how the camera's motion was chosen (pipeline/stages/background.py)
        "taken": (ent.MOTION_CAMERA_RULE,),
        "rule": (ent.MOTION_CAMERA_RULE,),
        "occlusion": (f"{ent.MOTION_CAMERA}/occlusion",),
        "linked": (f"{ent.MOTION_CAMERA}/linked",),
        "behind": (ent.MOTION_CAMERA_RULE,),
        "in_front": (ent.MOTION_CAMERA_RULE,),
        "carried": (ent.MOTION_CAMERA_RULE,),
        "lost": (ent.MOTION_CAMERA_RULE,),
    },
    "PathPlan": {  # on_path, once
        "motion": Nested("MotionPass"),
        "smoothing": Nested("SmoothingResult"),
        "orig_from_out": NotRecorded("equal to the smoothed path but for the crop, both recorded"),
        "rolling_shutter": Nested("Correction"),
        "crop": Nested("CropWindow"),
        "adaptive_crop": Nested("AdaptiveCrop"),
        "warnings": (ent.LOG,),
        "paths": Nested("PathComparison"),
    },
    "PathComparison": {
        "gaussian": _TRAJECTORY[ent.TRAJECTORY_GAUSSIAN],
        "l1": _TRAJECTORY[ent.TRAJECTORY_L1],
        "crop_corners": (ent.CROP_CONSTRAINT,),
        "crop_room_px": (ent.CROP_ROOM,),
    },
    "MotionPass": {
        "curr_from_prev": NotRecorded("recorded frame by frame from on_motion"),
        "tracks": NotRecorded("the inlier tracks, recorded frame by frame from on_motion"),
        "statuses": NotRecorded("recorded frame by frame from on_motion"),
        "times_s": (ent.VIDEO_TIME_TIMELINE,),
        "warnings": (ent.LOG,),
    },
    "SmoothingResult": {
        "orig_from_stab": NotRecorded("chooses the traced frames; shown as the smoothed trajectory"),
        "segment_starts": NotRecorded("scene cuts; the trajectories restart there"),
        "original_trajectory": _TRAJECTORY[ent.TRAJECTORY_ORIGINAL],
        "smoothed_trajectory": _TRAJECTORY[ent.TRAJECTORY_SMOOTHED],
        "settings": (ent.PATH_SETTINGS,),
        "setting_of": (ent.PATH_SETTING,),
        "planner": NotRecorded("the settings' labels name it (auto's choice included)"),
    },
    "AdaptiveCrop": {
        "scales": (ent.CROP_SCALE, ent.CROP_WINDOW),
        "anchor": (ent.CROP_WINDOW,),
        "width": NotRecorded("the frame's size"),
        "height": NotRecorded("the frame's size"),
    },
    "CropWindow": {"x0": (ent.CROP_WINDOW,), "y0": (ent.CROP_WINDOW,),
                   "scale": (ent.CROP_WINDOW, ent.CROP_SCALE, ent.META)},
    "Correction": {  # --rolling-shutter
        "readout": (ent.LOG,),
        "rows": Nested("RowMotion"),
        "curr_from_prev": NotRecorded("the motions between corrected views; the trajectories are their sums"),
    },
    "RowMotion": {
        "readout": (ent.ROLLING_SHUTTER_BANDS, ent.ROLLING_SHUTTER_SKEW + "/dx", ent.ROLLING_SHUTTER_SKEW + "/dy"),
        "height": NotRecorded("the frame's size"),
        "velocity": (ent.ROLLING_SHUTTER_BANDS, ent.ROLLING_SHUTTER_SKEW + "/dx", ent.ROLLING_SHUTTER_SKEW + "/dy"),
        "acceleration": (ent.ROLLING_SHUTTER_BANDS, ent.ROLLING_SHUTTER_SKEW + "/dx",
                         ent.ROLLING_SHUTTER_SKEW + "/dy"),
    },
    "FrameResult": {  # on_frame, every frame of pass 2
        "stamp": Nested("Stamp"),
        "pts": NotRecorded("the container's timestamp; the recording is timed by frame and video_time"),
        "output": (ent.OUTPUT_FRAME,),
        "input": Nested("Frame"),
        "warp": Nested("WarpResult"),
        "completion": Nested("CompletionResult"),
        "deblur": Nested("DeblurResult"),
        "temporal": Nested("TemporalResult"),
        "completed": Nested("CompletedFrame"),
        "cpu_seconds": NotRecorded("per-stage CPU time, for ffviz bench --profile"),
        "digests": NotRecorded("observers' digests of the fields above; the recorder's holds what it records of them"),
    },
    "CompletedFrame": {  # held for temporal consistency only, dropped before the recorder sees it
        "frame": NotRecorded("completion's frame, recorded as CompletionResult.frame"),
        "synthesized": NotRecorded("completion's missing pixels, recorded as CompletionResult.missing"),
    },
    "TemporalResult": {
        "frame": NotRecorded("the output before deblurring's change to the synthesized pixels; the output is recorded"),
        "share": (ent.COMPLETION_TEMPORAL,),  # its mean over the synthesized pixels
        "neighbours": NotRecorded("always t-r..t+r of the same shot; the share says how much they gave"),
    },
    "Stamp": {"index": (ent.FRAME_TIMELINE,), "time_s": (ent.VIDEO_TIME_TIMELINE,)},
    "Frame": {
        "index": (ent.FRAME_TIMELINE,), "time_s": (ent.VIDEO_TIME_TIMELINE,),
        "pts": NotRecorded("the container's timestamp"),
        "rgb": (ent.INPUT_FRAME,),
    },
    "WarpResult": {
        "frame": (ent.STABILIZED_FRAME,),
        "missing": (ent.STABILIZED_MISSING,),
        "orig_from_out": NotRecorded("the smoothed path's matrix for this frame, recorded as the trajectory"),
    },
    "CompletionResult": {
        "frame": (ent.COMPLETION_FRAME,),
        "missing": (f"{ent.COMPLETION_STATS}/missing", ent.COMPLETION_ACCEPTED),
        "mosaic": Nested("MosaicResult"),
        "neighbour_order": NotRecorded("the order neighbours were tried in; filled_by shows which one served"),
        "fills": Nested("NeighbourFill"),
        "source": _COMPLETION_STATS + (ent.COMPLETION_SOURCE, ent.COMPLETION_FILLED_BY),
        "filled_by": (ent.COMPLETION_FILLED_BY,),
        "fallback": (ent.COMPLETION_FALLBACK,),
        "corrected": NotRecorded("mosaic pixels replaced by a local warp; shown within filled_by"),
        "registered": NotRecorded("neighbours whose warps local registration refined; their pixels are in filled_by"),
        "unregistered_mosaic": NotRecorded("made only on request: the evaluation's baseline without registration"),
    },
    "MosaicResult": {
        "frame": (ent.trace_image("*"),),  # traced frames' "mosaic" stage
        "variance": (ent.COMPLETION_VARIANCE, ent.map_values(ent.COMPLETION_VARIANCE)),
        "accepted": (ent.COMPLETION_ACCEPTED,),
        "remaining": NotRecorded("missing minus accepted, both recorded"),
        "coverage": NotRecorded("how many neighbours covered each pixel; the variance map shows where"),
    },
    "NeighbourFill": {  # the first neighbour's, as in the thesis's Fig. 18
        "offset": (ent.trace_fmm_label("*"),),
        "alignment_error": NotRecorded("orders the neighbours; not shown"),
        "pieces": Nested("FlowPiece"),
        "shape": NotRecorded("the frame's size"),
        "filled": (ent.COMPLETION_FILLED_BY,),
        "reached": NotRecorded("where this neighbour could fill; filled shows what it did"),
    },
    "FlowPiece": {
        "box": NotRecorded("where the piece lies; the flow image is assembled from the pieces"),
        "scale": NotRecorded("the flow's working resolution"),
        "flow": Nested("LocalFlowResult"),
        "inpainted": Nested("MotionInpaintResult"),
        "owned": NotRecorded("which part of the piece is its own"),
    },
    "LocalFlowResult": {
        "flow": NotRecorded("kept within the inpainted flow (measured where reliable, inpainted elsewhere)"),
        "common": NotRecorded("where both frames are known"),
        "reliable": NotRecorded("where the measured flow is kept; the rest is inpainted (fmm/order shows where)"),
    },
    "MotionInpaintResult": {
        "flow": (ent.COMPLETION_FLOW_IMAGE, ent.COMPLETION_FLOW_ARROWS),
        "order": (ent.COMPLETION_FMM_ORDER, ent.map_values(ent.COMPLETION_FMM_ORDER), ent.trace_fmm("*")),
        "arrival": (ent.COMPLETION_FMM_ARRIVAL, ent.map_values(ent.COMPLETION_FMM_ARRIVAL)),
        "filled": (ent.trace_fmm("*"),),
    },
    "DeblurResult": {
        "frame": (ent.DEBLUR_AFTER,),
        "before": (ent.DEBLUR_BEFORE,),
        "blurriness": (ent.DEBLUR_BLURRINESS,),
        "neighbours": (ent.DEBLUR_NEIGHBOURS,),
        "weights": (ent.DEBLUR_WEIGHTS, ent.map_values(ent.DEBLUR_WEIGHTS)),
        "ratios": NotRecorded("b_t / b_t' per neighbour compared; the blurriness series shows b_t"),
        "provenance": (ent.DEBLUR_SOURCE, ent.DEBLUR_REFUSED),
    },
}
