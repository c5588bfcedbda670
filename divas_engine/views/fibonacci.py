"""Fibonacci-sphere candidate directions (paper App. C.1, eq:fib).

θ_i = 2π i φ⁻¹ (golden-angle azimuth), polar angle φ_i = arccos(1 − 2(i + ½)/N).

Deviation (documented): the paper writes arccos(1 − 2i/N), i = 0..N−1, which puts
sample 0 exactly on the pole (a straight top-down view whose image-up is undefined)
and leaves the sphere asymmetric (z from +1 down to −1 + 2/N). The half-index
offset is the standard equal-area form of the same lattice (each sample is the
centre of one of N equal-area latitude bands) and is symmetric.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["fibonacci_sphere", "up_frame"]

GOLDEN_RATIO = (1.0 + math.sqrt(5.0)) / 2.0


def fibonacci_sphere(n: int) -> np.ndarray:
    """``[n,3]`` unit directions in a local frame whose +z is the scene up."""
    if n < 1:
        raise ValueError(f"fibonacci_sphere: n must be ≥ 1, got {n}")
    i = np.arange(n, dtype=np.float64)
    theta = 2.0 * math.pi * i / GOLDEN_RATIO
    polar = np.arccos(np.clip(1.0 - 2.0 * (i + 0.5) / n, -1.0, 1.0))
    return np.stack(
        [np.sin(polar) * np.cos(theta), np.sin(polar) * np.sin(theta), np.cos(polar)], axis=1
    )


def up_frame(up: np.ndarray, front: np.ndarray | None = None) -> np.ndarray:
    """``[3,3]`` rotation whose columns are the up-aligned canonical axes (x, y, z = up).

    ``x`` is the part of ``front`` perpendicular to ``up`` (e.g. the direction from
    the scene centre towards the mean training camera: the "front" view); without
    it, or when it is parallel to ``up``, the world axis least aligned with ``up``.
    """
    z = np.asarray(up, dtype=np.float64)
    z = z / np.linalg.norm(z)
    x = None
    if front is not None:
        f = np.asarray(front, dtype=np.float64)
        f = f - (f @ z) * z
        if np.linalg.norm(f) > 1e-6:
            x = f / np.linalg.norm(f)
    if x is None:
        e = np.eye(3)[int(np.argmin(np.abs(z)))]
        x = e - (e @ z) * z
        x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)
