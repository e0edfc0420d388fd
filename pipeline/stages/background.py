"""Which of a pair's motions is the camera's (thesis 3.2, where large figures move in front of it).

RANSAC keeps the motion most tracks agree on. Where a figure fills much of the frame that can be the figure's, so
``motion.estimate`` also returns the other motions it finds among the outliers (up to two more), and this module
decides, over the clip rather than pair by pair, which one the camera's is (docs/decisions.md D45), from:

- **Occlusion** (`occlusion_votes`): what a moving layer uncovers or is about to cover belongs to a layer behind
  it. A pixel of frame t that no motion of the pair (t-1, t) explains, whose own layer's motion takes it back onto
  a pixel of frame t-1 another motion explains alone, has just come out from behind that other layer; backwards in
  time the same for pixels about to be covered. The background is seen behind, and a figure in front.
- **Places** (`place_links`): a pair's tracks start where the pair before ended, so each motion of a pair is linked
  to the motion of the pair before whose tracks ended where its tracks start.
- **Continuity** (`motion_changes`): the camera's motion changes from one frame to the next about as much as the
  clip's shake makes it change elsewhere (`CameraChooser.shake`); a figure's own velocity comes on top of it.

Each pair is a node of a chain with one state per motion ("this one is the camera's"), its occlusion evidence a
score per state, places and continuity a score per pair of states; `CameraChooser` finds the best states by dynamic
programming (Viterbi) with a bounded look-ahead: pairs are decided `LAG_PAIRS` at a time, each once at least as many
after it are known, with the pair before them fixed as decided. So a pair with no evidence of its own follows the
pairs linked to it, a run of pairs with misleading evidence is outvoted by the linked pairs around it, and memory
does not grow with the clip. Where there is no evidence at all, RANSAC's winner stays. Scores are log-odds: a clear
occlusion is worth up to 3 (half to each pair around the frame it is seen at), leaving a layer a sure link follows 20,
a jump of the camera's motion by a fifth of the frame up to 8.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import itertools
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

ANALYSIS_SIDE = 320  # px: the three frames of the occlusion test are compared at this long side
UNEXPLAINED = 14.0  # grey levels: a pixel farther than this from what every motion brings there is unexplained
EXPLAINED = 6.0  # grey levels: a pixel this close to what one motion brings, and ...
EXPLAINED_MARGIN = 4.0  # ... this much closer than every other motion brings, moves with that motion
SHARPNESS_RATIO = 1.3  # a frame whose gradient energy exceeds the blurriest's by more is blurred to match (a blurred
# frame leaves every edge unexplained by a sharp one's) ...
MATCH_SIGMAS = (0.5, 0.75, 1.0, 1.4, 2.0, 2.8, 4.0)  # ... by the least of these Gaussians (px at the size compared) that
# brings it within the ratio; where none does, the test is skipped
VOTE_FLOOR = 10.0  # occlusion votes (px at ANALYSIS_SIDE) a motion's lead must exceed to count: noise below
VOTE_SCALE = 40.0  # votes beyond the floor for one unit of log-odds ...
VOTE_CAP = 3.0  # ... and at most this many units a pair
FRAME_TEST_SHARE = 0.5  # each pair takes this share of a frame test's evidence: the test at frame t votes for both
# pairs around t, and a chain of linked pairs would count one occlusion twice
SHAKE_FLOOR = 0.005  # of the frame's diagonal: the least scale of the camera's changes of motion (a tripod's are ~0)
SHAKE_PAIRS = 300  # the camera's last changes of motion the scale is taken from
CONTINUITY_FREE = 2.0  # shakes: a change of the camera's motion within this many costs nothing
CONTINUITY_CAP = 8.0  # log-odds: the most a change of motion between pairs costs
WINNER_PRIOR = 1.5  # log-odds for the motion most tracks follow, once a chain of linked pairs
LINK_GAIN = 20.0  # log-odds against leaving a layer whose tracks all start where one motion of the pair before ended
LINK_RADIUS = 0.02  # of the frame's long side: a track start farther from every end of the pair before is not linked
SAME_LAYER = 0.8  # sameness (0..1) above which the occlusion test takes two motions of consecutive pairs for one layer
LINK_TRACKS = 8  # a link rests on the tracks that are linked; fewer than this count for what they are
LAG_PAIRS = 90  # pairs are decided this many at a time, each once at least this many after it are known (3 s at
# 30 fps)


@dataclass(frozen=True)
class PairLayers:
    """What the choice needs of one pair: its motions (full-resolution curr_from_prev; the first is RANSAC's
    winner, then the others found), the links to the pair before (``place_links``: rows its motions and one for
    tracks no motion held, columns this pair's; None: no link), each motion's occlusion votes (pixels it was seen
    behind, and in front of; px at ANALYSIS_SIDE), and how much the camera's motion would change between each
    motion of the pair before and each of this one (``motion_changes``; None where either pair failed)."""

    motions: tuple[np.ndarray, ...]
    links: np.ndarray | None = None
    behind: tuple[int, ...] = ()
    in_front: tuple[int, ...] = ()
    changes: np.ndarray | None = None
    carried: tuple[int, ...] = ()  # each motion's pairs tracked on since a motion of a pair's own was its layer

    @property
    def choosable(self) -> bool:
        return len(self.motions) > 1

    def occlusion_scores(self) -> np.ndarray:
        """(n,) log-odds per motion from the occlusion votes."""
        if not self.choosable:
            return np.zeros(len(self.motions))
        votes = np.asarray(self.behind, float) - np.asarray(self.in_front, float)
        lead = votes - np.array([np.delete(votes, k).max() for k in range(len(votes))])
        lead = np.sign(lead) * np.maximum(np.abs(lead) - VOTE_FLOOR, 0.0)  # a few pixels are noise, not evidence
        return FRAME_TEST_SHARE * np.clip(lead / VOTE_SCALE, -VOTE_CAP, VOTE_CAP) / 2.0

    @functools.cached_property
    def _own(self) -> np.ndarray:
        if self.links is not None or not self.choosable:
            return self.occlusion_scores()
        # where a chain of linked pairs starts, the motion most tracks follow is favoured a little: once a chain,
        # so that a long chain is decided by its evidence, and one with none keeps RANSAC's winner
        first = np.arange(len(self.motions)) == 0
        return self.occlusion_scores() + np.where(first, WINNER_PRIOR / 2, -WINNER_PRIOR / 2)

    def own_scores(self) -> np.ndarray:
        """(n,) this pair's own evidence per motion, log-odds."""
        return self._own

    @functools.cached_property
    def _places(self) -> np.ndarray | None:
        return None if self.links is None else self._link_scores()

    def link_scores(self, n_before: int, shake: float = 1.0) -> np.ndarray:
        """(n_before, n): the score of each pair of states (motion i of the pair before the camera's, motion j of
        this one): the places' links (``_link_scores``) plus continuity, the change of the camera's motion it
        implies against the clip's ``shake`` (the scale of its changes, a share of the diagonal): nothing within
        CONTINUITY_FREE of it (shake and a figure's step look alike there), Gaussian beyond, at most CONTINUITY_CAP;
        zeros where neither relates this pair to one of ``n_before`` motions."""
        scores = np.zeros((n_before, len(self.motions)))
        if self._places is not None and self._places.shape[0] == n_before:
            scores = scores + self._places
        if self.changes is not None and self.changes.shape[0] == n_before:
            beyond = np.maximum(self.changes / shake - CONTINUITY_FREE, 0.0)
            scores = scores - np.minimum(0.5 * beyond ** 2, CONTINUITY_CAP)
        return scores

    @functools.cached_property
    def _matched(self) -> list[tuple[int, int, float]]:
        return _matching(_sameness(self.links))

    def lost(self, before: int) -> bool:
        """Whether motion ``before`` of the pair before goes on as no motion of this pair (its layer lost here: a
        sky behind figures can leave the camera's motion no tracks for a pair); False where no links relate the
        two pairs."""
        return self.links is not None and before < self.links.shape[0] - 1 and \
            all(i != before for i, _, _ in self._matched)

    def _link_scores(self) -> np.ndarray:
        """(n_before, n): the score of each pair of states (motion i of the pair before the camera's, motion j of
        this pair) from the links: 0 where i and j are one layer by the best matching of the two pairs' motions, -w
        where either is that one layer and the other is not, 0 where neither is linked (``_matching``). Each
        matched layer's w is LINK_GAIN times the links' confidence and that match's margin (what it adds over the
        surest matching without it): two figures that split or merge leave their own match in doubt, not the
        background's. Staying on a layer scores 0 whichever layer it is, however many tracks hold it or however
        cleanly it links, so the links carry which layer is which and the evidence alone says which layer is the
        camera's."""
        gain = LINK_GAIN * _link_confidence(self.links)
        scores = np.zeros((self.links.shape[0] - 1, len(self.motions)))
        matched = self._matched
        for i, j, margin in matched:
            leaving = -gain * min(margin, 1.0)
            scores[i, :] = np.minimum(scores[i, :], leaving)
            scores[:, j] = np.minimum(scores[:, j], leaving)
        for i, j, _ in matched:
            scores[i, j] = 0.0
        return scores


@dataclass(frozen=True)
class CameraChoice:
    """How a pair's camera motion was chosen, for the debugger: the motion taken (0: RANSAC's winner, k: the k-th
    other), what weighed most, and the evidence in log-odds for the motion taken against the best other (positive:
    for it)."""

    taken: int
    rule: str  # "one motion", "occlusion at this frame", "the frames around it"
    occlusion: float  # this pair's occlusion evidence
    linked: float  # what the pairs around it added: their evidence, carried by the places and continuity
    behind: tuple[int, ...] = ()  # each motion's occlusion votes (px at ANALYSIS_SIDE): seen behind ...
    in_front: tuple[int, ...] = ()  # ... and seen in front
    carried: tuple[int, ...] = ()  # each motion's pairs tracked on (motion.continued; 0: measured in the pair)
    lost: bool = False  # the camera's layer of the pair before goes on as no motion of this pair: its chain switched


def decide(layers: Sequence[PairLayers], lag: int = LAG_PAIRS) -> list[CameraChoice]:
    """Every pair's choice at once, as ``CameraChooser`` makes them pair by pair."""
    chooser = CameraChooser(lag)
    choices = [choice for layers_one in layers for _, choice in chooser.push(layers_one)]
    return choices + [choice for _, choice in chooser.finish()]


# -- places -----------------------------------------------------------------------------------------------------

def track_ends(estimate) -> list[np.ndarray]:
    """Each motion's tracks' ends (full px): RANSAC's winner's inliers, then each other motion's."""
    return [estimate.curr_points[estimate.inliers], *(other.curr_points for other in estimate.others)]


def track_starts(estimate) -> list[np.ndarray]:
    return [estimate.prev_points[estimate.inliers], *(other.prev_points for other in estimate.others)]


def place_links(before, estimate, long_side: int) -> np.ndarray | None:
    """(motions before + 1, motions now): how many of each motion's tracks start nearest an end of each motion of
    the pair before (within LINK_RADIUS), the last row those nearest an end no motion held; None when either pair
    has one motion (nothing to choose here; and there, the one motion found need not be the camera's) or failed."""
    if before is None or before.status != "ok" or estimate.status != "ok" or not before.others \
            or not estimate.others:
        return None
    ends = [*track_ends(before), _held_by_none(before)]
    points = np.concatenate(ends)
    if not len(points):
        return None
    owner = np.concatenate([np.full(len(e), i) for i, e in enumerate(ends)])
    import scipy.spatial  # here: only pairs with several motions need it

    tree = scipy.spatial.cKDTree(points)
    starts = track_starts(estimate)
    counts = np.zeros((len(ends), len(starts)))
    for j, start in enumerate(starts):
        if len(start):
            distance, nearest = tree.query(start, k=1)
            counts[:, j] = np.bincount(owner[nearest[distance <= LINK_RADIUS * long_side]], minlength=len(ends))
    return counts


def _held_by_none(estimate) -> np.ndarray:
    """The ends of the tracks no motion of a pair holds (the other motions' tracks are their first fit's: an
    outlier within a pixel of one of them is one of them)."""
    if len(estimate.inliers) != len(estimate.curr_points):
        return np.zeros((0, 2), np.float32)
    outliers = estimate.curr_points[~estimate.inliers]
    held = [other.curr_points for other in estimate.others if len(other.curr_points)]
    if not len(outliers) or not held:
        return outliers
    return outliers[away_from(outliers, np.concatenate(held), 1.0)]


def away_from(points: np.ndarray, others: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: which ``points`` lie farther than ``radius`` from every one of ``others``."""
    if not len(others):
        return np.ones(len(points), bool)
    import scipy.spatial  # here: only pairs with several motions need it

    distance, _ = scipy.spatial.cKDTree(others).query(points, k=1)
    return distance > radius


def motions_of(estimate) -> tuple[np.ndarray, ...]:
    """A raw estimate's motions: RANSAC's winner, then the others."""
    return (estimate.curr_from_prev, *(other.curr_from_prev for other in estimate.others))


def motion_changes(before, estimate, width: int, height: int) -> np.ndarray | None:
    """(motions before, motions now): how much the camera's motion changes if it moved by motion i of the pair
    before and then by motion j: the mean distance between where the two take the frame's corners, a share of the
    frame's diagonal. A hand's shake changes the camera's motion by about the same from frame to frame, a figure's
    velocity comes on top of it. None where either pair failed."""
    if before is None or before.status != "ok" or estimate.status != "ok":
        return None
    corners = np.array([[0, 0], [width - 1, 0], [width - 1, height - 1], [0, height - 1]], np.float64)
    diagonal = float(np.hypot(width, height))
    changes = np.zeros((len(motions_of(before)), len(motions_of(estimate))))
    for i, a in enumerate(motions_of(before)):
        for j, b in enumerate(motions_of(estimate)):
            changes[i, j] = float(np.mean(np.linalg.norm(_apply(a, corners) - _apply(b, corners), axis=1))) / diagonal
    return changes


def _apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    moved = np.c_[points, np.ones(len(points))] @ matrix.T
    return moved[:, :2] / moved[:, 2:3]


def layers_of(estimate, before, width: int, height: int) -> PairLayers:
    """The pair's motions and the evidence that needs no image (votes come later, from ``occlusion_votes``)."""
    changes = motion_changes(before, estimate, width, height)
    if estimate.status != "ok" or not estimate.others:
        return PairLayers((estimate.curr_from_prev,), changes=changes)
    return PairLayers(motions_of(estimate), links=place_links(before, estimate, max(width, height)),
                      changes=changes, carried=(0, *(other.carried for other in estimate.others)))


# -- occlusion --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Votes:
    """Occlusion votes of the motions of one pair (px at ANALYSIS_SIDE): seen behind, and in front."""

    behind: tuple[int, ...]
    in_front: tuple[int, ...]

    @staticmethod
    def none(n: int) -> "Votes":
        return Votes((0,) * n, (0,) * n)

    def __add__(self, other: "Votes") -> "Votes":
        return Votes(tuple(a + b for a, b in zip(self.behind, other.behind)),
                     tuple(a + b for a, b in zip(self.in_front, other.in_front)))


def occlusion_votes(grays: Sequence[np.ndarray], scale: float, pair_in: Sequence[np.ndarray],
                    pair_out: Sequence[np.ndarray], same: Sequence[int]) -> tuple[Votes, Votes]:
    """The occlusion test at frame t (module docstring). ``grays``: frames t-1, t, t+1 (working size, ``scale``
    of full); ``pair_in``, ``pair_out``: the motions (full px, curr_from_prev) of (t-1, t) and (t, t+1); ``same``:
    for each motion of pair_out, the motion of pair_in that is the same layer (``same_layers``), -1 for none.
    Returns the votes of pair_in's motions and of pair_out's; none where a frame's sharpness cannot be matched
    (``_analysis_frames``).

    Uncovered at t: no motion of pair_in explains the pixel, one motion of pair_out alone does (the layer behind),
    and that layer's motion in pair_in takes it back onto a pixel of t-1 another motion of pair_in explains alone
    (the layer that was in front of it). Covered at t: the same with time reversed. Asking that an unexplained
    pixel was (or will be) covered, by another layer than its own, keeps out what no motion of the pair follows."""
    frames = _analysis_frames(grays)
    if frames is None:
        return Votes.none(len(pair_in)), Votes.none(len(pair_out))
    factor = frames[1].shape[1] / grays[1].shape[1]
    to_analysis = np.diag([scale * factor, scale * factor, 1.0])
    into_in = [to_analysis @ m @ np.linalg.inv(to_analysis) for m in pair_in]
    into_out = [to_analysis @ m @ np.linalg.inv(to_analysis) for m in pair_out]
    size = frames[1].shape
    came = [_residual(frames[1], frames[0], np.linalg.inv(m), size) for m in into_in]  # t from t-1
    goes = [_residual(frames[1], frames[2], m, size) for m in into_out]  # t to t+1
    valid = np.logical_and.reduce([ok for _, ok in came + goes])
    # frame t-1's pixels each motion of pair_in alone takes to t, frame t+1's each of pair_out alone brought
    left = _explained_alone([_residual(frames[0], frames[1], m, size) for m in into_in])
    reached = _explained_alone([_residual(frames[2], frames[1], np.linalg.inv(m), size) for m in into_out])
    unexplained_in = valid & (np.min([r for r, _ in came], axis=0) > UNEXPLAINED)
    unexplained_out = valid & (np.min([r for r, _ in goes], axis=0) > UNEXPLAINED)
    behind_in, front_in = [0] * len(pair_in), [0] * len(pair_in)
    behind_out, front_out = [0] * len(pair_out), [0] * len(pair_out)
    goes_alone, came_alone = _explained_alone(goes), _explained_alone(came)
    for x, y in enumerate(same):
        if y < 0:
            continue
        # uncovered: behind, x (pair_out) = y (pair_in); in front, the motion of pair_in explaining where y takes it
        behind_out[x] += _occlusion(unexplained_in & goes_alone[x], left, y, np.linalg.inv(into_in[y]), size,
                                    front_in)
        # covered: behind, y (pair_in) = x (pair_out); in front, the motion of pair_out arriving where x takes it
        behind_in[y] += _occlusion(unexplained_out & came_alone[y], reached, x, into_out[x], size, front_out)
    return Votes(tuple(behind_in), tuple(front_in)), Votes(tuple(behind_out), tuple(front_out))


def same_layers(links: np.ndarray | None, n_out: int) -> list[int]:
    """For each motion of a pair, the motion of the pair before that is the same layer: each other's best match by
    the links (``PairLayers.links``), and more than half the same; -1 for none."""
    if links is None:
        return [-1] * n_out
    sameness = _sameness(links)
    same = []
    for x in range(n_out):
        y = int(np.argmax(sameness[:, x]))
        same.append(y if sameness[y, x] > SAME_LAYER and int(np.argmax(sameness[y])) == x else -1)
    return same


def _sameness(links: np.ndarray) -> np.ndarray:
    """(n_before, n): how surely motion i of the pair before and motion j of this pair are one layer (0..1), from
    the link counts (``place_links``): the mean of the share of j's tracks linked to a motion that start at i's ends
    and the share of i's links that go to j; 0.5 (unknown) where j or i has no link. How many links there are is
    the pair's confidence (``_link_confidence``), not a motion's: a layer with fewer tracks is not less surely
    itself."""
    held = links[:-1]  # (the tracks starting where no motion's tracks ended are linked to no motion)
    into, out_of = held.sum(axis=0, keepdims=True), held.sum(axis=1, keepdims=True)
    sameness = (held / np.maximum(into, 1.0) + held / np.maximum(out_of, 1.0)) / 2.0
    return np.where((into > 0) & (out_of > 0), sameness, 0.5)


def _matching(sameness: np.ndarray) -> list[tuple[int, int, float]]:
    """The one-to-one matching of the motions before (rows) and now (columns) that is surest (the largest sum of
    sameness - 0.5 over its pairs more likely one layer than not), as those pairs, each with its margin: what the
    pair adds over the surest matching without it, 1 for a sure match (sameness 1) that has no rival."""
    rows, cols = sameness.shape
    gain = np.maximum(sameness - 0.5, 0.0)
    matchings = [list(zip(range(rows), chosen)) if rows <= cols else list(zip(chosen, range(cols)))
                 for chosen in itertools.permutations(range(max(rows, cols)), min(rows, cols))]
    values = [sum(gain[i, j] for i, j in pairs) for pairs in matchings]
    best = int(np.argmax(values))
    matched = []
    for i, j in matchings[best]:
        if gain[i, j] > 0:
            without = max(value - (gain[i, j] if (i, j) in pairs else 0.0) for value, pairs in zip(values, matchings))
            matched.append((i, j, float(2.0 * (values[best] - without))))
    return matched


def _link_confidence(links: np.ndarray) -> float:
    """The share of the pair's motions whose links are many enough to be trusted in full (LINK_TRACKS each)."""
    return float(np.minimum(links[:-1].sum(axis=0) / LINK_TRACKS, 1.0).mean())


def _occlusion(pixels: np.ndarray, alone_there: list[np.ndarray], own: int, there_from_here: np.ndarray,
               size: tuple[int, int], front_votes: list[int]) -> int:
    """Of ``pixels`` (unexplained here, explained alone by their layer in the next pair), those whose point under
    their own layer's motion (index ``own`` of ``alone_there``) in the other frame another motion explains alone:
    each such motion gets a front vote for its pixels; returns how many pixels were occluded at all."""
    occluded = np.zeros(size, bool)
    for front, alone in enumerate(alone_there):
        if front != own:
            hit = pixels & _seen_through(alone, there_from_here, size)
            front_votes[front] += int(hit.sum())
            occluded |= hit
    return int(occluded.sum())


def _analysis_frames(grays: Sequence[np.ndarray]) -> list[np.ndarray] | None:
    """The three frames at ANALYSIS_SIDE as float32, the sharper ones blurred to the blurriest's sharpness (within
    SHARPNESS_RATIO of its gradient energy), so that a motion-blurred frame among sharp ones is compared at one
    sharpness; None where a frame cannot be matched."""
    factor = min(1.0, ANALYSIS_SIDE / max(grays[1].shape))
    frames = [cv2.resize(g, None, fx=factor, fy=factor, interpolation=cv2.INTER_AREA).astype(np.float32)
              if factor < 1.0 else g.astype(np.float32) for g in grays]
    return at_one_sharpness(frames, [gradient_energy(f) for f in frames])


def at_one_sharpness(frames: Sequence[np.ndarray], energy: Sequence[float]) -> list[np.ndarray] | None:
    """``frames`` (of gradient energies ``energy``) with the sharper ones blurred to the blurriest's sharpness
    (within SHARPNESS_RATIO of its energy); None where a frame cannot be matched."""
    target = SHARPNESS_RATIO * max(min(energy), 1e-6)
    matched = [frame if sharpness <= target else blurred_to(frame, target) for frame, sharpness in zip(frames, energy)]
    return None if any(frame is None for frame in matched) else matched


def blurred_to(frame: np.ndarray, energy: float) -> np.ndarray | None:
    """``frame`` blurred by the least of MATCH_SIGMAS that brings its gradient energy down to ``energy``; None if
    none does."""
    for sigma in MATCH_SIGMAS:
        blurred = cv2.GaussianBlur(frame, (0, 0), sigma)
        if gradient_energy(blurred) <= energy:
            return blurred
    return None


def _explained_alone(residuals: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """Where each motion explains a pixel and every other motion does not (bool maps)."""
    values = np.array([r for r, _ in residuals])
    alone = []
    for k in range(len(values)):
        others = np.delete(values, k, axis=0).min(axis=0)
        alone.append((values[k] < EXPLAINED) & (values[k] + EXPLAINED_MARGIN < others))
    return alone


def _seen_through(mask: np.ndarray, other_from_frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``mask`` (of another frame) at the point ``other_from_frame`` takes each pixel of this frame to."""
    height, width = size
    return cv2.warpPerspective(mask.view(np.uint8), other_from_frame, (width, height),
                               flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=0).view(bool)


def _residual(frame: np.ndarray, other: np.ndarray, other_from_frame: np.ndarray,
              size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """How far each pixel of ``frame`` lies outside the range of ``other``'s 3x3 neighbourhood at the point the
    motion takes it to (so a motion off by under a pixel still explains a sharp edge), smoothed over 3x3; and where
    that point lies inside ``other`` (eroded by 2 px)."""
    height, width = size
    sampled = cv2.warpPerspective(other, other_from_frame, (width, height),
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                                  borderValue=-1.0)
    kernel = np.ones((3, 3), np.uint8)
    low, high = cv2.erode(sampled, kernel), cv2.dilate(sampled, kernel)
    outside = cv2.blur(np.maximum(np.maximum(frame - high, low - frame), 0.0), (3, 3))
    valid = cv2.erode((sampled >= 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return outside, valid


def gradient_energy(image: np.ndarray) -> float:
    return float(np.mean(cv2.Sobel(image, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(image, cv2.CV_32F, 0, 1) ** 2))


# -- the chain --------------------------------------------------------------------------------------------------

class CameraChooser:
    """Decides each pair's camera motion from a stream of ``PairLayers`` (module docstring). ``push`` returns the
    choices it could make (in order, as (PairLayers, CameraChoice)), ``finish`` the rest; the choices depend only on
    the sequence pushed, so a clip pushed in one piece or joined from segments gets the same ones.

    Pairs are decided ``lag`` at a time, once twice as many wait: the best chain over all waiting pairs (Viterbi,
    from the last decided pair's state) decides the first ``lag`` of them, each seeing at least ``lag`` pairs
    ahead; at most 2 x ``lag`` pairs wait, and each takes part in about two solutions."""

    def __init__(self, lag: int = LAG_PAIRS) -> None:
        self.lag = max(int(lag), 1)
        self.pending: list[PairLayers] = []
        self.before: tuple[int, int] | None = None  # the last decided pair: (its number of motions, its state)
        self.changes: collections.deque[float] = collections.deque(maxlen=SHAKE_PAIRS)

    @property
    def shake(self) -> float:
        """The scale of the camera's changes of motion in this clip (share of the diagonal): 1.4826 x the median
        change between the camera's motions of the last SHAKE_PAIRS decided pairs, at least SHAKE_FLOOR (4 x that
        before any). A steady camera's motion jumping by a figure's step is then unlikely, a shaking camera's not."""
        return max(SHAKE_FLOOR, 1.4826 * float(np.median(self.changes))) if self.changes else 4 * SHAKE_FLOOR

    def push(self, layers: PairLayers) -> list[tuple[PairLayers, CameraChoice]]:
        self.pending.append(layers)
        return self._decide(self.lag) if len(self.pending) >= 2 * self.lag else []

    def finish(self) -> list[tuple[PairLayers, CameraChoice]]:
        return self._decide(len(self.pending)) if self.pending else []

    def _decide(self, count: int) -> list[tuple[PairLayers, CameraChoice]]:
        """Decide the first ``count`` waiting pairs: the best chain's states (Viterbi's backtrack), explained by
        each pair's max-marginals (the best chain's score with the pair in each state)."""
        shake = self.shake
        forward, back_pointers = _forward(self.pending, self.before, shake)
        backward = _backward(self.pending, shake)
        states = [int(np.argmax(forward[-1]))]
        for pointers in reversed(back_pointers):
            states.append(int(pointers[states[-1]]))
        states.reverse()
        before = [None if self.before is None else self.before[1], *states[:count - 1]]
        decided = [(layers, _explain(layers, state, forward[k] + backward[k],
                                     before[k] is not None and layers.lost(before[k])))
                   for k, (layers, state) in enumerate(zip(self.pending[:count], states))]
        for layers, state, previous in zip(self.pending[:count], states, before):
            if layers.changes is not None and previous is not None and previous < layers.changes.shape[0]:
                self.changes.append(float(layers.changes[previous, state]))
        self.before = (len(self.pending[count - 1].motions), states[count - 1])
        del self.pending[:count]
        return decided


def _forward(chain: list[PairLayers], before: tuple[int, int] | None,
             shake: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Viterbi's forward scores (per pair, the best chain's score ending in each state) and back pointers (per
    pair after the first, the best state of the pair before for each of its states)."""
    scores, pointers = [], []
    for k, layers in enumerate(chain):
        own = layers.own_scores()
        if k == 0:
            entry = np.zeros(len(layers.motions)) if before is None else \
                layers.link_scores(before[0], shake)[before[1]]
            scores.append(entry + own)
        else:
            paths = scores[-1][:, None] + layers.link_scores(len(chain[k - 1].motions), shake)
            pointers.append(np.argmax(paths, axis=0))
            scores.append(np.max(paths, axis=0) + own)
    return scores, pointers


def _backward(chain: list[PairLayers], shake: float) -> list[np.ndarray]:
    """Per pair, the best score the pairs after it add, given each state of that pair."""
    scores = [np.zeros(len(chain[-1].motions))]
    for k in range(len(chain) - 1, 0, -1):
        after = chain[k]
        links = after.link_scores(len(chain[k - 1].motions), shake)
        scores.append(np.max(links + (after.own_scores() + scores[-1])[None, :], axis=1))
    return scores[::-1]


def _explain(layers: PairLayers, taken: int, marginal: np.ndarray, lost: bool = False) -> CameraChoice:
    """The choice with what weighed most for it against the best other motion: the pair's own occlusion evidence,
    or the pairs around it; ``lost``: the camera's layer of the pair before goes on as no motion of this pair."""
    if not layers.choosable:
        return CameraChoice(taken, "one motion", 0.0, 0.0)
    rival = int(np.argmax(np.where(np.arange(len(marginal)) == taken, -np.inf, marginal)))
    occlusion = float(np.subtract(*layers.occlusion_scores()[[taken, rival]]))
    linked = float(marginal[taken] - marginal[rival]) - occlusion
    rule = "occlusion at this frame" if occlusion >= linked else "the frames around it"
    return CameraChoice(taken, rule, occlusion, linked, layers.behind, layers.in_front, layers.carried, lost)


# -- the stream of pairs ------------------------------------------------------------------------------------------

class LayerEvidence:
    """Turns the stream of raw estimates (RANSAC's winner first, as ``motion.estimate`` returns them) into each
    pair's ``PairLayers``, which is complete once the pair after it is known (the occlusion test at frame t needs
    both pairs around t). ``push`` returns the (estimate, layers) it completed, ``finish`` the last."""

    def __init__(self) -> None:
        self.last = None  # the last pair: (estimate, layers without votes, votes so far, gray before, gray)

    def push(self, estimate, previous, prepared) -> list[tuple[object, PairLayers]]:
        """``previous``, ``prepared``: the pair's two motion.PreparedFrame (previous None for the first frame)."""
        before = None if self.last is None else self.last[0]
        layers = layers_of(estimate, before, prepared.width, prepared.height)
        votes = Votes.none(len(layers.motions))
        done = []
        if self.last is not None:
            last_estimate, last_layers, last_votes, gray_before, gray = self.last
            if last_layers.choosable and layers.choosable and gray_before is not None \
                    and gray_before.shape == gray.shape == prepared.gray.shape:
                votes_in, votes = occlusion_votes((gray_before, gray, prepared.gray), prepared.scale,
                                                  last_layers.motions, layers.motions,
                                                  same_layers(layers.links, len(layers.motions)))
                last_votes = last_votes + votes_in
            done.append(_with_votes(last_estimate, last_layers, last_votes))
        self.last = (estimate, layers, votes, None if previous is None else previous.gray, prepared.gray)
        return done

    def finish(self) -> list[tuple[object, PairLayers]]:
        if self.last is None:
            return []
        estimate, layers, votes, _, _ = self.last
        self.last = None
        return [_with_votes(estimate, layers, votes)]


def _with_votes(estimate, layers: PairLayers, votes: Votes) -> tuple[object, PairLayers]:
    if not layers.choosable:
        return estimate, layers
    return estimate, dataclasses.replace(layers, behind=votes.behind, in_front=votes.in_front)
