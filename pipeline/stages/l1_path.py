"""L1-optimal camera paths (Grundmann, Kwatra and Essa, CVPR 2011), beside eq. 18's Gaussian smoothing.

The original path is C_t = C_{t-1} F_t, F_t = ``prev_from_curr`` of frame t. The smooth path is P_t = C_t B_t with
B_t the update transform (``orig_from_stab``: stabilized pixel -> input pixel), a similarity about the frame centre:
B(u) = c + (x, y) + e^s R(r) (u - c), in units of the half-diagonal (every number near 1; a unit of any parameter
moves a frame corner by about one unit). Grundmann et al.'s residual R_t = F_{t+1} B_{t+1} - B_t is D P in frame t's
coordinates (P_{t+1} - P_t = C_t R_t): its translation is linear in (x, y); its rotation and log scale are
r_F + r_{t+1} - r_t and s_F + s_{t+1} - s_t, additive, so rotation and zoom do not leak into each other. One
linear program (HiGHS, scipy.optimize.linprog) then

    minimises  w1 |R|_1 + w2 |D R|_1 + w3 |D^2 R|_1  (R_t's four numbers weighted alike)
               + w_shake |P_rxy - L P_rxy|_1  (optional)

and gives still, constant-velocity and constant-acceleration pieces: a tripod, a dolly, a smooth pan, where a
low-pass keeps a slow wander. The optional shake term prices the shake directly (P's rotation, x and y minus their
local linear fit over half a second, the jitter measure's high-pass): it tells an abrupt pan start from one spread
over half a second, which |D R| prices alike. Only local F_t enter: nothing accumulates over a long shot. Constraints:
- margins (full mode): |x|, |y|, |r|, |s| bounded: how far a frame may depart from its input (completion fills
  what the departure uncovers); the parameters are then independent and solved as three smaller programs;
- crop window (crop mode): the corners of the centred window of scale z, mapped by B_t, stay inside frame t:
  linear in (a, b, x, y) = (e^s cos r, e^s sin r, x, y), written with a = 1 + s, b = r and the edge moved in by
  the bound of that linearisation's error over the box, so no output pixel lies outside its input, by construction.
Ties go to the path nearest the input (a cost too small to buy motion). Long shots are solved in overlapping
windows, the first frames of each pinned to the previous solution: time and memory grow linearly with length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.errors import ConfigError

# Grundmann et al.'s weights: constant-velocity and constant-acceleration pieces are cheap, jerk is expensive.
WEIGHTS = (10.0, 1.0, 100.0)
# Cost of each |B_t - I| parameter a frame, times the smallest weight: over a 600-frame window it cannot pay for
# one unit of motion, so it only chooses among equally smooth paths the one nearest the input.
DEPARTURE_WEIGHT = 1e-4
# Tripod: how far a held frame may depart from its input before the path has to move (completion fills the rest).
TRIPOD_MARGIN_FRACTION = 0.1
TRIPOD_MARGIN_DEG = 4.0
TRIPOD_MARGIN_SCALE = 0.08
CROP_EDGE_PX = 0.5  # the crop window's corners are kept this far inside the input frame's outer pixel centres
# The shake term is priced on every SHAKE_STRIDE-th frame (at SHAKE_STRIDE times the weight) and its fit reaches
# SHAKE_REACH sigmas: the shake of neighbouring frames overlaps over the fit's half second, so both cut the program's
# time at the same steadiness (docs/decisions.md D33).
SHAKE_STRIDE = 2
SHAKE_REACH = 2.5
# The parameters whose shake is priced: rotation, x and y (indices into (s, r, x, y)). With x and y alone the program
# bought translation room by turning the frames; the zoom is left to Grundmann et al.'s terms, since pricing its shake
# too made the output shakier (docs/decisions.md D33).
SHAKE_PARAMETERS = (1, 2, 3)


@dataclass(frozen=True)
class L1PathConfig:
    """How far an output frame may depart from its input, per parameter, and the program's window."""

    margin_fraction: float = 0.03  # translation bound (x and y) as a fraction of the frame's longer side
    margin_deg: float = 2.0  # degrees: rotation bound
    margin_scale: float = 0.04  # relative zoom bound (0.04: 4 %)
    window: int = 600  # frames per program; longer shots are solved in overlapping windows
    overlap: int = 90  # frames a window shares with the previous one (the first half pinned)
    weights: tuple[float, float, float] = WEIGHTS  # of |R|, |D R|, |D^2 R| in the program's cost (no unit)
    # Crop mode: the window of this scale of the frame, centred crop_offset px from the frame's centre, stays inside
    # every input frame. The translation margin is then this share of the room the window leaves (1: the window
    # alone bounds it); rotation and zoom keep their margins.
    crop_scale: float | None = None
    crop_room_share: float = 1.0
    crop_offset: tuple[float, float] = (0.0, 0.0)  # the window's centre from the frame's centre (px, x and y)
    # Crop mode: how far (log scale) a frame may zoom in past the window. A constant zoom-in costs the program nothing
    # and buys the path room by cropping more than the window, so it is bounded: 0 (never), or as far as the path the
    # window was taken from zooms in (so that path stays feasible).
    crop_zoom_in: float = 0.0
    # Weight of the shake term |P_rxy - L P_rxy|_1 (per frame, rotation, x and y each, in R's units); 0: Grundmann et
    # al.'s program alone. L: a local linear fit with Gaussian weights of shake_sigma_frames (the jitter measure's
    # half second: 15 frames at 30 fps) within SHAKE_REACH sigmas.
    shake_weight: float = 0.0
    shake_sigma_frames: float = 15.0

    @classmethod
    def tripod(cls) -> L1PathConfig:
        """The camera held still: only |R| costs, so the path is constant wherever a constant stays within
        the (wider) margin, and moves, by as little as it can, only where the input camera went further."""
        return cls(margin_fraction=TRIPOD_MARGIN_FRACTION, margin_deg=TRIPOD_MARGIN_DEG,
                   margin_scale=TRIPOD_MARGIN_SCALE, weights=(1.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        if not (self.margin_fraction >= 0 and self.margin_deg >= 0 and self.margin_scale >= 0):
            raise ConfigError("l1 path margins must be >= 0 (0: that parameter follows the input)")
        if self.window < 8 or not 4 <= self.overlap < self.window // 2:
            raise ConfigError(f"l1 path window {self.window} / overlap {self.overlap}: need window >= 8 and "
                             f"4 <= overlap < window / 2")
        if self.crop_scale is not None and not 0.05 <= self.crop_scale <= 1.0:
            raise ConfigError(f"crop scale must be in [0.05, 1], not {self.crop_scale}")
        if not self.crop_zoom_in >= 0.0:
            raise ConfigError(f"crop zoom-in must be >= 0, not {self.crop_zoom_in}")
        if not (self.shake_weight >= 0.0 and self.shake_sigma_frames > 0.0):
            raise ConfigError(f"shake weight must be >= 0 and its sigma > 0, not {self.shake_weight} / "
                             f"{self.shake_sigma_frames}")
        if not 0.0 <= self.crop_room_share <= 1.0:
            raise ConfigError(f"crop room share must be in [0, 1], not {self.crop_room_share}")


@dataclass(frozen=True)
class _Frame:
    """Normalised coordinates: u_hat = (u - centre) / half_diagonal."""

    width: int
    height: int

    @property
    def half_diagonal(self) -> float:
        return max(math.hypot(self.width - 1, self.height - 1) / 2.0, 1e-9)

    @property
    def to_hat(self) -> np.ndarray:
        l, cx, cy = self.half_diagonal, (self.width - 1) / 2.0, (self.height - 1) / 2.0
        return np.array([[1 / l, 0, -cx / l], [0, 1 / l, -cy / l], [0, 0, 1.0]])


def orig_from_stab(curr_from_prev: np.ndarray, config: L1PathConfig, width: int, height: int) -> np.ndarray:
    """(N, 3, 3) update transforms B_t = S_t of one shot from its inter-frame transforms (N, 3, 3; [0] unused)."""
    frame = _Frame(width, height)
    to_hat = frame.to_hat
    from_hat = np.linalg.inv(to_hat)
    n = len(curr_from_prev)
    # F_hat_t (t >= 1): the affine part of prev_from_curr in normalised coordinates.
    f_hat = np.zeros((n, 2, 3))
    f_hat[0, :, :2] = np.eye(2)
    for t in range(1, n):
        m = to_hat @ np.linalg.inv(curr_from_prev[t]) @ from_hat
        f_hat[t] = (m / m[2, 2])[:2]
    # C_t's rotation and log scale (summed over the shot): R_t's translation is taken by them into the shot's first
    # frame's axes, where a constant-velocity pan is a constant D P (in frame t's the camera's roll would shake it).
    p, q = (f_hat[:, 0, 0] + f_hat[:, 1, 1]) / 2.0, (f_hat[:, 1, 0] - f_hat[:, 0, 1]) / 2.0
    steps = np.column_stack([np.arctan2(q, p), np.log(np.maximum(np.hypot(p, q), 1e-9))])
    steps[0] = 0.0
    c_angle = np.cumsum(steps, axis=0)  # (N, 2): angle, log scale
    lower, upper = _bounds(n, config, frame)
    # Full mode: (s), (r) and (x, y) share no residual and no constraint, so three smaller programs.
    groups = [[0, 1, 2, 3]] if config.crop_scale is not None else [[0], [1], [2, 3]]
    params = np.empty((n, 4))
    if n <= config.window:
        for g in groups:
            params[:, g] = _solve(f_hat, c_angle, lower, upper, config, frame, g)
    else:
        pinned, start = config.overlap // 2, 0
        while True:
            stop = min(start + config.window, n)
            lo, hi = lower[start:stop].copy(), upper[start:stop].copy()
            if start > 0:  # continuity: the first frames keep the previous window's solution
                lo[:pinned] = hi[:pinned] = params[start:start + pinned]
            for g in groups:
                params[start:stop, g] = _solve(f_hat[start:stop], c_angle[start:stop], lo, hi, config, frame, g)
            if stop == n:
                break
            start = stop - config.overlap
    out = np.empty((n, 3, 3))
    for t, (log_scale, angle, x, y) in enumerate(params):
        a, b = math.exp(log_scale) * math.cos(angle), math.exp(log_scale) * math.sin(angle)
        out[t] = from_hat @ np.array([[a, -b, x], [b, a, y], [0.0, 0.0, 1.0]]) @ to_hat
    return out


def _bounds(n: int, config: L1PathConfig, frame: _Frame) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4) lower and upper bounds of (s, r, x, y): the margins (full mode) or the crop's room (crop mode)."""
    l = frame.half_diagonal
    zoom = math.log1p(config.margin_scale)
    turn = math.radians(min(config.margin_deg, 45.0))
    if config.crop_scale is None:
        shift = config.margin_fraction * max(frame.width, frame.height) / l
        lower, upper = [-zoom, -turn, -shift, -shift], [zoom, turn, shift, shift]
    else:
        room = (1.0 - config.crop_scale) / 2.0
        ox, oy = (abs(v) for v in config.crop_offset)
        sx = config.crop_room_share * (room * (frame.width - 1) + ox) / l
        sy = config.crop_room_share * (room * (frame.height - 1) + oy) / l
        # zoomed in past the window at most crop_zoom_in (zoomed out, the corners' constraints bound it)
        lower, upper = [-min(config.crop_zoom_in, zoom), -turn, -sx, -sy], [zoom, turn, sx, sy]
    return np.tile(lower, (n, 1)), np.tile(upper, (n, 1))


def _solve(f_hat: np.ndarray, c_angle: np.ndarray, lower: np.ndarray, upper: np.ndarray, config: L1PathConfig,
           frame: _Frame, group: list[int]) -> np.ndarray:
    """(n, len(group)) values of the parameters ``group`` (indices into (s, r, x, y)) over one window, the others'
    residuals left out (they share none with these). Each |v| is written v = e+ - e- with e+, e- >= 0 at the cost
    of their sum: one equality row per number. Variables: the parameters, then the e+ of R's numbers for each
    difference order used and of the departures from the input, then their e-."""
    import scipy.optimize  # here, not at the top: ~0.5 s of start-up a run on eq. 18's path does not need
    import scipy.sparse as sp
    n, k = len(f_hat), len(group)
    lower, upper = lower[:, group], upper[:, group]
    if n < 2 or np.all(lower == upper):
        return np.clip(np.zeros((n, k)), lower, upper)
    matrix, offset = _residual(f_hat, c_angle)  # R = matrix @ q + offset over all four parameters
    columns = (4 * np.arange(n)[:, None] + np.asarray(group)[None, :]).ravel()
    rows = (4 * np.arange(n - 1)[:, None] + np.asarray(group)[None, :]).ravel()
    residual, offset = matrix[rows][:, columns], offset[rows]
    blocks, costs = [], []
    for order, weight in enumerate(config.weights):
        if weight <= 0 or n - 1 - order < 1:
            continue
        diff = sp.kron(_difference(n - 1, order), sp.identity(k), format="csr")  # D^order over the R_t
        blocks.append((diff @ residual, diff @ offset))
        costs.append(np.full(blocks[-1][0].shape[0], weight))
    if config.shake_weight > 0 and n > 2:
        # P - L P of rotation, x and y: R's angle is P's angle step and R's translation is already in the shot's first
        # frame's axes, so the running sums of those rows of R are P's rotation, x and y (up to P_0, which L keeps)
        shake = _shake_operator(n, config.shake_sigma_frames)[::SHAKE_STRIDE]
        for position in (i for i, parameter in enumerate(group) if parameter in SHAKE_PARAMETERS):
            picked = np.arange(n - 1) * k + position
            blocks.append((shake @ residual[picked], shake @ offset[picked]))
            costs.append(np.full(shake.shape[0], config.shake_weight * SHAKE_STRIDE))
    blocks.append((sp.identity(k * n, format="csr"), np.zeros(k * n)))  # the departure from the input (q = 0)
    costs.append(np.full(k * n, DEPARTURE_WEIGHT * min(w for w in config.weights if w > 0)))
    n_q, n_slack = k * n, sum(len(c) for c in costs)
    n_vars = n_q + 2 * n_slack
    plus = sp.identity(n_slack, format="csr")
    a_eq = sp.hstack([sp.vstack([m for m, _ in blocks]), -plus, plus], format="csr")
    b_eq = -np.concatenate([m0 for _, m0 in blocks])
    a_ub = b_ub = None
    if config.crop_scale is not None:  # group is all four parameters
        crop, b_ub = _crop_rows(n, config.crop_scale, config.crop_offset, frame, lower[0], upper[0])
        a_ub = sp.hstack([crop, sp.csr_matrix((crop.shape[0], n_vars - n_q))], format="csr")
    cost = np.concatenate([np.zeros(n_q), *costs, *costs])
    bounds = np.column_stack([np.r_[lower.ravel(), np.zeros(n_vars - n_q)],
                              np.r_[upper.ravel(), np.full(n_vars - n_q, np.inf)]])
    # HiGHS's interior point (with crossover): the same optimum as its default (the dual simplex here) within
    # 0.1 px of a frame corner, in about two thirds of the time on long crop-window programs. It can stop on a
    # numerical error (HiGHS status 4) where the dual simplex solves the same program; falling through to the input
    # path would instead jump at a pinned window's first frames.
    for method in ("highs-ipm", "highs-ds"):
        result = scipy.optimize.linprog(cost, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=bounds,
                                        method=method)
        if result.status == 0 and result.x is not None:
            break
    if result.status != 0 or result.x is None:  # cannot happen: the input path (q = 0) is feasible; stay safe
        return np.clip(np.zeros((n, k)), lower, upper)
    return np.clip(result.x[:n_q].reshape(n, k), lower, upper)


def _residual(f_hat: np.ndarray, c_angle: np.ndarray):
    """R_t = F_{t+1} B_{t+1} - B_t for t = 0 .. n-2 as a (4 (n-1), 4 n) sparse matrix over q = (s, r, x, y) per frame
    and a (4 (n-1),) offset. Its log scale and rotation are F's (of its similarity part) plus B_{t+1}'s minus B_t's;
    its translation is F's linear part times (x, y)_{t+1} plus F's translation, minus (x, y)_t, turned and scaled by
    C_t's rotation and log scale ``c_angle[t]``."""
    import scipy.sparse as sp
    n = len(f_hat)
    f = f_hat[1:]
    p, q = (f[:, 0, 0] + f[:, 1, 1]) / 2.0, (f[:, 1, 0] - f[:, 0, 1]) / 2.0
    forward = np.zeros((n - 1, 4, 4))
    forward[:, 0, 0] = forward[:, 1, 1] = 1.0
    turn = np.zeros((n - 1, 4, 4))
    turn[:, 0, 0] = turn[:, 1, 1] = 1.0
    zoom = np.exp(c_angle[:-1, 1])
    cos, sin = zoom * np.cos(c_angle[:-1, 0]), zoom * np.sin(c_angle[:-1, 0])
    turn[:, 2, 2], turn[:, 2, 3], turn[:, 3, 2], turn[:, 3, 3] = cos, -sin, sin, cos
    forward[:, 2:, 2:] = turn[:, 2:, 2:] @ f[:, :, :2]
    nxt = sp.block_diag(list(forward), format="csr")  # acting on q_1 .. q_{n-1}
    now = sp.block_diag(list(turn), format="csr")  # acting on q_0 .. q_{n-2}
    zeros = sp.csr_matrix((4 * (n - 1), 4))
    matrix = sp.hstack([zeros, nxt], format="csr") - sp.hstack([now, zeros], format="csr")
    shift = np.einsum("tij,tj->ti", turn[:, 2:, 2:], f[:, :, 2])
    offset = np.column_stack([np.log(np.maximum(np.hypot(p, q), 1e-9)), np.arctan2(q, p), shift])
    return matrix, offset.ravel()


def _crop_rows(n: int, scale: float, offset: tuple[float, float], frame: _Frame, lower: np.ndarray,
               upper: np.ndarray):
    """Inequalities (rows over q, bounds) keeping the window's corners, mapped by each B_t, inside the frame: the
    window of ``scale`` centred ``offset`` px from the frame's centre. A corner w maps to (a wx - b wy + x,
    b wx + a wy + y), written with a = 1 + s and b = r; over the box ``lower``..``upper`` of (s, r) that is off by at
    most err_a |wx| + err_b |wy| (x; swapped for y), which moves the edge in: the exact corners stay inside."""
    import scipy.sparse as sp
    l = frame.half_diagonal
    hx, hy = (frame.width - 1) / 2.0 / l, (frame.height - 1) / 2.0 / l
    s_max = max(abs(lower[0]), abs(upper[0]))
    r_max = max(abs(lower[1]), abs(upper[1]))
    err_a = max(math.exp(s) - 1.0 - s for s in (lower[0], upper[0])) + math.exp(s_max) * (1.0 - math.cos(r_max))
    err_b = math.expm1(s_max) * math.sin(r_max) + (r_max - math.sin(r_max))
    ox, oy = offset[0] / l, offset[1] / l
    zx, zy = scale * hx, scale * hy
    rows = []
    # The largest and smallest of each coordinate over the corners: with a > 0, on the two corners of that side.
    for sign in (1.0, -1.0):
        wx = ox + sign * zx
        for wy in (oy - zy, oy + zy):  # sign * x = sign (wx (1 + s) - wy r + x)
            rows.append(([sign * wx, -sign * wy, sign, 0.0],
                         hx - CROP_EDGE_PX / l - err_a * abs(wx) - err_b * abs(wy) - sign * wx))
        wy = oy + sign * zy
        for wx in (ox - zx, ox + zx):  # sign * y = sign (wx r + wy (1 + s) + y)
            rows.append(([sign * wy, sign * wx, 0.0, sign],
                         hy - CROP_EDGE_PX / l - err_b * abs(wx) - err_a * abs(wy) - sign * wy))
    block = np.array([row for row, _ in rows])  # (8, 4)
    matrix = sp.kron(sp.identity(n), sp.csr_matrix(block), format="csr")
    return matrix, np.tile([bound for _, bound in rows], n)


def _shake_operator(n: int, sigma: float):
    """(n, n - 1) sparse K with K @ R = P - L P, for a path P_t = R_0 + .. + R_{t-1} (P_0 = 0): the path minus its
    local linear fit at each frame, Gaussian weights of ``sigma`` frames within SHAKE_REACH sigmas (truncated at the
    ends and the fit refitted there, so a constant velocity gives exactly 0 everywhere, the ends included). The
    fit's weights on P_j sum to 1, so K[t, i] = [i < t] - (those weights on the P_j with j > i): 0 for any i
    further from t than the fit reaches, which keeps K banded."""
    import scipy.sparse as sp
    radius = max(int(SHAKE_REACH * sigma + 0.5), 1)
    rows, columns, values = [], [], []
    for t in range(n):
        lo, hi = max(t - radius, 0), min(t + radius, n - 1)
        offsets = np.arange(lo - t, hi - t + 1, dtype=np.float64)
        gauss = np.exp(-offsets ** 2 / (2.0 * sigma ** 2))
        s0, s1, s2 = gauss.sum(), gauss @ offsets, gauss @ offsets ** 2
        det = s0 * s2 - s1 * s1
        fit = gauss * (s2 - s1 * offsets) / det if det > 1e-12 else gauss / s0  # the fit's value at t: fit @ P
        later = np.cumsum(fit[::-1])[::-1]  # later[m]: the fit's weight on P_lo+m .. P_hi, i.e. on R_{lo+m-1}
        i = np.arange(lo - 1, hi)
        coefficient = (i < t) - later
        keep = (i >= 0) & (i <= n - 2) & (np.abs(coefficient) > 1e-12)
        rows.append(np.full(int(keep.sum()), t))
        columns.append(i[keep])
        values.append(coefficient[keep])
    return sp.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(columns))), shape=(n, n - 1))


def _difference(n: int, order: int):
    """(n - order, n) forward difference of the given order (order 0: the identity)."""
    import scipy.sparse
    coefficients = [math.comb(order, j) * (-1) ** (order - j) for j in range(order + 1)]
    return scipy.sparse.diags([float(c) for c in coefficients], list(range(order + 1)), shape=(n - order, n),
                              format="csr", dtype=np.float64)


def similarity(parameters, width: int, height: int) -> np.ndarray:
    """3x3 similarity about the frame centre with parameters (x, y) px, angle (rad), log scale."""
    x, y, angle, log_scale = parameters
    s = math.exp(log_scale)
    c, n = s * math.cos(angle), s * math.sin(angle)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    # Maps the centre to centre + (x, y), rotating and scaling about it.
    return np.array([[c, -n, cx + x - (c * cx - n * cy)], [n, c, cy + y - (n * cx + c * cy)], [0.0, 0.0, 1.0]])
