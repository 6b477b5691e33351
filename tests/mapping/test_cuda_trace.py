"""The optional GPU walk: identical maps in numba's CUDA simulator, and a compiled kernel without FMA.

No GPU is needed: the simulator runs the kernel's Python on the CPU (in a subprocess, because the simulator is
chosen when numba.cuda is first imported), and the PTX is compiled with NVVM alone when the CUDA toolkit is
installed.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap

import pytest

SIMULATED_RUN = textwrap.dedent(
    """
    import numpy as np
    from fleetslam.mapping.cuda_trace import cuda_available
    from fleetslam.mapping.octree import OccupancyOctree

    assert cuda_available()
    rng = np.random.default_rng(3)
    res = 0.05
    steps = (-1.0, 0.0, 0.5, 1.0)
    diagonals = np.array([(x, y, z) for x in steps for y in steps for z in steps if (x, y, z) != (0, 0, 0)])
    scans = [
        (rng.normal(size=(150, 3)) * 0.6, np.zeros(3)),
        (np.array([0.05, -0.1, 0.15]) + diagonals * 0.7, np.array([0.05, -0.1, 0.15])),
        (rng.uniform(-0.8, 0.8, size=(120, 3)) + 0.3, np.array([0.3, 0.3, 0.311])),
    ]
    cpu = OccupancyOctree(res, accelerator="cpu")
    for points, origin in scans:
        cpu.insert_point_cloud(points.astype(np.float32), origin.astype(np.float32))
    b = cpu.leaves()
    # The simulator runs kernels as Python on its own array objects, which compiled CPU functions cannot take:
    # the walk's device functions run from their Python source (the same source the GPU compiles).
    from fleetslam.mapping import _kernels as K
    for name in ("_walk_ray", "_walk_slabs", "_before"):
        setattr(K, name, getattr(K, name).py_func)
    gpu = OccupancyOctree(res, accelerator="cuda")
    for points, origin in scans:
        gpu.insert_point_cloud(points.astype(np.float32), origin.astype(np.float32))
    a = gpu.leaves()
    assert len(a) > 100, len(a)
    assert np.array_equal(a.keys, b.keys) and np.array_equal(a.depths, b.depths)
    assert np.array_equal(a.log_odds, b.log_odds)
    print("identical", len(a))
    """
)


def test_gpu_walk_in_the_cuda_simulator_gives_the_cpu_map() -> None:
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    done = subprocess.run(
        [sys.executable, "-c", SIMULATED_RUN], env=env, capture_output=True, text=True, timeout=600, check=False
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.startswith("identical")


def test_gpu_kernel_compiles_to_additions_and_comparisons_only() -> None:
    """No fused multiply-add, multiplication, division or square root in floating point: the walk's rounding is
    the CPU's. Needs NVVM (the CUDA toolkit), not a GPU."""
    from numba.cuda.cudadrv.error import NvvmSupportError

    from fleetslam.mapping.cuda_trace import kernel_ptx

    try:
        ptx = kernel_ptx((8, 0))
    except NvvmSupportError as err:
        pytest.skip(f"no NVVM: {err}")
    float_ops = set(re.findall(r"\b((?:fma|mul|div|sqrt|add|sub|setp)\.[a-z.]*f(?:32|64))\b", ptx))
    assert any(op.startswith("add.") and op.endswith("f64") for op in float_ops), float_ops
    assert any(op.startswith("setp.") for op in float_ops), float_ops
    assert not {op for op in float_ops if op.split(".")[0] in ("fma", "mul", "div", "sqrt")}, float_ops


def test_cuda_accelerator_without_a_gpu_is_refused() -> None:
    from fleetslam.mapping.cuda_trace import cuda_available
    from fleetslam.mapping.octree import OccupancyOctree

    if cuda_available():
        pytest.skip("a GPU is present")
    with pytest.raises(ValueError, match="CUDA GPU"):
        OccupancyOctree(0.05, accelerator="cuda")
    with pytest.raises(ValueError, match="accelerator"):
        OccupancyOctree(0.05, accelerator="tpu")
