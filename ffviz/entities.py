"""Entity paths and timelines of every ffviz recording: one place, shared by recorder, blueprint and figures."""

FRAME_TIMELINE = "frame"
VIDEO_TIME_TIMELINE = "video_time"

META = "meta"
SIZES = "meta/sizes"  # static: input_size and recorded_size, (width, height) each (the layout follows the aspect)
LOG = "log"

INPUT_FRAME = "input/frame"

MOTION_PARAMS = "motion/params"  # /{dx,dy,angle,scale}: curr_from_prev decomposed
MOTION_INLIERS = "motion/inliers"
MOTION_INLIER_RATIO = "motion/inlier_ratio"
MOTION_RESIDUAL = "motion/residual_px"
MOTION_STATUS = "motion/status"
MOTION_FEATURES = "motion/features"  # /points (tracked corners in frame t), /arrows (prev -> curr)
MOTION_FOREGROUND = "motion/features/foreground"  # tracks of the other motion, a moving object's (orange points)
MOTION_IGNORED = "motion/features/ignored"  # where the pair's earlier frame's features were not used (--ignore*)
MOTION_CAMERA = "motion/camera"  # /{occlusion,linked}: log-odds for the motion taken as the camera's (Scalars)
MOTION_CAMERA_RULE = "motion/camera/rule"  # which motion was taken and what weighed most (TextLog, each pair)
MOTION_CAMERA_EVIDENCE = ("occlusion", "linked")
ROLLING_SHUTTER_BANDS = "motion/features/rolling_shutter"  # each band's view against the middle row's (arrows)
ROLLING_SHUTTER_SKEW = "motion/rolling_shutter"  # /{dx,dy}: bottom band's shift against the top band's, px
TRAJECTORY_ORIGINAL = "motion/trajectory/original"  # /{x,y,angle,zoom}
TRAJECTORY_SMOOTHED = "motion/trajectory/smoothed"
TRAJECTORY_GAUSSIAN = "motion/trajectory/gaussian"  # eq. 18's path on the same motion, whichever the run follows
TRAJECTORY_L1 = "motion/trajectory/l1"  # the L1 program's
TRAJECTORY_AXES = ("x", "y", "angle", "zoom")  # px, px, degrees, % of the shot's first frame's scale
PATH_SETTING = "motion/trajectory/setting"  # index of the path setting each frame was planned with (Scalars)
PATH_SETTINGS = "motion/trajectory/settings"  # the settings, one a line, in the command line's words (static text)
MOTION_PARAM_NAMES = ("dx", "dy", "angle", "scale")

STABILIZED_FRAME = "stabilized/frame"
STABILIZED_MISSING = "stabilized/missing"

OUTPUT_FRAME = "output/frame"
CROP_WINDOW = "stabilized/crop"  # --mode crop: the window kept of every stabilized frame (Boxes2D, static;
# per frame with --crop adaptive)
CROP_SCALE = "stabilized/crop_scale"  # --mode crop: the window's scale per frame (Scalars)
CROP_CONSTRAINT = "input/frame/crop_window"  # --mode crop: the output's corners in each input frame (LineStrips2D)
CROP_ROOM = "stabilized/crop_room"  # --mode crop: how far inside its input frame the window's nearest corner is (px)

# Frame streams: H.264 VideoStream by default (lossy, ~0.01 MB a frame); raw images with --lossless.
# deblur/before and deblur/after are sparse video streams too (sharpened frames only, cleared in between).
FRAME_STREAMS = (INPUT_FRAME, "stabilized/frame", "completion/frame", OUTPUT_FRAME, "deblur/before", "deblur/after")

# Float maps' values (at map_values(entity)) are stored as 16-bit PNG (EncodedDepthImage): stored = round(value /
# step) + 1, 0 = no value, clipped at 65535. With --lossless they are float32 DepthImages, exact.
MAP_STEPS = {"completion/mosaic/variance": 0.25,  # intensity^2 (0..255 scale); up to 16383.5
             "completion/fmm/order": 4.0,  # visiting order, to 4 pixels (shown as a share); up to 262132 pixels
             "completion/fmm/arrival": 0.01}  # Fast Marching arrival time T, px; up to 655 px
MAP_UNITS = {"completion/mosaic/variance": "intensity^2", "completion/fmm/order": "pixels filled before",
             "completion/fmm/arrival": "px"}


def map_values(entity: str) -> str:
    """Where a float map's values are (MAP_STEPS); ``entity`` itself holds the picture the views show: the map
    colour-mapped, transparent where it has no value (a depth image would show those as its lowest colour)."""
    return f"{entity}/values"


# Colour keys: small static images beside the views that show a colour-mapped image.
KEYS = "keys"


def key_entity(name: str) -> str:
    return f"{KEYS}/{name}"


NOTES = "notes"  # static markdown, one per tab


def note_entity(tab: str) -> str:
    """The tab's note; the tab's name made a path part (``local flow + motion inpainting`` -> ``local_flow_motion_inpainting``)."""
    return f"{NOTES}/" + "_".join(w for w in tab.replace("+", " ").split())

COMPLETION_VARIANCE = "completion/mosaic/variance"
COMPLETION_ACCEPTED = "completion/mosaic/accepted"
COMPLETION_FLOW_IMAGE = "completion/flow/image"  # colour-coded local flow (first neighbour), inpainted area included
COMPLETION_FLOW_ARROWS = "completion/flow/arrows"
COMPLETION_FMM_ORDER = "completion/fmm/order"
COMPLETION_FMM_ARRIVAL = "completion/fmm/arrival"
COMPLETION_FILLED_BY = "completion/filled_by"
COMPLETION_FALLBACK = "completion/fallback"
COMPLETION_SOURCE = "completion/source"  # how each pixel was filled: CompletionResult.source's classes
COMPLETION_FRAME = "completion/frame"
COMPLETION_STATS = "completion/stats"  # /missing and /<each completion.SOURCE_NAMES but original>: share of the frame
# The mean share of the synthesized pixels' values averaged in from the neighbouring completed frames (temporal
# consistency, pipeline/stages/temporal.py): a chart of its own, its values an order of magnitude above the shares
# of the frame charted beside them
COMPLETION_TEMPORAL = "completion/temporal"

DEBLUR_BLURRINESS = "deblur/blurriness"  # b_t (eq. 28), every frame
DEBLUR_NEIGHBOURS = "deblur/neighbours"  # how many sharper neighbours were interpolated from (eq. 30)
DEBLUR_WEIGHTS = "deblur/weights"  # share of each output pixel from the neighbours (eq. 30): picture; uint8 at /values
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


# Every colour-mapped image and the key picture that explains its colours (tests check each is recorded).
KEY_OF = {
    STABILIZED_MISSING: "missing",
    COMPLETION_VARIANCE: "variance",
    COMPLETION_ACCEPTED: "accepted",
    COMPLETION_FLOW_IMAGE: "flow",
    COMPLETION_FMM_ORDER: "fmm_order",
    COMPLETION_FMM_ARRIVAL: "fmm_arrival",
    COMPLETION_FILLED_BY: "filled_by",
    COMPLETION_FALLBACK: "filled_by",
    COMPLETION_SOURCE: "source",
    DEBLUR_WEIGHTS: "deblur_weights",
    DEBLUR_SOURCE: "deblur_source",
}
