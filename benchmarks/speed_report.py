"""docs/benchmarks-speed.md: one section per speed benchmark (issue 24), each rewritten by the script that measures it.

A section runs from its ``<!-- section: NAME -->`` marker to the next marker; a script replaces only its own, so
the motion, encoder, fast-preset and profile measurements can be regenerated one at a time.
"""

from __future__ import annotations

import os
import platform
import re
import time
from pathlib import Path

REPORT = Path(__file__).resolve().parents[1] / "docs" / "benchmarks-speed.md"
HEADER = """# Speed benchmarks (issue 24)

Each section below is written by the benchmark script it names; rerun that script to regenerate it. CPU seconds
are user + system of the measuring process (and its children), the figure that holds on this shared 2-core
machine; wall seconds depend on what else runs. How `ffviz bench` measures: [benchmarking.md](benchmarking.md).
"""


def machine_line() -> str:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {os.cpu_count()} cores, "
            f"Python {platform.python_version()}, load average {load:.1f} at the start")


def write_section(name: str, body: str, report: Path = REPORT) -> Path:
    """Replace (or append) section ``name`` of ``report`` with ``body`` (Markdown, starting with its heading)."""
    marker = f"<!-- section: {name} -->"
    text = report.read_text() if report.is_file() else HEADER
    block = f"{marker}\n{body.rstrip()}\n\n"
    pattern = re.compile(re.escape(marker) + r".*?(?=<!-- section: |\Z)", re.S)
    text = pattern.sub(lambda _: block, text) if marker in text else text.rstrip() + "\n\n" + block
    report.write_text(text.rstrip() + "\n")
    return report


def publish(name: str, lines: list[str], report: Path | None) -> None:
    """Write ``lines`` as section ``name`` of ``report`` (None: write nothing) and print them."""
    if report is not None:
        print(f"wrote {write_section(name, chr(10).join(lines), report)}")
    print("\n".join(lines))
