"""L1-optimal camera paths (Grundmann, Kwatra and Essa, CVPR 2011), beside eq. 18's Gaussian smoothing.

The original camera path of a shot is accumulated from the inter-frame transforms, C_t = first_from_t, and read
as four similarity parameters about the frame centre: x, y (px), angle (rad) and log scale. For each parameter
the smooth path P is the solution of one linear program,

    minimise  w1 |D P|_1 + w2 |D^2 P|_1 + w3 |D^3 P|_1   subject to  |P_t - C_t| <= margin_t,

with D the forward difference. The L1 norms make most differences exactly zero, so the path is a sequence of
still, constant-velocity and constant-acceleration pieces: what a viewer reads as a tripod, a dolly or a smooth
pan, where a low-pass keeps a slow wander. The margin bounds how far each output frame departs from its input
(completion fills what the departure uncovers); it replaces eq. 18's radius as the one control of how much is
smoothed. The parameters are independent under box constraints, so each is its own small program (HiGHS, through
scipy.optimize.linprog). Long shots are solved in overlapping windows, each window's first frames pinned to the
previous solution, so time and memory grow linearly with the length.

The correction of frame t is orig_from_stab_t = Sim(C_t)^-1 @ Sim(P_t), Sim the similarity of the four
parameters: where P_t = C_t it is the identity. Only similarity parts are corrected: a long shot's accumulated
shear or perspective drifts with the estimates' small errors, and undoing it would distort frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline import geometry
from pipeline.errors import ConfigError

# Grundmann et al.'s weights: constant-velocity and constant-acceleration pieces are cheap, jerk is expensive.
WEIGHTS = (10.0, 1.0, 100.0)
# Cost of |P - C| a frame, times the smallest weight: over a 600-frame window it cannot pay for one unit of
# motion (6e-2 < 1), so it only chooses among equally smooth paths the one nearest the input.
DEPARTURE_WEIGHT = 1e-4
# Tripod: how far a held frame may depart from its input before the path has to move (completion fills the rest).
TRIPOD_MARGIN_FRACTION = 0.1
TRIPOD_MARGIN_DEG = 4.0
TRIPOD_MARGIN_SCALE = 0.08


@dataclass(frozen=True)
class L1PathConfig:
    """How far an output frame may depart from its input, per parameter, and the program's window."""

    margin_fraction: float = 0.03  # translation bound (x and y) as a fraction of the frame's longer side
    margin_deg: float = 2.0  # rotation bound
    margin_scale: float = 0.04  # relative zoom bound
    window: int = 600  # frames per program; longer shots are solved in overlapping windows
    overlap: int = 90  # frames a window shares with the previous one (the first half pinned)
    weights: tuple[float, float, float] = WEIGHTS  # of |D P|, |D^2 P|, |D^3 P|

    @classmethod
    def tripod(cls) -> L1PathConfig:
        """The camera held still: only |D P| costs, so the path is constant wherever a constant stays within
        the (wider) margin, and moves, by as little as it can, only where the input camera went further."""
        return cls(margin_fraction=TRIPOD_MARGIN_FRACTION, margin_deg=TRIPOD_MARGIN_DEG,
                   margin_scale=TRIPOD_MARGIN_SCALE, weights=(1.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        if not (self.margin_fraction >= 0 and self.margin_deg >= 0 and self.margin_scale >= 0):
            raise ConfigError("l1 path margins must be >= 0 (0: that parameter follows the input)")
        if self.window < 8 or not 4 <= self.overlap < self.window // 2:
            raise ConfigError(f"l1 path window {self.window} / overlap {self.overlap}: need window >= 8 and "
                             f"4 <= overlap < window / 2")


def plan(original: np.ndarray, margin: float | np.ndarray, weights: tuple[float, float, float] = WEIGHTS, *,
         window: int = 600, overlap: int = 90) -> np.ndarray:
    """The L1-optimal path (N,) for one parameter's original path ``original`` (N,), within ``margin`` of it."""
    original = np.asarray(original, np.float64)
    n = len(original)
    margin = np.broadcast_to(np.asarray(margin, np.float64), (n,))
    if not np.any(margin > 0):
        return original.copy()  # nowhere to go: the path is the input's
    if n <= window:
        return _solve(original, original - margin, original + margin, weights)
    path = np.empty(n)
    pinned = overlap // 2
    start = 0
    while True:
        stop = min(start + window, n)
        lower, upper = original[start:stop] - margin[start:stop], original[start:stop] + margin[start:stop]
        if start > 0:  # continuity: the first frames keep the previous window's solution
            lower[:pinned] = upper[:pinned] = path[start:start + pinned]
        solved = _solve(original[start:stop], lower, upper, weights)
        path[start:stop] = solved
        if stop == n:
            return path
        start = stop - overlap


def _solve(original: np.ndarray, lower: np.ndarray, upper: np.ndarray, weights: tuple[float, float, float]
           ) -> np.ndarray:
    """One linear program: variables P (n), then slacks e1, e2, e3 of the differences of orders 1, 2, 3, then e0 of
    the departure |P - C|, at a cost too small to trade any smoothness for (DEPARTURE_WEIGHT): where many paths
    are equally smooth (a tripod's constant may sit anywhere within every margin) it picks the one nearest the
    input, not a corner of the feasible set."""
    import scipy.optimize  # here, not at the top: ~0.5 s of start-up a run on eq. 18's path does not need
    import scipy.sparse
    n = len(original)
    orders = [k for k in (1, 2, 3) if n > k]
    if not orders:
        return np.clip(original, lower, upper)
    # Work relative to the original's mean and scale, so that HiGHS sees numbers near 1.
    offset = float(np.mean(original))
    scale = max(float(np.max(upper - lower)), 1e-9)
    lo, hi = (lower - offset) / scale, (upper - offset) / scale
    sizes = [n - k for k in orders]
    n_vars = n + sum(sizes) + n
    cost = np.zeros(n_vars)
    blocks, rows = [], []
    column = n
    for k, size in zip(orders, sizes):
        cost[column:column + size] = weights[k - 1]
        difference = _difference(n, k)  # (size, n)
        slack = scipy.sparse.identity(size, format="csr")
        left = scipy.sparse.csr_matrix((size, column - n))
        right = scipy.sparse.csr_matrix((size, n_vars - column - size))
        # D P - e <= 0 and -D P - e <= 0.
        blocks.append(scipy.sparse.hstack([difference, left, -slack, right]))
        blocks.append(scipy.sparse.hstack([-difference, left, -slack, right]))
        rows.extend([size, size])
        column += size
    # P - e0 <= C and -P - e0 <= -C.
    centre = (original - offset) / scale
    cost[column:] = DEPARTURE_WEIGHT * min(w for w in weights if w > 0)
    identity, departure = scipy.sparse.identity(n, format="csr"), scipy.sparse.identity(n, format="csr")
    middle = scipy.sparse.csr_matrix((n, column - n))
    blocks.append(scipy.sparse.hstack([identity, middle, -departure]))
    blocks.append(scipy.sparse.hstack([-identity, middle, -departure]))
    a_ub = scipy.sparse.vstack(blocks, format="csr")
    b_ub = np.r_[np.zeros(a_ub.shape[0] - 2 * n), centre, -centre]
    bounds = np.column_stack([np.r_[lo, np.zeros(n_vars - n)], np.r_[hi, np.full(n_vars - n, np.inf)]])
    result = scipy.optimize.linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
    if result.status != 0 or result.x is None:
        return np.clip(original, lower, upper)  # cannot happen with feasible box bounds; stay safe
    return np.clip(result.x[:n] * scale + offset, lower, upper)


def _difference(n: int, order: int):
    """(n - order, n) forward difference of the given order."""
    import scipy.sparse
    coefficients = [math.comb(order, j) * (-1) ** (order - j) for j in range(order + 1)]
    return scipy.sparse.diags([float(c) for c in coefficients], list(range(order + 1)), shape=(n - order, n),
                              format="csr", dtype=np.float64)


def similarity_parameters(first_from_t: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, 4): x, y (frame-centre displacement, px), angle (rad), log scale of each accumulated transform."""
    out = np.empty((len(first_from_t), 4))
    for t, m in enumerate(first_from_t):
        dx, dy, angle, scale = geometry.decompose(m, width, height)
        out[t] = dx, dy, math.radians(angle), math.log(max(scale, 1e-9))
    return out


def similarity(parameters: np.ndarray, width: int, height: int) -> np.ndarray:
    """3x3 similarity about the frame centre with ``similarity_parameters``' (x, y, angle, log scale)."""
    x, y, angle, log_scale = parameters
    s = math.exp(log_scale)
    c, n = s * math.cos(angle), s * math.sin(angle)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    # Maps the centre to centre + (x, y), rotating and scaling about it.
    return np.array([[c, -n, cx + x - (c * cx - n * cy)], [n, c, cy + y - (n * cx + c * cy)], [0.0, 0.0, 1.0]])


def orig_from_stab(first_from_t: np.ndarray, config: L1PathConfig, width: int, height: int) -> np.ndarray:
    """(N, 3, 3) corrections S_t of one shot from its accumulated path ``first_from_t`` (N, 3, 3)."""
    original = similarity_parameters(first_from_t, width, height)
    side = max(width, height)  # the same bound in px for x and y: the area left to complete is what it costs
    margins = (config.margin_fraction * side, config.margin_fraction * side, math.radians(config.margin_deg),
               math.log1p(config.margin_scale))
    smooth = np.column_stack([plan(original[:, i], margins[i], config.weights, window=config.window,
                                   overlap=config.overlap) for i in range(4)])
    out = np.empty_like(first_from_t)
    for t in range(len(first_from_t)):
        # Only the similarity parts: the accumulated shear or perspective of a long shot drifts with the
        # estimates' small errors, and undoing it would distort frames far from the shot's start.
        m = np.linalg.inv(similarity(original[t], width, height)) @ similarity(smooth[t], width, height)
        out[t] = m / m[2, 2]
    return out
