"""`ffviz debug INPUT`: the what-if debugger from the command line.

With ``--frame``: scriptable, for reviews and CI: frame T rendered as the default and as one variant per ``--set``
into one recording, a table of what changed printed, and exit. Without: the interactive debugger in the browser
(ffviz/debug_app.py). Every setting is checked before anything is rendered: a bad one is one line naming the valid
choices, and nothing is recorded.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from pipeline import settings as named
from pipeline.config import StabilizeConfig
from pipeline.errors import ConfigError, InputError

RECORDINGS = Path("recordings")


def add_parser(commands: argparse._SubParsersAction, record_size_type: Any, record_size_default: Any) -> None:
    p = commands.add_parser(
        "debug", help="re-render frames alone with other settings and compare them (what-if debugger)",
        description="Render frames of INPUT alone, as the default and with other settings, into one recording whose "
                    "tabs show each stage of every variant side by side. With --frame: render and exit; without: "
                    "open the interactive debugger in the browser.",
        epilog="examples:\n  ffviz debug shaky.mp4 --frame 231 --set deblur.alpha=4 "
               "--set completion.neighbour_frames=2,deblur.alpha=4 --rrd review.rrd\n"
               "  ffviz debug shaky.mp4          # interactive, in the browser",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", type=Path, metavar="INPUT", help="the video to debug")
    p.add_argument("--frame", type=_frames, default=None, metavar="T[,T...]",
                   help="frames to render (from 0), then exit (default: the interactive debugger)")
    p.add_argument("--set", dest="variants", action="append", type=_settings, default=[], metavar="SETTINGS",
                   help="one variant: SECTION.FIELD=VALUE, several comma-separated (e.g. deblur.alpha=4 or "
                        "completion.neighbour_frames=2,deblur.alpha=4; a tuple's items joined by +); repeat for more "
                        "(default: the default only)")
    p.add_argument("--base", type=_settings, default={}, metavar="SETTINGS",
                   help="the session's own settings, every variant's starting point (motion.* and rolling_shutter "
                        "only here) (default: the defaults)")
    p.add_argument("--rrd", type=Path, default=None, metavar="FILE",
                   help=f"the recording (default: {RECORDINGS}/<input name>.debug.rrd); pass 1's motion is cached "
                        "beside it")
    p.add_argument("--record-size", type=record_size_type, default=record_size_default, metavar="PX|full",
                   help="long side of the recorded pictures in pixels, or 'full' (default: %(default)s)")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="frames rendered at once (default: cores)")
    p.add_argument("--port", type=int, default=9091, metavar="PORT",
                   help="interactive: the debugger page's port on 127.0.0.1 (default: %(default)s)")


def _frames(text: str) -> tuple[int, ...]:
    try:
        frames = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected frame numbers separated by commas, not {text!r}") from None
    if not frames or min(frames) < 0:
        raise argparse.ArgumentTypeError(f"frame numbers must be 0 or more, not {text!r}")
    return frames


def _settings(text: str) -> dict[str, str]:
    try:
        return named.parse_settings(text)
    except ConfigError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def cmd_debug(args: argparse.Namespace) -> int:
    if not args.input.is_file():
        raise InputError(f"input file not found: {args.input}")
    base = named.with_settings(StabilizeConfig(), args.base)
    for variant in args.variants:  # every setting judged before anything is rendered or written
        if named.changes_pass_1(variant):
            raise ConfigError(f"--set {','.join(variant)}: pass 1's settings (motion.*, rolling_shutter) go in --base")
        named.with_settings(base, variant)
    rrd = args.rrd or RECORDINGS / f"{args.input.stem}.debug.rrd"
    if args.frame is None:
        from ffviz import debug_app

        return debug_app.serve(args.input, base, rrd=rrd, record_size=args.record_size, port=args.port,
                               workers=args.workers)
    return _render_and_exit(args, base, rrd)


def _render_and_exit(args: argparse.Namespace, base: StabilizeConfig, rrd: Path) -> int:
    from ffviz.debugger import Debugger
    from ffviz.progress import tqdm_progress

    debugger = Debugger(args.input, base, rrd=rrd, record_size=args.record_size, workers=args.workers,
                        progress=tqdm_progress)
    with debugger:
        beyond = [t for t in args.frame if t >= debugger.n_frames]
        if beyond:
            raise ConfigError(f"--frame {','.join(map(str, beyond))}: not in the video, whose frames are "
                              f"0-{debugger.n_frames - 1}")
        rows = []
        for t in args.frame:
            for variant in ({}, *args.variants):
                debugger.frame(t, variant)
                rows.append((t, named.label(variant), debugger.rendered[-1][2]))
    _print_table(rows, debugger)
    return 0


def _print_table(rows: list[tuple[int, str, float]], debugger: Any) -> None:
    from ffviz.rrd import Recording
    from ffviz.recording.variants import PSNR_CAP, variant_entity
    from ffviz.runner import view_command

    recording = Recording.load(debugger.rrd)
    print("| frame | variant | render s | PSNR against the default (dB) | share filled another way |")
    print("|---|---|---|---|---|")
    for t, name, seconds in rows:
        psnr = _at(recording, variant_entity(name, "diff/stats/psnr_db"), t, PSNR_CAP)
        changed = _at(recording, variant_entity(name, "diff/stats/changed_source"), t, PSNR_CAP)
        print(f"| {t} | {name} | {seconds:.1f} | {psnr} | {changed} |")
    print(f"wrote {debugger.rrd} ({len(rows)} frame variants); to look inside: {view_command(debugger.rrd)}",
          flush=True)


def _at(recording: Any, entity: str, t: int, psnr_cap: float) -> str:
    if entity not in recording.entities:
        return "-"
    frames, values = recording.scalars(entity)
    found = [v for f, v in zip(frames, values) if f == t]
    if not found:
        return "-"
    return "identical" if entity.endswith("psnr_db") and found[-1] >= psnr_cap else f"{found[-1]:.3g}"
