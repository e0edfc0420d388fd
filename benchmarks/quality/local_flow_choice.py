"""Choose the default local-flow method (pipeline/stages/local_flow.py docstring) by accuracy and speed.

Two kinds of truth, both 640x360:
  photo   a real photograph (skimage.data) and a copy resampled along a known smooth flow (affine 0.5-3 px plus a
          sinusoid of 1 px), so target(p) = neighbour(p + f(p)) exactly; black invalid bands on both, mild noise.
  video   pipeline.evaluation.synthetic: frame t in its stabilized (intended) coordinates and neighbour t' warped there by the
          exact transforms. Truth: zero on the static background, the object's own motion on its footprint.
EPE (end-point error, px) on LocalFlowResult.common: mean over everything, background only, the object's interior
only; ms per frame pair (median of repeats, including grey conversion and filling).
A second table compares ways of filling the invalid pixels before DIS, measured near the invalid areas.
Usage: python -m benchmarks.quality.local_flow_choice
"""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np

from benchmarks import common
from pipeline.evaluation import synthetic
from pipeline.stages.local_flow import LocalFlowConfig, fill_invalid, local_flow
from pipeline.stages.warping import warp, warp_frame

WIDTH, HEIGHT = 640, 360
CANDIDATES = {
    "dis ultrafast": LocalFlowConfig(method="dis", dis_preset="ultrafast"),
    "dis fast": LocalFlowConfig(method="dis", dis_preset="fast"),
    "dis medium": LocalFlowConfig(method="dis", dis_preset="medium"),
    "dis fast f0": LocalFlowConfig(method="dis", dis_preset="fast", dis_finest_scale=0),
    "dis medium f0": LocalFlowConfig(method="dis", dis_preset="medium", dis_finest_scale=0),
    "farneback": LocalFlowConfig(method="farneback"),
    "lk grid 8": LocalFlowConfig(method="lk"),
}


