"""Every `ffviz` command and option is documented for users: help text on each, `--help` runs for each command."""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ffviz import cli


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = cli.build_parser()
    (commands,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(commands.choices)


def documented_actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) and a.help != argparse.SUPPRESS]


COMMANDS = sorted(subcommands())


def test_every_command_is_listed_with_help():
    parser = cli.build_parser()
    (commands,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    listed = {choice.dest: choice.help for choice in commands._choices_actions}
    assert set(listed) == set(COMMANDS) == {"stabilize", "demo", "metrics", "view", "snapshot", "figures", "batch",
                                            "bench", "compare", "debug"}
    assert all(text and text.strip() for text in listed.values()), listed
    assert "thin layer" not in (parser.description or "")
    for action in documented_actions(parser):
        assert action.help and action.help.strip(), action.option_strings


@pytest.mark.parametrize("command", COMMANDS)
def test_every_option_and_argument_has_help_with_its_default(command):
    for action in documented_actions(subcommands()[command]):
        name = action.option_strings[-1] if action.option_strings else action.dest
        assert action.help and action.help.strip(), f"ffviz {command} {name}: no help text"
        assert len(action.help) >= 15, f"ffviz {command} {name}: help too short to say anything: {action.help!r}"
        takes_value = not isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction))
        if action.option_strings and takes_value and not action.required:
            assert "default" in action.help or "required" in action.help, \
                f"ffviz {command} {name}: help does not say its default: {action.help!r}"


@pytest.mark.parametrize("command", COMMANDS)
def test_output_paths_follow_one_convention(command):
    """-o/--output names a file; --output-dir a folder; no other visible spelling."""
    for action in documented_actions(subcommands()[command]):
        options = set(action.option_strings)
        if "-o" in options:
            assert options == {"-o", "--output"}, (command, options)
        if "--output-dir" in options:
            assert options == {"--output-dir"}, (command, options)
        assert "--out" not in options and "--trace-frames" not in options, (command, options)


def test_frame_selections_share_one_name():
    for command in ("stabilize", "demo", "batch", "figures"):
        (frames,) = [a for a in documented_actions(subcommands()[command]) if "--frames" in a.option_strings]
        assert frames.metavar == "T1,T2,..."
    assert cli.build_parser().parse_args(["stabilize", "a.mp4", "-o", "b.mp4", "--frames", "3,1"]).frames == (1, 3)


def test_old_spellings_still_parse_hidden(capsys):
    parse = cli.build_parser().parse_args
    assert parse(["stabilize", "a.mp4", "-o", "b.mp4", "--trace-frames", "5"]).frames == (5,)
    assert parse(["figures", "a.rrd", "-o", "figs"]).output_dir == Path("figs")
    assert parse(["demo", "-o", "d"]).output_dir == Path("d")
    assert capsys.readouterr().err.count("is deprecated here") == 3


@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_help_runs_in_process(command, capsys):
    argv = ["--help"] if command is None else [command, "--help"]
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: ffviz")


def test_stabilize_help_ends_with_examples(capsys):
    with pytest.raises(SystemExit):
        cli.main(["stabilize", "--help"])
    text = capsys.readouterr().out
    examples = text[text.index("examples:"):]
    assert examples.count("ffviz stabilize ") >= 4 and "ffviz view recordings/shaky.rrd" in examples
    flat = " ".join(text.split())  # argparse wraps the help
    assert "(default: full)" in flat
    assert "(default: 60; 30 in crop mode with a window inside every frame)" in flat
    assert "frames" in text


def test_help_runs_as_installed_command():
    """The console script the user runs, as a subprocess (the venv's ffviz beside this Python)."""
    script = Path(sys.executable).parent / "ffviz"
    if not script.is_file():
        script = Path(shutil.which("ffviz") or "")
    if not script.is_file():
        pytest.skip("no ffviz console script installed beside this Python")
    for command in COMMANDS:
        result = subprocess.run([str(script), command, "--help"], capture_output=True, text=True, timeout=60)
        assert result.returncode == 0 and result.stderr == "", (command, result.stderr)
        assert result.stdout.startswith(f"usage: ffviz {command}")


def test_view_command_is_runnable_as_printed(monkeypatch, tmp_path):
    monkeypatch.setenv("FFVIZ_LAUNCHER", "./run")
    monkeypatch.setenv("FFVIZ_USER_CWD", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    assert cli.view_command(Path("recordings/demo.rrd")) == "./run view recordings/demo.rrd"
    monkeypatch.delenv("FFVIZ_LAUNCHER")
    monkeypatch.setattr(sys, "argv", ["/nonexistent/python-module"])
    assert cli.view_command(Path("r.rrd")).endswith("-m ffviz.cli view r.rrd")
