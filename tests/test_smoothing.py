"""Eq. 18 against ground truth: known jittered camera paths."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import geometry
from pipeline.stages.smoothing import SmoothingConfig, gaussian_weights, smooth

FPS = 30.0


def translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def rotation_about(deg: float, cx: float, cy: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy], [0.0, 0.0, 1.0]])


def camera_path(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Intended smooth pan + white hand-held jitter (px): camera positions (n, 2)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    intended = np.stack([2.0 * t + 20 * np.sin(2 * np.pi * t / 300), 10 * np.sin(2 * np.pi * t / 200)], axis=1)
    jitter = rng.normal(0.0, 4.0, size=(n, 2))
    return intended, intended + jitter


def inter_frame(positions: np.ndarray) -> np.ndarray:
    """curr_from_prev for a translating camera: a scene point at x_prev appears at x_prev - (c_t - c_prev)."""
    steps = [geometry.IDENTITY.copy()]
    for t in range(1, len(positions)):
        dx, dy = positions[t] - positions[t - 1]
        steps.append(translation(-dx, -dy))
    return np.array(steps)


def truncated_gaussian_filter(signal: np.ndarray, radius: int, sigma: float) -> np.ndarray:
    kernel = gaussian_weights(radius, sigma)
    out = np.empty_like(signal)
    for t in range(len(signal)):
        lo, hi = max(0, t - radius), min(len(signal) - 1, t + radius)
        w = kernel[lo - t + radius: hi - t + radius + 1]
        out[t] = (w[:, None] * signal[lo: hi + 1]).sum(axis=0) / w.sum()
    return out


def high_frequency_energy(signal: np.ndarray, cutoff_hz: float = 2.0) -> float:
    spectrum = np.abs(np.fft.rfft(signal - signal.mean(axis=0), axis=0)) ** 2
    freqs = np.fft.rfftfreq(len(signal), d=1.0 / FPS)
    return float(spectrum[freqs > cutoff_hz].sum())


def smoothed_positions(positions: np.ndarray, config: SmoothingConfig) -> np.ndarray:
    """Where the virtual camera sits: c_t plus the displacement S_t applies to frame t."""
    result = smooth(inter_frame(positions), config, width=640, height=360)
    offsets = np.array([s[:2, 2] for s in result.orig_from_stab])  # S_t = translate(c'_t - c_t)
    return positions + offsets


def test_translation_path_is_exactly_the_gaussian_filtered_path():
    _, shaky = camera_path(200)
    config = SmoothingConfig(radius_frames=15)
    expected = truncated_gaussian_filter(shaky, 15, np.sqrt(15))
    np.testing.assert_allclose(smoothed_positions(shaky, config), expected, atol=1e-6)


@pytest.mark.parametrize("radius", [6, 15, 30])
def test_removes_high_frequency_jitter_and_follows_the_intended_path(radius):
    # Bound stated: at least 90% of the jitter's energy above 2 Hz removed; the smoothed path stays
    # within 3 px RMS of the intended path, while the shaky one is 4 px RMS (per axis) away.
    intended, shaky = camera_path(300, seed=radius)
    stabilized = smoothed_positions(shaky, SmoothingConfig(radius_frames=radius))
    # Measured on the deviation from the intended path: a pan's ramp would leak over the whole spectrum.
    assert high_frequency_energy(stabilized - intended) < 0.10 * high_frequency_energy(shaky - intended)
    rms_to_intended = np.sqrt(np.mean((stabilized - intended) ** 2))
    assert rms_to_intended < 3.0
    assert np.sqrt(np.mean((shaky - intended) ** 2)) > 3.5


def test_no_accumulation_error_each_s_t_depends_only_on_its_window():
    rng = np.random.default_rng(1)
    steps = np.array([geometry.IDENTITY] + [rotation_about(rng.normal(0, 1), 320, 180) @ translation(*rng.normal(0, 5, 2))
                                            for _ in range(99)])
    config = SmoothingConfig(radius_frames=10)
    base = smooth(steps, config).orig_from_stab
    perturbed_steps = steps.copy()
    perturbed_steps[20] = rotation_about(10.0, 0, 0) @ translation(50, -30)  # a gross error at one frame
    perturbed = smooth(perturbed_steps, config).orig_from_stab
    changed = [t for t in range(100) if not np.allclose(base[t], perturbed[t], atol=1e-9)]
    # Frame 20's transform only enters windows that contain both 19 and 20: t in [10, 29].
    assert changed and min(changed) >= 10 and max(changed) <= 29


def test_radius_zero_is_identity_and_sigma_is_settable():
    _, shaky = camera_path(50)
    result = smooth(inter_frame(shaky), SmoothingConfig(radius_frames=0))
    np.testing.assert_allclose(result.orig_from_stab, np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-12)
    wide = smoothed_positions(shaky, SmoothingConfig(radius_frames=15, sigma=8.0))
    np.testing.assert_allclose(wide, truncated_gaussian_filter(shaky, 15, 8.0), atol=1e-6)


def test_windows_do_not_cross_scene_cuts():
    _, shaky = camera_path(120)
    steps = inter_frame(shaky)
    result = smooth(steps, SmoothingConfig(radius_frames=10), cuts=[60])
    # Before the cut: same as smoothing the first shot alone; after: same as the second shot alone.
    first = smooth(steps[:60], SmoothingConfig(radius_frames=10)).orig_from_stab
    second_steps = steps[60:].copy()
    second_steps[0] = np.eye(3)
    second = smooth(second_steps, SmoothingConfig(radius_frames=10)).orig_from_stab
    np.testing.assert_allclose(result.orig_from_stab[:60], first, atol=1e-9)
    np.testing.assert_allclose(result.orig_from_stab[60:], second, atol=1e-9)
    assert result.segment_starts == (0, 60)


def test_trajectories_report_the_camera_path_original_and_smoothed():
    _, shaky = camera_path(100)
    result = smooth(inter_frame(shaky), SmoothingConfig(radius_frames=15), width=640, height=360)
    # Original path: frame t's centre seen in frame 0 is displaced by c_t - c_0.
    np.testing.assert_allclose(result.original_trajectory[:, :2], shaky - shaky[0], atol=1e-6)
    np.testing.assert_allclose(result.smoothed_trajectory[:, :2],
                               truncated_gaussian_filter(shaky, 15, np.sqrt(15)) - shaky[0], atol=1e-6)
    np.testing.assert_allclose(result.original_trajectory[:, 2], 0.0, atol=1e-9)


def test_invalid_config_is_refused():
    with pytest.raises(ValueError):
        SmoothingConfig(radius_frames=-1)
    with pytest.raises(ValueError):
        SmoothingConfig(radius_frames=5, sigma=0.0)
