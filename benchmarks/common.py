"""What the benchmark scripts share: the repository's paths, their common options, and how they write a report.

The scripts run from the repository's root as modules, ``python -m benchmarks.speed.motion_speed [OPTIONS]``
(benchmarks/README.md lists them). Common options, each meaning the same in every script that takes it:
``--clip PATH`` (the clip measured), ``--frames N`` (its first N frames), ``--repeat N`` (runs of each measurement;
the report gives their median), ``--work DIR`` (inputs made once and kept), ``--report PATH`` / ``--no-report``.

A report (docs/benchmarks-*.md) is made of sections, each from its ``<!-- section: NAME -->`` marker to the next
marker (or the end); a script replaces only its own section (``write_section``), so the sections other scripts
write, and those written by hand (the decision log's figures, ``<!-- section: decision-log -->``), stay as they
are. Text above the first marker is the report's header, also kept.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import re
import time
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
VIDEOS = ROOT.parent / "shared" / "videos"  # the shared clips (never committed)

SPEED_REPORT = DOCS / "benchmarks-speed.md"
SPEED_HEADER = """# Speed benchmarks (issue 24)

Each section below is written by the benchmark script it names; rerun that script to regenerate it. CPU seconds
are user + system of the measuring process (and its children), the figure that holds on this shared 2-core
machine; wall seconds depend on what else runs. How `ffviz bench` measures: [benchmarking.md](benchmarking.md).
"""
RECORDING_REPORT = DOCS / "benchmarks-recording.md"
RECORDING_HEADER = """# Recording benchmarks (issue 22)

Each section is written by the benchmark script it names; rerun it to regenerate the section.
"""


# -- options -------------------------------------------------------------------------------------------------

def parser(doc: str) -> argparse.ArgumentParser:
    """A script's argument parser, described by the first line of its docstring ``doc``."""
    return argparse.ArgumentParser(description=doc.splitlines()[0])


def add_clip(parser: argparse.ArgumentParser, default: Path) -> None:
    parser.add_argument("--clip", type=Path, default=default, help="the clip measured (default: %(default)s)")


def add_frames(parser: argparse.ArgumentParser, default: int | None, help: str = "") -> None:
    parser.add_argument("--frames", type=int, default=default, metavar="N",
                        help=(help or "only the first N frames of each clip") + " (default: %(default)s)")


def add_repeat(parser: argparse.ArgumentParser, default: int, *other_spellings: str) -> None:
    parser.add_argument("--repeat", *other_spellings, dest="repeat", type=int, default=default, metavar="N",
                        help="runs of each measurement; the report gives their median (default: %(default)s)")


def add_work(parser: argparse.ArgumentParser, default: Path) -> None:
    parser.add_argument("--work", type=Path, default=default, metavar="DIR",
                        help="inputs made once and kept, and the outputs (default: %(default)s)")


def add_report(parser: argparse.ArgumentParser, report: Path, *, by_default: bool = True) -> None:
    """--report PATH and --no-report. ``by_default``: the script writes its section of ``report`` unless told
    --no-report; otherwise only when given --report (alone: ``report``; or --report PATH)."""
    shown = report.relative_to(ROOT) if report.is_relative_to(ROOT) else report
    if by_default:
        parser.add_argument("--report", type=Path, default=report, metavar="PATH",
                            help="the report whose section this script rewrites (default: %(default)s)")
    else:
        parser.add_argument("--report", type=Path, nargs="?", const=report, default=None, metavar="PATH",
                            help=f"also write the results as this script's section of PATH (--report alone: {shown}); "
                                 "default: print only")
    parser.add_argument("--no-report", action="store_true", help="print only, write no report")


def report_path(args: argparse.Namespace) -> Path | None:
    """The report the parsed ``args`` say to write, or None (print only)."""
    return None if args.no_report else args.report


def from_tests(name: str) -> ModuleType:
    """tests/NAME.py as a module (tests/ is not a package): the helpers a benchmark shares with a test."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "tests" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# -- reports -------------------------------------------------------------------------------------------------

def machine_line() -> str:
    """When, on how many cores, which Python, and the load the machine started with."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {os.cpu_count()} cores, "
            f"Python {platform.python_version()}, load average {load:.1f} at the start")


def write_section(name: str, body: str, report: Path, header: str = "") -> Path:
    """Replace section ``name`` of ``report`` with ``body`` (Markdown), or append it; a report that does not exist
    yet starts with ``header``. Every other section and the header stay as they are."""
    marker = f"<!-- section: {name} -->"
    text = report.read_text() if report.is_file() else header
    block = f"{marker}\n{body.rstrip()}\n\n"
    pattern = re.compile(r"^" + re.escape(marker) + r"\n.*?(?=^<!-- section: |\Z)", re.S | re.M)
    if pattern.search(text):
        text = pattern.sub(lambda _: block, text, count=1)
    else:
        text = (text.rstrip() + "\n\n" if text.strip() else "") + block
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text(text.rstrip() + "\n")
    return report


def save(name: str, lines: list[str], report: Path | None, header: str = "") -> None:
    """Write ``lines`` as section ``name`` of ``report`` and say so (None: write nothing), for scripts that printed
    their rows as they were measured."""
    if report is not None:
        print(f"wrote {write_section(name, chr(10).join(lines), report, header)}")


def publish(name: str, lines: list[str], report: Path | None, header: str = "") -> None:
    """Write ``lines`` as section ``name`` of ``report`` (None: write nothing) and print them."""
    save(name, lines, report, header)
    print("\n".join(lines))
