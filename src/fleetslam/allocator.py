"""How fleetslam's processes ask glibc's allocator to keep the memory they free for their next frame.

A camera frame's worth of NumPy, OpenCV and message buffers is allocated and freed again at every frame. With
glibc's defaults a freed block of more than 128 KiB goes back to the system (``munmap``, or a heap trimmed at its
top), so the next frame's block of the same size comes back as fresh pages, each one a page fault when first
written: measured on this project's 2-vCPU machine, SLAM on a 640×480 cell took 705–729 minor faults per frame,
57 with the thresholds below, and 37.3–37.7 instead of 41.5 ms of CPU per frame (same trajectory to the digit); a
publisher's serialize-and-put loop of 1 MB Images took 57 µs or ~1 ms per message depending on whether glibc had
just trimmed. Keeping up to :data:`TRIM_THRESHOLD_BYTES` free at the heap's top costs no more resident memory than
the process's own peak.

The ``fleetslam`` command applies it to its process (every node the launcher starts); a program that imports
fleetslam as a library keeps its allocator as it is unless it calls :func:`keep_freed_memory` itself. Settings
given in the environment (``GLIBC_TUNABLES``, ``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_MMAP_THRESHOLD_``) are left
to win.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Mapping

MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
"""Blocks up to this size come from the heap, not from ``mmap`` (glibc's largest allowed value on 64-bit)."""
TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024
"""Free memory at the heap's top kept before it is handed back to the system."""

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_ENVIRONMENT_SETTINGS = ("GLIBC_TUNABLES", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_")


def keep_freed_memory(environ: Mapping[str, str] | None = None) -> bool:
    """Set glibc's mmap and trim thresholds (:data:`MMAP_THRESHOLD_BYTES`, :data:`TRIM_THRESHOLD_BYTES`) for this
    process; True when they were set. Nothing is done off Linux, with another C library (no ``mallopt``), or when
    the environment already tunes the allocator."""
    environ = os.environ if environ is None else environ
    if not sys.platform.startswith("linux") or any(environ.get(name) for name in _ENVIRONMENT_SETTINGS):
        return False
    try:
        # The C library already loaded into this process (the allocator it runs on); find_library would spawn
        # ldconfig at every command's start.
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # musl and others have no mallopt
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    mmap_set = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
    trim_set = mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    return bool(mmap_set and trim_set)
