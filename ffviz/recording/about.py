"""The about tab: the run's summary (versions, input, how it was recorded, settings, timings), rewritten as more of
the run becomes known."""

from __future__ import annotations

import dataclasses
from typing import Any

import rerun as rr

import ffviz


def about_markdown(info: Any, config: Any, *, report: Any = None, crop: Any = None, warnings: int = 0,
                   recording: str = "", seconds_logging: float = 0.0, planned: tuple[str, str] | None = None) -> str:
    """The about tab's markdown. ``recording``: how the images are stored and at which size (one line);
    ``planned``: (planner, setting label) of the path the plan followed."""
    lines = ["# About this recording", "",
             f"- ffviz {ffviz.__version__}, rerun-sdk {rr.__version__} (open it with the same rerun version)"]
    lines += _input_lines(info)
    if recording:
        lines.append(f"- recorded: {recording}")
    if config is not None:
        lines += ["", "## Settings", ""] + [f"- {row}" for row in _settings_summary(config)]
        if planned is not None and getattr(getattr(config, "smoothing", None), "path", None) == "auto":
            planner, label = planned
            chose = "the L1 program in the crop window" if planner == "l1" else "eq. 18's path"
            lines.append(f"- auto chose: {chose} (`{label}`)")
    lines += _crop_lines(crop)
    lines += ["", "## Run", ""] + _run_lines(report, seconds_logging)
    lines.append(f"- warnings: {warnings}" + (" (listed below)" if warnings else ""))
    if config is not None:
        lines += ["", "## All settings", ""] + [f"- {row}" for row in _config_rows(config)]
    return "\n".join(lines) + "\n"


def _input_lines(info: Any) -> list[str]:
    if info is None:
        return []
    lines = [f"- input: `{info.path}`: {info.width}x{info.height}, {float(info.fps):.3f} frames/s, "
             f"{info.frame_count} frames"]
    colour = getattr(info, "colour", None)
    if colour is not None:
        shown = ("tone-mapped from HDR to SDR" if colour.hdr else "BT.2020 mapped into BT.709"
                 if colour.primaries == 9 else "as decoded")
        lines.append(f"- colour: {colour.summary()}; the output keeps it. Frames here are 8-bit display RGB ({shown})")
    return lines


def _crop_lines(crop: Any) -> list[str]:
    if crop is not None and hasattr(crop, "scales"):  # --crop adaptive
        return [f"- adaptive crop: scale {crop.scales.min():.3f}-{crop.scales.max():.3f} about ({crop.anchor[0]:.1f}, "
                f"{crop.anchor[1]:.1f}), {crop.cropping_ratio:.1%} of the area kept on average (stabilized/crop_scale)"]
    if crop is not None:
        return [f"- crop window: x0 {crop.x0:.1f}, y0 {crop.y0:.1f}, scale {crop.scale:.3f} "
                f"({crop.cropping_ratio:.1%} of the area kept)"]
    return []


def _run_lines(report: Any, seconds_logging: float) -> list[str]:
    if report is None:
        return ["- running (or interrupted): timings are written when the run finishes"]
    seconds = float(getattr(report, "seconds_motion", 0.0)) + float(getattr(report, "seconds_render", 0.0))
    lines = [f"- {report.n_frames} frames in {seconds:.1f} s (motion pass {report.seconds_motion:.1f} s, render pass "
             f"{report.seconds_render:.1f} s; the recorder, on its own thread, was busy {seconds_logging:.1f} s)"]
    if getattr(report, "cuts", None):
        lines.append(f"- scene cuts at frames {', '.join(map(str, report.cuts))}")
    return lines


_MODE_WORDS = {"full": "full frame: stabilize, then complete the missing area (chapter 4)",
               "crop": "crop: stabilize, then crop to a window every frame covers",
               "none": "stabilize only: the missing area stays black"}


def _settings_summary(config: Any) -> list[str]:
    """The run's settings in a few words, then each setting that differs from the defaults (`section.name`)."""
    if not dataclasses.is_dataclass(config):
        return [f"`{config}`"]
    rows = []
    mode = getattr(config, "mode", None)
    if mode is not None:
        fill = getattr(config, "crop_fill", 0.0)
        rows.append(f"mode: {_MODE_WORDS.get(mode, mode)}" if not fill else
                    f"mode: crop: stabilize, then crop to the largest window whose parts outside the frames are at "
                    f"most {fill:.2%} of the pixels over the clip, completed there (chapter 4)")
    smoothing = getattr(config, "smoothing", None)
    if smoothing is not None:
        words = {"gaussian": f"eq. 18, Gaussian over k = {smoothing.radius_frames} frames each side",
                 "auto": "auto (the L1 program in the crop window where as steady as eq. 18, else eq. 18)"}
        rows.append("camera path: " + words.get(smoothing.path, f"{smoothing.path} (L1 program)"))
    deblur = getattr(config, "deblur", None)
    if mode == "full" and deblur is not None:
        rows.append("deblurring: " + (f"on, from neighbours {deblur.min_ratio:g}x sharper within "
                                      f"{deblur.neighbour_frames} frames" if deblur.enabled else "off"))
    try:  # the mode's own defaults (its camera path differs); the mode itself against the tool's default mode
        defaults = type(config)(**({"mode": mode} if mode is not None else {}))
    except (TypeError, ValueError):
        return rows
    changed = _changed_settings(config, defaults)
    mode_field = type(config).__dataclass_fields__.get("mode")
    if mode_field is not None and mode != mode_field.default:
        changed.insert(0, ("mode", mode))
    rows.append("changed from the defaults: " + (", ".join(f"`{name} = {value!r}`" for name, value in changed)
                                                if changed else "nothing"))
    return rows


def _changed_settings(config: Any, defaults: Any, prefix: str = "") -> list[tuple[str, Any]]:
    changed = []
    for field in dataclasses.fields(config):
        value, default = getattr(config, field.name), getattr(defaults, field.name, None)
        if dataclasses.is_dataclass(value) and type(value) is type(default):
            changed += _changed_settings(value, default, f"{prefix}{field.name}.")
        elif value != default:
            changed.append((f"{prefix}{field.name}", value))
    return changed


def _config_rows(config: Any) -> list[str]:
    """One line per setting: `section.name = value`, nested dataclasses flattened."""
    if not dataclasses.is_dataclass(config):
        return [f"`{config}`"]
    rows: list[str] = []
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if dataclasses.is_dataclass(value):
            inner = ", ".join(f"{f.name}={getattr(value, f.name)!r}" for f in dataclasses.fields(value))
            rows.append(f"**{field.name}**: {inner}")
        else:
            rows.append(f"**{field.name}**: {value!r}")
    return rows