def smooth_flow(rng: np.random.Generator, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """(H, W, 2) float32: an affine field of 0.5-3 px over the frame plus a 1 px sinusoid."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    u, v = (xs - width / 2) / width, (ys - height / 2) / height  # -0.5..0.5
    shift = rng.uniform(0.5, 2.0, 2) * rng.choice([-1, 1], 2)
    linear = rng.uniform(-1.0, 1.0, (2, 2))  # +-1 px across the frame
    phase = rng.uniform(0, 2 * np.pi, 2)
    fx = shift[0] + linear[0, 0] * u + linear[0, 1] * v + np.sin(2 * np.pi * (xs / 240.0) + phase[0])
    fy = shift[1] + linear[1, 0] * u + linear[1, 1] * v + np.cos(2 * np.pi * (ys / 160.0 + xs / 400.0) + phase[1])
    return np.stack([fx, fy], axis=-1).astype(np.float32)


def photo_case(image: str, rng: np.random.Generator, noise: float = 1.5):
    """target(p) = photo(p + f(p)); black invalid bands cut from both (where each would be missing)."""
    photo = cv2.resize(synthetic.load_image(image), (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA)
    flow = smooth_flow(rng)
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    target = cv2.remap(photo, xs + flow[..., 0], ys + flow[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    neighbour = photo.copy()
    noisy = [np.clip(im + rng.normal(0, noise, im.shape), 0, 255).astype(np.uint8) for im in (target, neighbour)]
    target_valid = np.ones((HEIGHT, WIDTH), bool)
    neighbour_valid = np.ones((HEIGHT, WIDTH), bool)
    target_valid[:, :48] = False
    target_valid[:20] = False
    neighbour_valid[:, -40:] = False
    neighbour_valid[-30:] = False
    for im, valid in zip(noisy, (target_valid, neighbour_valid)):
        im[~valid] = 0
    return noisy[0], target_valid, noisy[1], neighbour_valid, flow, np.zeros((HEIGHT, WIDTH), bool)


def video_case(video: synthetic.SyntheticVideo, t: int, t_other: int):
    """Frame t and neighbour t' in t's stabilized coordinates, exact transforms; truth flow and object interior."""
    world_from_stab = np.linalg.inv(video.intended_frame_from_world[t])
    target = warp_frame(video.frames[t], video.frame_from_world[t] @ world_from_stab)
    other = warp_frame(video.frames[t_other], video.frame_from_world[t_other] @ world_from_stab)
    flow = np.zeros((HEIGHT, WIDTH, 2), np.float32)
    pose = video.object_world_from_patch
    stab_from_stab = np.linalg.inv(world_from_stab) @ pose[t_other] @ np.linalg.inv(pose[t]) @ world_from_stab
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    moved = np.einsum("ij,jhw->ihw", stab_from_stab, np.stack([xs, ys, np.ones_like(xs)]))
    on_object = _stab_mask(video, t, world_from_stab)
    on_object_later = _stab_mask(video, t_other, world_from_stab)
    flow[on_object] = np.stack([moved[0] - xs, moved[1] - ys], axis=-1)[on_object]
    # Background next to the object is occluded in one of the frames: no truth there.
    near = cv2.dilate((on_object | on_object_later).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    interior = cv2.erode(on_object.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    known = ~near | interior
    return target.frame, ~target.missing, other.frame, ~other.missing, flow, interior, known


def _stab_mask(video: synthetic.SyntheticVideo, t: int, world_from_stab: np.ndarray) -> np.ndarray:
    orig_from_stab = video.frame_from_world[t] @ world_from_stab
    return warp(video.object_mask[t].astype(np.uint8), orig_from_stab, interpolation=cv2.INTER_NEAREST).astype(bool)


def fill_rgb(image: np.ndarray, valid: np.ndarray) -> np.ndarray:
    return np.stack([fill_invalid(np.ascontiguousarray(image[..., c]), valid) for c in range(3)], axis=-1)


def timed(fn, repeats: int = 5):
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return result, 1000 * float(np.median(times))


def epe(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    return float(np.linalg.norm(estimate - truth, axis=-1)[mask].mean()) if mask.any() else float("nan")


def main(argv: list[str] | None = None) -> int:
    common.parser(__doc__).parse_args(argv)  # no options: --help describes the script
    rng = np.random.default_rng(0)
    photo_cases = [photo_case(name, rng) for name in ("astronaut", "coffee", "chelsea", "rocket") for _ in range(2)]
    video = synthetic.generate(synthetic.SyntheticConfig(n_frames=40, blurred_frames=(), seed=1))
    video_cases = [video_case(video, t, t + d) for t in (10, 20, 30) for d in (-3, -1, 2)]
    print(f"{'method':14s} {'photo EPE':>9s} {'p95':>6s} {'video bg':>9s} {'object':>7s} {'ms/frame':>9s}")
    for name, config in CANDIDATES.items():
        photo_epe, photo_p95, times = [], [], []
        for target, tv, neighbour, nv, truth, _ in photo_cases:
            result, ms = timed(lambda: local_flow(target, tv, neighbour, nv, config))
            error = np.linalg.norm(result.flow - truth, axis=-1)[result.common]
            photo_epe.append(error.mean())
            photo_p95.append(np.percentile(error, 95))
            times.append(ms)
        background, on_object = [], []
        for target, tv, neighbour, nv, truth, interior, known in video_cases:
            result = local_flow(target, tv, neighbour, nv, config)
            background.append(epe(result.flow, truth, result.common & known & ~interior))
            on_object.append(epe(result.flow, truth, result.common & interior))
        print(f"{name:14s} {np.mean(photo_epe):9.3f} {np.mean(photo_p95):6.2f} {np.mean(background):9.3f} "
              f"{np.nanmean(on_object):7.2f} {np.median(times):9.1f}", flush=True)

    # Filling the invalid pixels before the flow: EPE on `common` within 24 px of the target's invalid pixels
    # (where motion inpainting starts from) and elsewhere.
    print(f"\nfill before DIS medium    {'near target holes':>17s} {'elsewhere':>9s}")
    config = LocalFlowConfig()
    for fill in ("other, then push-pull", "push-pull", "black (none)"):
        near_epe, far_epe = [], []
        for target, tv, neighbour, nv, truth, _ in photo_cases:
            in_both = local_flow(target, tv, neighbour, nv, config).common
            if fill == "other, then push-pull":  # what local_flow does
                flow = local_flow(target, tv, neighbour, nv, config).flow
            else:  # pre-filled (or left black) and declared valid, so local_flow fills nothing
                first = fill_rgb(target, tv) if fill == "push-pull" else target
                second = fill_rgb(neighbour, nv) if fill == "push-pull" else neighbour
                everywhere = np.ones_like(tv)
                flow = local_flow(first, everywhere, second, everywhere, config).flow
            near = cv2.distanceTransform(tv.astype(np.uint8), cv2.DIST_L2, 5) < 24
            near_epe.append(epe(flow, truth, in_both & near))
            far_epe.append(epe(flow, truth, in_both & ~near))
        print(f"{fill:25s} {np.mean(near_epe):17.3f} {np.mean(far_epe):9.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
