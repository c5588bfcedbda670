"""Camera rigs for the synthetic scenes: LLFF-like forward-facing grids and 360° rings.

All cameras are :class:`~divas_engine.camera.Camera` (OpenCV convention) built
with ``Camera.look_at``; world up is +z.
"""

from __future__ import annotations

import math

import numpy as np

from ..camera import Camera

__all__ = ["Intrinsics", "forward_facing_rig", "ring_rig", "half_ring_rigs"]

UP = np.array([0.0, 0.0, 1.0])


class Intrinsics:
    """Shared pinhole intrinsics of a rig (principal point at the image centre)."""

    def __init__(self, width: int = 640, height: int = 480, fx: float = 600.0):
        self.width, self.height, self.fx = int(width), int(height), float(fx)

    def camera(self, eye, target, name: str) -> Camera:
        return Camera.look_at(
            eye, target, UP, width=self.width, height=self.height, fx=self.fx, name=name
        )


def forward_facing_rig(
    rng: np.random.Generator,
    intr: Intrinsics,
    *,
    center,
    look_at,
    rows: int,
    cols: int,
    step: tuple[float, float],
    jitter: float,
    aim_jitter: float,
    prefix: str,
    offset: tuple[float, float] = (0.0, 0.0),
    depth_offset: float = 0.0,
) -> list[Camera]:
    """A jittered planar grid of cameras facing ``look_at`` (LLFF-like).

    The grid plane is perpendicular to the horizontal viewing direction through
    ``center``; ``step`` is the (horizontal, vertical) spacing, ``offset`` shifts
    the grid in units of ``step`` (test cameras sit between training positions),
    ``jitter`` is the uniform position noise as a fraction of ``step`` and
    ``aim_jitter`` the look-at noise in world units.
    """
    center, look_at = np.asarray(center, float), np.asarray(look_at, float)
    fwd = look_at - center
    fwd[2] = 0.0
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, UP)
    right /= np.linalg.norm(right)
    cams = []
    for r in range(rows):
        for c in range(cols):
            gx = (c - (cols - 1) / 2 + offset[0] + jitter * rng.uniform(-1, 1)) * step[0]
            gz = ((rows - 1) / 2 - r + offset[1] + jitter * rng.uniform(-1, 1)) * step[1]
            gy = depth_offset + jitter * 0.5 * step[0] * rng.uniform(-1, 1)
            eye = center + gx * right + gz * UP + gy * fwd
            tgt = look_at + aim_jitter * rng.uniform(-1, 1, 3)
            cams.append(intr.camera(eye, tgt, f"{prefix}{len(cams):03d}"))
    return cams


def ring_rig(
    rng: np.random.Generator,
    intr: Intrinsics,
    *,
    center,
    radius: float,
    elevations_deg: list[float],
    counts: list[int],
    prefix: str,
    az_range_deg: tuple[float, float] = (0.0, 360.0),
    az_offset: float = 0.0,
    radius_jitter: float = 0.0,
    angle_jitter_deg: float = 0.0,
    aim_jitter: float = 0.0,
) -> list[Camera]:
    """Cameras on horizontal rings around ``center`` looking at it.

    ``az_offset`` shifts each ring by that fraction of its azimuth step (0.5 puts
    test cameras between training ones). A range narrower than 360° is sampled
    end-to-end inclusive (a half ring); a full circle exclusive of its end.
    """
    center = np.asarray(center, float)
    a0, a1 = az_range_deg
    full = (a1 - a0) >= 360.0 - 1e-9
    cams = []
    for ring, (elev, n) in enumerate(zip(elevations_deg, counts)):
        if full:
            az = a0 + (np.arange(n) + az_offset + 0.37 * ring) * (a1 - a0) / n
        else:
            step = (a1 - a0) / max(n - 1, 1)
            az = a0 + (np.arange(n) + az_offset) * step
        for a in az:
            aa = math.radians(a + angle_jitter_deg * rng.uniform(-1, 1))
            ee = math.radians(elev + angle_jitter_deg * rng.uniform(-1, 1))
            rr = radius * (1.0 + radius_jitter * rng.uniform(-1, 1))
            eye = center + rr * np.array(
                [math.cos(ee) * math.cos(aa), math.cos(ee) * math.sin(aa), math.sin(ee)]
            )
            tgt = center + aim_jitter * rng.uniform(-1, 1, 3)
            cams.append(intr.camera(eye, tgt, f"{prefix}{len(cams):03d}"))
    return cams


def half_ring_rigs(
    rng: np.random.Generator,
    intr: Intrinsics,
    *,
    center,
    radius: float,
    elevations_deg: list[float],
    test_elevation_deg: float,
) -> tuple[list[Camera], list[Camera]]:
    """Training and test cameras on the front half ring (azimuth −165° … −15°) of a
    scene against a wall: 30 training cameras per elevation (jittered: radius 3 %,
    angles 1°, aim 0.02), 8 test cameras at ``test_elevation_deg`` between them."""
    train = ring_rig(
        rng,
        intr,
        center=center,
        radius=radius,
        elevations_deg=list(elevations_deg),
        counts=[30] * len(elevations_deg),
        prefix="train_",
        az_range_deg=(-165, -15),
        radius_jitter=0.03,
        angle_jitter_deg=1.0,
        aim_jitter=0.02,
    )
    test = ring_rig(
        rng,
        intr,
        center=center,
        radius=radius,
        elevations_deg=[test_elevation_deg],
        counts=[8],
        prefix="test_",
        az_range_deg=(-165, -15),
        az_offset=0.5,
        aim_jitter=0.02,
    )
    return train, test
