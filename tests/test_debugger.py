"""The what-if debugger: a frame rendered alone equals that frame of a whole run; settings by name; variants
recorded side by side with their differences; the scriptable `ffviz debug`; bad input refused before anything."""

from __future__ import annotations

import numpy as np
import pytest

from ffviz import cli, entities as ent
from ffviz.debugger import Debugger
from ffviz.recording.variants import variant_entity
from ffviz.rrd import Recording
from pipeline import settings as named
from pipeline.config import StabilizeConfig
from pipeline.errors import ConfigError
from pipeline.evaluation import synthetic
from pipeline.frame_session import FrameSession
from pipeline.runtime.observer import StageCollector
from pipeline.stabilize import stabilize
from tests.conftest import real_clip


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    path = tmp_path_factory.mktemp("debug") / "shaky.mp4"
    synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(width=320, height=180, n_frames=24, seed=5)),
                          path)
    return path


def _whole_run(path, config):
    outputs = StageCollector("output")
    stabilize(path, None, config, observer=outputs)
    return [rgb for _, rgb in outputs.results["output"]]


@pytest.mark.parametrize("config", [StabilizeConfig(), StabilizeConfig(mode="crop"),
                                    named.with_settings(StabilizeConfig(), {"deblur.alpha": "4",
                                                                            "completion.neighbour_frames": "2"})],
                         ids=["full", "crop", "settings"])
def test_a_frame_rendered_alone_is_the_whole_runs_frame(clip, config, tmp_path):
    whole = _whole_run(clip, config)
    session = FrameSession(clip, config, cache=tmp_path / "motion.npz")
    for t in (0, 1, 11, 22, 23):  # the ends (windows cut short) and the middle
        np.testing.assert_array_equal(session.render(t).output, whole[t], err_msg=f"frame {t}")


@pytest.mark.real_video
def test_a_real_clips_frame_rendered_alone_is_the_whole_runs_frame(tmp_path):
    path = real_clip("sudheerachary_small-shaky-5.avi")
    whole = _whole_run(path, StabilizeConfig())
    session = FrameSession(path, cache=tmp_path / "motion.npz")
    for t in (0, 57, 131, len(whole) - 1):  # decoded after a seek to the key frame before each window
        np.testing.assert_array_equal(session.render(t).output, whole[t], err_msg=f"frame {t}")


def test_pass_1_is_read_from_its_cache_and_recomputed_when_the_input_changes(clip, tmp_path, monkeypatch):
    cache = tmp_path / "motion.npz"
    first = FrameSession(clip, cache=cache)
    import pipeline.frame_session as frame_session

    def refused(*args, **kwargs):
        raise AssertionError("pass 1 ran again")

    monkeypatch.setattr(frame_session, "estimate_motion", refused)
    again = FrameSession(clip, cache=cache)
    np.testing.assert_array_equal(again.motion.curr_from_prev, first.motion.curr_from_prev)
    assert again.motion.times_s == first.motion.times_s
    with pytest.raises(AssertionError, match="pass 1 ran again"):  # other motion settings: another key
        FrameSession(clip, named.with_settings(StabilizeConfig(), {"motion.max_corners": "200"}), cache=cache)


def test_variants_are_recorded_side_by_side_with_their_differences(clip, tmp_path):
    rrd = tmp_path / "debug.rrd"
    with Debugger(clip, rrd=rrd) as debugger:
        default = debugger.frame(12)
        tight = debugger.frame(12, {"completion.neighbour_frames": 1}, name="tight")
        path = debugger.frame(12, {"smoothing.radius_frames": "5"})
    assert default.completion is not None and default.deblur is not None  # every intermediate returned
    assert not np.array_equal(default.output, tight.output)
    recording = Recording.load(rrd)
    for name in ("default", "tight", "radius_frames=5"):
        for entity in (ent.OUTPUT_FRAME, ent.COMPLETION_SOURCE, ent.STABILIZED_MISSING, ent.COMPLETION_VARIANCE):
            assert recording.indices(variant_entity(name, entity)) == [12], (name, entity)
    frames, psnr = recording.scalars(variant_entity("tight", "diff/stats/psnr_db"))
    assert list(frames) == [12] and 20 < psnr[0] < 99
    _, changed = recording.scalars(variant_entity("tight", "diff/stats/changed_source"))
    changed_map = recording.image(variant_entity("tight", "diff/source"), 12)
    assert 0 < changed[0] == pytest.approx(changed_map.mean(), abs=1e-6)
    difference = recording.image(variant_entity("tight", "diff/output"), 12)
    assert difference.shape[:2] == default.output.shape[:2]
    assert variant_entity("default", "diff/output") not in recording.entities
    # the path-shaping variant re-planned the path: both paths recorded for every frame
    for name in ("default", "radius_frames=5"):
        frames, _ = recording.scalars(variant_entity(name, "path/x"))
        assert len(frames) == 24


def test_bad_settings_and_frames_are_refused_before_anything_is_recorded(clip, tmp_path):
    rrd = tmp_path / "debug.rrd"
    with Debugger(clip, rrd=rrd) as debugger:
        for settings, words in (({"deblur.alfa": 4}, "alpha, enabled"), ({"completion.neighbour_frames": -2}, ">= 0"),
                                ({"deblur.alpha": "four"}, "a number"), ({"motion.max_corners": 10}, "open the video"),
                                ({"deblur": 4}, "deblur.alpha")):
            with pytest.raises(ConfigError, match=words):
                debugger.frame(3, settings)
        with pytest.raises(ConfigError, match="0-23"):
            debugger.frame(24)
        assert debugger.rendered == []
    assert not any(entity.startswith("variants/") for entity in Recording.load(rrd).entities)


