"""The C allocator's settings for a run that allocates and frees frame-sized arrays on every frame.

glibc serves a request above its mmap threshold (128 KiB at first, raised on the fly to the largest block freed)
with a fresh mapping and gives it back to the kernel when freed; below it, from a heap whose free top is handed
back once it exceeds the trim threshold. Each fresh page then costs a page fault and the kernel's zeroing on first
touch. A stabilize run makes and drops megabyte arrays (decoded frames, warps, float planes) many times a frame, from
several threads, so with the dynamic thresholds it touches fresh pages for several times the video's decoded size:
system time of the order of a tenth of the whole run. ``reuse_freed_memory`` fixes both thresholds so that freed
blocks stay in the process and are reused, and caps the arenas (a heap each, its own lock) at two: with one per
thread, each kept up to the trim threshold free, and at 1080p (arrays of 6-25 MB) the peak rose above the dynamic
thresholds' own; with one for all threads, their lock was contended (more CPU at 360p).

Invariants: only where the allocation goes changes, never what is computed; the peak resident size stays within
about the trim threshold of what the run holds at once, whatever the video's length (freed memory is reused, not
accumulated).
A process-wide setting, so it is made by the program's entry point (ffviz/cli.py), never on import.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys

# mallopt's parameter numbers (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
# Blocks up to this size come from the heaps (glibc refuses more than half its 64 MiB per-thread heap): a float32
# RGB 1080p frame is 25 MB.
MMAP_THRESHOLD = 32 * 1024 * 1024
# A heap keeps up to this much free memory at its top instead of returning it: several frames' worth of arrays.
TRIM_THRESHOLD = 128 * 1024 * 1024
# Threads share two heaps (module docstring): the frame workers, the decoder, x264 and the main thread on one each
# would hold more memory; on a single one they wait for its lock.
ARENAS = 2


def reuse_freed_memory() -> bool:
    """Set both glibc thresholds and the number of arenas (the module docstring); True when they were set, False
    elsewhere (not Linux, not glibc: nothing changes). Both thresholds at once: setting one turns off the dynamic
    adjustment of the other, and the trim threshold alone at its 128 KiB default returns more memory than before."""
    libc = _libc()
    if libc is None:
        return False
    try:
        return all([bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)),
                    bool(libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)), bool(libc.mallopt(_M_ARENA_MAX, ARENAS))])
    except AttributeError:  # a C library without mallopt
        return False


@functools.lru_cache(maxsize=1)
def _libc() -> ctypes.CDLL | None:
    if not sys.platform.startswith("linux"):
        return None
    name = ctypes.util.find_library("c") or "libc.so.6"
    try:
        libc = ctypes.CDLL(name)
    except OSError:
        return None
    return libc if hasattr(libc, "gnu_get_libc_version") else None  # musl's mallopt does nothing
