"""How `ffviz bench` measures one command: as a child process, from outside, so no method pays for the benchmark's
Python. Wall and CPU seconds and the peak resident set come from the child's own rusage (os.wait4, taken by a small
launcher, below), and the share of the machine's CPU time the hypervisor took meanwhile (steal, /proc/stat): on a
virtual machine whose host is busy, a program on both cores loses more than one on one core, so ratios between
methods move with it. The benchmarks in benchmarks/ measure their commands the same way (``run_measured``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence


@dataclass(frozen=True)
class ChildRun:
    seconds: float  # wall clock
    cpu_seconds: float  # user + system, the command and the children it waited for
    peak_rss_bytes: int  # the largest resident set of the command (or of a child it waited for)
    returncode: int
    output_tail: str  # last non-empty line of its stderr (else stdout), for a one-line failure report
    # Clock ticks of the whole machine while it ran (all CPUs): (stolen by the hypervisor, all). None where
    # /proc/stat is not available.
    machine_ticks: tuple[int, int] | None = None

    @property
    def steal(self) -> float | None:
        """Share of the machine's CPU time the hypervisor took while the command ran."""
        return steal_share(self.machine_ticks)


# Linux keeps a process's peak RSS across exec, and at exec counts the pages it still shares with the
# parent it was forked from: a command forked straight from this process would report at least this
# process's own size (`true` forked from a 500 MB Python reads 511 MiB). So a small launcher (Python
# without site, ~6 MB) forks the command, waits for it with wait4 and reports the command's own rusage.
_LAUNCHER = """
import os, sys, time
report, argv = sys.argv[1], sys.argv[2:]
started = time.perf_counter()
pid = os.fork()
if pid == 0:
    try:
        os.execvp(argv[0], argv)
    except OSError as error:
        sys.stderr.write(f"cannot run {argv[0]}: {error.strerror}\\n")
    os._exit(127)
_, status, usage = os.wait4(pid, 0)
with open(report, "w") as f:
    f.write(f"{time.perf_counter() - started} {usage.ru_utime + usage.ru_stime} {usage.ru_maxrss}")
code = os.waitstatus_to_exitcode(status)
sys.exit(code if code >= 0 else 128 - code)
"""


def measured_argv(command: Sequence[str], report: Path) -> list[str]:
    """``command`` run under the measuring launcher, which writes "wall_s cpu_s peak_rss_kib" to ``report``
    and exits with the command's status (128 + N for signal N)."""
    return [sys.executable, "-I", "-S", "-c", _LAUNCHER, str(report), *command]


def read_measurement(report: Path) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds, peak RSS bytes) from a launcher's report."""
    seconds, cpu_seconds, max_rss_kib = report.read_text().split()
    return float(seconds), float(cpu_seconds), int(max_rss_kib) * 1024  # ru_maxrss is in KiB on Linux


def machine_ticks(stat: Path = Path("/proc/stat")) -> tuple[int, int] | None:
    """(steal, total) clock ticks of all CPUs since boot, from the "cpu" line of /proc/stat (Linux); None when it
    cannot be read. Total is user + nice + system + idle + iowait + irq + softirq + steal (guest time is already
    counted in user and nice)."""
    try:
        with stat.open() as f:
            fields = f.readline().split()
        ticks = [int(value) for value in fields[1:9]]
    except (OSError, ValueError):
        return None
    if not fields or fields[0] != "cpu" or len(ticks) < 8:
        return None
    return ticks[7], sum(ticks)


def ticks_between(before: tuple[int, int] | None, after: tuple[int, int] | None) -> tuple[int, int] | None:
    if before is None or after is None:
        return None
    return after[0] - before[0], after[1] - before[1]


def add_ticks(a: tuple[int, int] | None, b: tuple[int, int] | None) -> tuple[int, int] | None:
    return None if a is None or b is None else (a[0] + b[0], a[1] + b[1])


def steal_share(ticks: tuple[int, int] | None) -> float | None:
    """Stolen / all ticks; None when unknown or no tick elapsed."""
    if ticks is None or ticks[1] <= 0:
        return None
    return ticks[0] / ticks[1]


def run_measured(command: Sequence[str], *, cwd: Path | None = None) -> ChildRun:
    """Run a command to its end and measure it: wall and CPU seconds, and peak RSS from its wait4 rusage.

    stdout and stderr go to separate files: written to one file, a child's block-buffered stdout (any program
    whose stdout is not a terminal) lands after the error it wrote unbuffered to stderr, so "the last line"
    would depend on buffering. The one-line report is the last line of stderr, else of stdout."""
    with tempfile.TemporaryDirectory(prefix="ffviz-bench-") as tmp:
        report = Path(tmp) / "rusage"
        out_path, err_path = Path(tmp) / "stdout", Path(tmp) / "stderr"
        with out_path.open("wb") as out, err_path.open("wb") as err:  # files, not pipes: nobody reads meanwhile
            ticks_before = machine_ticks()
            # Own session: Ctrl-C reaches only this process, which then ends the launcher and command together.
            child = subprocess.Popen(measured_argv(command, report), stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                     cwd=cwd, start_new_session=True)
            try:
                returncode = child.wait()
            except BaseException:
                os.killpg(child.pid, signal.SIGKILL)
                child.wait()
                raise
            ticks = ticks_between(ticks_before, machine_ticks())
        stdout, stderr = (path.read_text("utf-8", "replace") for path in (out_path, err_path))
        if not report.is_file():  # the launcher itself failed
            raise RuntimeError(f"measuring launcher failed (exit {returncode}): {(stdout + stderr).strip()[-300:]}")
        seconds, cpu_seconds, peak = read_measurement(report)
    tail = _last_line(stderr) or _last_line(stdout)
    return ChildRun(seconds=seconds, cpu_seconds=cpu_seconds, peak_rss_bytes=peak, returncode=returncode,
                    output_tail=tail, machine_ticks=ticks)


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.replace("\r", "\n").splitlines() if line.strip()]
    return lines[-1] if lines else ""