def test_the_scriptable_form_records_the_default_and_one_variant_per_set(clip, tmp_path, capsys):
    rrd = tmp_path / "review.rrd"
    assert cli.main(["debug", str(clip), "--frame", "5,17", "--set", "deblur.alpha=4", "--set",
                     "completion.neighbour_frames=2,deblur.alpha=4", "--rrd", str(rrd)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| 5 |") or line.startswith("| 17 |")]
    assert len(rows) == 6 and "neighbour_frames=2,alpha=4" in out and f"wrote {rrd}" in out
    recording = Recording.load(rrd)
    for name in ("default", "alpha=4", "neighbour_frames=2,alpha=4"):
        assert recording.indices(variant_entity(name, ent.OUTPUT_FRAME)) == [5, 17]


@pytest.mark.parametrize("argv, words", [
    (["--frame", "3", "--set", "deblur.alfa=4"], "unknown setting 'deblur.alfa'; the settings of 'deblur' are: alpha"),
    (["--frame", "3", "--set", "completion.neighbour_frames=-1"], "completion radius must be >= 0"),
    (["--frame", "99"], "not in the video, whose frames are 0-23"),
    (["--frame", "3", "--set", "motion.max_corners=9"], "go in --base"),
])
def test_bad_input_is_one_line_and_no_recording(clip, tmp_path, capsys, argv, words):
    rrd = tmp_path / "bad.rrd"
    assert cli.main(["debug", str(clip), "--rrd", str(rrd), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err
    assert not rrd.exists() and not list(tmp_path.glob(".bad.*"))


def test_settings_by_name_read_each_type_and_name_the_choices():
    config = named.with_settings(StabilizeConfig(), {"deblur.enabled": "off", "completion.flow_max_side": "none",
                                                     "completion.candidates": "local warp+majority",
                                                     "smoothing.max_shift": "12.5", "mode": "crop"})
    assert (config.deblur.enabled, config.completion.flow_max_side, config.completion.candidates,
            config.smoothing.max_shift, config.mode) == (False, None, ("local warp", "majority"), 12.5, "crop")
    assert named.parse_settings("a.b=1, c.d=x y") == {"a.b": "1", "c.d": "x y"}
    assert named.label({"deblur.alpha": 4, "smoothing.radius_frames": "90"}) == "alpha=4,radius_frames=90"
    assert "completion.mosaic.variance_threshold" in named.setting_names()
    with pytest.raises(ConfigError, match="choose one of full, none, crop"):
        named.with_settings(StabilizeConfig(), {"mode": "zoom"})
    with pytest.raises(ConfigError, match="expected SECTION.FIELD=VALUE"):
        named.parse_settings("deblur.alpha")


class _FakeViewer:
    """What the notebook panel uses of rerun.notebook.Viewer: its event callbacks and the time control."""

    def __init__(self) -> None:
        self.callbacks, self.times = [], []

    def on_event(self, callback) -> None:
        self.callbacks.append(callback)

    def set_time_ctrl(self, *, timeline=None, sequence=None, **_) -> None:
        self.times.append((timeline, sequence))

    def emit(self, event) -> None:
        for callback in self.callbacks:
            callback(event)


def test_the_notebook_follows_the_time_cursor_and_renders_the_frame_on_apply(clip, tmp_path):
    """The viewer's events move the frame control (JSON as the widget sends them, parsed by rerun's own reader);
    "apply" renders the frame the cursor is on with the changed settings; a bad setting is a line, not a render."""
    import ipywidgets
    from rerun._event import _viewer_event_from_json_str

    from ffviz.debug_app import _notebook_panel
    from ffviz.debug_session import DebugSession

    with Debugger(clip, rrd=tmp_path / "nb.rrd") as debugger:
        session = DebugSession(debugger)
        viewer = _FakeViewer()
        panel = _notebook_panel(session, viewer, ipywidgets)
        ids = '"application_id": "ffviz-debug", "recording_id": "r"'
        viewer.emit(_viewer_event_from_json_str('{"type": "timeline_change", "timeline": "frame", "time": 3, ' + ids + '}'))
        viewer.emit(_viewer_event_from_json_str('{"type": "time_update", "time": 9, ' + ids + '}'))
        frame_box = panel.children[0].children[0]
        assert session.frame == 9 and frame_box.value == 9
        viewer.emit(_viewer_event_from_json_str('{"type": "time_update", "time": 500, ' + ids + '}'))
        assert session.frame == 23  # clamped to the last frame
        frame_box.value = 9  # typed: the viewer's cursor follows
        assert viewer.times[-1] == (ent.FRAME_TIMELINE, 9)
        controls = {child.description: child for child in panel.children[1].children}
        controls["deblur alpha (eq. 31)"].value = "4"
        apply, status = panel.children[0].children[2], panel.children[3]
        apply.click()
        assert debugger.rendered[-1][:2] == (9, "alpha=4") and "variant 'alpha=4' rendered" in status.value
        controls["deblur alpha (eq. 31)"].value = "-1"
        apply.click()
        assert status.value.startswith("not rendered:") and "alpha" in status.value
        assert [(t, name) for t, name, _ in debugger.rendered] == [(9, "default"), (9, "alpha=4")]  # default first
