"""The allocator thresholds the ``fleetslam`` command sets: a frame's buffers freed and allocated again do not come
back as fresh pages (page faults) every time."""

import json
import os
import subprocess
import sys

import pytest

from fleetslam.allocator import keep_freed_memory

#: One "frame": two 1 MB buffers alive at once, then freed (a message serialized and handed to Zenoh, which copies
#: it): with glibc's defaults the freed heap top is trimmed and each frame faults its pages in again (~480 here).
CHURN = """
import json, resource, sys
from fleetslam.allocator import keep_freed_memory
applied = keep_freed_memory() if sys.argv[1] == "tuned" else None
for _ in range(5):  # warm-up: glibc's thresholds adapt to the first frees
    a = b"x" * (1 << 20); b = a + b"y"; del a, b
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(100):
    a = b"x" * (1 << 20); b = a + b"y"; del a, b
print(json.dumps({"applied": applied, "faults": (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 100}))
"""


def _churn(mode: str) -> dict[str, float]:
    env = {k: v for k, v in os.environ.items() if k not in ("GLIBC_TUNABLES", "MALLOC_TRIM_THRESHOLD_")}
    out = subprocess.run([sys.executable, "-c", CHURN, mode], env=env, capture_output=True, text=True, check=True)
    figures: dict[str, float] = json.loads(out.stdout)
    return figures


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_frames_are_reused_without_page_faults() -> None:
    tuned = _churn("tuned")
    if not tuned["applied"]:
        pytest.skip("the C library has no mallopt (not glibc)")
    assert tuned["faults"] < 20  # a 1 MB block is 256 pages: not faulted in again (glibc 2.36's defaults: ~480)


def test_allocator_settings_in_the_environment_are_left_to_win() -> None:
    assert keep_freed_memory({"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=0"}) is False
    assert keep_freed_memory({"MALLOC_TRIM_THRESHOLD_": "1000"}) is False
