"""Entity paths and timelines of every ffviz recording: one place, shared by recorder, blueprint and figures."""

FRAME_TIMELINE = "frame"
VIDEO_TIME_TIMELINE = "video_time"

META = "meta"
LOG = "log"

INPUT_FRAME = "input/frame"

MOTION_PARAMS = "motion/params"  # /{dx,dy,angle,scale}: curr_from_prev decomposed
MOTION_INLIERS = "motion/inliers"
MOTION_INLIER_RATIO = "motion/inlier_ratio"
MOTION_RESIDUAL = "motion/residual_px"
MOTION_STATUS = "motion/status"
MOTION_FEATURES = "motion/features"  # /points (tracked corners in frame t), /arrows (prev -> curr)
TRAJECTORY_ORIGINAL = "motion/trajectory/original"  # /{x,y,angle}
TRAJECTORY_SMOOTHED = "motion/trajectory/smoothed"
TRAJECTORY_AXES = ("x", "y", "angle")
MOTION_PARAM_NAMES = ("dx", "dy", "angle", "scale")

STABILIZED_FRAME = "stabilized/frame"
STABILIZED_MISSING = "stabilized/missing"

OUTPUT_FRAME = "output/frame"

COMPLETION_VARIANCE = "completion/mosaic/variance"
COMPLETION_ACCEPTED = "completion/mosaic/accepted"
COMPLETION_FLOW_IMAGE = "completion/flow/image"  # colour-coded local flow (first neighbour), inpainted area included
COMPLETION_FLOW_ARROWS = "completion/flow/arrows"
COMPLETION_FMM_ORDER = "completion/fmm/order"
COMPLETION_FMM_ARRIVAL = "completion/fmm/arrival"
COMPLETION_FILLED_BY = "completion/filled_by"
COMPLETION_FALLBACK = "completion/fallback"
COMPLETION_FRAME = "completion/frame"
COMPLETION_STATS = "completion/stats"  # /{missing,mosaic,local_warp,fallback}: fraction of the frame
