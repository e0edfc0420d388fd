"""`ffviz figures`: every thesis figure rendered from a recording alone, with the expected panels."""

from __future__ import annotations

import pytest
from matplotlib.image import imread

from ffviz import cli, figures
from ffviz.recorder import RerunRecorder
from ffviz.rrd import Recording
from pipeline.evaluation import synthetic
from pipeline.runtime.observer import Observers, StageCollector
from pipeline.stabilize import StabilizeConfig, stabilize

TRACED = (4, 20)
FRAMES = (4, 12, 20)


@pytest.fixture(scope="module")
def full_recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("figures")
    video = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=30, seed=3, jitter_px=4.0,
                                                         blur_length_px=6.0))
    clip = folder / "shaky.mp4"
    synthetic.write_video(video, clip)
    rrd = folder / "full.rrd"
    recorder = RerunRecorder(rrd, level="full", trace_frames=TRACED)
    deblurred = StageCollector("deblur")
    stabilize(clip, None, StabilizeConfig(mode="full"), observer=Observers(recorder, deblurred))
    return rrd, {stamp.index: result for stamp, result in deblurred.results["deblur"]}


def expected_panels(deblurred: dict) -> dict[str, int]:
    sharpened = [t for t, r in sorted(deblurred.items()) if r.neighbours]
    assert sharpened, "some blurred frame should have had a sharper neighbour"
    blurriest = sorted(sharpened, key=lambda t: -deblurred[t].blurriness)[:figures.MAX_DEBLUR_FRAMES]
    deblur_rows = [t for t in FRAMES if t in sharpened] or blurriest
    return {
        "trajectories": 4,  # x, y, angle, zoom
        "stabilized_vs_original": 2 * len(FRAMES),
        "completed_vs_stabilized": 2 * len(FRAMES),
        "motion_inpainting": figures.FMM_COLUMNS * len(TRACED),
        "deblurring": 3 * len(deblur_rows),  # before, after, weights
        "blurriness": 1,
        "mosaic_variance": 2 * len(FRAMES),
    }


def test_every_figure_is_written_with_its_panels(full_recording, tmp_path, capsys):
    rrd, deblurred = full_recording
    expected = expected_panels(deblurred)
    assert set(expected) == set(figures.FIGURES)
    out = tmp_path / "png"
    assert cli.main(["figures", str(rrd), "--output-dir", str(out), "--frames", ",".join(map(str, FRAMES))]) == 0
    printed = capsys.readouterr().out
    assert "skipped" not in printed
    for name in expected:
        image = imread(out / f"{name}.png")
        assert image.ndim == 3 and min(image.shape[:2]) > 100 and image.std() > 0.05, name
    built = {r.name: r.figure for r in figures.build_figures(Recording.load(rrd), FRAMES)}
    for name, panels in expected.items():
        axes = [ax for ax in built[name].axes if ax.get_visible() and ax.get_label() != "<colorbar>"]
        assert len(axes) == panels, name
        assert all(ax.has_data() for ax in axes), name


@pytest.mark.parametrize("fmt, magic", [("pdf", b"%PDF"), ("svg", b"<?xml")])
def test_pdf_and_svg_on_request(full_recording, tmp_path, fmt, magic):
    rrd, _ = full_recording
    written = figures.render_figures(rrd, tmp_path, fmt=fmt)
    assert sorted(p.name for p in written) == sorted(f"{name}.{fmt}" for name in figures.FIGURES)
    for path in written:
        assert path.read_bytes().startswith(magic), path


def test_a_summary_recording_gives_the_trajectories_and_notes_the_rest(tmp_path, capsys):
    video = synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=20, seed=2))
    clip = tmp_path / "clip.mp4"
    synthetic.write_video(video, clip)
    rrd = tmp_path / "summary.rrd"
    collector = StageCollector("deblur")
    stabilize(clip, None, StabilizeConfig(mode="none"), observer=Observers(RerunRecorder(rrd, level="summary"), collector))
    assert cli.main(["figures", str(rrd), "--output-dir", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    # Series only: the trajectories, and the blurriness when the pipeline deblurred.
    series = {"trajectories"} | ({"blurriness"} if collector.results["deblur"] else set())
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(f"{name}.png" for name in series)
    for name in set(figures.FIGURES) - series:
        assert f"skipped {name}:" in printed


def test_a_file_that_is_not_a_recording_is_one_line_error(tmp_path, capsys):
    bogus = tmp_path / "x.rrd"
    bogus.write_text("hello")
    assert cli.main(["figures", str(bogus), "--output-dir", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a Rerun recording" in err[0]


def test_figures_use_the_viewers_colours(full_recording):
    """Trajectories in the recorder's line colours; the variance map on the viewer's colour bar (turbo, 0-400)."""
    from matplotlib.colors import to_hex

    from ffviz import visual

    recording = Recording.load(full_recording[0])
    fig = figures.trajectories(recording)
    for ax, axis in zip(fig.axes, ("x", "y", "angle")):
        colours = [to_hex(line.get_color()) for line in ax.get_lines()]
        assert colours == [visual.hex_colour(visual.TRAJECTORY_COLOURS[kind, axis])
                           for kind in ("original", "smoothed", "gaussian", "l1")][:len(colours)]
    fig = figures.mosaic_variance(recording)
    images = [im for ax in fig.axes for im in ax.get_images() if im.get_cmap().name == "turbo"]
    assert images and all(im.get_clim() == visual.VARIANCE_RANGE for im in images)
