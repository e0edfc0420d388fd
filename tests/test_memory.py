"""The allocator settings (pipeline/runtime/memory.py): frame-sized arrays made and dropped again and again reuse
freed memory instead of faulting in fresh pages each time; the entry point applies them."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from pipeline.runtime import memory

_CHURN = textwrap.dedent("""
    import resource, sys
    import numpy as np
    from pipeline.runtime import memory
    if sys.argv[1] == "reuse":
        assert memory.reuse_freed_memory()
    for _ in range(2):  # warm up: the first blocks are fresh either way
        frames = [np.ones((720, 1280, 3), np.float32) for _ in range(4)]
        del frames
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for i in range(10):  # four 1280x720 float32 frames (11 MB each), written whole, then dropped
        frames = [np.full((720, 1280, 3), i, np.float32) for _ in range(4)]
        del frames
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
""")


def _faults(mode: str) -> int:
    done = subprocess.run([sys.executable, "-c", _CHURN, mode], capture_output=True, text=True, check=True)
    return int(done.stdout.split()[-1])


@pytest.mark.skipif(memory._libc() is None, reason="glibc's mallopt only")
def test_freed_frames_are_reused_instead_of_faulted_in_again():
    pages_a_frame = 720 * 1280 * 3 * 4 // 4096
    default, reused = _faults("default"), _faults("reuse")
    assert default > 5 * pages_a_frame  # glibc's defaults give back what exceeds twice the largest block freed
    assert reused < 2 * pages_a_frame  # the same blocks each time


def test_the_cli_sets_them_before_running_a_command(monkeypatch):
    from ffviz import cli

    calls = []
    monkeypatch.setattr(memory, "reuse_freed_memory", lambda: calls.append(True) or True)
    monkeypatch.setitem(cli.COMMANDS, "metrics", lambda args: 0)
    assert cli.main(["metrics", "in.mp4", "out.mp4"]) == 0
    assert calls == [True]
