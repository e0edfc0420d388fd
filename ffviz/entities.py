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

DEBLUR_BLURRINESS = "deblur/blurriness"  # b_t (eq. 28), every frame
DEBLUR_NEIGHBOURS = "deblur/neighbours"  # how many sharper neighbours were interpolated from (eq. 30)
DEBLUR_WEIGHTS = "deblur/weights"  # share of each output pixel from the neighbours (eq. 30), uint8
DEBLUR_WEIGHTS_SCALE = 255.0  # deblur/weights value of a share of 1
DEBLUR_SOURCE = "deblur/source"  # per pixel: the neighbour that gave it most (eq. 30), or refused (other content)
DEBLUR_REFUSED = "deblur/refused"  # share of the frame where a sharper neighbour was refused, every frame
DEBLUR_BEFORE = "deblur/before"  # frames that were sharpened, before and after (cleared on the others)
DEBLUR_AFTER = "deblur/after"

# Stage stepping: chosen frames followed through every stage on their own timelines.
STAGE_TIMELINE = "stage"  # 0..5, index into TRACE_STAGES; rows also carry frame = the traced frame
FMM_STEP_TIMELINE = "fmm_step"  # 0..steps: the Fast Marching band advancing into the missing area (Fig. 18)
TRACE = "trace"
TRACE_STAGES = ("input", "stabilized", "mosaic", "motion-inpainted", "deblurred", "output")


def trace_image(frame: int) -> str:
    """The traced frame's image after each stage (timeline ``stage``)."""
    return f"{TRACE}/{frame}/image"


def trace_label(frame: int) -> str:
    """Boxes2D framing the image, labelled with the stage's name (timeline ``stage``)."""
    return f"{TRACE}/{frame}/label"


def trace_fmm(frame: int) -> str:
    """Motion inpainting of the first neighbour's flow, step by step (timeline ``fmm_step``)."""
    return f"{TRACE}/{frame}/fmm"


def trace_fmm_label(frame: int) -> str:
    return f"{TRACE}/{frame}/fmm_label"
