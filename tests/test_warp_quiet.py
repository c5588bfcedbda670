"""Warp stays off the user's terminal on a CPU-only machine: no init banner, no per-module
load lines and no "Could not find or load the NVIDIA CUDA driver" line, while stderr
works again right after (the mute covers the init only)."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import numpy as np
import divas_kernels as k
dev = k.resolve_device("auto")
a = k.to_device(np.arange(4, dtype=np.int32), dev)
print("ok", str(dev), int(a.numpy().sum()))
import os
os.write(2, b"stderr restored after init\\n")
"""


def test_no_warp_noise_on_stderr_and_stderr_restored():
    r = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().startswith("ok ") and r.stdout.strip().endswith(" 6")
    assert "CUDA driver" not in r.stderr and "initialized" not in r.stderr
    assert "Module " not in r.stdout + r.stderr  # no per-module load lines
    assert "stderr restored after init" in r.stderr


def test_driver_probe_matches_warp(device):
    """The probe that decides the mute agrees with what Warp found."""
    import warp as wp

    from divas_kernels import _launch

    wp.init()
    if _launch._cuda_driver_loadable() is False:
        assert wp.get_cuda_device_count() == 0
